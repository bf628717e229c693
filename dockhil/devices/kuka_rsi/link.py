"""The KUKA RSI link: the UDP socket and the thread that answers each controller datagram (`<Rob>`)
at once with `<Sen>` from the latest setpoint the driver handed over (one reference replaced whole,
never a queue), moving the correction toward it by at most one cycle's travel; and what it counts on
the way. The datagrams and the angles are in rsi.py; the driver node is dockhil/devices/kuka_rsi/driver.py.

Per datagram, in this order: only the configured controller's address is read; a datagram that is
oversized, malformed, without RIst or IPOC, or whose IPOC is not above the last one is counted (one
warning line per kind) and neither answered nor used. Otherwise the correction moves toward the
latest setpoint by at most max_speed * cycle and max_angular_speed * cycle, and the answer echoes
the IPOC. The correction is held (does not change) when there is no setpoint, when the setpoint is
older than stale_after (the graph stalled) or not finite, and after a hold.

Every exchange goes to `cycles` (a CycleLog, which the driver publishes on /robot/cycles), once the next
datagram tells whether the controller took its answer: the setpoint as the absolute pose it commands
(start pose + RKorr) and the actual pose (RIst), both in BASE, metres and a quaternion (x, y, z, w); the
device cycle IPOC // the cycle in ms, on 16 bits as the Modbus controller's counter (the calibration
unwraps both alike); `taken` false (the datagram's pose comes before its answer, which the next cycle
takes); `written` false for an answer the controller counted late (its Delay rose by more than the
datagrams that never came in between: it kept the correction it had, which `setpoint` then holds).

Latency: the answer is one %-format of a prebuilt template after expat has read a bounded datagram.
While the link runs, the process's switch interval is lowered so that the thread waits for the
interpreter at most that long while another thread runs; `realtime` asks for SCHED_FIFO for it.
"""

from __future__ import annotations

import math
import socket
import sys
import threading
import time

from dockhil.contact.rotations import IDENTITY, quat_conjugate, quat_from_rotvec, quat_multiply
from dockhil.errors import DeviceError
from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.cycle_log import CycleLog
from dockhil.devices.limits import angle_between
from dockhil.runtime import realtime

SWITCH_INTERVAL = 0.0002  # s: longest wait of the link thread for the interpreter while another thread runs

KINDS = {
    "foreign": "from another address than the controller's",
    "oversized": "oversized",
    "malformed": "malformed",
    "repeated": "with an IPOC not above the last one",
}


def _finite(values) -> bool:
    for v in values:
        if not math.isfinite(v):
            return False
    return True


def open_socket(host: str, listen: str, port: int, device: str) -> tuple[socket.socket, str]:
    """The socket bound to listen:port and the controller's address; DeviceError in one line if not."""
    try:
        controller = socket.gethostbyname(host)
    except OSError as exc:
        raise DeviceError(f"{device}: cannot resolve {host!r}: {exc.strerror or exc}") from None
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((listen, port))
    except OSError as exc:
        sock.close()
        raise DeviceError(
            f"{device}: cannot listen on {listen}:{port}: {exc.strerror or exc} (another program uses the port?)"
        ) from None
    sock.settimeout(0.05)  # the link looks at `stopping` this often
    return sock, controller


