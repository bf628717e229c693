"""Robot-command driver over Modbus TCP (pymodbus): setpoints out, actual pose in, safety limits.

The register map is in dockhil/devices/modbus_robot/registers.py, the link thread and the claim in
dockhil/devices/modbus_robot/link.py, the ports, limits and safety paths it shares with robot_rsi
in dockhil/devices/robot_base.py. A link thread owns
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

import socket
import time

from dockhil.devices.limits import PoseTwist
from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.link import ModbusLink, NoDelayClient, set_nodelay, verify_and_hold
from dockhil.devices.robot_base import HOLD_CONFIRM_TIMEOUT, RobotDriver, limit_params
from dockhil.errors import DeviceError
from dockhil.msgs import Header, RobotCycles
from dockhil.node import Output, Param
from dockhil.runtime import ownership


class RobotModbusDriver(RobotDriver):
    """Robot over Modbus TCP: setpoints from /robot/command, actual pose to /robot/state, safety limits."""

    outputs = {
        **RobotDriver.outputs,
        "cycles": Output(RobotCycles, "/robot/cycles", help="every device cycle since the last tick: sent and read"),
    }
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
        **limit_params(
            max_speed=Param(
                float,
                0.1,
                unit="m/s",
                help="setpoint speed limit: the commanded twist, and the setpoint sent per device cycle (0: off)",
                ge=0.0,
                le=10.0,
            ),
            max_angular_speed=Param(
                float,
                0.5,
                unit="rad/s",
                help="setpoint angular speed limit: the commanded twist, and the setpoint sent per device cycle "
                "(0: off)",
                ge=0.0,
                le=10.0,
            ),
            reach=(2**31 - 1) / mm.POSITION_COUNTS,  # as far as the register map carries a position (+-2147.48 m)
        ),
    }

    def setup(self) -> None:
        p = self.p
        self._begin_setup()
        # pymodbus is imported here: only scenes with this driver load it
        from dockhil.devices.modbus_robot.link import quiet_pymodbus

        quiet_pymodbus()
        self.device = f"robot controller (Modbus TCP {p.host}:{p.port})"
        self._seen_readings = 0
        self._reconnects_seen = 0
        self._status_word: int | None = None
        self.heartbeat_losses = 0
        # One graph per controller: this host first (a lock file naming the owner), then the controller's
        # owner registers, read before anything is written.
        lock = ownership.claim(f"modbus-{_address(p.host)}-{p.port}", self.device)
        self._claim = mm.encode_owner(ownership.session_id(self.ctx.name), ownership.short_owner())
        self._connect_claimed(lock, self._connect)

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
            self._start_q = mm.start_orientation(start)
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

    # -- the device's part of the step (the sequence is RobotDriver.step) ---------------
    def _check_device(self, now: float) -> None:
        link, p = self.link, self.p
        if not link.connected and p.reconnect_timeout and link.lost_since is not None:
            gone = now - link.lost_since
            if gone > p.reconnect_timeout:
                raise DeviceError(
                    f"{self.device}: connection lost for {gone:.1f} s "
                    f"(reconnect_timeout {p.reconnect_timeout:g} s): {link.last_error}"
                )
        if not link.connected or link.reconnects != self._reconnects_seen:
            # After a loss the controller holds until a fresh setpoint, and the link starts it from the
            # actual pose: nothing of the old connection is written.
            self._reconnects_seen = link.reconnects
            self._moving = False

    def _command_reading(self) -> mm.ControllerReading | None:
        return self.link.latest()[1]

    def _lag(self) -> tuple[tuple[float, float] | None, str]:
        return self.link.lag, "setpoint"

    def _cycles_output(self, header: Header, now: float) -> dict:
        return self.link.cycles.output(header, now)

    def _fresh_reading(self) -> mm.ControllerReading | None:
        count, reading = self.link.latest()
        if reading is None or count == self._seen_readings:
            return None
        self._seen_readings = count
        return reading

    def _status(self, reading: mm.ControllerReading) -> str:  # type: ignore[override]  # its link's readings
        if reading.status != self._status_word:
            self._status_changed(reading.status)
        return mm.describe_status(reading.status)

    def _hand_over(self, values: PoseTwist | None, stamp: float) -> None:
        if values is not None:
            try:  # here, not in the link's thread, where a failed write reads as a lost connection
                mm.encode_block(values)
            except mm.RegisterError as exc:
                self._trip("register_range", str(exc), f"register map: {exc}")
        self.link.submit(values, stamp, self.ctx.dt)

    def _check_actual(self, reading: mm.ControllerReading) -> None:  # type: ignore[override]
        super()._check_actual(reading)
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

    def _close_device(self, link: ModbusLink) -> bool:  # type: ignore[override]  # the link it opened
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
        if self.heartbeat_losses > 1:
            self.log(f"warning: {self.device}: the controller lost our heartbeat {self.heartbeat_losses} times")
        if not held and self.tripped is None:
            self.log(
                f"warning: {self.device}: could not hold the robot at close (not connected); "
                f"the controller holds when our heartbeat stops"
            )
        return held


def _address(host: str) -> str:
    """One name for one controller in the lock key (localhost and 127.0.0.1 are the same device)."""
    try:
        return socket.gethostbyname(host)
    except OSError:
        return host
