"""The robot controller's Modbus link: a thread that owns the pymodbus client and runs the device
cycle (`ModbusLink`), the setpoint it sends each cycle, rate-limited from the last one sent
(`SetpointLimiter`), and the claim protocol on the controller's owner registers (`claim_controller`,
`verify_and_hold`; the registers in modbus_map.py). The driver node is dockhil/devices/modbus_robot/driver.py.

Never a stale setpoint, never a jump on resuming: a setpoint is written only in the connection it
was handed over in; after a reconnect the robot holds until a command that arrived after the
reconnect, and after any hold, reconnect or stall the setpoint sent starts from the actual pose
read back. pymodbus is not imported here: the driver hands over its client.
"""

from __future__ import annotations

import logging
import math
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, TypeAlias

from dockhil.devices.cycle_log import CycleLog
from dockhil.devices.handover import SWITCH_INTERVAL, Handover
from dockhil.devices.limits import angle_between, toward_within, turn_within
from dockhil.devices.modbus_robot import registers as mm

if TYPE_CHECKING:
    from pymodbus.client import ModbusTcpClient

    Client: TypeAlias = "ModbusTcpClient | NoDelayClient"  # the pymodbus client, or it with TCP_NODELAY kept

MAX_UNCONFIRMED = 64  # setpoints written that the controller has not echoed yet, kept as ones it may take


class SetpointLimiter:
    """What the device is sent on one of its cycles: the latest commanded setpoint, approached from the
    previous value sent (or, after a hold, a reconnect or a stall, from the actual pose read back) by at
    most max_speed and max_angular_speed times the cycle's time, that time capped at max_cycle; and, from
    every setpoint the controller may hold (the one whose heartbeat it echoes, its record, and each one
    written since, which it may still take), by at most the same speeds times the time since that one was
    written, capped at max_cycle. A late or bunched command, a stalled link or controller, a write the
    controller missed thus never becomes a jump. No I/O: the caller gives each cycle's time, each write and
    each echo."""

    def __init__(self, max_speed: float, max_angular_speed: float, max_cycle: float):
        self.max_speed = max_speed  # m/s, 0: off
        self.max_angular_speed = max_angular_speed  # rad/s, 0: off
        self.max_cycle = max_cycle  # s
        self.sent: mm.PoseTwist | None = None  # the last value sent; None: start from the actual pose
        # (written at, setpoint): the one the controller echoed it took, and each written after it
        self.held: tuple[float, mm.PoseTwist] | None = None
        self.unconfirmed: list[tuple[int, float, mm.PoseTwist]] = []  # (heartbeat, written at, setpoint)

    def reset(self) -> None:
        """The controller stopped following: the next setpoint starts from the actual pose."""
        self.sent = self.held = None
        self.unconfirmed = []

    def wrote(self, heartbeat: int, at: float, setpoint: mm.PoseTwist) -> None:
        """A setpoint went to the controller with this heartbeat at `at`."""
        self.unconfirmed.append((heartbeat, at, setpoint))
        del self.unconfirmed[:-MAX_UNCONFIRMED]

    def echoed(self, heartbeat: int) -> None:
        """The controller reports the heartbeat of the last write it took: the setpoints written with it or
        before are past, the latest of them is the one it holds."""
        keep = []
        for hb, at, setpoint in self.unconfirmed:
            if (heartbeat - hb) & 0xFFFF < 0x8000:
                self.held = (at, setpoint)
            else:
                keep.append((hb, at, setpoint))
        self.unconfirmed = keep

    def next(self, target: mm.PoseTwist, actual: mm.PoseTwist, dt: float, now: float | None = None) -> mm.PoseTwist:
        """The setpoint for a device cycle `dt` seconds after the previous one (at `now` on the caller's
        clock: the reach from each setpoint the controller may hold is counted from its write)."""
        dt = min(max(dt, 0.0), self.max_cycle)
        origin = self.sent if self.sent is not None else actual
        held = [] if self.held is None else [self.held]
        held += [(at, s) for _, at, s in self.unconfirmed]
        ages = [min(max(now - at, dt), self.max_cycle) if now is not None else dt for at, _ in held]
        position = (
            toward_within(
                origin[:3],
                target[:3],
                self.max_speed * dt,
                [s[:3] for _, s in held],
                [self.max_speed * a for a in ages],
            )
            if self.max_speed
            else target[:3]
        )
        orientation = (
            turn_within(
                origin[3:7],
                target[3:7],
                self.max_angular_speed * dt,
                [s[3:7] for _, s in held],
                [self.max_angular_speed * a for a in ages],
            )
            if self.max_angular_speed
            else target[3:7]
        )
        self.sent = tuple(position) + tuple(orientation) + tuple(target[7:])
        return self.sent

    def lag(self, target: mm.PoseTwist) -> tuple[float, float] | None:
        """How far (m, rad) the commanded setpoint is ahead of the last value sent; None: nothing sent
        since the robot last stopped."""
        if self.sent is None:
            return None
        if self.sent[:7] == tuple(target[:7]):
            return 0.0, 0.0  # reached (the angle formula leaves a rounding residue)
        step = math.sqrt(sum((b - a) ** 2 for a, b in zip(self.sent[:3], target[:3])))
        return step, angle_between(self.sent[3:7], target[3:7])