class RsiLink(threading.Thread):
    """Owns the UDP socket: answers every controller datagram at once from the latest setpoint."""

    def __init__(
        self,
        sock,
        controller: str,
        cycle: float,
        max_speed: float,
        max_angular_speed: float,
        stale_after: float,
        sentype: str = "ImFree",
        clock=time.monotonic,
        realtime: bool = False,
        describe: str = "RSI link",
    ):
        super().__init__(name="robot-rsi-link", daemon=True)
        self.sock = sock
        self.controller = controller
        self.cycle = cycle
        self.max_step_mm = max_speed * cycle * 1000.0
        self.max_step_rad = max_angular_speed * cycle
        self.stale_after = stale_after
        self.write = rsi.SenWriter(sentype)
        self.clock = clock
        self.realtime = realtime
        self.describe = describe  # the device, as the fatal error's line names it
        self.stopping = False
        self.connected = True  # the safety stop's contract: a hold can be answered while datagrams come
        # Latest values, each replaced whole (one reference: no lock on the answering path).
        self.target: tuple[float, tuple, tuple] | None = None  # (handed over at, X Y Z mm, quaternion) or None
        self.korr = ((0.0, 0.0, 0.0), IDENTITY, (0.0, 0.0, 0.0))  # position mm, quaternion, A B C degrees
        self.accepted = self.korr  # the last correction the controller had in time, as far as Delay tells
        self.latest: tuple[int, rsi.RobFrame, float] | None = None  # (count, frame, received at)
        self.first: rsi.RobFrame | None = None
        self.started = threading.Event()
        self.hold_latched = False
        self.hold_written = threading.Event()
        self.last_ipoc = -1
        self.missing = 0  # controller datagrams that never came: IPOC gaps of more than one cycle
        self.received = 0
        self.answered = 0
        self.counted = dict.fromkeys(KINDS, 0)
        self.stale_holds = 0
        self.delay = 0  # the controller's count of late answers, as it last reported it
        self.delay_at_start: int | None = None  # ... and as it reported it first
        self.delay_at_close: int | None = None  # ... and when the driver began to close (set by it)
        self.lock = threading.Lock()
        self.notes: list[str] = []
        self.fatal: str | None = None
        self.cycles = CycleLog()  # every exchange, as the controller took it (the driver publishes it)
        self.cycle_ms = round(cycle * 1000.0)
        self._exchange: tuple | None = None  # (read at, frame, correction sent, the answer before it taken)
        self._pending: list | None = None  # the last exchange logged, until the next datagram says if it was taken
        self._in_force: tuple | None = None  # the absolute setpoint the controller last took (BASE, m, quaternion)
        self._start: tuple = ((0.0, 0.0, 0.0), IDENTITY)  # the start pose (the first RIst): mm, quaternion

    # -- from the node thread ------------------------------------------------------
    def submit(self, position_mm, orientation) -> None:
        """Move the correction toward this (None: hold where it is)."""
        self.target = None if position_mm is None else (self.clock(), position_mm, orientation)

    def hold(self, timeout: float) -> bool:
        """Hold the correction from now on; True once an answer carrying the hold has been sent."""
        self.hold_written.clear()
        self.hold_latched = True
        return self.hold_written.wait(timeout)

    def take_notes(self) -> list[str]:
        with self.lock:
            notes, self.notes = self.notes, []
        return notes

    def start(self) -> None:
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval, SWITCH_INTERVAL))
        super().start()

    def stop(self) -> None:
        self.stopping = True
        self.join(timeout=2.0)
        self.sock.close()
        sys.setswitchinterval(self._switch_interval)

    def lead(self) -> tuple[float, float] | None:
        """How far (m, rad) the latest setpoint is ahead of the correction sent; None: no setpoint."""
        target = self.target
        if target is None:
            return None
        (kp, kq, _), tp, tq = self.korr, target[1], target[2]
        return math.sqrt(sum((a - b) ** 2 for a, b in zip(kp, tp))) / 1000.0, angle_between(kq, tq)

    def ignored(self) -> str:
        """The datagrams counted and not used, by kind ('' if none)."""
        return ", ".join(f"{n} {KINDS[k]}" for k, n in self.counted.items() if n)

    def report(self, device: str) -> list[str]:
        """The warning lines of what was counted while the link ran, for its close."""
        lines = []
        if self.ignored():
            lines.append(f"warning: {device}: datagrams ignored: {self.ignored()}")
        if self.missing:
            lines.append(
                f"warning: {device}: {self.missing} controller datagrams never came (gaps in the IPOC "
                f"between {self.first.ipoc} and {self.last_ipoc})"
            )
        if self.stale_holds:
            lines.append(f"warning: {device}: held on a stale setpoint for {self.stale_holds} cycles")
        if self.delay_at_start is not None and self.delay > self.delay_at_start:
            running = (self.delay if self.delay_at_close is None else self.delay_at_close) - self.delay_at_start
            closing = self.delay - self.delay_at_start - running
            lines.append(
                f"warning: {device}: the controller counted {running} late answer{'' if running == 1 else 's'} "
                "while the graph ran" + (f", {closing} while the driver closed (the robot held)" if closing else "")
            )
        return lines

    # -- the answering path -----------------------------------------------------------
    def _note(self, line: str) -> None:
        with self.lock:
            self.notes.append(line)

    def _count(self, kind: str, why: str) -> None:
        self.counted[kind] += 1
        if self.counted[kind] == 1:  # the first one tells the story; close() reports the counts
            self._note(
                f"warning: datagram {KINDS[kind]} ignored ({why}); such datagrams are counted, never answered nor used"
            )

    def handle(self, data: bytes, host: str, now: float) -> bytes | None:
        """The answer to one datagram received from `host` at `now`, or None if it is ignored."""
        if host != self.controller:
            self._count("foreign", host)
            return None
        try:
            frame = rsi.parse_rob(data)
        except rsi.RsiError as exc:
            self._count("oversized" if len(data) > rsi.MAX_DATAGRAM else "malformed", str(exc))
            return None
        if frame.ipoc <= self.last_ipoc:
            self._count("repeated", f"IPOC {frame.ipoc} after {self.last_ipoc}")
            return None
        never_came = 0
        if self.last_ipoc >= 0:
            never_came = max(0, round((frame.ipoc - self.last_ipoc) / (self.cycle * 1000.0)) - 1)
            self.missing += never_came
        self.last_ipoc = frame.ipoc
        # Was our last answer taken? Not when Delay rose by more than the datagrams that never came (the
        # controller counts each of those as late too): it kept the correction it had (HOLDON), so this
        # cycle's step starts from there, and the cycle log says so.
        taken = not (
            frame.delay is not None and self.delay_at_start is not None and frame.delay - self.delay > never_came
        )
        if taken:
            self.accepted = self.korr
        else:
            self.korr = self.accepted
        answer = self.write(self._advance(now), frame.ipoc)
        self._exchange = (now, frame, self.korr, taken)
        self.received += 1
        self.latest = (self.received, frame, now)
        if frame.delay is not None:
            if self.delay_at_start is None:
                self.delay_at_start = frame.delay
            elif frame.delay > self.delay and self.delay == self.delay_at_start:
                self._note(
                    f"warning: the controller counts late answers (Delay D={frame.delay}); "
                    f"it stops RSI after its limit of late answers"
                )
            self.delay = frame.delay
        if self.first is None:
            self.first = frame
            self.started.set()
        return answer

    def log_exchange(self, sent: float | None) -> None:
        """Log the datagram just answered (`sent`: when its answer went; None: it did not go), and hand the
        one before it to `cycles`, now that this datagram's Delay tells whether its answer was taken."""
        exchange, self._exchange = self._exchange, None
        if exchange is None:
            return
        read, frame, (kp, kq, _abc), taken = exchange  # taken: the answer before this datagram's (handle)
        pending = self._pending
        if pending is not None:
            if pending[3] and taken:
                self._in_force = pending[2]
            else:  # the controller kept the correction it had
                pending[2], pending[3] = self._in_force, False
            self.cycles.add(*pending)
        if self._in_force is None:  # no correction yet: the start pose
            r = self.first.rist
            self._start = (r[0], r[1], r[2]), rsi.abc_to_quat(*r[3:])
            self._in_force = (r[0] / 1000.0, r[1] / 1000.0, r[2] / 1000.0, *self._start[1])
        p0, q0 = self._start
        setpoint = (
            (p0[0] + kp[0]) / 1000.0,
            (p0[1] + kp[1]) / 1000.0,
            (p0[2] + kp[2]) / 1000.0,
            *quat_multiply(kq, q0),
        )
        r = frame.rist
        actual = (r[0] / 1000.0, r[1] / 1000.0, r[2] / 1000.0, *rsi.abc_to_quat(*r[3:]))
        cycle = (frame.ipoc // self.cycle_ms) & 0xFFFF
        self._pending = [read if sent is None else sent, read, setpoint, sent is not None, actual, cycle, False]

    def _advance(self, now: float):
        """The correction for this cycle (X Y Z A B C): one bounded step toward the latest setpoint."""
        (kp, kq, abc) = self.korr
        target = self.target
        if self.hold_latched or target is None:
            return (*kp, *abc)
        handed, p, q = target
        if now - handed > self.stale_after:
            self.stale_holds += 1
            if self.stale_holds == 1:
                self._note(
                    f"warning: holding: the latest setpoint is {now - handed:.3f} s old > "
                    f"stall_timeout {self.stale_after:g} s"
                )
            return (*kp, *abc)
        if not (_finite(p) and _finite(q)):  # never formatted, never sent
            return (*kp, *abc)
        dx, dy, dz = p[0] - kp[0], p[1] - kp[1], p[2] - kp[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dist > self.max_step_mm:
            s = self.max_step_mm / dist
            kp = (kp[0] + dx * s, kp[1] + dy * s, kp[2] + dz * s)
        else:
            kp = p
        if q != kq:
            x, y, z, w = quat_multiply(q, quat_conjugate(kq))
            if w < 0.0:
                x, y, z, w = -x, -y, -z, -w
            s = math.sqrt(x * x + y * y + z * z)
            angle = 2.0 * math.atan2(s, w)
            if angle > self.max_step_rad:
                k = self.max_step_rad / s
                kq = quat_multiply(quat_from_rotvec((x * k, y * k, z * k)), kq)
            else:
                kq = q
            abc = rsi.quat_to_abc(kq)
        self.korr = (kp, kq, abc)
        return (*kp, *abc)

    def run(self) -> None:
        if self.realtime:
            realtime.ask(realtime.DEVICE_PRIORITY, "the RSI link", self._note)
        sock, clock, handle = self.sock, self.clock, self.handle
        buf = bytearray(rsi.MAX_DATAGRAM + 1)  # one byte more: a datagram that fills it is oversized
        view = memoryview(buf)
        while not self.stopping:
            try:
                n, addr = sock.recvfrom_into(buf)
            except TimeoutError:
                continue
            except OSError as exc:
                if not self.stopping:
                    self.fatal = f"{self.describe}: receiving failed: {exc.strerror or exc}"
                return
            t = clock()
            answer = handle(bytes(view[:n]), addr[0], t)
            if answer is None:
                continue
            try:
                sock.sendto(answer, addr)
            except OSError as exc:
                self._note(f"warning: answer to {addr[0]}:{addr[1]} not sent ({exc.strerror or exc})")
                self.log_exchange(None)
                continue
            self.log_exchange(clock())
            self.answered += 1
            if self.hold_latched:
                self.hold_written.set()
