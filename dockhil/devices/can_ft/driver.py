"""F/T sensor driver over CAN (python-can): publishes /ft/wrench from the sensor's frames.

The frame layout is in dockhil/devices/can_ft/frames.py. The stale-data
watchdog runs on the runtime's clock (tick.t), never on time.*. python-can is imported
in setup(), so a scene that does not use this driver never loads it.
One graph per adapter: setup claims the interface and channel (a lock file
naming the owner) before it opens anything; close() lets go. A serial channel
another user could plant or replace is refused before a sample is read
(dockhil/devices/device_path.py), and a restart within the graph keeps the
graph's first tare (dockhil/devices/tare.py): it may come back in contact.
"""

from __future__ import annotations

import os
import time

from dockhil.runtime import ownership
from dockhil.errors import DeviceError, LaunchError
from dockhil.devices.can_ft import multicast as can_multicast
from dockhil.devices.can_ft import frames as ff
from dockhil.devices import tare
from dockhil.devices.device_path import private_link, untrusted
from dockhil.devices.can_ft.slcan_reader import SlcanReader
from dockhil.node import Node, Output, Param
from dockhil.msgs import Vector3, Wrench, WrenchStamped

# A step reads at most this many frames, so a flooded bus cannot stall the loop.
MAX_FRAMES_PER_STEP = 512


def one_line(exc: BaseException) -> str:
    """An exception and its cause as one line (python-can wraps the useful part)."""
    text = str(exc) or type(exc).__name__
    cause = exc.__cause__
    if cause is not None and str(cause) and str(cause) not in text:
        text += f" ({cause})"
    return " ".join(text.split())