def quiet_pymodbus() -> None:
    # pymodbus logs every refused or dropped connection; the driver reports device problems itself, as one line.
    logger = logging.getLogger("pymodbus.logging")
    if not logger.handlers:
        logger.addHandler(logging.NullHandler())
        logger.propagate = False


MAX_CONTROLLER_CYCLE = 0.02  # s: the slowest controller cycle placed (docs/hardware.md: 1-8 ms)


class ControllerPhase:
    """When the controller's own cycles run, from its cycle count read back: each read that reports cycle k
    came after cycle k ran, so t_k = phase + k period is at most that read's time; the reads that came
    soonest after their cycle bound it closest (a busy machine's late read only loosens the bound). The
    period from the count over the reads kept. `mid(t)`: the middle between two of its cycles nearest t,
    where a write is taken by the same cycle whatever the host's jitter of up to half a cycle. No I/O."""

    KEPT = 256  # reads (about half a second at 2 ms)
    LEAST = 32  # reads before the phase is known

    def __init__(self) -> None:
        self.reads: deque[tuple[float, int]] = deque(maxlen=self.KEPT)  # (time read, cycle count unwrapped)
        self.anchor: tuple[float, int] | None = None  # the first read: the period over the whole span since

    def read(self, at: float, cycle: int) -> None:
        if self.reads:
            last = self.reads[-1][1]
            cycle = last + ((cycle - last) & 0xFFFF)
        else:
            self.anchor = (at, cycle)
        self.reads.append((at, cycle))

    def clear(self) -> None:
        self.reads.clear()
        self.anchor = None

    def _fit(self) -> tuple[float, float] | None:
        """(when the anchor's cycle ran, period) [s], or None while not known. The period over the span since
        the anchor (a read's lateness spread over all its cycles), the phase from the recent reads."""
        reads, anchor = self.reads, self.anchor
        if anchor is None or len(reads) < self.LEAST or reads[-1][1] - anchor[1] < self.LEAST:
            return None
        period = (reads[-1][0] - anchor[0]) / (reads[-1][1] - anchor[1])
        if not 0.0 < period <= MAX_CONTROLLER_CYCLE:
            return None  # not a controller's cycle (its count restarted): the writes stay on the host's grid
        return min(at - (k - anchor[1]) * period for at, k in reads), period

    def mid(self, t: float) -> float:
        """The middle between two of the controller's cycles nearest t (t while they are not known)."""
        fit = self._fit()
        if fit is None:
            return t
        phase, period = fit
        return phase + (math.floor((t - phase) / period) + 0.5) * period


