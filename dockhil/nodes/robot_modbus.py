"""Robot-command driver over Modbus TCP (pymodbus): setpoints out, actual pose in, safety limits.

The register map is in dockhil/hardware/modbus_map.py, the link thread and the claim in
dockhil/hardware/modbus_link.py, the checks it shares with robot_rsi in
dockhil/hardware/robot_limits.py. A link thread owns
the Modbus connection and runs the device cycle: one Modbus round trip takes
a few hundred microseconds, too long to block a 1 kHz step. step() hands it
the latest fresh setpoint (replacing one not yet sent: never a queue) and
picks up the newest reading; the thread, on each cycle, writes a setpoint
moved from the last value sent by at most one cycle's travel at max_speed
and max_angular_speed (the cycle's time on the link's clock, capped at
max_cycle; SetpointLimiter), keeps the heartbeat going, and reconnects with
backoff. Late or bunched graph ticks thus neither trip a speed limit nor
become a jump.

Never a stale setpoint, never a jump on resuming: a setpoint is written only
in the connection it was handed over in; after a reconnect the robot holds
until a command that arrived after the reconnect, and after any hold,
reconnect or stall the setpoint sent starts from the actual pose read back.
(The controller enforces the same: it resumes only on a setpoint written
after it stopped, and only from the connection holding a live claim.)

One graph per controller: setup claims it, on this host by a lock file and
on the controller by its owner registers (modbus_map.py), and refuses, before
writing anything, a controller another graph owns. close() lets go.

Safety: a limit violation requests a hold, waits briefly for the hold to
be written, and raises SafetyStop (one line naming the limit and the value);
from then on nothing is commanded. close() holds the robot. The limits cover
the full pose: position (workspace box, max_speed, max_following_error) and
orientation (max_tilt, the rotation angle from the actual orientation at
connect; max_angular_speed on the commanded angular velocity and on the
rotation of the setpoint sent per device cycle; max_orientation_error; a
quaternion that is not unit within modbus_map.UNIT_TOLERANCE trips
"non-unit quaternion"), the
measured twist (max_actual_speed, max_actual_angular_speed) and the measured
wrench (max_force, max_torque). The defaults pass a one-axis scene, which
commands the identity orientation and no angular velocity. Angles between
orientations are those of the smallest rotation, 2 atan2(|v|, |w|) of
q1 q0*, so q and -q are one orientation.

Time: every watchdog and the device cycle are timed on the runtime's clock
(`ctx.clock`), never on message stamps. A command that runs further ahead
of the setpoint sent than stall_timeout's travel at max_speed (or than the
following error, after a resume) moves faster than the limit and stops; any
gap between two steps longer than `stall_timeout` (this process or the
simulation stalled) holds the robot and stops. A NaN or Inf in a
setpoint or a force trips "non-finite setpoint"/"non-finite force".
pymodbus is imported in setup(), so a scene without this driver never loads it.
"""

from __future__ import annotations

import math
import socket
import time

from dockhil.runtime import ownership
from dockhil.errors import DeviceError, LaunchError
from dockhil.hardware import SafetyStop
from dockhil.hardware import modbus_map as mm
from dockhil.hardware.modbus_link import NoDelayClient, ModbusLink, set_nodelay, verify_and_hold
from dockhil.hardware.robot_limits import (
    angle_between,
    command_values,
    message_key,
    non_finite,
    quat_norm,
    quat_tuple,
    start_orientation,
    vector_norm,
)
from dockhil.node import Input, Node, Output, Param
from dockhil.msgs import EStop, Pose, Quaternion, RobotCommand, RobotCycles, RobotState, Twist, Vector3, WrenchStamped

# The workspace bounds reach at most as far as the register map carries a position (+-2147.48 m).
_MAP_M = (2**31 - 1) / mm.POSITION_COUNTS
HOLD_CONFIRM_TIMEOUT = 0.25  # s: how long a safety stop waits for the hold to be written


