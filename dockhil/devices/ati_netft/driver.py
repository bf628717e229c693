"""F/T sensor driver for the ATI Net F/T box (RDT over UDP): publishes /ft/wrench.

The protocol is in dockhil/devices/ati_netft/protocol.py. The box is the clock: a receive thread reads
its records as they come (up to 7000 a second) and keeps a running sum; each step takes the
mean of the records since the last step and starts the sum again, so nothing queues. Only
datagrams from the box's address and port count; a record older than one already used, a
repeat, a short or oversized datagram is counted and dropped, never applied. A non-zero
status word, or no record for stale_timeout on the runtime's clock, stops the graph with one
line (the robot driver holds). One graph per box: setup claims host:port before it sends.
Standard library only (socket, urllib).
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from typing import cast

from dockhil.devices import tare
from dockhil.devices.ati_netft import protocol as rdt
from dockhil.devices.ft_base import FtDriver, Raw, problems_line, tare_params
from dockhil.errors import DeviceError, ParamError
from dockhil.node import Param
from dockhil.runtime import ownership, realtime

STOP_QUIET_S = 0.05  # at close: the box is taken to have stopped once no record came for this long
STOP_WAIT_S = 0.5  # at most, whatever still comes
RESEND_START_S = 0.25  # a start request is one datagram: ask again while the box says nothing


class _Receiver:
    """Reads the box's socket in a thread: a running sum of the usable records and the counts of
    everything else."""

    def __init__(self, sock: socket.socket, box: tuple[str, int], say: Callable[[str], object] = print) -> None:
        self.sock, self.box, self.say = sock, box, say
        self.lock = threading.Lock()
        self.seq = rdt.SequenceCheck()
        self.n = 0
        self.sums = [0] * 6  # counts: exact integers
        self.fault: rdt.Record | None = None
        self.records = 0  # records of the box received at all
        self.repeated = 0
        self.bad = 0  # short or oversized datagrams from the box
        self.foreign = 0
        self.foreign_from: tuple[str, int] | None = None  # the first other sender
        self._last_ft: int | None = None
        self.collected: list[tuple[int, ...]] | None = None  # while taring: each usable record's counts
        self._collect = 0
        self._run = True
        self.thread = threading.Thread(target=self._loop, name="netft-receive", daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        realtime.raise_device_thread(self.say, "the Net F/T receive thread")
        sock = self.sock
        while self._run:
            try:
                data, sender = sock.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:
                if not self._run:
                    return
                continue  # an ICMP error of an earlier send (port unreachable): keep reading
            if sender[:2] != self.box:
                with self.lock:
                    self.foreign += 1
                    self.foreign_from = self.foreign_from or sender[:2]
                continue
            try:
                record = rdt.decode_record(data)
            except rdt.RdtError:
                with self.lock:
                    self.bad += 1
                continue
            with self.lock:
                self.records += 1
                if not self.seq.accept(record.rdt_sequence):
                    continue
                if record.status:
                    self.fault = self.fault or record
                    continue
                if record.ft_sequence == self._last_ft:
                    self.repeated += 1  # the box's same internal sample again: not new data
                    continue
                self._last_ft = record.ft_sequence
                self.n += 1
                s, c = self.sums, record.counts
                for i in range(6):
                    s[i] += c[i]
                if self.collected is not None and len(self.collected) < self._collect:
                    self.collected.append(c)

    def collect(self, n: int) -> None:
        """Keep the counts of the next n usable records (for the tare) in `collected`."""
        with self.lock:
            self.collected, self._collect = [], n

    def take(self) -> tuple[int, list[int], rdt.Record | None]:
        """(records, their summed counts, the first faulty record) since the last take."""
        with self.lock:
            out = self.n, self.sums, self.fault
            self.n, self.sums = 0, [0] * 6
            return out

    def stop(self) -> None:
        self._run = False
        self.thread.join(timeout=2.0)


class FtNetFtDriver(FtDriver):
    """F/T sensor on an ATI Net F/T box (RDT over UDP): tare at start, gap, fault and stale-data detection."""

    sample = "record"
    params = {
        "host": Param(str, "192.168.1.1", help="the box's address (factory setting 192.168.1.1)"),
        "port": Param(int, rdt.RDT_PORT, help="the box's RDT UDP port", ge=1, le=65535),
        "http_port": Param(int, 80, help="the box's web server port (netftapi2.xml)", ge=1, le=65535),
        "http_timeout": Param(
            float, 2.0, unit="s", help="longest time for the box's web server to serve its whole page", gt=0.0, le=60.0
        ),
        "counts_per_force": Param(
            float, 0.0, help="counts per force unit (0: cfgcpf of the box's netftapi2.xml)", ge=0.0, scale=(1e-3, 1e12)
        ),
        "counts_per_torque": Param(
            float, 0.0, help="counts per torque unit (0: cfgcpt of netftapi2.xml)", ge=0.0, scale=(1e-3, 1e12)
        ),
        "force_unit": Param(
            str, "", help="the box's force unit: N, lbf, klbf, kN, kgf, gf ('': scfgfu of netftapi2.xml)"
        ),
        "torque_unit": Param(
            str, "", help="the box's torque unit: Nm, Nmm, lbf-in, lbf-ft, kgf-cm, kNm ('': scfgtu of netftapi2.xml)"
        ),
        # the tare and the mounting as for the CAN sensor (tare_samples counts records here)
        **tare_params(
            stale_help="no new record for this long is an error",
            open_help="time for the box to start streaming",
            frame="probe",
        ),
    }

    @classmethod
    def resolve_params(cls, node_name: str, given: dict) -> dict:
        values = super().resolve_params(node_name, given)
        for name, check in (("force_unit", rdt.force_factor), ("torque_unit", rdt.torque_factor)):
            if values[name]:
                try:
                    check(values[name])
                except rdt.RdtError as exc:
                    raise ParamError(f"node {node_name!r} parameter {name!r}: {exc}") from None
        return values

    # -- the device's part (the sequence is FtDriver's) ------------------------------
    def _open(self) -> None:
        p = self.p
        self.device = f"Net F/T box {p.host}:{p.port}"
        try:
            address = socket.getaddrinfo(p.host, p.port, socket.AF_INET, socket.SOCK_DGRAM)[0][4][0]
        except (OSError, IndexError) as exc:
            raise DeviceError(f"{self.device}: cannot resolve {p.host!r}: {exc}") from None
        self.box = (str(address), p.port)  # an IPv4 address is a str
        self.ticks = self.ticks_with_data = self.averaged = self.most_per_tick = 0
        self._foreign_logged = False
        self.receiver: _Receiver | None = None
        self.sock: socket.socket | None = None
        self._stream_stopped = False
        self._claim: ownership.DeviceLock | None = ownership.claim_for_graph(f"netft-{address}-{p.port}", self.device)
        try:
            self.calibration = self._calibration()
            self.force_scale = self.calibration.newtons_per_count
            self.torque_scale = self.calibration.newton_metres_per_count
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            # Room for a stall of the receive thread at 7000 records a second (the kernel caps it at
            # net.core.rmem_max): what overflows the buffer is lost, and counted as such.
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
            self.sock.bind(("", 0))
            self.sock.settimeout(0.05)
            self.receiver = _Receiver(self.sock, self.box, self.log)
        except BaseException:
            self._shutdown()
            raise

    def _calibration(self) -> rdt.Calibration:
        """From the parameters where given, the rest from the box's netftapi2.xml."""
        p = self.p
        given = {
            "counts_per_force": p.counts_per_force,
            "counts_per_torque": p.counts_per_torque,
            "force_unit": p.force_unit,
            "torque_unit": p.torque_unit,
        }
        try:
            if all(given.values()):
                calibration = rdt.Calibration(**given)
            else:
                calibration = rdt.calibration_from(self._netftapi2(), given)
        except rdt.RdtError as exc:
            raise DeviceError(
                f"{self.device}: {exc} (or give counts_per_force, counts_per_torque, force_unit and torque_unit)"
            ) from None
        problem = calibration.full_scale_problem()
        if problem:
            raise DeviceError(f"{self.device}: {problem}")
        self.log(f"{self.device}: {calibration.describe()}")
        return calibration

    def _netftapi2(self) -> dict[str, str]:
        """The box's configuration page; asked again until open_timeout while nothing answers (the
        box, or its emulator, may still be starting)."""
        p = self.p
        deadline = time.monotonic() + p.open_timeout
        while True:
            try:
                return rdt.fetch_netftapi2(p.host, p.http_port, p.http_timeout)
            except rdt.Unreachable:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.05)

    def _send(self, command: int) -> None:
        try:
            self.sock.sendto(rdt.encode_request(command), self.box)  # type: ignore[union-attr]  # open: _open made it
        except OSError as exc:
            raise DeviceError(
                f"{self.device}: cannot send the {rdt.COMMANDS[command]} request: {exc.strerror or exc}"
            ) from None

    def _first_samples(self, want: int) -> list[Raw]:
        """Wait for the stream; the first `want` usable records as (force, torque) (at least one must come)."""
        p, receiver = self.p, cast(_Receiver, self.receiver)  # open: _open made it
        want = max(1, want)
        receiver.collect(want)
        deadline, asked, streaming = time.monotonic() + p.open_timeout, 0.0, False
        while True:
            now = time.monotonic()
            if not receiver.records and now - asked >= RESEND_START_S:
                self._send(rdt.CMD_START)
                asked = now
            with receiver.lock:
                n, fault = len(receiver.collected), receiver.fault  # type: ignore[arg-type]  # collect() made it a list
            self._refuse_fault(fault)
            if n >= want:
                break
            if n and not streaming:
                streaming, deadline = True, now + p.open_timeout  # the tare's own time from the first record
            if now >= deadline:
                if not n:
                    raise DeviceError(
                        f"{self.device}: no RDT records within {p.open_timeout:g} s of the start request: is the "
                        f"box powered, at this address, and does its network let UDP port {p.port} through?"
                        + self._foreign_note()
                    )
                raise DeviceError(f"{self.device}: only {n} of {want} tare records within {p.open_timeout:g} s")
            time.sleep(0.002)
        with receiver.lock:
            records, receiver.collected = receiver.collected, None
        receiver.take()  # the graph's ticks start from here
        fs, ts = self.force_scale, self.torque_scale
        return [
            (tuple(c[i] * fs for i in range(3)), tuple(c[3 + i] * ts for i in range(3)))
            for c in records  # type: ignore[union-attr]  # collect() made it a list
        ]

    def _foreign_note(self) -> str:
        r = self.receiver
        if r is None or not r.foreign:
            return ""
        host, port = r.foreign_from  # type: ignore[misc]  # set with the first foreign datagram
        return f" ({r.foreign} datagrams came from {host}:{port} instead: is that the box, on another address or port?)"

    def _refuse_fault(self, fault: rdt.Record | None) -> None:
        if fault is not None:
            f = [c * self.force_scale for c in fault.counts[:3]]
            raise DeviceError(
                f"{self.device}: the box reports status {fault.status:#010x} "
                f"({rdt.describe_status(fault.status)}) in record {fault.rdt_sequence}; holding "
                f"(raw force {tare.fmt(f)} N; see the box's web page)"
            )

    def _read(self) -> Raw | None:
        r = cast(_Receiver, self.receiver)  # open: _open made it
        n, sums, fault = r.take()
        self._refuse_fault(fault)
        if r.foreign and not self._foreign_logged:
            self._foreign_logged = True
            host, port = r.foreign_from  # type: ignore[misc]  # set with the first foreign datagram
            self.log(
                f"warning: {self.device}: ignoring datagrams from {host}:{port}, not the box "
                f"(counted; another device sends to this driver's port)"
            )
        self.ticks += 1
        if not n:
            return None
        self.ticks_with_data += 1
        self.averaged += n
        self.most_per_tick = max(self.most_per_tick, n)
        fs, ts = self.force_scale / n, self.torque_scale / n  # the mean of the records since the last step
        return tuple(sums[i] * fs for i in range(3)), tuple(sums[3 + i] * ts for i in range(3))

    def _is_open(self) -> bool:
        return getattr(self, "_claim", None) is not None

    def counters(self) -> dict[str, int]:
        r = cast(_Receiver, self.receiver)  # open: _open made it
        with r.lock:
            return {
                "records": r.records,
                "lost": r.seq.lost,
                "reordered": r.seq.reordered,
                "duplicates": r.seq.duplicates,
                "restarts": r.seq.restarts,
                "repeated": r.repeated,
                "bad datagrams": r.bad,
                "foreign datagrams": r.foreign,
            }

    def _stop_stream(self) -> None:
        """The box stops streaming to us, and what it sent before is read (until none came for STOP_QUIET_S,
        at most STOP_WAIT_S): the gaps counted are then every one the box could show, as it counts them."""
        if self.sock is None or self._stream_stopped:
            return
        self._stream_stopped = True
        try:
            self.sock.sendto(rdt.encode_request(rdt.CMD_STOP), self.box)
        except OSError:
            return
        r = self.receiver
        if r is None:
            return
        deadline, seen, quiet_since = time.monotonic() + STOP_WAIT_S, r.records, time.monotonic()
        while time.monotonic() < deadline and time.monotonic() - quiet_since < STOP_QUIET_S:
            time.sleep(0.005)
            if r.records != seen:
                seen, quiet_since = r.records, time.monotonic()

    def _shutdown(self) -> None:
        self._stop_stream()
        if self.receiver is not None:
            self.receiver.stop()
        if self.sock is not None:
            self.sock.close()
            self.sock = None
        claim = getattr(self, "_claim", None)
        if claim is not None:
            claim.release()
            self._claim = None

    def _report(self) -> list[str]:
        self._stop_stream()
        lines = []
        if self.ticks_with_data:
            lines.append(
                f"{self.device}: {self.averaged} records averaged over {self.ticks_with_data} ticks "
                f"({self.averaged / self.ticks_with_data:.2f} a tick, at most {self.most_per_tick})"
            )
        counted = self.counters()
        return lines + problems_line(self.device, [(n, what) for what, n in counted.items() if what != "records"])
