"""Robot-controller emulator: a Modbus TCP server (dockhil.devices.modbus_robot.server) with a servo behind it.

It serves the register map of dockhil/devices/modbus_robot/registers.py. A servo
cycle, on its own clock as a real controller's, follows the setpoint
through a pure delay and a first-order lag:

    target(t) = setpoint written at t - delay
    d position/dt = (target - position) / tau            (tau = 0: pose = target)
    orientation:  the same lag on the rotation from the actual orientation to
                  the target's, the shortest way: per cycle of dt, a slerp by
                  a = 1 - exp(-dt/tau), so the remaining angle decays as
                  exp(-t/tau) about a fixed axis

sampled once per servo cycle. When, inside the controller, the cycles are
spent is `timing` (a host cannot know it; both are plausible): `ours`, a
setpoint is taken by the next cycle and becomes the target at the first cycle
`delay` after it (a zero-order hold on whole cycles, as in a digital
controller), and a read returns the pose after the servo's step over the cycle
before; `immediate`, a setpoint is taken as it is written, the servo follows it
`delay` later in continuous time (any delay, not whole cycles), and a read
returns the pose sampled at the last cycle, before the servo's step over the
next. The actual
twist is the pose's change over the last VELOCITY_WINDOW_S: linear velocity
[m/s], and angular velocity [rad/s] as the rotation vector of that change
divided by its time, both in the reference frame of the pose (the target's
interface frame).

Controller rules the driver relies on:
- FOLLOWING needs ENABLE, no HOLD, a live heartbeat, and a setpoint written
  since the robot last stopped: after a hold, a lost heartbeat or a restart
  the controller never resumes on an old setpoint; it holds until a fresh one.
- A heartbeat that does not change for `heartbeat_timeout` holds the robot
  and sets HEARTBEAT_LOST, so a host that dies mid-motion stops the robot.
- HOLD and DISABLED stop at the actual pose; the delay line is flushed.
- FAULT (set by `inject_fault`, for tests, or by a setpoint whose quaternion
  is not unit within modbus_map.UNIT_TOLERANCE) holds until CONTROL RESET.
- One owner: while a host's claim (SESSION, OWNER_NAME) is alive, writes from
  any other connection are refused with exception 6 (device busy), so a
  second graph cannot move or hold the first one's robot; the claim dies
  with the owner's heartbeat or when it writes SESSION 0.
- No claim, no motion: a write of CONTROL, HEARTBEAT or SETPOINT (registers
  0..27) from a connection that holds no live claim is refused the same way
  (exception 6), counted (`unclaimed`) and logged once per connection; it
  never moves the robot. A host whose claim lapsed (it stalled past the
  heartbeat timeout) claims again before it writes anything.

Run alone: python -m dockhil.devices.modbus_robot.emulator --port 5020 [--delay S --tau S]
It prints "listening HOST:PORT" once it accepts connections.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import sys
import threading
import time
from collections import deque

from dockhil.contact.rotations import quat_conjugate, quat_from_rotvec, quat_multiply, quat_to_rotvec
from dockhil.devices.limits import UNIT_TOLERANCE
from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.server import DEVICE_BUSY, READ_INPUT, ModbusTcpServer
from dockhil.devices.servo_line import follow_due

FOLLOW, HOLD, DISABLED = "follow", "hold", "disabled"


def _normalize(q):
    n = math.sqrt(sum(c * c for c in q))
    return tuple(c / n for c in q) if n > 0 else (0.0, 0.0, 0.0, 1.0)


def _is_unit(q) -> bool:
    return abs(math.sqrt(sum(c * c for c in q)) - 1.0) <= UNIT_TOLERANCE


def _rotation_between(q_old, q_new):
    """Rotation vector [rad] (the shortest way, angle in [0, pi]) that turns q_old into q_new,
    in the reference frame: q_new = exp(v) q_old."""
    return quat_to_rotvec(quat_multiply(q_new, quat_conjugate(q_old)))


VELOCITY_WINDOW_S = 0.01
TIMINGS = ("ours", "immediate")  # where inside the controller its cycles are spent (module docstring)


class ServoModel:
    """The controller's state machine and servo, advanced by `cycle(now)`. No I/O: with the `immediate`
    timing, a write says when it came (`host_wrote(..., now=)`)."""

    def __init__(self, delay: float = 0.0, tau: float = 0.0, heartbeat_timeout: float = 0.2, timing: str = "ours"):
        if timing not in TIMINGS:
            raise ValueError(f"timing {timing!r}: one of {', '.join(TIMINGS)}")
        self.timing = timing
        self.delay = delay
        self.tau = tau
        self.heartbeat_timeout = heartbeat_timeout
        self.holding = mm.encode_write(0, 0, mm.HOLD_POSE)  # what the host wrote
        self.position = [0.0, 0.0, 0.0]
        self.orientation = (0.0, 0.0, 0.0, 1.0)
        self.linear = (0.0, 0.0, 0.0)
        self.angular = (0.0, 0.0, 0.0)
        self.mode = DISABLED
        self.fault = False
        self.heartbeat_lost = False
        self.cycles = 0
        self.max_speed = 0.0  # m/s: the largest actual speed reported (a test checks a run kept its limits)
        self.max_position = [-math.inf] * 3  # m: the largest actual position reached, per axis
        self.setpoint_fresh = False  # a setpoint was written since the robot last stopped
        self._last_heartbeat: int | None = None
        self._heartbeat_t: float | None = None
        self._last_t: float | None = None
        self._line: deque = deque()  # (time written, setpoint) awaiting the delay
        self._history: deque = deque()  # (time, position, orientation) over the velocity window
        self._target = self._actual_pose()
        self.inputs = mm.encode_inputs(0, 0, 0, self.actual())
        # Ownership: the session and name of the host whose claim is alive, and its connection.
        self.owner_session = 0
        self.owner_name = ""
        self.owner_client = None
        self.claim = mm.encode_owner(0, "")  # holding registers 28..45 as last written
        self.refused = 0  # writes refused: another host owns the controller, or no live claim
        self.unclaimed = 0  # of those, writes of control, heartbeat or setpoint without a live claim
        self.log = None  # callable(line): says once per connection that its writes are refused
        self._told: set = set()  # connections already told of
        self._claim_new = False
        self._claimed_at: float | None = None

    def _actual_pose(self):
        return tuple(self.position) + tuple(self.orientation)

    def actual(self) -> mm.PoseTwist:
        return tuple(self.position) + tuple(self.orientation) + tuple(self.linear) + tuple(self.angular)

    def host_wrote(self, address: int, values: list[int], client=None, now: float | None = None) -> bool:
        """A Modbus write to holding registers [address, address + len) over connection `client` at time `now`
        (the servo's clock; None: the last cycle's); False if refused: another host owns the controller (or a
        claim without its session id)."""
        end = address + len(values)
        claim = list(values[mm.HR_SESSION - address :]) if address <= mm.HR_SESSION < end else None
        if claim is not None and (address != mm.HR_SESSION or len(claim) < 2):
            self.refused += 1  # a claim writes its session id whole, alone
            return False
        session = None if claim is None else (claim[0] << 16) | claim[1]
        if self.owner_session and client != self.owner_client and session != self.owner_session:
            self.refused += 1
            return False
        if address < mm.HR_COUNT and (not self.owner_session or client != self.owner_client):
            # Control, heartbeat and setpoint move the robot: only the live claim's connection may write them.
            self.refused += 1
            self.unclaimed += 1
            if self.log is not None and client not in self._told:
                self._told.add(client)
                self.log(
                    f"refused a write of holding registers {address}-{end - 1} from connection {client}: "
                    f"it holds no live claim (claim SESSION and OWNER_NAME, registers {mm.HR_SESSION}-"
                    f"{mm.HR_END - 1}, first); counting, not logging, the rest"
                )
            return False
        if claim is not None:
            if session == 0:
                self._release()
            else:
                self.claim = (claim + mm.encode_owner(0, "")[len(claim) :])[: mm.HR_CLAIM_COUNT]
                self.owner_session, self.owner_name = mm.decode_owner(self.claim)
                self.owner_client = client
                self._claim_new = True
        end = min(end, mm.HR_COUNT)
        if address < 0 or address >= end:
            return True
        self.holding[address:end] = values[: end - address]
        if end > mm.HR_SETPOINT:
            self.setpoint_fresh = True
            if self.timing == "immediate" and self.mode == FOLLOW:  # taken as it comes
                self._take(self._last_t if now is None else now)
        return True

    def _take(self, now: float | None) -> None:
        setpoint = mm.decode_holding(self.holding).setpoint
        self._line.append((now if now is not None else 0.0, setpoint[:3] + _normalize(setpoint[3:7])))

    def _release(self) -> None:
        self.owner_session, self.owner_name, self.owner_client = 0, "", None
        self.claim = mm.encode_owner(0, "")
        self._claimed_at = None

    def owner_inputs(self) -> list[int]:
        """Input registers 31..48: who owns the controller."""
        return mm.encode_owner(self.owner_session, self.owner_name)

    def status(self) -> int:
        s = 0
        control = self.holding[mm.HR_CONTROL]
        if control & mm.CONTROL_ENABLE:
            s |= mm.STATUS_ENABLED
        if self.mode == HOLD:
            s |= mm.STATUS_HOLDING
        if self.mode == FOLLOW:
            s |= mm.STATUS_FOLLOWING
        if self.fault:
            s |= mm.STATUS_FAULT
        if self.heartbeat_lost:
            s |= mm.STATUS_HEARTBEAT_LOST
        return s

    def cycle(self, now: float) -> None:
        host = mm.decode_holding(self.holding)
        if host.heartbeat != self._last_heartbeat:
            self._last_heartbeat, self._heartbeat_t = host.heartbeat, now
        self.heartbeat_lost = self._heartbeat_t is None or now - self._heartbeat_t > self.heartbeat_timeout
        if self._claim_new:
            self._claim_new, self._claimed_at = False, now
        if self.owner_session:
            # The claim lives on the owner's heartbeat: a host that died or lost the link lets go.
            last = max(self._claimed_at, self._heartbeat_t if self._heartbeat_t is not None else self._claimed_at)
            if now - last > self.heartbeat_timeout:
                self._release()
        if host.control & mm.CONTROL_RESET:
            self.fault = False
            self.holding[mm.HR_CONTROL] &= ~mm.CONTROL_RESET  # a one-shot command
        if self.setpoint_fresh and not _is_unit(host.setpoint[3:7]):
            self.fault = True  # a setpoint orientation that is no rotation: refuse it, hold until RESET
        if not host.control & mm.CONTROL_ENABLE:
            mode = DISABLED
        elif host.control & mm.CONTROL_HOLD or self.heartbeat_lost or self.fault:
            mode = HOLD
        else:
            mode = FOLLOW if self.setpoint_fresh else HOLD
        if mode != FOLLOW:
            self.setpoint_fresh = False  # resuming needs a setpoint written from now on
        immediate = self.timing == "immediate"
        if immediate:  # the pose of now: the setpoints followed from when each was due
            self._advance(now)
        if mode != self.mode:
            self._line.clear()
            self._target = self._actual_pose()  # stop where the robot is
            self.mode = mode
            if immediate and mode == FOLLOW:
                self._take(now)
        if not immediate:
            # The pose moves over the cycle that ends now toward the target held
            # during it (a zero-order hold), then the target for the next cycle is
            # taken from the delay line.
            self._advance(now)
            if mode == FOLLOW:
                self._line.append((now, host.setpoint[:3] + _normalize(host.setpoint[3:7])))
                while self._line and self._line[0][0] <= now - self.delay:
                    self._target = self._line.popleft()[1]
        self.cycles = (self.cycles + 1) & 0xFFFF
        self.inputs = mm.encode_inputs(self.status(), host.heartbeat, self.cycles, self.actual())

    def _advance(self, now: float) -> None:
        t = now if self._last_t is None else self._last_t
        self._last_t = now
        if self.timing == "immediate":  # each target from the moment it is due, the lag exact in between
            follow_due(self._line, self.delay, t, now, self._follow, self._set_target)
        else:
            self._follow(now - t)
        self._record(now)

    def _set_target(self, target: tuple) -> None:
        self._target = target

    def _follow(self, dt: float) -> None:
        """The first-order lag toward the target over dt (exact for a target held over it)."""
        target = self._target
        if self.tau > 0 and dt > 0:
            a = 1.0 - math.exp(-dt / self.tau)
        else:
            a = 1.0 if self.tau == 0 else 0.0
        self.position = [p + a * (t - p) for p, t in zip(self.position, target[:3])]
        # The same lag on the rotation: a slerp by `a` toward the target (the shortest way), so the
        # remaining angle decays as the position error does, exp(-t/tau), about a fixed axis.
        error = _rotation_between(self.orientation, target[3:7])
        self.orientation = _normalize(quat_multiply(quat_from_rotvec(a * error), self.orientation))

    def _record(self, now: float) -> None:
        # Velocity over a window of VELOCITY_WINDOW_S, as a controller filters its encoders:
        # a per-cycle difference turns the host's write jitter into spurious speed spikes.
        self._history.append((now, list(self.position), self.orientation))
        while len(self._history) > 2 and now - self._history[1][0] >= VELOCITY_WINDOW_S:
            self._history.popleft()
        t_old, p_old, q_old = self._history[0]
        span = now - t_old
        if span > 0:
            self.linear = tuple((p - o) / span for p, o in zip(self.position, p_old))
            self.angular = tuple(float(w) / span for w in _rotation_between(q_old, self.orientation))
        self.max_speed = max(self.max_speed, math.sqrt(sum(v * v for v in self.linear)))
        self.max_position = [max(m, p) for m, p in zip(self.max_position, self.position)]

    def teleport(self, position, orientation=None) -> None:
        """Move the actual pose at once (tests: an encoder jump, a collision); the servo pulls it back."""
        self.position = list(position)
        if orientation is not None:
            self.orientation = _normalize(orientation)

    def place(self, position, orientation) -> None:
        """Put the robot at rest at this pose, where the servo holds it (tests: a robot that starts
        away from the scene's start pose)."""
        self.position = list(position)
        self.orientation = _normalize(orientation)
        self._target = self._actual_pose()
        self._history.clear()


class RobotControllerEmulator:
    """The Modbus TCP server and the servo, on one asyncio loop (so a request
    and a servo cycle never interleave)."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 5020,
        delay: float = 0.0,
        tau: float = 0.0,
        cycle: float = 0.001,
        heartbeat_timeout: float = 0.2,
        clock=time.monotonic,
        log=None,
        timing: str = "ours",
    ):
        self.clock = clock  # the servo's time (monotonic seconds); ServoModel itself takes `now` per cycle
        self.host = host
        self.port = port
        self.period = cycle
        self.servo = ServoModel(delay, tau, heartbeat_timeout, timing)
        self.servo.log = log
        self.requests = 0
        self._server = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stopped: asyncio.Event | None = None
        self._servo_task: asyncio.Task | None = None

    def _action(self, function: int, address: int, count: int, values: list[int] | None, connection: int):
        """One request (dockhil.devices.modbus_robot.server's handle): the registers read, None for a write, or an
        exception code."""
        self.requests += 1
        if function == READ_INPUT:  # hand out the servo's latest
            return (self.servo.inputs + self.servo.owner_inputs())[address : address + count]
        if values is not None:
            if not self.servo.host_wrote(address, values, connection, self.clock()):
                return DEVICE_BUSY  # another host owns the controller
            return None
        # holding read: the controller may have changed them (RESET)
        return (self.servo.holding + self.servo.claim)[address : address + count]

    async def start(self) -> int:
        """Listen and start the servo; return the port (useful with port 0)."""
        self._server = ModbusTcpServer(self._action, self.host, self.port, mm.HR_END, mm.IR_END)
        self.port = await self._server.start()
        self._stopped = asyncio.Event()
        self._servo_task = asyncio.get_running_loop().create_task(self._run_servo())
        return self.port

    async def _run_servo(self) -> None:
        clock = self.clock
        next_t = clock()
        while True:
            now = clock()
            self.servo.cycle(now)
            next_t += self.period
            delay = next_t - clock()
            if delay < -self.period:  # fell behind: do not burst to catch up
                next_t = clock()
                delay = 0.0
            await asyncio.sleep(max(delay, 0.0))

    async def stop_async(self) -> None:
        if self._servo_task is not None:
            self._servo_task.cancel()
        if self._server is not None:
            await self._server.stop()
        if self._stopped is not None:
            self._stopped.set()

    async def serve(self, on_listening=None) -> None:
        await self.start()
        if on_listening:
            on_listening(self)
        await self._stopped.wait()

    # -- in a thread, for a node or a test -----------------------------------
    def start_thread(self, timeout: float = 5.0) -> int:
        ready = threading.Event()
        error: list[BaseException] = []

        def run():
            from dockhil.runtime import realtime

            # It stands for the controller: its cycle is the device's clock, above the node loops.
            realtime.raise_device_thread(print if self.servo.log is None else self.servo.log, "the robot emulator")
            self._loop = asyncio.new_event_loop()
            try:
                self._loop.run_until_complete(self.start())
            except BaseException as exc:  # noqa: BLE001 - handed to the starting thread
                error.append(exc)
                ready.set()
                self._loop.close()
                return
            ready.set()
            self._loop.run_until_complete(self._stopped.wait())
            self._loop.close()

        self._thread = threading.Thread(target=run, name="robot-emulator", daemon=True)
        self._thread.start()
        if not ready.wait(timeout):
            raise RuntimeError("robot emulator did not start")
        if error:
            raise error[0]
        return self.port

    def call(self, fn, *args):
        """Run fn(*args) on the emulator's loop (between requests and servo cycles)."""
        if self._loop is None:
            return fn(*args)
        fut = asyncio.run_coroutine_threadsafe(self._call(fn, *args), self._loop)
        return fut.result(timeout=5.0 + (args[0] if fn is time.sleep else 0.0))

    @staticmethod
    async def _call(fn, *args):
        return fn(*args)

    def stop_thread(self) -> None:
        if self._loop is not None and self._thread is not None and self._thread.is_alive():
            asyncio.run_coroutine_threadsafe(self.stop_async(), self._loop).result(timeout=5.0)
            self._thread.join(timeout=5.0)

    def inject_fault(self) -> None:
        self.call(setattr, self.servo, "fault", True)

    def stall(self, seconds: float) -> None:
        """Stop the controller for `seconds`, as a SIGSTOP would: no request answered, no servo cycle."""
        self.call(time.sleep, seconds)


def claim_port(host: str, port: int):
    """Claim the emulator's port for this graph (port 0, a free port, needs no claim); a DeviceLock or None."""
    if port == 0:
        return None
    import socket

    from dockhil.runtime import ownership

    try:
        address = socket.gethostbyname(host)
    except OSError:
        address = host
    return ownership.claim(f"modbus-emulator-{address}-{port}", f"robot controller emulator port {host}:{port}")


def listen_problem(host: str, port: int) -> str:
    """Why listening on host:port fails, in the OS's words."""
    import socket

    try:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
    except OSError as exc:
        return exc.strerror or str(exc)
    return "the server did not start"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dockhil.devices.modbus_robot.emulator",
        description="Robot-controller emulator: Modbus TCP server with a servo.",
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=5020, help="TCP port (0: any free port)")
    parser.add_argument("--delay", type=float, default=0.0, help="servo delay [s]")
    parser.add_argument("--tau", type=float, default=0.0, help="servo lag time constant [s]")
    parser.add_argument("--cycle", type=float, default=0.001, help="servo period [s]")
    parser.add_argument(
        "--timing", choices=TIMINGS, default="ours", help="when a setpoint is taken and the pose sampled"
    )
    parser.add_argument("--heartbeat-timeout", type=float, default=0.2, help="hold when the heartbeat stops [s]")
    args = parser.parse_args(argv)
    from dockhil.errors import DockhilError
    from dockhil.log import Log

    say = Log("robot emulator:")
    for name, value, lo, hi in (
        ("--port", args.port, 0, 65535),
        ("--delay", args.delay, 0.0, 1.0),
        ("--tau", args.tau, 0.0, 10.0),
        ("--cycle", args.cycle, 1e-5, 0.1),
        ("--heartbeat-timeout", args.heartbeat_timeout, 1e-3, 10.0),
    ):
        if not lo <= value <= hi:  # NaN too
            say.error(f"{name} {value} is outside its range [{lo:g}, {hi:g}]")
            return 2
    try:
        lock = claim_port(args.host, args.port)  # held until this process ends
    except DockhilError as exc:
        say.error(str(exc))
        return 2
    emulator = RobotControllerEmulator(
        args.host,
        args.port,
        args.delay,
        args.tau,
        args.cycle,
        args.heartbeat_timeout,
        log=say.warning,
        timing=args.timing,
    )

    async def run():
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, lambda: loop.create_task(emulator.stop_async()))
        await emulator.serve(lambda em: print(f"listening {em.host}:{em.port}", flush=True))

    try:
        asyncio.run(run())
    except (OSError, RuntimeError):
        say.error(f"cannot listen on {args.host}:{args.port}: {listen_problem(args.host, args.port)}")
        return 2
    finally:
        if lock is not None:
            lock.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