class RobotModbusDriver(Node):
    """Robot over Modbus TCP: setpoints from /robot/command, actual pose to /robot/state, safety limits."""

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
    outputs = {
        "state": Output(RobotState, "/robot/state", help="actual pose read from the controller"),
        "cycles": Output(RobotCycles, "/robot/cycles", help="every device cycle since the last tick: sent and read"),
    }
    moves_hardware = True
    params = {
        "host": Param(str, "127.0.0.1", help="controller address"),
        "port": Param(int, 5020, help="controller Modbus TCP port", ge=1, le=65535),
        "device_id": Param(int, 1, help="Modbus unit id", ge=0, le=255),
        "timeout": Param(float, 0.1, unit="s", help="connect and per-request timeout", gt=0.0, le=10.0),
        "connect_timeout": Param(
            float, 2.0, unit="s", help="setup fails if no connection within this", gt=0.0, le=600.0
        ),
        "reconnect_min": Param(float, 0.05, unit="s", help="first reconnect backoff (doubles)", gt=0.0, le=10.0),
        "reconnect_max": Param(float, 1.0, unit="s", help="longest reconnect backoff", gt=0.0, le=60.0),
        "reconnect_timeout": Param(
            float,
            5.0,
            unit="s",
            help="connection lost (the controller did not answer) this long stops the graph (0: never)",
            ge=0.0,
            le=3600.0,
        ),
        "poll_period": Param(
            float,
            0.002,
            unit="s",
            help="device cycle: read the actual pose and write the latest setpoint at least this often",
            gt=0.0,
            le=0.1,
        ),
        # Within a velocity window of 10 ms the setpoint moves at most max_speed x (10 ms + max_cycle): 5 ms
        # keeps that 1.5 max_speed, under max_actual_speed, however the link's cycles bunch.
        "max_cycle": Param(
            float,
            0.005,
            unit="s",
            help="longest device cycle the speed limits credit: one "
            "write moves the setpoint at most max_speed x min(time since the previous cycle, "
            "max_cycle), so a late cycle never catches up in a jump",
            gt=0.0,
            le=0.1,
        ),
        "max_force": Param(float, 200.0, unit="N", help="contact force limit |F| (0: off)", ge=0.0, le=1e5),
        "max_speed": Param(
            float,
            0.1,
            unit="m/s",
            help="setpoint speed limit: the commanded twist, and the setpoint sent per device cycle (0: off)",
            ge=0.0,
            le=10.0,
        ),
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
        "max_angular_speed": Param(
            float,
            0.5,
            unit="rad/s",
            help="setpoint angular speed limit: the commanded twist, and the setpoint sent per device cycle (0: off)",
            ge=0.0,
            le=10.0,
        ),
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
        "x_min": Param(float, -0.5, unit="m", help="workspace lower bound, x", ge=-_MAP_M, le=_MAP_M),
        "x_max": Param(
            float, 0.1, unit="m", help="workspace upper bound, x (x > 0 is penetration)", ge=-_MAP_M, le=_MAP_M
        ),
        "y_min": Param(float, -0.2, unit="m", help="workspace lower bound, y", ge=-_MAP_M, le=_MAP_M),
        "y_max": Param(float, 0.2, unit="m", help="workspace upper bound, y", ge=-_MAP_M, le=_MAP_M),
        "z_min": Param(float, -0.2, unit="m", help="workspace lower bound, z", ge=-_MAP_M, le=_MAP_M),
        "z_max": Param(float, 0.2, unit="m", help="workspace upper bound, z", ge=-_MAP_M, le=_MAP_M),
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
        "frame": Param(str, "", help="header frame id of the published state"),
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
        # pymodbus is imported here: only scenes with this driver load it
        from dockhil.hardware.robot_emulator import quiet_pymodbus

        quiet_pymodbus()
        self.device = f"robot controller (Modbus TCP {p.host}:{p.port})"
        self.link: ModbusLink | None = None
        self.tripped: SafetyStop | None = None
        self._last_cmd = None
        self._last_wrench_key = None
        self._last_wrench_t: float | None = None
        self._first_t: float | None = None
        self._last_step_at: float | None = None
        self._last_cmd_at: float | None = None  # when the last fresh command arrived
        self._moving = False  # a setpoint was handed over since the last hold
        self._start_q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)  # set by _connect
        self._seen_readings = 0
        self._reconnects_seen = 0
        self._status_word = None
        self.heartbeat_losses = 0
        # One graph per controller: this host first (a lock file naming the owner), then the controller's
        # owner registers, read before anything is written.
        self._lock = ownership.claim(f"modbus-{_address(p.host)}-{p.port}", self.device)
        self._claim = mm.encode_owner(ownership.session_id(self.ctx.name), ownership.short_owner())
        try:
            self._connect()
        except BaseException:
            self._lock.release()
            raise

    def _connect(self) -> None:
        """Connect, check the register map, claim the controller, hold; start the link thread."""
        from pymodbus.client import ModbusTcpClient

        p = self.p
        client = ModbusTcpClient(p.host, port=p.port, timeout=p.timeout, retries=0)
        deadline = time.monotonic() + p.connect_timeout
        backoff = p.reconnect_min
        while not client.connect():
            if time.monotonic() + backoff > deadline:
                raise DeviceError(f"{self.device}: no connection within {p.connect_timeout:g} s: {self._probe()}")
            time.sleep(backoff)
            backoff = min(backoff * 2, p.reconnect_max)
        try:
            set_nodelay(client)
            start = verify_and_hold(client, p.device_id, 0, self._claim)
            self._start_q = start_orientation(start)
        except mm.RegisterError as exc:
            client.close()
            raise DeviceError(f"{self.device}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - e.g. the server closed on us
            client.close()
            raise DeviceError(f"{self.device}: {' '.join(str(exc).split())}") from None
        self.link = ModbusLink(NoDelayClient(client), self.device, p, self._probe, self._claim, self.ctx.clock, start)
        self.link.start()

    def _probe(self) -> str:
        try:
            with socket.create_connection((self.p.host, self.p.port), timeout=self.p.timeout):
                return "the server accepts connections but the Modbus client could not connect"
        except OSError as exc:
            return exc.strerror or str(exc) or type(exc).__name__

    # -- step -------------------------------------------------------------------
    def step(self, tick, inputs):
        if self.tripped is not None:
            raise self.tripped  # latched: nothing is commanded after a safety stop
        link, p = self.link, self.p
        t = now = self.ctx.clock()
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
        if not link.connected and p.reconnect_timeout and link.lost_since is not None:
            gone = now - link.lost_since
            if gone > p.reconnect_timeout:
                raise DeviceError(
                    f"{self.device}: connection lost for {gone:.1f} s "
                    f"(reconnect_timeout {p.reconnect_timeout:g} s): {link.last_error}"
                )
        if self._first_t is None:
            self._first_t = t

        estop = inputs.get("estop")
        if estop is not None and estop.active:
            self._trip("estop", estop.reason or "active", f"estop: e-stop active ({estop.reason or 'no reason given'})")

        ft_fresh = self._check_wrench(inputs.get("wrench"), t)

        if not link.connected or link.reconnects != self._reconnects_seen:
            # After a loss the controller holds until a fresh setpoint, and the link starts it from the
            # actual pose: nothing of the old connection is written.
            self._reconnects_seen = link.reconnects
            self._moving = False
        cmd = inputs.get("command")
        if cmd is not None and (self._last_cmd is None or message_key(cmd) != message_key(self._last_cmd)):
            self._check_command(cmd, link.latest()[1])
            self._last_cmd, self._last_cmd_at = cmd, now
            if not ft_fresh or not cmd.enable:
                link.submit(None)  # no F/T data yet: hold rather than move blind
                self._moving = False
            else:
                values = command_values(cmd)
                try:  # here, not in the link's thread, where a failed write reads as a lost connection
                    mm.encode_block(values)
                except mm.RegisterError as exc:
                    self._trip("register_range", str(exc), f"register map: {exc}")
                link.submit(values)
                self._moving = True
        elif self._moving and now - self._last_cmd_at > p.stall_timeout:
            age = now - self._last_cmd_at
            self._trip(
                "stale_command",
                age,
                f"stale command: no new setpoint for {age:.3f} s > stall_timeout "
                f"{p.stall_timeout:g} s while moving (the simulation stalled)",
            )
        self._check_lag(link.lag)

        count, reading = link.latest()
        out = link.cycles.output(tick.header(p.frame), now)
        if reading is None or count == self._seen_readings:
            return out
        self._seen_readings = count
        self._check_actual(reading)
        if reading.status != self._status_word:
            self._status_changed(reading.status)
        return {**out, "state": _state(tick.header(p.frame), reading)}

    def _check_wrench(self, wrench: WrenchStamped | None, t: float) -> bool:
        """Check the force limit and the watchdog; True if the F/T data are fresh enough to move."""
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
            waited = t - self._first_t
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

    def _check_command(self, cmd: RobotCommand, reading: mm.ControllerReading | None) -> None:
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

    def _check_unit(self, what: str, q) -> None:
        """A quaternion that is not unit is no rotation: what it would command is undefined."""
        n = quat_norm(q)
        if abs(n - 1.0) > mm.UNIT_TOLERANCE:
            self._trip(
                "non_unit_quaternion",
                n,
                f"non-unit quaternion: {what} orientation |q| = {n:.9g} "
                f"(x, y, z, w = {q[0]:g}, {q[1]:g}, {q[2]:g}, {q[3]:g}); a rotation needs |q| = 1 "
                f"within {mm.UNIT_TOLERANCE:g}",
            )

    def _check_tilt(self, what: str, q) -> None:
        """Orientation workspace: the angle of the rotation from the orientation at start."""
        tilt = angle_between(self._start_q, q)
        if self.p.max_tilt and tilt > self.p.max_tilt:
            self._trip(
                "max_tilt",
                tilt,
                f"max_tilt: {what} orientation {tilt:.4f} rad from the start orientation > {self.p.max_tilt:g} rad",
            )

    def _check_lag(self, lag: tuple[float, float] | None) -> None:
        """The link sends each device cycle at most one cycle's travel at max_speed (max_angular_speed)
        toward the commanded setpoint, so late or bunched commands only put the command briefly ahead of
        what is sent. A command further ahead than stall_timeout's travel moves faster than the limit."""
        if lag is None:
            return
        p = self.p
        distance, turn = lag
        # After a resume from the actual pose the command may be as far ahead as the following errors allow.
        if p.max_speed and distance > max(p.max_speed * p.stall_timeout, p.max_following_error):
            self._trip(
                "max_speed",
                distance,
                f"max_speed: the command ran {distance:.4f} m ahead of the setpoint "
                f"sent at {p.max_speed:g} m/s (more than stall_timeout {p.stall_timeout:g} s of travel and "
                f"max_following_error): it moves faster than max_speed",
            )
        if p.max_angular_speed and turn > max(p.max_angular_speed * p.stall_timeout, p.max_orientation_error):
            self._trip(
                "max_angular_speed",
                turn,
                f"max_angular_speed: the command turned {turn:.4f} rad ahead of "
                f"the setpoint sent at {p.max_angular_speed:g} rad/s (more than stall_timeout "
                f"{p.stall_timeout:g} s of turning and max_orientation_error): it turns faster than "
                f"max_angular_speed",
            )

    def _check_actual(self, reading: mm.ControllerReading) -> None:
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
        if reading.status & mm.STATUS_FAULT:
            self.link.hold(HOLD_CONFIRM_TIMEOUT)
            raise DeviceError(f"{self.device}: controller reports a fault (status {reading.status:#06x}); holding")

    def _status_changed(self, status: int) -> None:
        old = self._status_word
        self._status_word = status
        if status & mm.STATUS_HEARTBEAT_LOST and old is not None and not old & mm.STATUS_HEARTBEAT_LOST:
            self.heartbeat_losses += 1
            if self.heartbeat_losses == 1:  # the first one tells the story; close() reports the count
                self.log(
                    f"warning: {self.device}: controller lost our heartbeat and holds; resuming on the next command"
                )

    def _trip(self, limit: str, value, text: str) -> None:
        line = f"safety stop: {text}"
        held = self.link.connected and self.link.hold(HOLD_CONFIRM_TIMEOUT)
        if not held:
            self.link.hold(0.0)
            line += "; hold not confirmed (controller unreachable: its heartbeat timeout holds the robot)"
        else:
            line += "; robot held"
        self.tripped = SafetyStop(line, limit, value)
        raise self.tripped

    def close(self) -> None:
        link = getattr(self, "link", None)
        if link is None:
            return
        self.link = None
        held = link.connected and link.hold(HOLD_CONFIRM_TIMEOUT)
        link.stop()
        for line in link.take_notes():
            self.log(line)
        if link.connected and not link.fatal:
            try:  # let go of the controller, so the next graph need not wait for our claim to time out
                link.client.write_registers(mm.HR_SESSION, mm.encode_owner(0, ""), device_id=self.p.device_id)
            except Exception:  # noqa: BLE001 - the heartbeat timeout ends the claim anyway
                pass
        link.client.close()
        self._lock.release()
        if self.heartbeat_losses > 1:
            self.log(f"warning: {self.device}: the controller lost our heartbeat {self.heartbeat_losses} times")
        if not held and self.tripped is None:
            self.log(
                f"warning: {self.device}: could not hold the robot at close (not connected); "
                f"the controller holds when our heartbeat stops"
            )


def _address(host: str) -> str:
    """One name for one controller in the lock key (localhost and 127.0.0.1 are the same device)."""
    try:
        return socket.gethostbyname(host)
    except OSError:
        return host


def _state(header, reading: mm.ControllerReading) -> RobotState:
    a = reading.actual
    return RobotState(
        header=header,
        pose=Pose(position=Vector3(a[0], a[1], a[2]), orientation=Quaternion(a[3], a[4], a[5], a[6])),
        twist=Twist(linear=Vector3(a[7], a[8], a[9]), angular=Vector3(a[10], a[11], a[12])),
        status=mm.describe_status(reading.status),
    )