class FtCanDriver(Node):
    """F/T sensor over CAN: tare (or a given bias, checked) at the graph's first start, stale-data and bus-error detection."""

    outputs = {"wrench": Output(WrenchStamped, "/ft/wrench", help="wrench the contact exerts on the chaser")}
    params = {
        "interface": Param(
            str,
            "slcan",
            help="python-can interface: slcan, socketcan, udp_multicast, pcan, virtual, ...; pty: slcan "
            "on an emulated adapter's pseudo-terminal",
        ),
        "channel": Param(
            str,
            "",
            help="python-can channel: serial port, can0, multicast group, ... (slcan, empty: the emulator's "
            "link ft.slcan in the graph's private run directory)",
        ),
        "loopback": Param(
            bool,
            True,
            help="udp_multicast: the group on this host's loopback, its own datagrams alone "
            "(false: python-can's choice, the routed interface)",
        ),
        "bitrate": Param(int, 1_000_000, unit="bit/s", help="CAN bitrate", gt=0, le=1_000_000),
        **ff.frame_params(),
        "sign": Param(float, 1.0, help="-1 if the sensor reports the force on the target side", choices=(1.0, -1.0)),
        "tare_samples": Param(
            int,
            100,
            help="samples averaged into the bias at the graph's first start (0: raw readings, no "
            "tare and no given bias); nothing may touch the probe meanwhile. A restart keeps the first tare",
            ge=0,
            le=100_000,
        ),
        "bias": Param(
            list,
            [],
            unit="N, N m",
            help="[fx, fy, fz, tx, ty, tz] the unloaded probe reads untared (the loop file's tare): "
            "subtracted instead of a tare at start, whose samples only check it (tare.mismatch); [] tares",
        ),
        "bias_from": Param(str, "", help="where the bias comes from (the loop file), named when it is refused"),
        # A tare takes whatever loads the probe at start for the sensor's offset, and every force limit downstream
        # would then miss it: a large bias means the probe is pressed, a large spread that it moved while taring.
        "max_bias": Param(
            float,
            50.0,
            unit="N",
            help="largest tare bias |F| accepted; more means something "
            "loads the probe at start (raise it for a heavy tool; 0: off)",
            ge=0.0,
            le=10_000.0,
        ),
        "max_bias_torque": Param(
            float, 5.0, unit="N m", help="largest tare bias |T| accepted (0: off)", ge=0.0, le=1_000.0
        ),
        "max_tare_spread": Param(
            float,
            2.0,
            unit="N",
            help="largest standard deviation of a force axis over the "
            "tare samples (the noise band); more means the probe moved or was touched while "
            "taring (0: off)",
            ge=0.0,
            le=1_000.0,
        ),
        "max_tare_spread_torque": Param(
            float,
            0.2,
            unit="N m",
            help="largest standard deviation of a torque axis over the tare samples (0: off)",
            ge=0.0,
            le=100.0,
        ),
        "stale_timeout": Param(float, 0.1, unit="s", help="no new sample for this long is an error", gt=0.0, le=10.0),
        "open_timeout": Param(
            float, 2.0, unit="s", help="time for the device to appear and start streaming", gt=0.0, le=120.0
        ),
        "max_bus_errors": Param(
            int, 10, help="error frames in a row without a valid sample that are an error", ge=1, le=100_000
        ),
        "open_delay": Param(
            float,
            0.0,
            unit="s",
            help="slcan only: wait after opening the serial port (adapters that reset on open need ~2 s)",
            ge=0.0,
            le=30.0,
        ),
        "frame": Param(str, "", help="header frame id of the published wrench"),
    }

    @classmethod
    def resolve_params(cls, node_name: str, given: dict) -> dict:
        values = super().resolve_params(node_name, given)
        tare.check_bias_param(node_name, values)
        can_multicast.check_params(node_name, values)
        return values

    def setup(self) -> None:
        p = self.p
        if self.ctx.sim_time:
            raise LaunchError(
                f"node {self.ctx.name!r} reads a real F/T sensor and runs only in wall time (launch with --wall-time)"
            )
        import can  # here, not at module import: only scenes with this driver load python-can

        self._can = can
        if p.interface == "pty":  # the emulator's adapter on a pseudo-terminal speaks slcan
            p.interface = "slcan"
        if not p.channel and p.interface == "slcan":
            p.channel = private_link("ft.slcan")
        # A path others could plant or replace would feed us their forces: checked before and after each open.
        self._path = p.channel.split("@")[0] if p.interface == "slcan" or "/" in p.channel else None
        self.device = f"F/T sensor ({p.interface} {p.channel}, CAN ID {p.can_id:#05x})"
        self.scaling = ff.FtScaling(p.force_resolution, p.torque_resolution)
        self.assembler = ff.SampleAssembler()
        self.bias_force = (0.0, 0.0, 0.0)
        self.bias_torque = (0.0, 0.0, 0.0)
        self.lost = 0
        self.repeated = 0
        self.bad_frames = 0
        self.error_frames = 0
        self._error_run = 0
        self._last_seq: int | None = None
        self._last_fresh_t: float | None = None
        self._bad_logged = 0
        channel = os.path.abspath(p.channel) if p.interface == "slcan" else p.channel
        self._lock = ownership.claim(f"can-{p.interface}-{channel}", f"F/T adapter ({p.interface} {p.channel})")
        # The bus itself is this graph's while the driver reads it: another graph's emulator would
        # stream frames with the sensor's IDs (a serial slcan adapter is a point-to-point link: its
        # path is the claim above).
        self._bus_claim = None
        if p.interface != "slcan":
            try:
                self._bus_claim = ownership.claim_for_graph(
                    f"can-bus-{p.interface}-{channel}", f"CAN bus {p.interface} {p.channel}"
                )
            except BaseException:
                self._lock.release()
                raise
        try:
            self.bus = self._open_bus(time.monotonic() + p.open_timeout)
            # python-can's slcan reads a byte per system call; the adapter's port is read in bulk.
            self.slcan = SlcanReader(self.bus.serialPortOrig) if p.interface == "slcan" else None
            self.recv = self.slcan.recv if self.slcan is not None else self.bus.recv
            self._tare()
        except BaseException:
            self._shutdown_bus()
            self._release_claims()
            raise

    def _release_claims(self) -> None:
        self._lock.release()
        if self._bus_claim is not None:
            self._bus_claim.release()

    def _open_bus(self, deadline: float):
        can, p = self._can, self.p
        kwargs = {}
        if p.interface == "slcan":
            # Non-blocking serial reads: recv(0) must not wait a serial timeout per step.
            kwargs = {"sleep_after_open": p.open_delay, "timeout": 0.0}
        multicast = p.interface == "udp_multicast" and p.loopback
        while True:
            self._check_path()
            try:
                # No ID filters: several interfaces filter error frames with them,
                # and foreign frames cost only a comparison in decode_frame.
                bus = can.Bus(interface=p.interface, channel=p.channel, bitrate=p.bitrate, **kwargs)
                if multicast:
                    self._on_loopback(bus)
            except (can.CanInterfaceNotImplementedError, ValueError, TypeError) as exc:
                raise DeviceError(f"{self.device}: cannot open: {one_line(exc)}") from None
            except (can.CanError, OSError) as exc:
                if multicast:  # no route for the group: waiting will not make one
                    raise DeviceError(can_multicast.join_failure(self.device, p.channel, exc)) from None
                # The device may still be appearing (adapter enumerating, emulator starting).
                if time.monotonic() >= deadline:
                    raise DeviceError(f"{self.device}: cannot open: {one_line(exc)}") from None
                time.sleep(0.05)
                continue
            try:  # planted between the check and the open: refused before a sample is read
                self._check_path()
            except BaseException:
                bus.shutdown()
                raise
            return bus

    def _on_loopback(self, bus) -> None:
        try:
            can_multicast.on_loopback(bus, self.p.channel)
        except OSError as exc:
            bus.shutdown()
            raise DeviceError(can_multicast.join_failure(self.device, self.p.channel, exc)) from None

    def _check_path(self) -> None:
        why = untrusted(self._path) if self._path else None
        if why:
            raise DeviceError(
                f"{self.device}: refused: {why}; whoever can plant or replace it feeds this driver "
                f"its forces: use a device in /dev, or a path in a directory only you can write "
                f"(leave channel empty for the emulator's link in the graph's private run directory)"
            )

    def _read_samples(self) -> list[ff.FtSample]:
        """New samples on the bus, oldest first; raises DeviceError on bus and sensor faults."""
        can = self._can
        samples = []
        for _ in range(MAX_FRAMES_PER_STEP):
            try:
                msg = self.recv(0.0)
            except (can.CanError, OSError) as exc:
                raise DeviceError(f"{self.device}: bus error: {one_line(exc)}") from None
            if msg is None:
                break
            if msg.is_error_frame:
                self.error_frames += 1
                self._error_run += 1
                if self._error_run >= self.p.max_bus_errors:
                    raise DeviceError(
                        f"{self.device}: bus error: {self._error_run} error frames in a row "
                        f"(check wiring, termination and bitrate {self.p.bitrate})"
                    )
                continue
            try:
                half = ff.decode_frame(
                    msg.arbitration_id,
                    msg.data,
                    self.p.can_id,
                    self.scaling,
                    is_extended_id=msg.is_extended_id,
                    is_remote_frame=msg.is_remote_frame,
                )
            except ff.FrameError as exc:
                self.bad_frames += 1
                if self._bad_logged < 5:  # the first few tell the story; the count is logged at close
                    self._bad_logged += 1
                    self.log(f"warning: {self.device}: dropped a bad frame: {exc}")
                continue
            if half is None:
                continue
            sample = self.assembler.add(half)
            if sample is None:
                continue
            self._error_run = 0
            if sample.seq == self._last_seq:
                self.repeated += 1  # a stuck sensor repeats itself; not new data
                continue
            if self._last_seq is not None:
                self.lost += (sample.seq - self._last_seq - 1) % 256
            self._last_seq = sample.seq
            if sample.status & (ff.STATUS_FAULT | ff.STATUS_OVERRANGE):
                raise DeviceError(
                    f"{self.device}: sensor reports {ff.describe_status(sample.status)} "
                    f"(raw force {tare.fmt(sample.force)} N, torque {tare.fmt(sample.torque)} N m)"
                )
            samples.append(sample)
        return samples

    def _tare(self) -> None:
        """Tare at the graph's first start; a restart keeps that tare (it may come back in contact)."""
        p = self.p
        limits = tare.TareLimits(p.max_bias, p.max_bias_torque, p.max_tare_spread, p.max_tare_spread_torque)
        bias = tare.graph_tare(
            self.ctx.name,
            self.device,
            p.tare_samples,
            limits,
            lambda n: [(s.force, s.torque) for s in self._first_samples(n)],
            self.log,
            given=tare.given_bias(p.bias, p.sign),
            given_from=p.bias_from,
        )
        if bias is not None:
            self.bias_force, self.bias_torque = bias.force, bias.torque

    def _first_samples(self, want: int) -> list[ff.FtSample]:
        """The first `want` samples the sensor streams, within open_timeout (each budget)."""
        p = self.p
        got: list[ff.FtSample] = []
        deadline = time.monotonic() + p.open_timeout
        while len(got) < want:
            new = self._read_samples()
            if new and not got:
                # Streaming: allow the tare its own time budget from the first sample on.
                deadline = time.monotonic() + p.open_timeout
            got.extend(new)
            if len(got) >= want:
                break
            if time.monotonic() >= deadline:
                if not got:
                    raise DeviceError(
                        f"{self.device}: no F/T frames on CAN IDs {p.can_id:#05x}/{p.can_id + 1:#05x} within "
                        f"{p.open_timeout:g} s: is the sensor powered, streaming, and at {p.bitrate} bit/s?"
                    )
                raise DeviceError(f"{self.device}: only {len(got)} of {want} tare samples within {p.open_timeout:g} s")
            time.sleep(0.0005)
        return got[:want]

    def step(self, tick, inputs):
        samples = self._read_samples()
        t = tick.t  # the runtime's clock (a test chooses it), so "stale after 0.1 s" is decided exactly
        if self._last_fresh_t is None:
            self._last_fresh_t = t  # the stale clock starts with the first tick
        if not samples:
            age = t - self._last_fresh_t
            if age > self.p.stale_timeout:
                raise DeviceError(
                    f"{self.device}: stale data: no new sample for {age:.3f} s (stale_timeout {self.p.stale_timeout:g} s)"
                )
            return {}  # nothing new: publish nothing rather than repeat an old sample
        self._last_fresh_t = t
        s = samples[-1]  # one message per tick: the newest sample
        sign = self.p.sign
        force = Vector3(*(sign * (s.force[i] - self.bias_force[i]) for i in range(3)))
        torque = Vector3(*(sign * (s.torque[i] - self.bias_torque[i]) for i in range(3)))
        return {"wrench": WrenchStamped(header=tick.header(self.p.frame), wrench=Wrench(force=force, torque=torque))}

    def _shutdown_bus(self) -> None:
        bus = getattr(self, "bus", None)
        if bus is not None:
            self.bus = None
            try:
                bus.shutdown()
            except Exception:  # the device may already be gone; closing must not raise
                pass

    def close(self) -> None:
        if getattr(self, "bus", None) is None:
            return
        self._shutdown_bus()
        self._release_claims()
        problems = [
            f"{n} {what}"
            for n, what in (
                (self.lost, "samples lost"),
                (self.repeated, "samples repeated"),
                (self.bad_frames + (self.slcan.malformed if self.slcan is not None else 0), "bad frames"),
                (self.error_frames, "error frames"),
                (self.assembler.orphans, "unpaired frames"),
            )
            if n
        ]
        if problems:
            self.log(f"warning: {self.device}: {', '.join(problems)}")
