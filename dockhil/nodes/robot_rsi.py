"""Robot-command driver over KUKA RSI (Ethernet XML over UDP): the robot is the clock.

The controller sends one datagram per interpolation cycle (4 ms, or 12 ms)
and must have the answer within that cycle (dockhil/hardware/rsi.py). A link
thread blocks on the socket and answers each datagram at once from the latest
setpoint the node's step handed over (one reference replaced whole, never a
queue); step() only hands setpoints over and reads the latest actual pose.

The answer's RKorr is absolute: the correction from the pose the robot had
when RSI started (the first RIst seen), in the controller's BASE frame, mm and
degrees: commanded position = start + (X, Y, Z), commanded orientation =
R(A, B, C) R(start), a rotation about the TCP in BASE axes (configure the
controller's correction as absolute, in #BASE: docs/hardware.md). The scene's
robot frame (+x the docking axis) sits in BASE at KUKA angles scene_a,
scene_b, scene_c. The start pose is the scene's first commanded pose (bring
the robot there before starting RSI; in hil.yaml it is x = 0, the surfaces
touching): the correction is the command's change from it, and the published
state is the RIst pose relative to the start pose, in the scene frame, plus
that first pose, as robot_modbus publishes it. No state before the first
command.

The link thread, per datagram, in this order: only the configured controller's
address is read; a datagram that is oversized, malformed, without RIst or IPOC,
or whose IPOC is not above the last one is counted (one warning line per kind)
and neither answered nor used. Otherwise the correction moves toward the latest
setpoint by at most max_speed * cycle and max_angular_speed * cycle, and the
answer echoes the IPOC. The correction is held (does not change) when there is
no setpoint, when the setpoint is older than stall_timeout (the graph stalled)
or not finite, after a safety stop and at close.

Safety, in step(), as robot_modbus (the same limits, checked by the same
code): force and torque on the F/T input, the F/T watchdog, workspace and tilt,
the commanded twist and the command's lead, the following error from RIst, the
measured speed; a stall of this driver; an e-stop. A controller that sends
nothing for controller_timeout stopped RSI: the graph stops with one line.

Latency: the answer is one %-format of a prebuilt template after expat has read
a bounded datagram. The process's switch interval is lowered so that the link
thread waits for the interpreter at most that long while the node's thread runs;
`realtime` asks for SCHED_FIFO for the link thread (bench/rsi.py measures both).
"""

from __future__ import annotations

import math
import socket
import sys
import threading
import time

from dockhil.contact.rotations import IDENTITY, quat_conjugate, quat_from_rotvec, quat_multiply, rotate, rotate_back
from dockhil.errors import DeviceError, LaunchError
from dockhil.hardware import rsi
from dockhil.msgs import Pose, Quaternion, RobotState, Twist, Vector3
from dockhil.node import Param
from dockhil.hardware.robot_limits import command_values, message_key, non_finite
from dockhil.nodes.robot_modbus import RobotModbusDriver
from dockhil.runtime import realtime

SWITCH_INTERVAL = 0.0002  # s: longest wait of the link thread for the interpreter while another thread runs
VELOCITY_WINDOW_S = 0.02  # the measured twist is the pose's change over at least this long
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