class ModbusLink(threading.Thread):
    """Owns the Modbus client: on each of its cycles writes the rate-limited setpoint (or a hold, or the
    heartbeat) and reads the actual pose. The device's cycle is this thread's, on `clock`."""

    def __init__(
        self,
        client: Client,
        describe: str,
        p: SimpleNamespace,
        probe: Callable[[], str],
        claim: list[int] | None = None,
        clock: Callable[[], float] = time.monotonic,
        reading: mm.ControllerReading | None = None,
    ) -> None:
        super().__init__(name="robot-modbus-link", daemon=True)
        self.clock = clock
        self.client = client
        self.claim = claim  # our ownership registers, written again on every reconnect
        self.describe = describe
        self.p = p
        self.probe = probe  # why a connect failed, as text
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.stop_event = threading.Event()
        self.stopping = False
        self.target: mm.PoseTwist | None = None  # the latest commanded setpoint; None: hold
        self.fresh = False  # a command (or hold) was handed over since the last cycle took one
        self.handover = Handover()  # the pose for the time of each cycle, from the command's time and velocity
        self.limiter = SetpointLimiter(p.max_speed, p.max_angular_speed, p.max_cycle)
        # (m, rad) the commanded setpoint is ahead of the one sent; None: not known (a cycle under way, or
        # nothing sent since the robot last stopped)
        self.lag: tuple[float, float] | None = (0.0, 0.0)
        self.hold_latched = False
        self.hold_written = threading.Event()
        self.connected = True  # setup hands over a connected, verified client
        self.lost_since: float | None = None
        self._backoff = p.reconnect_min  # the wait after the next failed reconnect (doubles)
        self.cycle_at: float = clock()  # when the previous device cycle ran
        # The cycles' grid (every poll_period on `clock`): a regular cycle lands at the same phase of the
        # controller's own cycle each time, so the controller takes each write the same number of its
        # cycles after the last; a cycle timed by the graph's commands or by the exchange's own length would
        # beat against it (writes 1.6 and 2.4 ms apart taken 1, 2 or 3 cycles apart).
        self._next_at: float | None = None
        self.phase = ControllerPhase()  # the controller's cycles, each write placed between two of them
        self.last_error = ""
        self.reading: mm.ControllerReading | None = reading
        self.readings = 0
        self.heartbeat = 0
        self.writes = 0
        self.setpoint_heartbeat = 0  # the heartbeat written with the last setpoint
        self.longest_gap_s = 0.0  # the longest the controller went without taking a write while moving
        self._progress_at = clock()  # when the controller last took a newer write (its heartbeat echo changed)
        self._echo: int | None = None
        self._moving = False
        self.largest_step = 0.0  # m: the largest step between two setpoints sent in a row (not across a resume)
        self.reconnects = 0
        self.fatal: str | None = None
        self.notes: list[str] = []  # log lines for the node thread to emit
        self.cycles = CycleLog()  # every exchange: what was sent, what was read, when (the driver publishes it)
        self._written = reading.actual if reading is not None else None  # the last setpoint written

    # -- from the node thread -------------------------------------------------
    def submit(self, setpoint: mm.PoseTwist | None, stamp: float | None = None, tick: float = 0.0) -> None:
        """Make this the latest setpoint (None: hold until the next one). Never queued: the link's next
        cycle takes the latest; with the command's `stamp`, the pose for the cycle's own time, up to `tick`
        ahead along the setpoint's velocity (dockhil/devices/handover.py)."""
        with self.lock:
            # A timed command moving on from one before it waits for the next cycle on the grid, which
            # writes the pose for its own time; the first, an untimed one or a hold goes at once.
            timed = setpoint is not None and stamp is not None and self.handover.motion is not None
            if setpoint is not None and stamp is not None:
                self.handover.put(
                    self.clock(), stamp, tick, setpoint[:3], setpoint[3:7], setpoint[7:10], setpoint[10:13]
                )
            else:
                self.handover.clear()
            self.target = setpoint
            self.fresh = True
        if not timed:
            self.wake.set()

    def hold(self, timeout: float) -> bool:
        """Hold from now on; True once a hold has been written to the controller."""
        with self.lock:
            self.hold_latched = True
            self.target = None
            self.hold_written.clear()
        self.wake.set()
        return self.hold_written.wait(timeout)

    def latest(self) -> tuple[int, mm.ControllerReading | None]:
        with self.lock:
            return self.readings, self.reading

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
        self.stop_event.set()
        self.wake.set()
        self.join(timeout=2.0 + 2 * self.p.timeout)
        if hasattr(self, "_switch_interval"):
            sys.setswitchinterval(self._switch_interval)

    # -- the thread -------------------------------------------------------------
    def _note(self, line: str) -> None:
        with self.lock:
            self.notes.append(line)

    def run(self) -> None:
        from dockhil.runtime import realtime

        # The device's cycle is this thread's: above the node loops in a process running real-time.
        realtime.raise_device_thread(self._note, "the Modbus link")
        while not self.stopping:
            wait = self.cycle_once()
            if not self.connected:
                self._next_at = None
                self.stop_event.wait(wait)  # commands do not shorten the backoff; close() does
            else:
                self.wake.wait(self._until_next(wait))

    def _until_next(self, wait: float) -> float:
        """The wait until the grid's next cycle (`wait` after a cycle that was no regular one)."""
        now, period = self.clock(), self.p.poll_period
        if wait != period or self._next_at is None:
            self._next_at = now + wait
        elif now >= self._next_at:  # past the cycle due: on to the next on the grid (late ones skipped)
            self._next_at += period * (1 + math.floor((now - self._next_at) / period))
            # between two of the controller's cycles, not at the edge where jitter takes it one early or late
            self._next_at = self.phase.mid(self._next_at)
        return max(0.0, self._next_at - now)

    def cycle_once(self) -> float:
        """One device cycle (or one reconnect attempt); the time to wait before the next."""
        if not self.connected:
            if not self._reconnect():
                wait, self._backoff = self._backoff, min(self._backoff * 2, self.p.reconnect_max)
                return wait
        self._backoff = self.p.reconnect_min
        self.wake.clear()
        with self.lock:
            target, fresh, self.fresh = self.target, self.fresh, False
            hold = self.hold_latched
            timed = self.handover.pose(self.clock()) if target is not None else None
        if (
            timed is not None and target is not None
        ):  # the pose for this cycle's time: written every cycle while it moves
            target, fresh = (*timed[0], *timed[1], *target[7:]), True
            self.lag = None  # until this cycle has sent toward the target
        try:
            self._cycle(target, fresh, hold)
        except Exception as exc:  # noqa: BLE001 - any failure of the link is a lost connection
            self._lost(exc)
            return 0.0
        return self.p.poll_period

    def _cycle(self, target: mm.PoseTwist | None, fresh: bool, hold: bool) -> None:
        client, dev = self.client, self.p.device_id
        now = self.clock()
        dt, self.cycle_at = now - self.cycle_at, now
        self.heartbeat = (self.heartbeat + 1) & 0xFFFF
        limiter = self.limiter
        reading = self.reading
        written = False
        if (
            reading is not None
            and not reading.status & mm.STATUS_FOLLOWING
            and (reading.heartbeat - self.setpoint_heartbeat) & 0xFFFF < 0x8000
        ):
            # The controller saw our last setpoint and does not follow (it holds, e.g. it lost our heartbeat):
            # it stands at the actual pose, and the next setpoint starts from there.
            limiter.reset()
        if hold or target is None:
            limiter.reset()
            if hold or fresh:
                self._check(
                    client.write_registers(
                        0, mm.encode_write(mm.CONTROL_ENABLE | mm.CONTROL_HOLD, self.heartbeat), device_id=dev
                    )
                )
            else:
                self._check(client.write_register(mm.HR_HEARTBEAT, self.heartbeat, device_id=dev))
            if hold:
                self.hold_written.set()
        elif fresh or limiter.lag(target) not in (None, (0.0, 0.0)):
            before = limiter.sent
            # read on connect (verify_and_hold's reading) before any cycle writes
            setpoint = limiter.next(target, reading.actual, dt, now)  # type: ignore[union-attr]
            if before is not None:
                step = math.sqrt(sum((b - a) ** 2 for a, b in zip(before[:3], setpoint[:3])))
                self.largest_step = max(self.largest_step, step)
            self._check(
                client.write_registers(0, mm.encode_write(mm.CONTROL_ENABLE, self.heartbeat, setpoint), device_id=dev)
            )
            self.writes += 1
            limiter.wrote(self.heartbeat, now, setpoint)
            self.setpoint_heartbeat = self.heartbeat
            self._written, written = setpoint, True
        else:
            self._check(client.write_register(mm.HR_HEARTBEAT, self.heartbeat, device_id=dev))
        lag = limiter.lag(target) if target is not None and not hold else (0.0, 0.0)
        rr = self._check(client.read_input_registers(0, count=mm.IR_COUNT, device_id=dev))
        reading = mm.decode_inputs(rr.registers)
        self.phase.read(self.clock(), reading.cycle)
        limiter.echoed(reading.heartbeat)
        self._progress(reading.heartbeat, target is not None and not hold)
        # The controller echoes the heartbeat it last took: this one, if it ran a cycle since the write.
        self.cycles.add(
            now,
            self.clock(),
            self._written or reading.actual,
            written,
            reading.actual,
            reading.cycle,
            reading.heartbeat == self.heartbeat,
        )
        with self.lock:
            self.reading = reading
            self.readings += 1
            self.lag = lag

    def _progress(self, echo: int | None, moving: bool) -> None:
        """The controller took a newer write when its heartbeat echo changes: the time since the last one,
        while moving, is a gap in the device's cycles (a stalled controller, a lost connection)."""
        now = self.clock()
        if self._moving and (echo != self._echo or not moving):
            self.longest_gap_s = max(self.longest_gap_s, now - self._progress_at)
        if echo != self._echo or not moving or not self._moving:
            self._echo, self._progress_at = echo, now
        self._moving = moving

    @staticmethod
    def _check(response):
        if response.isError():
            raise ConnectionError(f"controller answered with an error: {response}")
        return response

    def _lost(self, exc: BaseException) -> None:
        self.client.close()
        self.connected = False
        self.lost_since = self.clock()
        self._echo = None  # the next reading after the reconnect closes the gap, if it moved when lost
        self.phase.clear()  # a controller that restarted counts its cycles anew
        self.last_error = " ".join(str(exc).split()) or type(exc).__name__
        self.limiter.reset()
        with self.lock:
            self.target = None  # a setpoint handed over before the loss is never written
            self.fresh = False
            self.lag = (0.0, 0.0)
        self._note(f"warning: {self.describe}: connection lost ({self.last_error}); reconnecting")

    def _reconnect(self) -> bool:
        if not self.client.connect():
            self.last_error = self.probe()
            return False
        try:
            reading = verify_and_hold(self.client, self.p.device_id, self.heartbeat, self.claim)
        except mm.RegisterError as exc:
            self.fatal = f"{self.describe}: {exc}"
            self.stopping = True
            return False
        except Exception as exc:  # noqa: BLE001
            self.client.close()
            self.last_error = " ".join(str(exc).split())
            return False
        now = self.clock()
        with self.lock:
            self.target = None  # commands from before the reconnect are stale
            self.fresh = False
            self.reading = reading  # the actual pose the next setpoint starts from
            if self.hold_latched:
                self.hold_written.set()
        self.limiter.reset()
        self._progress(None, False)  # the gap of a loss while moving ends here (the robot holds until a command)
        gap = now - (self.lost_since or now)
        self.cycle_at = now
        self.connected = True
        self.lost_since = None
        self.reconnects += 1
        self._note(
            f"{self.describe}: reconnected after {gap:.2f} s; holding until a fresh command, then "
            f"moving on from the actual pose"
        )
        return True


