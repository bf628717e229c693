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
from typing import TYPE_CHECKING

from dockhil.devices import tare
from dockhil.devices.can_ft import frames as ff
from dockhil.devices.can_ft import multicast as can_multicast
from dockhil.devices.can_ft.slcan_reader import SlcanReader
from dockhil.devices.device_path import private_link, untrusted
from dockhil.devices.ft_base import FtDriver, Raw, problems_line, tare_params
from dockhil.errors import DeviceError
from dockhil.node import Param
from dockhil.runtime import ownership

if TYPE_CHECKING:
    import can

# A step reads at most this many frames, so a flooded bus cannot stall the loop.
MAX_FRAMES_PER_STEP = 512


def one_line(exc: BaseException) -> str:
    """An exception and its cause as one line (python-can wraps the useful part)."""
    text = str(exc) or type(exc).__name__
    cause = exc.__cause__
    if cause is not None and str(cause) and str(cause) not in text:
        text += f" ({cause})"
    return " ".join(text.split())


class FtCanDriver(FtDriver):
    """F/T sensor over CAN: tare (or a given bias, checked) at the graph's first start, stale-data and bus-error detection."""

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
        **tare_params(
            stale_help="no new sample for this long is an error",
            open_help="time for the device to appear and start streaming",
            frame="",
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
    }

    @classmethod
    def resolve_params(cls, node_name: str, given: dict) -> dict:
        values = super().resolve_params(node_name, given)
        can_multicast.check_params(node_name, values)
        return values

    # -- the device's part (the sequence is FtDriver's) ------------------------------
    def _open(self) -> None:
        p = self.p
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
        self.lost = 0
        self.repeated = 0
        self.bad_frames = 0
        self.error_frames = 0
        self._error_run = 0
        self._last_seq: int | None = None
        self._bad_logged = 0
        channel = os.path.abspath(p.channel) if p.interface == "slcan" else p.channel
        self._lock: ownership.DeviceLock | None = ownership.claim(
            f"can-{p.interface}-{channel}", f"F/T adapter ({p.interface} {p.channel})"
        )
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
            self.bus: can.BusABC | None = self._open_bus(time.monotonic() + p.open_timeout)
            # python-can's slcan reads a byte per system call; the adapter's port is read in bulk.
            self.slcan = (
                SlcanReader(self.bus.serialPortOrig)  # type: ignore[attr-defined]  # slcan's bus has it
                if p.interface == "slcan"
                else None
            )
            self.recv = self.slcan.recv if self.slcan is not None else self.bus.recv
        except BaseException:
            self._shutdown()
            raise

    def _release_claims(self) -> None:
        if self._lock is not None:
            self._lock.release()
        if self._bus_claim is not None:
            self._bus_claim.release()

    def _open_bus(self, deadline: float) -> can.BusABC:
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

    def _on_loopback(self, bus: can.BusABC) -> None:
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

    def _first_samples(self, want: int) -> list[Raw]:
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
        return [(s.force, s.torque) for s in got[:want]]

    def _read(self) -> Raw | None:
        samples = self._read_samples()
        return (samples[-1].force, samples[-1].torque) if samples else None  # one message per tick: the newest

    def _is_open(self) -> bool:
        return getattr(self, "bus", None) is not None

    def _shutdown(self) -> None:
        self._shutdown_bus()
        if getattr(self, "_lock", None) is not None:
            self._release_claims()
            self._lock = None

    def _shutdown_bus(self) -> None:
        bus = getattr(self, "bus", None)
        if bus is not None:
            self.bus = None
            try:
                bus.shutdown()
            except Exception:  # the device may already be gone; closing must not raise
                pass

    def _report(self) -> list[str]:
        return problems_line(
            self.device,
            (
                (self.lost, "samples lost"),
                (self.repeated, "samples repeated"),
                (self.bad_frames + (self.slcan.malformed if self.slcan is not None else 0), "bad frames"),
                (self.error_frames, "error frames"),
                (self.assembler.orphans, "unpaired frames"),
            ),
        )