class SceneFrame:
    """The scene's robot frame in the controller's BASE frame, the start pose (the first RIst), and the
    scene pose the robot had there (the first command: the robot was brought to the scene's start)."""

    def __init__(self, abc, start):
        self.q_sb = rsi.abc_to_quat(*abc)  # scene axes -> BASE axes
        self.p0 = start[:3]  # mm
        self.q0 = rsi.abc_to_quat(*start[3:])
        self.anchor((0.0, 0.0, 0.0), IDENTITY)

    def anchor(self, position, orientation) -> None:
        """The scene pose (m, quaternion) of the robot at the start pose."""
        self.a_p = tuple(position)
        self.a_q = tuple(orientation)

    def correction(self, position, orientation) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Scene pose (m, quaternion) -> correction from the start: (X Y Z mm, rotation quaternion) in BASE."""
        a = self.a_p
        d = rotate(self.q_sb, (position[0] - a[0], position[1] - a[1], position[2] - a[2]))
        turn = quat_multiply(orientation, quat_conjugate(self.a_q))  # in scene axes
        q = quat_multiply(quat_multiply(self.q_sb, turn), quat_conjugate(self.q_sb))
        return (d[0] * 1000.0, d[1] * 1000.0, d[2] * 1000.0), q

    def scene_pose(self, rist) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """RIst (mm, degrees in BASE) -> scene pose: (m, quaternion)."""
        p0, a = self.p0, self.a_p
        d = rotate_back(self.q_sb, ((rist[0] - p0[0]) / 1000.0, (rist[1] - p0[1]) / 1000.0, (rist[2] - p0[2]) / 1000.0))
        turn = quat_multiply(rsi.abc_to_quat(*rist[3:]), quat_conjugate(self.q0))  # in BASE axes
        q = quat_multiply(quat_multiply(quat_multiply(quat_conjugate(self.q_sb), turn), self.q_sb), self.a_q)
        return (a[0] + d[0], a[1] + d[1], a[2] + d[2]), q if q[3] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


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
        self.lock = threading.Lock()
        self.notes: list[str] = []
        self.fatal: str | None = None

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
        if self.last_ipoc >= 0:
            self.missing += max(0, round((frame.ipoc - self.last_ipoc) / (self.cycle * 1000.0)) - 1)
        self.last_ipoc = frame.ipoc
        if frame.delay is not None and self.delay_at_start is not None and frame.delay > self.delay:
            # An answer since the last datagram came late: the controller kept the correction it had
            # (HOLDON), so this cycle's step starts from there, not from what it never applied.
            self.korr = self.accepted
        else:
            self.accepted = self.korr
        answer = self.write(self._advance(now), frame.ipoc)
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
                    self.fatal = f"receiving failed: {exc.strerror or exc}"
                return
            t = clock()
            answer = handle(bytes(view[:n]), addr[0], t)
            if answer is None:
                continue
            try:
                sock.sendto(answer, addr)
            except OSError as exc:
                self._note(f"warning: answer to {addr[0]}:{addr[1]} not sent ({exc.strerror or exc})")
                continue
            self.answered += 1
            if self.hold_latched:
                self.hold_written.set()


class _Reading:
    """The actual pose as robot_modbus's checks read it: actual = position, quaternion, twist; status."""

    __slots__ = ("actual", "status")

    def __init__(self, actual):
        self.actual = actual
        self.status = 0


_SHARED = (
    "max_force",
    "max_actual_speed",
    "max_following_error",
    "max_torque",
    "max_actual_angular_speed",
    "max_tilt",
    "max_orientation_error",
    "x_min",
    "x_max",
    "y_min",
    "y_max",
    "z_min",
    "z_max",
    "ft_timeout",
    "stall_timeout",
    "ft_grace",
    "frame",
)