def read_owner(client: Client, device_id: int) -> tuple[int, str]:
    rr = client.read_input_registers(mm.IR_OWNER, count=mm.IR_OWNER_COUNT, device_id=device_id)
    if rr.isError():
        raise mm.RegisterError(
            f"cannot read the owner registers (input {mm.IR_OWNER}-{mm.IR_END - 1}): {rr}; "
            f"without them nothing keeps another graph from commanding this robot"
        )
    return mm.decode_owner(rr.registers)


def claim_controller(client: Client, device_id: int, claim: list[int]) -> None:
    """Claim the controller for our session; RegisterError naming the owner if another host has it."""
    ours = mm.decode_owner(claim)[0]
    session, name = read_owner(client, device_id)
    if session not in (0, ours):
        raise mm.RegisterError(_owned(session, name))
    wr = client.write_registers(mm.HR_SESSION, claim, device_id=device_id)
    if wr.isError():  # another host claimed it in between
        raise mm.RegisterError(_owned(*read_owner(client, device_id)))


def _owned(session: int, name: str) -> str:
    return (
        f"owned by graph {name or '(no name)'} (session {session:#010x}); nothing written. Stop that graph "
        f"first; a claim ends when its owner stops, or when its heartbeat has been silent for the "
        f"controller's heartbeat timeout"
    )


