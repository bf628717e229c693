"""What the robot drivers (modbus_robot over Modbus TCP, kuka_rsi over KUKA RSI) share, written once:
their ports, the parameters of their safety limits, and the whole safety sequence, in one order. A
driver adds its device: the claim to hold while it connects, its link thread (a RobotLink:
dockhil/devices/base.py), and the hooks the sequence calls (`_check_device`, `_ready`,
`_command_reading`, `_hand_over`, `_lag`, `_cycles_output`, `_fresh_reading`, `_status`,
`_close_device`).

Setup refuses sim time and an empty workspace before anything runs, and lets go of the device's
claim if connecting fails. Each step (`step`, here and nowhere else): a safety stop stays latched;
the link's notes are logged and its fatal error stops the graph; a gap between two steps longer
than stall_timeout stops; the device's own liveness (`_check_device`); an e-stop stops; the F/T
input is checked (max_force, max_torque, a NaN or Inf, the watchdog ft_timeout after ft_grace) and,
until fresh F/T data came, every setpoint is a hold. A fresh command is checked (non-finite, unit
quaternion, workspace, max_tilt from the start orientation, the commanded twist, the following
errors from the actual pose) and handed over; while moving, no fresh command for stall_timeout
stops, and so does a command that runs ahead of what was sent further than stall_timeout's travel.
A fresh reading is checked for the workspace, max_tilt and the measured twist, and published.

A limit violation requests a hold, waits briefly for the hold to be sent, and raises SafetyStop (one
line naming the limit and the value); from then on nothing is commanded. Close holds the robot
(`_close_device` answers the device with a hold and lets go of it) and says in one line whether the
robot holds and where: its last command and its last actual pose. Angles between orientations are
those of the smallest rotation (limits.angle_between).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from dockhil.contact.rotations import IDENTITY, Quat
from dockhil.devices.base import RobotLink
from dockhil.devices.limits import (
    UNIT_TOLERANCE,
    PoseTwist,
    angle_between,
    command_values,
    message_key,
    non_finite,
    quat_norm,
    quat_tuple,
    vector_norm,
)
from dockhil.errors import DeviceError, LaunchError, SafetyStop
from dockhil.msgs import EStop, Header, Pose, Quaternion, RobotCommand, RobotState, Twist, Vector3, WrenchStamped
from dockhil.node import Input, Node, Output, Param, Tick
from dockhil.runtime.ownership import DeviceLock

HOLD_CONFIRM_TIMEOUT = 0.25  # s: how long a safety stop waits for the hold to be written


class Reading(Protocol):
    """What a driver reads of the robot: `actual`, the 13 values of robot_state (scene frame)."""

    @property
    def actual(self) -> PoseTwist: ...


def limit_params(max_speed: Param, max_angular_speed: Param, reach: float) -> dict[str, Param]:
    """The safety limits' parameters, with the driver's own commanded speed limits among them; the
    workspace bounds reach at most `reach` [m] from the origin (what the device can carry)."""
    return {
        "max_force": Param(float, 200.0, unit="N", help="contact force limit |F| (0: off)", ge=0.0, le=1e5),
        "max_speed": max_speed,
        "max_actual_speed": Param(
            float,
            0.2,
            unit="m/s",
            help="measured speed limit; above max_speed to allow for tracking transients and velocity noise (0: off)",
            ge=0.0,
            le=10.0,
        ),
        "max_following_error": Param(
            float,
            0.02,
            unit="m",
            help="setpoint distance from the actual pose (catches a start far from the robot before it jumps; 0: off)",
            ge=0.0,
            le=10.0,
        ),
        "max_torque": Param(float, 20.0, unit="N m", help="contact torque limit |T| (0: off)", ge=0.0, le=1e4),
        "max_angular_speed": max_angular_speed,
        "max_actual_angular_speed": Param(
            float,
            1.0,
            unit="rad/s",
            help="measured angular speed limit; above "
            "max_angular_speed as max_actual_speed is above max_speed (0: off)",
            ge=0.0,
            le=10.0,
        ),
        "max_tilt": Param(
            float,
            0.5,
            unit="rad",
            help="orientation workspace: rotation angle of the commanded "
            "and the actual orientation from the orientation at start (0: off)",
            ge=0.0,
            le=math.pi,
        ),
        "max_orientation_error": Param(
            float,
            0.1,
            unit="rad",
            help="setpoint orientation's angle from the actual "
            "orientation (catches a start turned away from the robot; 0: off)",
            ge=0.0,
            le=math.pi,
        ),
        "x_min": Param(float, -0.5, unit="m", help="workspace lower bound, x", ge=-reach, le=reach),
        "x_max": Param(
            float, 0.1, unit="m", help="workspace upper bound, x (x > 0 is penetration)", ge=-reach, le=reach
        ),
        "y_min": Param(float, -0.2, unit="m", help="workspace lower bound, y", ge=-reach, le=reach),
        "y_max": Param(float, 0.2, unit="m", help="workspace upper bound, y", ge=-reach, le=reach),
        "z_min": Param(float, -0.2, unit="m", help="workspace lower bound, z", ge=-reach, le=reach),
        "z_max": Param(float, 0.2, unit="m", help="workspace upper bound, z", ge=-reach, le=reach),
        "ft_timeout": Param(
            float, 0.05, unit="s", help="F/T watchdog: no new wrench this long stops (0: off)", ge=0.0, le=10.0
        ),
        "stall_timeout": Param(
            float,
            0.2,
            unit="s",
            help="longest gap between two steps of this driver, or "
            "between two fresh setpoints while moving, before it holds and stops (a stalled "
            "process or simulation); the controller's own heartbeat timeout is 0.2 s",
            gt=0.0,
            le=60.0,
        ),
        "ft_grace": Param(
            float,
            2.0,
            unit="s",
            help="time from the first tick for the first wrench; commands are held until it arrives",
            ge=0.0,
            le=600.0,
        ),
        "max_device_gap": Param(
            float,
            0.05,
            unit="s",
            help="validity: longest the device may go without taking a command while the loop moves it (cycles "
            "that never came, answers it did not take, a stalled controller); longer, the run is INVALID",
            gt=0.0,
            le=10.0,
        ),
        "max_path_error": Param(
            float,
            0.005,
            unit="m",
            help="validity: farthest the actual pose may be from the command while moving (the robot's delay "
            "and lag at the scene's speed stay well within it); farther, the run is INVALID",
            gt=0.0,
            le=10.0,
        ),
        "frame": Param(str, "", help="header frame id of the published state"),
    }


def robot_state(header: Header, actual: Sequence[float], status: str) -> RobotState:
    """The published state of an actual pose and twist (x y z, qx qy qz qw, vx vy vz, wx wy wz)."""
    a = actual
    return RobotState(
        header=header,
        pose=Pose(position=Vector3(a[0], a[1], a[2]), orientation=Quaternion(a[3], a[4], a[5], a[6])),
        twist=Twist(linear=Vector3(a[7], a[8], a[9]), angular=Vector3(a[10], a[11], a[12])),
        status=status,
    )


class RobotDriver(Node):
    """A robot driver's ports, its safety sequence (`step`) and its close (`close`); the device fills
    in the hooks below."""

    inputs = {
        "command": Input(RobotCommand, "/robot/command", help="setpoint: probe pose relative to the target"),
        # Its maximum age is the driver's own watchdog, ft_timeout (with ft_grace before the first).
        "wrench": Input(
            WrenchStamped,
            "/ft/wrench",
            feedthrough=False,
            required=False,
            max_age=math.inf,
            help="measured contact wrench, for max_force and the F/T watchdog",
        ),
        # Event topic: silent while nothing happens, so no maximum age.
        "estop": Input(EStop, "/estop", feedthrough=False, required=False, max_age=math.inf, help="emergency stop"),
    }
    outputs = {"state": Output(RobotState, "/robot/state", help="actual pose read from the controller")}
    moves_hardware = True
    device: str
    link: Any  # the device's RobotLink, with what the device's hooks use of it

    # -- setup ------------------------------------------------------------------
    def _begin_setup(self) -> None:
        """Refuse sim time and an empty workspace before anything runs; the state the safety paths keep."""
        p = self.p
        if self.ctx.sim_time:
            raise LaunchError(
                f"node {self.ctx.name!r} commands a real robot and runs only in wall time (launch with --wall-time)"
            )
        for axis in "xyz":
            lo, hi = getattr(p, f"{axis}_min"), getattr(p, f"{axis}_max")
            if lo >= hi:
                raise LaunchError(f"node {self.ctx.name!r}: workspace {axis}_min {lo} must be below {axis}_max {hi}")
        self.link = None
        self.tripped: SafetyStop | None = None
        self._last_cmd: RobotCommand | None = None
        self._last_wrench_key: tuple | None = None
        self._last_wrench_t: float | None = None
        self._first_t: float | None = None
        self._last_step_at: float | None = None
        self._last_cmd_at = 0.0  # when the last fresh command arrived
        self._moving = False  # a setpoint was handed over since the last hold
        self._start_q: tuple[float, ...] = IDENTITY  # max_tilt's reference, set on connect
        self._last_actual: PoseTwist | None = None  # the last actual pose read, for the close's line
        self._path_error = 0.0  # m: the largest distance of the actual pose from the command while moving
        self._device_gap = 0.0  # s: the link's longest gap, kept at close

    def _connect_claimed(self, lock: DeviceLock, connect: Callable[[], object]) -> None:
        """Keep `lock`, this graph's claim of the device, while connect() runs; let go if it fails."""
        self._lock = lock
        try:
            connect()
        except BaseException:
            lock.release()
            raise

    # -- the device's part -------------------------------------------------------
    def _check_device(self, now: float) -> None:
        """The device's own liveness (a connection lost too long, a controller that stopped sending)."""

    def _ready(self, cmd: RobotCommand | None) -> bool:
        """Whether the step goes on to the command (RSI waits for the first one to anchor the scene)."""
        return True

    def _command_reading(self) -> Reading | None:
        """The reading a fresh command's following errors are checked against (None: none yet)."""
        raise NotImplementedError

    def _hand_over(self, values: PoseTwist | None, stamp: float) -> None:
        """Hand the link the setpoint's command values (None: hold) and the time they are for (the command's
        tick times the scene's step: the link gives the device the pose for the time of its cycle,
        dockhil/devices/handover.py)."""
        raise NotImplementedError

    def _lag(self) -> tuple[tuple[float, float] | None, str]:
        """How far the command runs ahead of what was sent (m, rad; None: nothing to be ahead of), and
        the name of what is sent."""
        raise NotImplementedError

    def _cycles_output(self, header: Header, now: float) -> dict:
        """The outputs of the device cycles since the last step (/robot/cycles)."""
        raise NotImplementedError

    def _fresh_reading(self) -> Reading | None:
        """The reading that came since the last step, or None."""
        raise NotImplementedError

    def _status(self, reading: Reading) -> str:
        """The published state's status of a reading."""
        return "ok"

    def _close_device(self, link: RobotLink) -> bool:
        """Answer the device with a hold, stop the link and let go of the device; whether the hold was
        confirmed."""
        raise NotImplementedError

    # -- step -------------------------------------------------------------------
    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        """The safety sequence of a tick, in this order for every device."""
        now = self._begin_step()
        self._check_device(now)
        ft_fresh = self._check_inputs(inputs, now)
        cmd = inputs.get("command")
        if not self._ready(cmd):
            return {}
        self._take_command(cmd, self._command_reading(), ft_fresh, now)
        self._check_lag(*self._lag())
        header = tick.header(self.p.frame)
        out = self._cycles_output(header, now)
        reading = self._fresh_reading()
        if reading is None:
            return out
        self._check_actual(reading)
        self._last_actual = reading.actual
        if self._moving and self._last_cmd is not None:
            a, c = reading.actual, self._last_cmd.pose.position
            self._path_error = max(
                self._path_error, math.sqrt((c.x - a[0]) ** 2 + (c.y - a[1]) ** 2 + (c.z - a[2]) ** 2)
            )
        return {**out, "state": robot_state(header, reading.actual, self._status(reading))}

    def close(self) -> None:
        """Hold the robot, let go of the device, and say in one line whether the robot holds and where."""
        link = getattr(self, "link", None)
        if link is None:
            return
        self.link = None
        self._device_gap = link.longest_gap_s
        held = self._close_device(link)
        self._lock.release()
        self.log(f"{self.device}: {'the robot holds' if held else 'the hold was not confirmed'}; {self._where()}")

    def device_figures(self) -> dict:
        """The device's cycles as validity judges them (dockhil/runtime/validity.py: device_reasons)."""
        link = self.link
        return {
            "what": getattr(self, "device", "the robot controller"),
            "gap_is": "taking a command",
            "longest_gap_s": link.longest_gap_s if link is not None else self._device_gap,
            "gap_limit_s": self.p.max_device_gap,
            "path_error_m": self._path_error,
            "path_error_limit_m": self.p.max_path_error,
        }

    def _where(self) -> str:
        """The last command and the last actual pose, in the scene frame."""
        cmd = self._last_cmd
        said = "no command" if cmd is None else "last command " + _position(command_values(cmd))
        actual = self._last_actual
        return f"{said}, {'no pose read' if actual is None else 'actual ' + _position(actual)}"

    def _begin_step(self) -> float:
        """The step's time, after the latched stop, the link's notes and fatal error, and the stall check."""
        if self.tripped is not None:
            raise self.tripped  # latched: nothing is commanded after a safety stop
        link, p = self.link, self.p
        now = self.ctx.clock()
        for line in link.take_notes():
            self.log(line)
        if link.fatal:
            raise DeviceError(link.fatal)
        if self._last_step_at is not None and now - self._last_step_at > p.stall_timeout:
            gap = now - self._last_step_at
            self._trip(
                "stall",
                gap,
                f"stall: no step for {gap:.3f} s > stall_timeout {p.stall_timeout:g} s "
                f"(this process was stopped or starved); resuming would jump",
            )
        self._last_step_at = now
        return now

    def _check_inputs(self, inputs: dict[str, Any], t: float) -> bool:
        """The e-stop and the F/T input; True if the F/T data are fresh enough to move."""
        if self._first_t is None:
            self._first_t = t
        estop = inputs.get("estop")
        if estop is not None and estop.active:
            self._trip("estop", estop.reason or "active", f"estop: e-stop active ({estop.reason or 'no reason given'})")
        return self._check_wrench(inputs.get("wrench"), t, self._first_t)

    def _take_command(self, cmd: RobotCommand | None, reading: Reading | None, ft_fresh: bool, now: float) -> None:
        """Check a fresh command and hand it over (a hold without fresh F/T data or when disabled); while
        moving, no fresh command for stall_timeout stops."""
        p = self.p
        if cmd is not None and (self._last_cmd is None or message_key(cmd) != message_key(self._last_cmd)):
            self._check_command(cmd, reading)
            self._last_cmd, self._last_cmd_at = cmd, now
            moving = bool(ft_fresh and cmd.enable)  # no F/T data yet: hold rather than move blind
            # the command's time: its tick on the scene's clock (its stamp is when the tick ran, jitter and all)
            self._hand_over(command_values(cmd) if moving else None, cmd.header.tick * self.ctx.dt)
            self._moving = moving
        elif self._moving and now - self._last_cmd_at > p.stall_timeout:
            age = now - self._last_cmd_at
            self._trip(
                "stale_command",
                age,
                f"stale command: no new setpoint for {age:.3f} s > stall_timeout "
                f"{p.stall_timeout:g} s while moving (the simulation stalled)",
            )

    # -- the checks -------------------------------------------------------------
    def _check_wrench(self, wrench: WrenchStamped | None, t: float, first_t: float) -> bool:
        """Check the force limit and the watchdog (from first_t, the first step's time); True if the F/T
        data are fresh enough to move."""
        p = self.p
        if wrench is not None and message_key(wrench) != self._last_wrench_key:
            self._last_wrench_key = message_key(wrench)
            self._last_wrench_t = t
            bad = non_finite(("force", wrench.wrench.force), ("torque", wrench.wrench.torque))
            if bad:
                self._trip("non_finite", bad, f"non-finite force: measured wrench {bad}")
            f = vector_norm(wrench.wrench.force)
            if p.max_force and f > p.max_force:
                self._trip("max_force", f, f"max_force: contact force |F| = {f:.1f} N > {p.max_force:g} N")
            torque = vector_norm(wrench.wrench.torque)
            if p.max_torque and torque > p.max_torque:
                self._trip(
                    "max_torque", torque, f"max_torque: contact torque |T| = {torque:.2f} N m > {p.max_torque:g} N m"
                )
        if not p.ft_timeout:
            return True
        if self._last_wrench_t is None:
            waited = t - first_t
            if waited > p.ft_grace + p.ft_timeout:
                self._trip(
                    "ft_timeout",
                    waited,
                    f"ft_timeout: no F/T data {waited:.3f} s after start (ft_grace {p.ft_grace:g} s + "
                    f"ft_timeout {p.ft_timeout:g} s; connect /ft/wrench or set ft_timeout 0)",
                )
            return False
        age = t - self._last_wrench_t
        if age > p.ft_timeout:
            self._trip("ft_timeout", age, f"ft_timeout: no F/T data for {age:.3f} s > {p.ft_timeout:g} s")
        return True

    def _check_position(self, what: str, x: float, y: float, z: float) -> None:
        p = self.p
        for axis, v in (("x", x), ("y", y), ("z", z)):
            lo, hi = getattr(p, f"{axis}_min"), getattr(p, f"{axis}_max")
            if v < lo:
                self._trip("workspace", v, f"workspace: {what} position.{axis} = {v:.4f} m below {axis}_min {lo:g} m")
            if v > hi:
                self._trip("workspace", v, f"workspace: {what} position.{axis} = {v:.4f} m above {axis}_max {hi:g} m")

    def _check_command(self, cmd: RobotCommand, reading: Reading | None) -> None:
        p = self.p
        bad = non_finite(
            ("position", cmd.pose.position),
            ("orientation", cmd.pose.orientation),
            ("linear velocity", cmd.twist.linear),
            ("angular velocity", cmd.twist.angular),
        )
        if bad:
            self._trip("non_finite", bad, f"non-finite setpoint: commanded {bad}")
        pos, q = cmd.pose.position, quat_tuple(cmd.pose.orientation)
        self._check_unit("commanded", q)
        self._check_position("commanded", pos.x, pos.y, pos.z)
        self._check_tilt("commanded", q)
        speed = vector_norm(cmd.twist.linear)
        if p.max_speed and speed > p.max_speed:
            self._trip("max_speed", speed, f"max_speed: commanded speed {speed:.3f} m/s > {p.max_speed:g} m/s")
        rate = vector_norm(cmd.twist.angular)
        if p.max_angular_speed and rate > p.max_angular_speed:
            self._trip(
                "max_angular_speed",
                rate,
                f"max_angular_speed: commanded angular speed {rate:.3f} rad/s > {p.max_angular_speed:g} rad/s",
            )
        if p.max_following_error and reading is not None:
            a = reading.actual
            err = math.sqrt((pos.x - a[0]) ** 2 + (pos.y - a[1]) ** 2 + (pos.z - a[2]) ** 2)
            if err > p.max_following_error:
                self._trip(
                    "max_following_error",
                    err,
                    f"max_following_error: setpoint {err:.4f} m from the actual pose > "
                    f"{p.max_following_error:g} m (move the robot to the start pose first)",
                )
        if p.max_orientation_error and reading is not None:
            turn = angle_between(reading.actual[3:7], q)
            if turn > p.max_orientation_error:
                self._trip(
                    "max_orientation_error",
                    turn,
                    f"max_orientation_error: setpoint orientation {turn:.4f} rad from the actual "
                    f"orientation > {p.max_orientation_error:g} rad (turn the robot to the start "
                    f"orientation first)",
                )

    def _check_unit(self, what: str, q: Quat) -> None:
        """A quaternion that is not unit is no rotation: what it would command is undefined."""
        n = quat_norm(q)
        if abs(n - 1.0) > UNIT_TOLERANCE:
            self._trip(
                "non_unit_quaternion",
                n,
                f"non-unit quaternion: {what} orientation |q| = {n:.9g} "
                f"(x, y, z, w = {q[0]:g}, {q[1]:g}, {q[2]:g}, {q[3]:g}); a rotation needs |q| = 1 "
                f"within {UNIT_TOLERANCE:g}",
            )

    def _check_tilt(self, what: str, q: Quat) -> None:
        """Orientation workspace: the angle of the rotation from the orientation at start."""
        tilt = angle_between(self._start_q, q)
        if self.p.max_tilt and tilt > self.p.max_tilt:
            self._trip(
                "max_tilt",
                tilt,
                f"max_tilt: {what} orientation {tilt:.4f} rad from the start orientation > {self.p.max_tilt:g} rad",
            )

    def _check_lag(self, lag: tuple[float, float] | None, sent: str) -> None:
        """The link sends each device cycle at most one cycle's travel at max_speed (max_angular_speed)
        toward the commanded setpoint, so late or bunched commands only put the command briefly ahead of
        what is sent (the `sent` setpoint or correction; `lag`, m and rad, None: nothing to be ahead of).
        A command further ahead than stall_timeout's travel moves faster than the limit."""
        if lag is None:
            return
        p = self.p
        distance, turn = lag
        # After a resume from the actual pose the command may be as far ahead as the following errors allow.
        if p.max_speed and distance > max(p.max_speed * p.stall_timeout, p.max_following_error):
            self._trip(
                "max_speed",
                distance,
                f"max_speed: the command ran {distance:.4f} m ahead of the {sent} "
                f"sent at {p.max_speed:g} m/s (more than stall_timeout {p.stall_timeout:g} s of travel and "
                f"max_following_error): it moves faster than max_speed",
            )
        if p.max_angular_speed and turn > max(p.max_angular_speed * p.stall_timeout, p.max_orientation_error):
            self._trip(
                "max_angular_speed",
                turn,
                f"max_angular_speed: the command turned {turn:.4f} rad ahead of "
                f"the {sent} sent at {p.max_angular_speed:g} rad/s (more than stall_timeout "
                f"{p.stall_timeout:g} s of turning and max_orientation_error): it turns faster than "
                f"max_angular_speed",
            )

    def _check_actual(self, reading: Reading) -> None:
        a, p = reading.actual, self.p
        self._check_unit("actual", a[3:7])
        self._check_position("actual", a[0], a[1], a[2])
        self._check_tilt("actual", a[3:7])
        speed = math.sqrt(a[7] ** 2 + a[8] ** 2 + a[9] ** 2)
        if p.max_actual_speed and speed > p.max_actual_speed:
            self._trip(
                "max_actual_speed",
                speed,
                f"max_actual_speed: measured speed {speed:.3f} m/s > {p.max_actual_speed:g} m/s",
            )
        rate = math.sqrt(a[10] ** 2 + a[11] ** 2 + a[12] ** 2)
        if p.max_actual_angular_speed and rate > p.max_actual_angular_speed:
            self._trip(
                "max_actual_angular_speed",
                rate,
                f"max_actual_angular_speed: measured angular speed "
                f"{rate:.3f} rad/s > {p.max_actual_angular_speed:g} rad/s",
            )

    def _trip(self, limit: str, value: float | str | None, text: str) -> None:
        line = f"safety stop: {text}"
        held = self.link.connected and self.link.hold(HOLD_CONFIRM_TIMEOUT)
        if not held:
            self.link.hold(0.0)
            line += "; hold not confirmed (controller unreachable: its heartbeat timeout holds the robot)"
        else:
            line += "; robot held"
        self.tripped = SafetyStop(line, limit, value)
        raise self.tripped


def _position(values: Sequence[float]) -> str:
    return f"x {values[0]:.4f} y {values[1]:.4f} z {values[2]:.4f} m"