class RobotRsiDriver(RobotModbusDriver):
    """KUKA robot over RSI: corrections answered on the robot's cycle from /robot/command, actual pose to
    /robot/state, the safety limits of robot_modbus."""

    params = {
        "host": Param(str, "127.0.0.1", help="the controller's address: the only sender read"),
        "port": Param(
            int,
            49152,
            help="local UDP port the controller sends to (its Ethernet configuration's PORT)",
            ge=1,
            le=65535,
        ),
        "listen": Param(str, "0.0.0.0", help="local address to listen on"),
        "cycle": Param(
            float,
            0.004,
            unit="s",
            help="the controller's RSI cycle: 0.004 (KR C4/C5) or 0.012 (older controllers)",
            choices=rsi.CYCLES,
        ),
        "sentype": Param(str, "ImFree", help="the Sen Type the controller expects (its configuration's SENTYPE)"),
        "max_speed": Param(
            float,
            0.1,
            unit="m/s",
            help="commanded speed limit: the twist, and the command's "
            "lead on the correction; the correction moves at most this times the cycle per cycle",
            gt=0.0,
            le=10.0,
        ),
        "max_angular_speed": Param(
            float,
            0.5,
            unit="rad/s",
            help="commanded angular speed limit: the twist, "
            "and the command's lead on the correction; the correction turns at most this "
            "times the cycle per cycle",
            gt=0.0,
            le=10.0,
        ),
        **{name: RobotModbusDriver.params[name] for name in _SHARED},
        "connect_timeout": Param(
            float,
            10.0,
            unit="s",
            help="setup fails if no datagram came within this (start the RSI program on the controller)",
            gt=0.0,
            le=600.0,
        ),
        "controller_timeout": Param(
            float,
            0.5,
            unit="s",
            help="no datagram this long: the controller stopped RSI (a controller sends every cycle), the graph stops",
            gt=0.0,
            le=10.0,
        ),
        "scene_a": Param(
            float,
            0.0,
            unit="deg",
            help="KUKA angle A of the scene's robot frame (+x the docking axis) in the controller's BASE frame",
            ge=-180.0,
            le=180.0,
        ),
        "scene_b": Param(
            float, 0.0, unit="deg", help="KUKA angle B of the scene's robot frame in BASE", ge=-90.0, le=90.0
        ),
        "scene_c": Param(
            float, 0.0, unit="deg", help="KUKA angle C of the scene's robot frame in BASE", ge=-180.0, le=180.0
        ),
        "realtime": Param(
            bool,
            False,
            help="ask for SCHED_FIFO scheduling of the answering thread (root, "
            "CAP_SYS_NICE or an rtprio limit; one line and normal priority without); on under "
            "--realtime",
        ),
    }

    def setup(self) -> None:
        p = self.p
        if self.ctx.sim_time:
            raise LaunchError(
                f"node {self.ctx.name!r} commands a real robot and runs only in wall time (launch with --wall-time)"
            )
        for axis in "xyz":
            lo, hi = getattr(p, f"{axis}_min"), getattr(p, f"{axis}_max")
            if lo >= hi:
                raise LaunchError(f"node {self.ctx.name!r}: workspace {axis}_min {lo} must be below {axis}_max {hi}")
        try:
            rsi.SenWriter(p.sentype)
        except ValueError as exc:
            raise LaunchError(f"node {self.ctx.name!r}: sentype: {exc}") from None
        ticks = p.cycle / self.ctx.dt
        if abs(ticks - round(ticks)) > 1e-6:
            self.log(
                f"warning: the scene's rate {1 / self.ctx.dt:g} Hz is not a multiple of the RSI rate "
                f"{1 / p.cycle:g} Hz: the robot takes every {ticks:.2f}th setpoint, unevenly (docs/time.md)"
            )
        self.device = f"robot controller (KUKA RSI {p.host} -> UDP port {p.port})"
        self.link: RsiLink | None = None
        self.tripped = None
        self._last_cmd = None
        self._last_wrench_key = None
        self._last_wrench_t: float | None = None
        self._first_t: float | None = None
        self._last_step_at: float | None = None
        self._last_cmd_at: float | None = None
        self._moving = False  # a setpoint was handed over since the last hold
        self._start_q = IDENTITY  # the first command's orientation, once it came (max_tilt)
        self._anchored = None  # the first command: the scene pose of the start pose
        self._seen = 0
        self._history: list[tuple[float, tuple, tuple]] = []
        self._actual = None
        self._lock = rsi.claim_port(p.port)  # one graph per RSI port, refused in one line naming the owner
        try:
            self._open()
        except BaseException:
            self._lock.release()
            raise

    def _open(self) -> None:
        p = self.p
        try:
            controller = socket.gethostbyname(p.host)
        except OSError as exc:
            raise DeviceError(f"{self.device}: cannot resolve {p.host!r}: {exc.strerror or exc}") from None
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((p.listen, p.port))
        except OSError as exc:
            sock.close()
            raise DeviceError(
                f"{self.device}: cannot listen on {p.listen}:{p.port}: {exc.strerror or exc} "
                f"(another program uses the port?)"
            ) from None
        sock.settimeout(0.05)  # the link looks at `stopping` this often
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval, SWITCH_INTERVAL))
        inherited = realtime.granted()  # a node loop launched with --realtime: its answering thread goes above it
        self.link = RsiLink(
            sock,
            controller,
            p.cycle,
            p.max_speed,
            p.max_angular_speed,
            p.stall_timeout,
            p.sentype,
            self.ctx.clock,
            p.realtime or inherited,
        )
        self.link.start()
        if not self.link.started.wait(p.connect_timeout):
            counted = ", ".join(f"{n} {KINDS[k]}" for k, n in self.link.counted.items() if n)
            self._stop_link(self.link)
            self.link = None
            extra = f" (datagrams ignored: {counted})" if counted else ""
            raise DeviceError(
                f"{self.device}: no RSI datagram from {p.host} within {p.connect_timeout:g} s: start "
                f"the RSI program on the controller, and check its Ethernet configuration's IP_NUMBER "
                f"and PORT name this host and port {p.port}{extra}"
            )
        self.frame = SceneFrame((p.scene_a, p.scene_b, p.scene_c), self.link.first.rist)
        start = self.link.first.rist
        self.log(
            f"{self.device}: RSI running, cycle {p.cycle * 1000:g} ms; start pose X {start[0]:.2f} "
            f"Y {start[1]:.2f} Z {start[2]:.2f} mm, A {start[3]:.2f} B {start[4]:.2f} C {start[5]:.2f} deg"
        )

    def _stop_link(self, link: RsiLink) -> None:
        link.stopping = True
        link.join(timeout=2.0)
        link.sock.close()
        sys.setswitchinterval(self._switch_interval)

    # -- step -----------------------------------------------------------------------
    def step(self, tick, inputs):
        if self.tripped is not None:
            raise self.tripped  # latched: the correction stays held after a safety stop
        link, p = self.link, self.p
        now = self.ctx.clock()
        for line in link.take_notes():
            self.log(line)
        if link.fatal:
            raise DeviceError(f"{self.device}: {link.fatal}")
        if self._last_step_at is not None and now - self._last_step_at > p.stall_timeout:
            gap = now - self._last_step_at
            self._trip(
                "stall",
                gap,
                f"stall: no step for {gap:.3f} s > stall_timeout {p.stall_timeout:g} s "
                f"(this process was stopped or starved); resuming would jump",
            )
        self._last_step_at = now
        latest = link.latest
        silent = now - latest[2]
        if silent > p.controller_timeout:
            link.hold_latched = True
            raise DeviceError(
                f"{self.device}: no datagram for {silent:.3f} s > controller_timeout "
                f"{p.controller_timeout:g} s: the controller stopped RSI (late answers: Delay "
                f"D={link.delay}; see its message window)"
            )
        if self._first_t is None:
            self._first_t = now

        estop = inputs.get("estop")
        if estop is not None and estop.active:
            self._trip("estop", estop.reason or "active", f"estop: e-stop active ({estop.reason or 'no reason given'})")

        ft_fresh = self._check_wrench(inputs.get("wrench"), now)
        cmd = inputs.get("command")
        if self._anchored is None:
            if cmd is None:
                return {}  # no state before the scene says where the robot stands
            self._check_command_values(cmd)
            values = command_values(cmd)
            self.frame.anchor(values[:3], values[3:7])
            self._start_q = values[3:7]
            self._anchored = values
            self.log(f"the start pose is the scene's pose x {values[0]:.4f} y {values[1]:.4f} z {values[2]:.4f} m")
        reading = self._reading(latest)
        if cmd is not None and (self._last_cmd is None or message_key(cmd) != message_key(self._last_cmd)):
            self._check_command(cmd, reading)
            self._last_cmd, self._last_cmd_at = cmd, now
            if not ft_fresh or not cmd.enable:
                link.submit(None, None)  # no F/T data yet: hold rather than move blind
                self._moving = False
            else:
                values = command_values(cmd)
                link.submit(*self.frame.correction(values[:3], values[3:7]))
                self._moving = True
        elif self._moving and now - self._last_cmd_at > p.stall_timeout:
            age = now - self._last_cmd_at
            self._trip(
                "stale_command",
                age,
                f"stale command: no new setpoint for {age:.3f} s > stall_timeout "
                f"{p.stall_timeout:g} s while moving (the simulation stalled)",
            )

        self._check_ahead()

        if latest[0] == self._seen:
            return {}
        self._seen = latest[0]
        self._check_actual(reading)
        a = reading.actual
        return {
            "state": RobotState(
                header=tick.header(p.frame),
                pose=Pose(position=Vector3(a[0], a[1], a[2]), orientation=Quaternion(a[3], a[4], a[5], a[6])),
                twist=Twist(linear=Vector3(a[7], a[8], a[9]), angular=Vector3(a[10], a[11], a[12])),
                status="ok",
            )
        }

    def _check_ahead(self) -> None:
        """The link moves the correction by at most one cycle's travel at max_speed (max_angular_speed)
        toward the command, so late or bunched commands only put the command briefly ahead of the
        correction sent. A command further ahead than stall_timeout's travel (or the following error, at
        the start) moves faster than the limit: robot_modbus's rule, on the correction in BASE."""
        link, p = self.link, self.p
        target = link.target
        if not self._moving or target is None:
            return
        (kp, kq, _), tp, tq = link.korr, target[1], target[2]
        distance = math.sqrt(sum((a - b) ** 2 for a, b in zip(kp, tp))) / 1000.0
        x, y, z, w = quat_multiply(tq, quat_conjugate(kq))
        turn = 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))
        if distance > max(p.max_speed * p.stall_timeout, p.max_following_error):
            self._trip(
                "max_speed",
                distance,
                f"max_speed: the command ran {distance:.4f} m ahead of the "
                f"correction sent at {p.max_speed:g} m/s (more than stall_timeout {p.stall_timeout:g} s "
                f"of travel and max_following_error): it moves faster than max_speed",
            )
        if turn > max(p.max_angular_speed * p.stall_timeout, p.max_orientation_error):
            self._trip(
                "max_angular_speed",
                turn,
                f"max_angular_speed: the command turned {turn:.4f} rad ahead "
                f"of the correction sent at {p.max_angular_speed:g} rad/s (more than stall_timeout "
                f"{p.stall_timeout:g} s of turning and max_orientation_error): it turns faster than "
                f"max_angular_speed",
            )

    def _check_command_values(self, cmd) -> None:
        """The first command, which anchors the scene to the start pose, must be a pose."""
        bad = non_finite(("position", cmd.pose.position), ("orientation", cmd.pose.orientation))
        if bad:
            self._trip("non_finite", bad, f"non-finite setpoint: commanded {bad}")
        self._check_unit("commanded", command_values(cmd)[3:7])

    def _reading(self, latest) -> _Reading:
        """The latest RIst in the scene frame, with the twist over VELOCITY_WINDOW_S of receive times."""
        count, frame, t = latest
        if self._actual is not None and self._actual[0] == count:
            return self._actual[1]
        position, q = self.frame.scene_pose(frame.rist)
        history = self._history
        history.append((t, position, q))
        while len(history) > 2 and t - history[1][0] >= VELOCITY_WINDOW_S:
            history.pop(0)
        t0, p0, q0 = history[0]
        span = t - t0
        linear = angular = (0.0, 0.0, 0.0)
        if span > 0:
            linear = tuple((a - b) / span for a, b in zip(position, p0))
            x, y, z, w = quat_multiply(q, quat_conjugate(q0))
            if w < 0.0:
                x, y, z, w = -x, -y, -z, -w
            s = math.sqrt(x * x + y * y + z * z)
            k = (2.0 * math.atan2(s, w) / s if s > 1e-12 else 2.0) / span
            angular = (x * k, y * k, z * k)
        reading = _Reading((*position, *q, *linear, *angular))
        self._actual = (count, reading)
        return reading

    def close(self) -> None:
        link = getattr(self, "link", None)
        if link is None:
            return
        self.link = None
        received = link.received
        # Hold: the answers keep the last correction until the controller has one of them, then stop.
        held = link.hold(min(0.25, 3 * self.p.cycle + 0.05))
        sending = link.received != received  # no datagram while we waited: RSI had stopped, nothing to hold
        self._stop_link(link)
        for line in link.take_notes():
            self.log(line)
        counted = ", ".join(f"{n} {KINDS[k]}" for k, n in link.counted.items() if n)
        if counted:
            self.log(f"warning: {self.device}: datagrams ignored: {counted}")
        if link.missing:
            self.log(
                f"warning: {self.device}: {link.missing} controller datagrams never came (gaps in the IPOC "
                f"between {link.first.ipoc} and {link.last_ipoc})"
            )
        if link.stale_holds:
            self.log(f"warning: {self.device}: held on a stale setpoint for {link.stale_holds} cycles")
        if link.delay_at_start is not None and link.delay > link.delay_at_start:
            self.log(f"warning: {self.device}: the controller counted {link.delay - link.delay_at_start} late answers")
        self._lock.release()
        if not held and self.tripped is None and sending:
            self.log(
                f"warning: {self.device}: could not confirm the hold at close; the controller stops RSI "
                f"when the answers stop"
            )