def verify_and_hold(
    client: Client, device_id: int, heartbeat: int, claim: list[int] | None = None
) -> mm.ControllerReading:
    """Check the device speaks this register map, claim it if asked, then hold the robot where it is."""
    rr = client.read_input_registers(0, count=mm.IR_COUNT, device_id=device_id)
    if rr.isError():
        raise mm.RegisterError(f"cannot read input registers 0-{mm.IR_COUNT - 1}: {rr}")
    reading = mm.decode_inputs(rr.registers)
    mm.start_orientation(reading)  # a controller that reports no rotation is refused before anything is written
    if claim is not None:
        claim_controller(client, device_id, claim)
    wr = client.write_registers(0, mm.encode_write(mm.CONTROL_ENABLE | mm.CONTROL_HOLD, heartbeat), device_id=device_id)
    if wr.isError():  # e.g. our claim lapsed in between: try again, as after any failed connect
        raise ConnectionError(f"cannot write holding registers 0-1: {wr}")
    return reading


class NoDelayClient:
    """The pymodbus client, with TCP_NODELAY set again after every reconnect."""

    def __init__(self, client: ModbusTcpClient) -> None:
        self._client = client

    def connect(self) -> bool:
        ok = self._client.connect()
        if ok:
            set_nodelay(self._client)
        return ok

    def __getattr__(self, name: str) -> Any:
        return getattr(self._client, name)


def set_nodelay(client: ModbusTcpClient) -> None:
    # Small request/response frames: do not let Nagle hold a setpoint back.
    sock = getattr(client, "socket", None)
    if sock is not None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass
