"""The KUKA RSI link: the UDP socket and the thread that answers each controller datagram (`<Rob>`)
at once with `<Sen>` from the latest setpoint the driver handed over (one reference replaced whole,
never a queue), moving the correction toward it by at most one cycle's travel; and what it counts on
the way. The datagrams and the angles are in rsi.py; the driver node is dockhil/devices/kuka_rsi/driver.py.

Per datagram, in this order: only the configured controller's address is read; a datagram that is
oversized, malformed (also: a pose or a count no controller sends, an IPOC further ahead of the last
than the time since it allows), without RIst or IPOC, or whose IPOC is not above the last one is
counted (one warning line per kind) and neither answered nor used; nothing a datagram carries stops
the answering thread. The controller's first datagram fixes its port: another port of its address is
foreign. Otherwise the correction moves toward the latest setpoint by at most max_speed * cycle and
max_angular_speed * cycle from every correction the controller may hold when it takes the answer,
and the answer echoes the IPOC. What it may hold is what it reports, never a guess about our own
answers: RSol (the commanded pose: start + the correction it holds) names the correction, and every
answer sent after it may still be taken (a late one, by a controller that takes it where it
arrives); without RSol, an unchanged Delay says the last answer was taken, and a Delay that rose
leaves every answer since the last one confirmed possible. Whatever is lost, late, skipped,
duplicated or reordered, the controller steps at most one cycle's travel (the answers' 4 decimals
included). The correction is held (does not change) when there is no setpoint, when the setpoint
is older than stale_after (the graph stalled) or not finite, after a hold, and while MAX_UNTAKEN
answers wait to be confirmed.

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
from collections.abc import Callable, Iterable, Sequence

from dockhil.contact.rotations import IDENTITY, quat_conjugate, quat_multiply
from dockhil.devices.cycle_log import CycleLog
from dockhil.devices.handover import SWITCH_INTERVAL, Handover
from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.limits import angle_between, toward_within, turn_within
from dockhil.errors import DeviceError
from dockhil.runtime import realtime

ZERO = (0.0, 0.0, 0.0)
# What the 4 decimals of RKorr and RSol may add to a step: half a unit of the last digit on each of three
# coordinates, on both poses of a step and on the start (mm; degrees as radians).
ROUNDING_MM = 3e-4
ROUNDING_RAD = math.radians(3e-4)
MATCH_MM = 2e-4  # an RSol this close to an answer (after the start is taken off) may show that answer
MATCH_RAD = math.radians(2e-4)
CATCH_UP = 1.25  # a timed command's step a cycle at most this times its own motion in a cycle ...
CATCH_UP_FLOOR = 0.25  # ... or this part of the limit, whichever is more
MAX_UNTAKEN = 64  # answers sent that the controller may still take; past it, the answers hold
# An IPOC may run ahead of the controller's clock as the earliest datagram showed it by at most this many
# cycles (drift, jitter): further is no controller's, and taking it would lock the real ones out.
IPOC_LEAD_CYCLES = 25

KINDS = {
    "foreign": "from another address than the controller's",
    "oversized": "oversized",
    "malformed": "malformed",
    "repeated": "with an IPOC not above the last one",
}


def _finite(values: Iterable[float]) -> bool:
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
        sock: socket.socket,
        controller: str,
        cycle: float,
        max_speed: float,
        max_angular_speed: float,
        stale_after: float,
        sentype: str = "ImFree",
        clock: Callable[[], float] = time.monotonic,
        realtime: bool = False,
        describe: str = "RSI link",
    ) -> None:
        super().__init__(name="robot-rsi-link", daemon=True)
        self.sock = sock
        self.controller = controller
        self.cycle = cycle
        self.max_step_mm = max_speed * cycle * 1000.0  # one cycle's travel
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
        self.handover = Handover()  # the pose for the time of each cycle, from the command's time and velocity
        self.korr = ((0.0, 0.0, 0.0), IDENTITY, (0.0, 0.0, 0.0))  # the last answer: position mm, quaternion, A B C
        # What the controller may hold when it takes our next answer: `held`, the correction it reported (RSol)
        # or that Delay confirmed, and every answer sent since that it may still take. Each answer is within one
        # cycle's travel of all of them, so whichever it takes, it steps no further.
        self.held: tuple = ((0.0, 0.0, 0.0), IDENTITY)  # position mm, quaternion
        self.held_exact = True  # held is one of our answers (not RSol's 4 decimals, which hide the rest)
        self.sent_since: list[tuple] = []
        self.controller_port: int | None = None  # the controller's port, from its first datagram
        self._rsol0: tuple | None = None  # the commanded pose of the first datagram (no correction): mm, quaternion
        self.latest: tuple[int, rsi.RobFrame, float] | None = None  # (count, frame, received at)
        self.first: rsi.RobFrame | None = None
        self.started = threading.Event()
        self.hold_latched = False
        self.hold_written = threading.Event()
        self.last_ipoc = -1
        self._least_offset = math.inf  # ms: the least (receive time - IPOC) seen: the controller's clock and ours
        self.missing = 0  # controller datagrams that never came: IPOC gaps of more than one cycle
        self.received = 0
        self.answered = 0
        self.counted = dict.fromkeys(KINDS, 0)
        self.stale_holds = 0
        self.longest_gap_s = 0.0  # the most cycles in a row the controller did not take a command while moving
        self._untaken = 0
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
    def submit(
        self,
        position_mm: tuple[float, ...] | None,
        orientation: tuple[float, ...] | None,
        stamp: float | None = None,
        tick: float = 0.0,
        linear: Sequence[float] = ZERO,
        angular: Sequence[float] = ZERO,
    ) -> None:
        """Move the correction toward this (None: hold where it is); with the command's `stamp`, each cycle
        toward the pose for its own time, up to `tick` ahead along the velocity (mm/s, rad/s in BASE)."""
        if position_mm is None or orientation is None:  # given together, or neither (hold)
            self.target = None
            return
        now = self.clock()
        if stamp is None:
            self.handover.clear()
        else:
            self.handover.put(now, stamp, tick, position_mm, orientation, linear, angular)
        self.target = (now, position_mm, orientation)

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
                f"between {self.first.ipoc} and {self.last_ipoc})"  # type: ignore[union-attr]  # a gap follows a first
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

    def handle(self, data: bytes, host: str, now: float, port: int | None = None) -> bytes | None:
        """The answer to one datagram received from `host` (`port`) at `now`, or None if it is ignored."""
        if host != self.controller:
            self._count("foreign", host if port is None else f"{host}:{port}")
            return None
        try:
            frame = rsi.parse_rob(data)
        except rsi.RsiError as exc:
            self._count("oversized" if len(data) > rsi.MAX_DATAGRAM else "malformed", str(exc))
            return None
        if port is not None and self.controller_port not in (None, port):  # another sender on its address
            self._count("foreign", f"{host}:{port}, not the controller's port {self.controller_port}")
            return None
        if frame.ipoc <= self.last_ipoc:
            self._count("repeated", f"IPOC {frame.ipoc} after {self.last_ipoc}")
            return None
        # An IPOC counts the controller's milliseconds: it runs ahead of our clock by no more than it did at
        # the least (a datagram arrives after it was sent), however late this thread reads it.
        offset = now * 1000.0 - frame.ipoc
        if self.latest is not None and offset < self._least_offset - IPOC_LEAD_CYCLES * self.cycle_ms:
            self._count("malformed", f"IPOC {frame.ipoc} after {self.last_ipoc}: ahead of the controller's clock")
            return None
        self._least_offset = min(self._least_offset, offset)
        if self.controller_port is None and port is not None:
            self.controller_port = port  # from here on, another port of the controller's address is foreign
        never_came = 0
        if self.last_ipoc >= 0:
            never_came = max(0, (frame.ipoc - self.last_ipoc + self.cycle_ms // 2) // self.cycle_ms - 1)
            self.missing += never_came
        self.last_ipoc = frame.ipoc
        taken, in_force = self._took(frame, never_came)
        if self.target is not None and not self.hold_latched and self.latest is not None:
            # cycles that never came and answers not taken, in a row: a stalled controller or link
            missed = never_came + (0 if taken else 1)
            self._untaken = self._untaken + missed if missed else 0
            self.longest_gap_s = max(self.longest_gap_s, self._untaken * self.cycle)
        else:
            self._untaken = 0
        # the cycle's time on our clock, from its IPOC: the controller's clock, not when this thread woke
        answer = self.write(self._advance(now, (frame.ipoc + self._least_offset) / 1000.0), frame.ipoc)
        self._exchange = (now, frame, self.korr, taken, in_force)
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

    def _took(self, frame: rsi.RobFrame, never_came: int) -> tuple[bool, tuple | None]:
        """What the controller holds, from what this datagram reports (`held`, `sent_since`); whether it
        took our last answer, and the absolute pose it commands (RSol: BASE, m, quaternion; None without)."""
        if frame.rsol is not None:
            r = frame.rsol
            q = rsi.abc_to_quat(*r[3:])
            if self._rsol0 is None:
                self._rsol0 = (r[:3], q)
            p0, q0 = self._rsol0
            held = ((r[0] - p0[0], r[1] - p0[1], r[2] - p0[2]), quat_multiply(q, quat_conjugate(q0)))
            since, exact = self.sent_since, False
            for k, (kp, kq) in enumerate(since):
                # The oldest answer it may show: those before it are past, it or any after may be held.
                if math.dist(kp, held[0]) <= MATCH_MM and angle_between(kq, held[1]) <= MATCH_RAD:
                    held, self.sent_since, exact = since[k], since[k + 1 :], True
                    break
            else:  # none of those sent since: the one it held before?
                kp, kq = self.held
                if self.held_exact and math.dist(kp, held[0]) <= MATCH_MM and angle_between(kq, held[1]) <= MATCH_RAD:
                    held, exact = self.held, True
            self.held, self.held_exact = held, exact
            taken = not self.sent_since  # it holds the last answer sent
            return taken, (r[0] / 1000.0, r[1] / 1000.0, r[2] / 1000.0, *q)
        # Without RSol, Delay tells: unchanged, the last answer came in time and was taken. Risen, some
        # answer was late, or a datagram never came: which was taken is not known, so any may be held.
        if frame.delay is not None and self.delay_at_start is not None and frame.delay == self.delay:
            if self.sent_since:
                self.held, self.held_exact, self.sent_since = self.sent_since[-1], True, []
        # the cycle log's reading (calibration): a datagram that never came counts one late answer
        taken = not (
            frame.delay is not None and self.delay_at_start is not None and frame.delay - self.delay > never_came
        )
        return taken, None

    def _may_hold(self) -> list[tuple]:
        return [self.held, *self.sent_since]

    def log_exchange(self, sent: float | None) -> None:
        """Log the datagram just answered (`sent`: when its answer went; None: it did not go), and hand the
        one before it to `cycles`, now that this datagram's Delay tells whether its answer was taken."""
        exchange, self._exchange = self._exchange, None
        if exchange is None:
            return
        # taken: the answer before this datagram's (handle); in_force: the pose the controller commands (RSol)
        read, frame, (kp, kq, _abc), taken, in_force = exchange
        pending = self._pending
        if pending is not None:
            if in_force is not None:  # the controller says what it took
                self._in_force = in_force
                pending[2], pending[3] = in_force, pending[3] and taken
            elif pending[3] and taken:
                self._in_force = pending[2]
            else:  # the controller kept the correction it had
                pending[2], pending[3] = self._in_force, False
            self.cycles.add(*pending)
        if self._in_force is None:  # no correction yet: the start pose
            r = self.first.rist  # type: ignore[union-attr]  # an exchange logged follows a first datagram
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

    def _advance(self, now: float, cycle_at: float | None = None) -> tuple[float, ...]:
        """The correction for this cycle (X Y Z A B C): one bounded step toward the latest setpoint, within one
        cycle's travel of every correction the controller may hold."""
        may_hold = self._may_hold()
        kp, kq, abc = self.korr
        if any(
            math.dist(kp, c[0]) > self.max_step_mm + ROUNDING_MM
            or angle_between(kq, c[1]) > self.max_step_rad + ROUNDING_RAD
            for c in may_hold
        ):  # our last answer is out of reach of what the controller reports: go on from what it holds
            kp, kq = self.held
            abc = rsi.quat_to_abc(kq)
            kp, kq, abc = self._rounded(kp, abc)
            self.korr = (kp, kq, abc)
        target = self.target
        if self.hold_latched or target is None or len(self.sent_since) >= MAX_UNTAKEN:
            return self._sent(kp, abc)
        handed, p, q = target
        if self.handover.motion is not None:
            p, q = self.handover.pose(now if cycle_at is None else cycle_at) or (p, q)
        if now - handed > self.stale_after:
            self.stale_holds += 1
            if self.stale_holds == 1:
                self._note(
                    f"warning: holding: the latest setpoint is {now - handed:.3f} s old > "
                    f"stall_timeout {self.stale_after:g} s"
                )
            return self._sent(kp, abc)
        if not (_finite(p) and _finite(q)):  # never formatted, never sent
            return self._sent(kp, abc)
        # Rounding to the answer's 4 decimals may add to the step: where it would exceed it, a bit less.
        pace = self._pace() if math.dist(kp, p) <= 2.0 * self.max_step_mm else self.max_step_mm
        for margin in (0.0, 1.0):
            travel = self.max_step_mm - margin * ROUNDING_MM
            reach = [travel] * len(may_hold)
            step = toward_within(kp, p, min(travel, pace), [c[0] for c in may_hold], reach)
            step = (round(step[0], 4), round(step[1], 4), round(step[2], 4))
            if self._within(step, None, may_hold):
                kp = step
                break
        if q != kq:
            for margin in (0.0, 1.0):
                turn = turn_within(kq, q, self.max_step_rad - margin * ROUNDING_RAD, [c[1] for c in may_hold])
                turn_abc = rsi.quat_to_abc(turn)
                turn_abc = (round(turn_abc[0], 4), round(turn_abc[1], 4), round(turn_abc[2], 4))
                turn = rsi.abc_to_quat(*turn_abc)
                if self._within(None, turn, may_hold):
                    kq, abc = turn, turn_abc
                    break
        self.korr = (kp, kq, abc)
        return self._sent(kp, abc)

    def _pace(self) -> float:
        """The most the correction moves this cycle [mm] near its goal: a little more than the command moves
        in a cycle, so that what a cycle the controller did not take left behind is made up over the next
        ones, not in one (at least CATCH_UP_FLOOR of the limit); the limit without a timed command, for one
        standing still (and, in _advance, for a goal further than two cycles' travel)."""
        speed = self.handover.speed()
        if not speed:  # no timed command, or one that stands still: reached at the limit
            return self.max_step_mm
        return max(CATCH_UP * speed * self.cycle, CATCH_UP_FLOOR * self.max_step_mm)

    def _within(self, kp: Sequence[float] | None, kq: Sequence[float] | None, may_hold: list[tuple]) -> bool:
        """Whether the answer's position kp or orientation kq (None: not judged) is within one cycle's travel
        of all the controller may hold (of an RSol not one of our answers, by its rounding less)."""
        for i, (cp, cq) in enumerate(may_hold):
            slack = 0.0 if i or self.held_exact else 1.0
            if kp is not None and math.dist(kp, cp) > self.max_step_mm - slack * ROUNDING_MM + 1e-9:  # float digits
                return False
            if kq is not None and angle_between(kq, cq) > self.max_step_rad - slack * ROUNDING_RAD + 1e-12:
                return False
        return True

    @staticmethod
    def _rounded(kp, abc):
        """The correction as the answer's 4 decimals carry it, and so as the controller takes it."""
        kp = (round(kp[0], 4), round(kp[1], 4), round(kp[2], 4))
        abc = (round(abc[0], 4), round(abc[1], 4), round(abc[2], 4))
        return kp, rsi.abc_to_quat(*abc), abc

    def _sent(self, kp, abc):
        """Keep what is sent among what the controller may take; the answer's values."""
        kq = self.korr[1]
        last = self.sent_since[-1] if self.sent_since else self.held
        if (kp, kq) != last:
            self.sent_since.append((kp, kq))
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
            try:
                answer = handle(bytes(view[:n]), addr[0], t, addr[1])
            except Exception as exc:  # noqa: BLE001 - no datagram stops the answering thread
                self._count("malformed", f"{type(exc).__name__}: {str(exc)[:60]}")
                continue
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
