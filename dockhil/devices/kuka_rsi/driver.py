"""Robot-command driver over KUKA RSI (Ethernet XML over UDP): the robot is the clock.

The controller sends one datagram per interpolation cycle (4 ms, or 12 ms)
and must have the answer within that cycle (dockhil/devices/kuka_rsi/protocol.py). A link
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
command (with `anchor: origin` the start pose is the scene's origin and the
state comes from the first datagram on: dockhil calibrate's profile starts
from the pose read).

Every datagram and its answer go to /robot/cycles (RobotCycles, as
robot_modbus publishes them), in the scene frame as the state: the device
cycle IPOC // the cycle in ms, the setpoint the pose start + RKorr that the
controller took (dockhil/devices/kuka_rsi/link.py), so that dockhil calibrate
times the robot at the controller's cycle.

The link thread (dockhil/devices/kuka_rsi/link.py) reads only the configured
controller's address and port, counts and ignores datagrams it cannot use, and moves the
correction toward the latest setpoint by at most max_speed * cycle and
max_angular_speed * cycle from every correction the controller may hold, as it
reports them (RSol; without it, Delay and the IPOC sequence): a controller whose
datagrams carry neither is refused at setup. The correction is held (does not
change) when there is no setpoint, when the setpoint is older than
stall_timeout (the graph stalled) or not finite, after a safety stop and at
close.

Safety, in step(), as robot_modbus (the same limits, checked by the same
code: dockhil/devices/robot_base.py): force and torque on the F/T input, the F/T watchdog, workspace and tilt,
the commanded twist and the command's lead, the following error from RIst, the
measured speed; a stall of this driver; an e-stop. A controller that sends
nothing for controller_timeout stopped RSI: the graph stops with one line.

Latency: the link lowers the process's switch interval while it runs;
`realtime` asks for SCHED_FIFO for the link thread (bench/rsi.py measures both).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from dockhil.contact.rotations import IDENTITY, Quat, quat_conjugate, quat_multiply, rotate, rotate_back
from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.kuka_rsi.link import RsiLink, open_socket
from dockhil.devices.limits import PoseTwist, command_values, non_finite
from dockhil.devices.robot_base import RobotDriver, limit_params
from dockhil.errors import DeviceError, LaunchError
from dockhil.msgs import Header, RobotCommand, RobotCycles
from dockhil.node import Output, Param
from dockhil.runtime import realtime

VELOCITY_WINDOW_S = 0.02  # the measured twist is the pose's change over at least this long
# The workspace bounds reach at most this far from the scene origin [m]: past any KUKA arm on a linear
# unit; a bound beyond it is a unit slip (mm for m), not a workspace.
RSI_REACH_M = 100.0


class SceneFrame:
    """The scene's robot frame in the controller's BASE frame, the start pose (the first RIst), and the
    scene pose the robot had there (the first command: the robot was brought to the scene's start)."""

    def __init__(self, abc: Sequence[float], start: Sequence[float]) -> None:
        self.q_sb = rsi.abc_to_quat(*abc)  # scene axes -> BASE axes
        self.p0 = start[:3]  # mm
        self.q0 = rsi.abc_to_quat(*start[3:])
        self.anchor((0.0, 0.0, 0.0), IDENTITY)

    def anchor(self, position: Sequence[float], orientation: Sequence[float]) -> None:
        """The scene pose (m, quaternion) of the robot at the start pose."""
        self.a_p = tuple(position)
        self.a_q = tuple(orientation)

    def correction(
        self, position: Sequence[float], orientation: Quat
    ) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Scene pose (m, quaternion) -> correction from the start: (X Y Z mm, rotation quaternion) in BASE."""
        a = self.a_p
        d = rotate(self.q_sb, (position[0] - a[0], position[1] - a[1], position[2] - a[2]))
        turn = quat_multiply(orientation, quat_conjugate(self.a_q))  # in scene axes
        q = quat_multiply(quat_multiply(self.q_sb, turn), quat_conjugate(self.q_sb))
        return (d[0] * 1000.0, d[1] * 1000.0, d[2] * 1000.0), q

    def velocity(
        self, linear: Sequence[float], angular: Sequence[float]
    ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Scene twist (m/s, rad/s) -> the correction's rate in BASE: (mm/s, rad/s about BASE axes)."""
        v = rotate(self.q_sb, linear)
        return (v[0] * 1000.0, v[1] * 1000.0, v[2] * 1000.0), tuple(rotate(self.q_sb, angular))

    def scene_pose(self, rist: Sequence[float]) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """RIst (mm, degrees in BASE) -> scene pose: (m, quaternion)."""
        return self._scene(rist[:3], rsi.abc_to_quat(*rist[3:]))

    def scene_values(self, pose: Sequence[float]) -> tuple:
        """A pose in BASE as the link logs it, (x, y, z, qx, qy, qz, qw) in m, -> the same in the scene frame,
        as scene_pose."""
        position, q = self._scene((pose[0] * 1000.0, pose[1] * 1000.0, pose[2] * 1000.0), pose[3:7])
        return (*position, *q)

    def _scene(
        self, mm: Sequence[float], q_base: Quat
    ) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        p0, a = self.p0, self.a_p
        d = rotate_back(self.q_sb, ((mm[0] - p0[0]) / 1000.0, (mm[1] - p0[1]) / 1000.0, (mm[2] - p0[2]) / 1000.0))
        turn = quat_multiply(q_base, quat_conjugate(self.q0))  # in BASE axes
        q = quat_multiply(quat_multiply(quat_multiply(quat_conjugate(self.q_sb), turn), self.q_sb), self.a_q)
        return (a[0] + d[0], a[1] + d[1], a[2] + d[2]), q if q[3] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


class _Reading:
    """The actual pose as the safety checks read it: actual = position, quaternion, twist."""

    __slots__ = ("actual",)

    def __init__(self, actual):
        self.actual = actual


_MAX_SPEED = Param(
    float,
    0.1,
    unit="m/s",
    help="commanded speed limit: the twist, and the command's "
    "lead on the correction; the correction moves at most this times the cycle per cycle",
    gt=0.0,
    le=10.0,
)
_MAX_ANGULAR_SPEED = Param(
    float,
    0.5,
    unit="rad/s",
    help="commanded angular speed limit: the twist, "
    "and the command's lead on the correction; the correction turns at most this "
    "times the cycle per cycle",
    gt=0.0,
    le=10.0,
)


class RobotRsiDriver(RobotDriver):
    """KUKA robot over RSI: corrections answered on the robot's cycle from /robot/command, actual pose to
    /robot/state, the safety limits of the robot drivers."""

    outputs = {
        **RobotDriver.outputs,
        "cycles": Output(
            RobotCycles, "/robot/cycles", help="every controller datagram since the last tick: its answer and RIst"
        ),
    }
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
        # the speeds first: they say how the correction moves
        "max_speed": _MAX_SPEED,
        "max_angular_speed": _MAX_ANGULAR_SPEED,
        **limit_params(_MAX_SPEED, _MAX_ANGULAR_SPEED, reach=RSI_REACH_M),
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
        "anchor": Param(
            str,
            "command",
            choices=("command", "origin"),
            help="the scene pose of the start pose: the first command's (command: no state before it), or "
            "the scene's origin, x = y = z = 0 and no rotation (origin: the state from the first datagram on; "
            "dockhil calibrate sets it, its profile starting from the pose read)",
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
        self._begin_setup()
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
        self._anchored: PoseTwist | None = None  # the first command: the scene pose of the start pose
        self._seen = 0
        self._history: list[tuple[float, tuple, tuple]] = []
        self._actual: tuple[int, _Reading] | None = None
        # one graph per RSI port, refused in one line naming the owner
        self._connect_claimed(rsi.claim_port(p.port), self._open)

    def _open(self) -> None:
        p = self.p
        sock, controller = open_socket(p.host, p.listen, p.port, self.device)
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
            self.device,
        )
        self.link.start()
        if not self.link.started.wait(p.connect_timeout):
            counted = self.link.ignored()
            self.link.stop()
            self.link = None
            extra = f" (datagrams ignored: {counted})" if counted else ""
            raise DeviceError(
                f"{self.device}: no RSI datagram from {p.host} within {p.connect_timeout:g} s: start "
                f"the RSI program on the controller, and check its Ethernet configuration's IP_NUMBER "
                f"and PORT name this host and port {p.port}{extra}"
            )
        first = self.link.first
        if first.rsol is None and first.delay is None:
            self.link.stop()
            self.link = None
            raise DeviceError(
                f"{self.device}: the controller's datagrams carry neither RSol nor Delay, so nothing tells which "
                f"correction it took: add DEF_RSol (or DEF_Delay) to the SEND elements of its Ethernet configuration"
            )
        self.frame = SceneFrame((p.scene_a, p.scene_b, p.scene_c), self.link.first.rist)
        if p.anchor == "origin":  # the default anchor, the scene's origin, holds from the start
            self._anchored = (0.0, 0.0, 0.0, *IDENTITY)
        start = self.link.first.rist
        self.log(
            f"{self.device}: RSI running, cycle {p.cycle * 1000:g} ms; start pose X {start[0]:.2f} "
            f"Y {start[1]:.2f} Z {start[2]:.2f} mm, A {start[3]:.2f} B {start[4]:.2f} C {start[5]:.2f} deg"
        )

    # -- the device's part of the step (the sequence is RobotDriver.step) ---------------
    def _check_device(self, now: float) -> None:
        link, p = self.link, self.p
        self._latest = latest = link.latest  # one snapshot of the controller's last datagram for the step
        silent = now - latest[2]
        if silent > p.controller_timeout:
            link.hold_latched = True
            raise DeviceError(
                f"{self.device}: no datagram for {silent:.3f} s > controller_timeout "
                f"{p.controller_timeout:g} s: the controller stopped RSI (late answers: Delay "
                f"D={link.delay}; see its message window)"
            )

    def _ready(self, cmd: RobotCommand | None) -> bool:
        """The first command anchors the scene to the start pose; before it, nothing is commanded."""
        if self._anchored is not None:
            return True
        if cmd is None:
            self.link.cycles.take()  # nor cycles: the scene frame is not anchored yet
            return False  # no state before the scene says where the robot stands
        self._check_command_values(cmd)
        values = command_values(cmd)
        self.frame.anchor(values[:3], values[3:7])
        self._start_q = values[3:7]
        self._anchored = values
        self.log(f"the start pose is the scene's pose x {values[0]:.4f} y {values[1]:.4f} z {values[2]:.4f} m")
        return True

    def _command_reading(self) -> _Reading:
        return self._reading(self._latest)

    def _lag(self) -> tuple[tuple[float, float] | None, str]:
        # The link moves the correction by at most one cycle's travel toward the command: the lead's rule
        # (or the following error's, at the start) on the correction in BASE.
        return (self.link.lead() if self._moving else None), "correction"

    def _cycles_output(self, header: Header, now: float) -> dict:
        return self.link.cycles.output(header, now, self.frame.scene_values)

    def _fresh_reading(self) -> _Reading | None:
        latest = self._latest
        if latest[0] == self._seen:
            return None
        self._seen = latest[0]
        return self._reading(latest)

    def _hand_over(self, values: PoseTwist | None, stamp: float) -> None:
        if values is None:
            self.link.submit(None, None)
            return
        position, orientation = self.frame.correction(values[:3], values[3:7])
        linear, angular = self.frame.velocity(values[7:10], values[10:13])
        self.link.submit(position, orientation, stamp, self.ctx.dt, linear, angular)

    def _check_command_values(self, cmd: RobotCommand) -> None:
        """The first command, which anchors the scene to the start pose, must be a pose."""
        bad = non_finite(("position", cmd.pose.position), ("orientation", cmd.pose.orientation))
        if bad:
            self._trip("non_finite", bad, f"non-finite setpoint: commanded {bad}")
        self._check_unit("commanded", command_values(cmd)[3:7])

    def _reading(self, latest: tuple[int, rsi.RobFrame, float]) -> _Reading:
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

    def _close_device(self, link: RsiLink) -> bool:  # type: ignore[override]  # the link it opened
        received = link.received
        link.delay_at_close = link.delay  # what comes late from here on does not move the robot: it holds
        # Hold: the answers keep the last correction until the controller has one of them, then stop.
        held = link.hold(min(0.25, 3 * self.p.cycle + 0.05))
        sending = link.received != received  # no datagram while we waited: RSI had stopped, nothing to hold
        link.stop()
        for line in link.take_notes() + link.report(self.device):
            self.log(line)
        if not held and self.tripped is None and sending:
            self.log(
                f"warning: {self.device}: could not confirm the hold at close; the controller stops RSI "
                f"when the answers stop"
            )
        return held
