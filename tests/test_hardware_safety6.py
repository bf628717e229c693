"""The full pose over Modbus, and the robot driver's limits on orientation, angular speed and torque.

The register map and the emulated controller carry position, orientation (unit quaternion)
and twist both ways; the servo's rotation follows a step with the delay and first-order lag
of its closed form. Each limit trips, against the emulator over Modbus TCP, at its value:
the robot held, one line naming the limit and the value, nothing commanded afterwards.

As in test_hardware_safety.py, the driver runs on a ManualClock advanced one period per
step; the servo model is stepped on times the test chooses (multiples of 1/1024 s, exact
in binary, so no comparison in the delay line or the velocity window sits on a rounding edge).
"""

from __future__ import annotations

import math
import time

import pytest

from dockhil.devices.limits import UNIT_TOLERANCE
from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.driver import RobotModbusDriver
from dockhil.devices.modbus_robot.emulator import FOLLOW, HOLD, VELOCITY_WINDOW_S, ServoModel
from dockhil.msgs import Header, Pose, Quaternion, RobotCommand, Twist, Vector3, Wrench, WrenchStamped
from dockhil.node import ManualClock, NodeContext
from tests.conftest import node_process_error, wait_for
from tests.test_hardware_modbus import ENV, read_holding
from tests.test_hardware_safety import DT, ClockedDrive, following, make, mode, never_written, settled, tripped

__all__ = ["make"]  # the driver fixture, shared with test_hardware_safety.py


def rotation(axis, angle: float) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation by `angle` about `axis`, from the half-angle formula."""
    n = math.sqrt(sum(c * c for c in axis))
    s = math.sin(angle / 2) / n
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2))


IDENTITY = (0.0, 0.0, 0.0, 1.0)


def command6(d: ClockedDrive, q=IDENTITY, w=(0.0, 0.0, 0.0), x: float = 0.0, stamp: float | None = None):
    return RobotCommand(
        header=Header(stamp=d.now() if stamp is None else stamp, tick=d.k, seq=d.k),
        pose=Pose(position=Vector3(x=x), orientation=Quaternion(*q)),
        twist=Twist(angular=Vector3(*w)),
    )


def wrench6(d: ClockedDrive, torque=(0.0, 0.0, 0.0), fx: float = 0.0) -> WrenchStamped:
    return WrenchStamped(
        header=Header(stamp=d.now(), tick=d.k, seq=d.k), wrench=Wrench(force=Vector3(x=fx), torque=Vector3(*torque))
    )


def keep_stepping(drive: ClockedDrive, make_inputs, seconds: float = 2.0) -> None:
    """Step the driver for up to `seconds` of real time (the controller moves in real time)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        drive.step(**make_inputs(drive))
        time.sleep(0.001)


# -- the register map and the servo ---------------------------------------------------------------


POSE6 = (0.012345, -0.0031, 0.2) + rotation((1.0, -2.0, 2.0), 0.7) + (0.01, -0.02, 0.003) + (0.1, -0.25, 0.05)


def test_a_six_dof_pose_and_twist_round_trip_through_the_register_map_both_ways():
    expected = tuple(round(v * per_unit) / per_unit for v, (_, per_unit, _) in zip(POSE6, mm.FIELDS))
    host = mm.decode_holding(mm.encode_write(mm.CONTROL_ENABLE, 7, POSE6))
    assert host.setpoint == expected
    controller = mm.decode_inputs(mm.encode_inputs(mm.STATUS_ENABLED, 7, 1, POSE6))
    assert controller.actual == expected
    # one count is the resolution: 1e-6 m, 1e-9 per quaternion component, 1e-6 m/s and rad/s
    assert max(abs(a - b) for a, b in zip(expected, POSE6)) <= 0.5e-6
    assert max(abs(a - b) for a, b in zip(expected[3:7], POSE6[3:7])) <= 0.5e-9
    assert abs(math.sqrt(sum(c * c for c in expected[3:7])) - 1.0) < UNIT_TOLERANCE


STEP = 1.0 / 1024  # servo period [s]


class Servo:
    """A ServoModel driven as a host would: every cycle a heartbeat, setpoints when asked."""

    def __init__(self, delay: float, tau: float):
        self.model = ServoModel(delay=delay, tau=tau)
        assert self.model.host_wrote(mm.HR_SESSION, mm.encode_owner(1, "test"))  # a host claims before it writes
        self.k = 0
        self.heartbeat = 0

    @property
    def now(self) -> float:
        return self.k * STEP

    def write(self, setpoint) -> None:
        self.heartbeat += 1
        self.model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, self.heartbeat, setpoint))

    def cycle(self) -> mm.PoseTwist:
        self.heartbeat += 1
        self.model.host_wrote(mm.HR_HEARTBEAT, [self.heartbeat])
        self.k += 1
        self.model.cycle(self.now)
        return mm.decode_inputs(self.model.inputs).actual  # what the host reads


def test_the_servo_reports_the_pose_it_was_sent_with_no_lag():
    servo = Servo(delay=0.0, tau=0.0)
    servo.write(POSE6)
    servo.cycle()  # the setpoint enters the servo: FOLLOW, target taken
    actual = servo.cycle()
    assert servo.model.mode == FOLLOW
    sent = mm.decode_holding(mm.encode_write(0, 0, POSE6)).setpoint
    norm = math.sqrt(sum(c * c for c in sent[3:7]))
    assert actual[:3] == pytest.approx(sent[:3], abs=1e-12)
    assert actual[3:7] == pytest.approx([c / norm for c in sent[3:7]], abs=1e-9)  # one count


def test_the_servo_follows_an_orientation_step_with_its_delay_and_lag():
    delay, tau, theta0 = 0.02, 0.05, 0.4
    axis = (2.0, -1.0, 2.0)
    n = [c / 3.0 for c in axis]
    target = rotation(axis, theta0)
    servo = Servo(delay, tau)
    for _ in range(5):
        servo.write(mm.HOLD_POSE)
        servo.cycle()
    assert servo.model.mode == FOLLOW
    k_written = servo.k + 1  # the cycle that first sees the step
    servo.write((0.0, 0.0, 0.0) + target + (0.0,) * 6)
    # The delay line hands the step to the servo at the first cycle at least `delay` after it entered
    # (21 cycles of 1/1024 s: 20.5 ms); the pose moves toward it from the cycle after.
    k_target = k_written + math.ceil(delay / STEP)
    history = {}
    while servo.k < k_target + 200:
        actual = servo.cycle()
        history[servo.k] = actual
        if servo.k <= k_target:
            assert actual[3:7] == pytest.approx(IDENTITY, abs=1e-9), servo.k  # the delay
    window = math.ceil(VELOCITY_WINDOW_S / STEP)  # cycles: the first span of at least the window

    def turned(k: int) -> float:  # closed form of the first-order lag: the angle turned by cycle k
        return theta0 * (1.0 - math.exp(-max(k - k_target, 0) * STEP / tau))

    for k in (k_target + 1, k_target + 10, k_target + 51, k_target + 200):
        q = rotation(axis, turned(k))
        assert history[k][3:7] == pytest.approx(q, abs=2e-9), k  # about the step's axis: one count, twice
        rate = (turned(k) - turned(k - window)) / (window * STEP)
        assert history[k][10:13] == pytest.approx([rate * c for c in n], abs=2e-6), k  # one count, twice
    assert history[k_target + 51][10:13] != pytest.approx((0.0, 0.0, 0.0), abs=0.1)  # it is turning
    assert servo.model.mode == FOLLOW and not servo.model.fault


def test_the_servo_faults_on_a_setpoint_that_is_no_rotation():
    servo = Servo(0.0, 0.0)
    servo.write(mm.HOLD_POSE)
    servo.cycle()
    servo.write((0.001, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5) + (0.0,) * 6)
    actual = servo.cycle()
    assert servo.model.fault and servo.model.mode == HOLD
    assert actual[:7] == pytest.approx(mm.HOLD_POSE[:7])  # it never went there
    assert mm.describe_status(servo.model.status()) == "fault"


def test_the_driver_commands_and_reads_an_orientation_through_the_controller(controller, make):
    drive = make()
    following(drive, controller)
    rate, turns = 0.4, 20  # rad/s: a ramp under max_angular_speed, one step per period
    axis = (0.0, 0.0, 1.0)
    for i in range(1, turns + 1):
        drive.step(command=command6(drive, rotation(axis, rate * DT * i)))
    final = rotation(axis, rate * DT * turns)
    settled(drive, lambda d: {"command": command6(d, final)})
    assert read_holding(controller.port).setpoint[3:7] == pytest.approx(final, abs=1e-9)
    wait_for(
        lambda: controller.call(lambda: controller.servo.orientation) == pytest.approx(final, abs=1e-9),
        what="the servo at the final orientation",
    )
    keep_stepping(drive, lambda d: {"command": command6(d, final)}, 0.05)
    state = drive.states[-1]
    q = state.pose.orientation
    assert (q.x, q.y, q.z, q.w) == pytest.approx(final, abs=2e-9)


# -- the limits ---------------------------------------------------------------------------------


def test_max_torque(controller, make):
    drive = make(max_torque=20.0, ft_timeout=0.05)
    following(drive, controller, lambda d: {"command": command6(d), "wrench": wrench6(d, (0.0, 12.0, 16.0))})
    drive.step(command=command6(drive), wrench=wrench6(drive, (0.0, 12.0, 16.0)))  # |T| = 20 N m: at the limit
    tripped(
        drive,
        controller,
        lambda: drive.step(command=command6(drive), wrench=wrench6(drive, (0.0, 12.0, 16.5))),
        "max_torque",
        "max_torque: contact torque |T| = 20.40 N m > 20 N m",
        math.hypot(12.0, 16.5),
    )


def test_a_non_finite_torque_trips_by_name(controller, make):
    drive = make(ft_timeout=0.05)
    following(drive, controller, lambda d: {"command": command6(d), "wrench": wrench6(d)})
    tripped(
        drive,
        controller,
        lambda: drive.step(command=command6(drive), wrench=wrench6(drive, (0, math.inf, 0))),
        "non_finite",
        "non-finite force: measured wrench torque.y = inf",
    )


@pytest.mark.parametrize(
    "q, norm", [((0.0, 0.0, 0.0, 1.1), 1.1), ((0.0, 0.0, 0.0, 0.0), 0.0), ((0.6, 0.0, 0.0, 0.8 + 2e-6), None)]
)
def test_a_non_unit_quaternion_trips_by_name_before_it_is_written(controller, make, q, norm):
    drive = make()
    following(drive, controller)
    settled(drive)
    expect = math.sqrt(sum(c * c for c in q)) if norm is None else norm  # 1.0000016: just past 1e-6
    stop = tripped(
        drive,
        controller,
        lambda: drive.step(command=command6(drive, q)),
        "non_unit_quaternion",
        f"non-unit quaternion: commanded orientation |q| = {expect:.9g} ",
    )
    assert stop.value == pytest.approx(expect, abs=1e-12)
    assert "a rotation needs |q| = 1 within 1e-06" in str(stop)
    never_written(controller)


def test_a_quaternion_within_the_unit_tolerance_is_a_rotation(controller, make):
    drive = make()
    following(drive, controller)
    q = (0.0, 0.0, 0.0, 1.0 + 0.9e-6)
    drive.step(command=command6(drive, q))
    settled(drive)
    assert read_holding(controller.port).setpoint[6] == pytest.approx(1.0 + 0.9e-6, abs=1e-9)


@pytest.mark.parametrize("field", ["orientation", "angular"])
def test_a_non_finite_orientation_or_angular_velocity_trips_by_name(controller, make, field):
    drive = make()
    following(drive, controller)
    settled(drive)
    cmd = (
        command6(drive, (0.0, 0.0, 0.0, math.nan))
        if field == "orientation"
        else command6(drive, w=(0.0, 0.0, -math.inf))
    )
    expect = "orientation.w = nan" if field == "orientation" else "angular velocity.z = -inf"
    tripped(
        drive, controller, lambda: drive.step(command=cmd), "non_finite", f"non-finite setpoint: commanded {expect}"
    )
    never_written(controller)


def test_max_tilt_of_the_commanded_orientation(controller, make):
    drive = make(max_tilt=0.01, max_actual_angular_speed=0.0)
    following(drive, controller)
    axis = (1.0, 2.0, 2.0)
    for i in range(1, 25):  # 0.4 rad/s, under max_angular_speed, up to 0.0096 rad: under the limit
        drive.step(command=command6(drive, rotation(axis, 0.0004 * i)))
    settled(drive, lambda d: {"command": command6(d, rotation(axis, 0.0096))})  # the last of them written
    tripped(
        drive,
        controller,
        lambda: drive.step(command=command6(drive, rotation(axis, 0.0104))),
        "max_tilt",
        "max_tilt: commanded orientation 0.0104 rad from the start orientation > 0.01 rad",
        0.0104,
    )
    assert read_holding(controller.port).setpoint[3:7] == pytest.approx(rotation(axis, 0.0096), abs=1e-9)


def test_max_tilt_is_measured_from_the_start_orientation(controller, make):
    start = rotation((1.0, 0.0, 0.0), 0.3)
    controller.call(controller.servo.place, (0.0, 0.0, 0.0), start)
    drive = make(max_tilt=0.2)
    following(drive, controller, lambda d: {"command": command6(d, start)})  # 0.3 rad from identity: fine
    tilted = tuple(float(c) for c in _product(start, rotation((0.0, 1.0, 0.0), 0.21)))
    tripped(
        drive,
        controller,
        lambda: drive.step(command=command6(drive, tilted)),
        "max_tilt",
        "max_tilt: commanded orientation 0.2100 rad from the start orientation > 0.2 rad",
        0.21,
    )


def _product(a, b):
    """Hamilton product a b, scalar last, written out here independently of the driver's helper."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def test_max_tilt_of_the_actual_orientation(controller, make):
    drive = make(max_tilt=0.05, max_actual_angular_speed=0.0, max_orientation_error=0.0)  # only max_tilt watches
    following(drive, controller)
    pushed = rotation((0.0, 0.0, 1.0), 0.2)

    def push(d):  # a sustained disturbance: the servo pulls back, the push turns it again
        controller.call(controller.servo.teleport, (0.0, 0.0, 0.0), pushed)
        return {"command": command6(d)}

    stop = tripped(drive, controller, lambda: keep_stepping(drive, push), "max_tilt", "max_tilt: actual orientation 0.")
    assert str(stop).endswith(" rad from the start orientation > 0.05 rad; robot held")
    assert 0.05 < stop.value <= 0.2 + 1e-9


def test_max_angular_speed_of_the_commanded_twist(controller, make):
    drive = make(max_angular_speed=0.5)
    following(drive, controller, lambda d: {"command": command6(d, w=(0.0, 0.0, 0.5))})  # at the limit
    tripped(
        drive,
        controller,
        lambda: drive.step(command=command6(drive, w=(0.0, 0.3, 0.45))),
        "max_angular_speed",
        "max_angular_speed: commanded angular speed 0.541 rad/s > 0.5 rad/s",
        math.hypot(0.3, 0.45),
    )


def test_a_turn_faster_than_max_angular_speed_is_sent_at_that_speed_then_stops(controller, make):
    drive = make(max_angular_speed=0.5, max_orientation_error=0.0, max_tilt=0.0, stall_timeout=0.2)
    following(drive, controller)
    axis = (0.0, 0.0, 1.0)

    def run():  # 2 rad/s: the setpoint sent turns at most 0.5 rad/s, until the command is 0.1 rad ahead
        for _ in range(1000):
            drive.step(command=command6(drive, rotation(axis, 0.002 * drive.k), stamp=0.0))
            time.sleep(0.001)

    stop = tripped(drive, controller, run, "max_angular_speed", "max_angular_speed: the command turned 0.")
    assert "rad ahead of the setpoint sent at 0.5 rad/s" in str(stop) and stop.value > 0.1
    sent = read_holding(controller.port).setpoint[3:7]
    assert 2 * math.atan2(abs(sent[2]), sent[3]) <= 0.5 * drive.k * DT + 1e-6


def test_a_turn_after_a_short_gap_is_sent_at_max_angular_speed(controller, make):
    drive = make(max_angular_speed=0.5)
    following(drive, controller)
    q = rotation((0.0, 1.0, 0.0), 0.06)
    t0 = drive.now()
    drive.step(command=command6(drive, q), dt=0.15)  # 0.06 rad after 0.15 s
    settled(drive, lambda d: {"command": command6(d, q)})  # reached on the driver's clock, at 0.5 rad/s
    # The gap is credited as one device cycle at most (max_cycle), the rest turned at 0.5 rad/s.
    assert drive.now() - t0 >= 0.15 + (0.06 - 0.5 * drive.node.p.max_cycle) / 0.5 - 0.002
    wait_for(lambda: read_holding(controller.port).setpoint[3:7] == pytest.approx(q, abs=1e-9), what="the write")


def test_max_actual_angular_speed(controller, make):
    drive = make(max_actual_angular_speed=1.0, max_tilt=0.0, max_orientation_error=0.0)  # only the speed watches
    following(drive, controller)
    # Lurches of 0.5 rad in one cycle, out and back every 50 ms: the windowed speed stays above 1 rad/s
    # for ~30 ms after each while the servo turns back (tau 5 ms), and a busy machine may hold the
    # driver's poll past one such window.
    lurch = {"at": 0.0, "out": True}

    def lurching(d):
        if time.monotonic() >= lurch["at"]:
            turned = rotation((0.0, 0.0, 1.0), 0.5 if lurch["out"] else 0.0)
            controller.call(controller.servo.teleport, (0.0, 0.0, 0.0), turned)
            lurch["at"], lurch["out"] = time.monotonic() + 0.05, not lurch["out"]
        return {"command": command6(d)}

    stop = tripped(
        drive,
        controller,
        lambda: keep_stepping(drive, lurching, seconds=5.0),
        "max_actual_angular_speed",
        "max_actual_angular_speed: measured angular speed ",
    )
    assert stop.value > 1.0


def test_max_orientation_error_catches_a_start_turned_away_from_the_robot(controller, make):
    start = rotation((1.0, 0.0, 0.0), 0.3)
    controller.call(controller.servo.place, (0.0, 0.0, 0.0), start)
    drive = make(max_orientation_error=0.1)
    wait_for(lambda: drive.node.link.latest()[1] is not None, what="a reading")
    tripped(
        drive,
        controller,
        lambda: drive.step(command=command6(drive)),  # the identity: 0.3 rad away
        "max_orientation_error",
        "max_orientation_error: setpoint orientation 0.3000 rad from the actual "
        "orientation > 0.1 rad (turn the robot to the start orientation first)",
        0.3,
    )
    assert controller.call(lambda: controller.servo.orientation) == pytest.approx(start, abs=1e-12)  # never moved


def test_the_limits_hold_nothing_in_a_one_dof_motion(controller, make):
    """The defaults pass a scene that commands the identity orientation and no angular velocity."""
    drive = make(ft_timeout=0.05)
    following(drive, controller, lambda d: {"command": command6(d), "wrench": wrench6(d, fx=-1.0)})
    for i in range(1, 101):  # 0.05 m/s along x, a contact force and zero torque
        drive.step(command=command6(drive, x=0.00005 * i), wrench=wrench6(drive, fx=-20.0))
        time.sleep(0.001)  # no faster than real time: the controller follows in real time
    settled(drive, lambda d: {"command": command6(d, x=0.005), "wrench": wrench6(d, fx=-20.0)})
    assert read_holding(controller.port).setpoint[0] == pytest.approx(0.005)
    assert drive.node.tripped is None and mode(controller) == FOLLOW


@pytest.mark.parametrize(
    "name, value, says",
    [
        ("max_tilt", -0.1, "must be >= 0.0"),
        ("max_tilt", 4.0, "must be <= 3.14159"),
        ("max_orientation_error", 3.5, "must be <= 3.14159"),
        ("max_torque", "strong", "expected float"),
        ("max_actual_angular_speed", -1.0, "must be >= 0.0"),
    ],
)
def test_a_bad_limit_gives_one_line_and_nothing_moves(name, value, says):
    spec = {
        "name": "robot",
        "type_name": "robot_modbus",
        "dt": 0.001,
        "clock": "wall",
        "params": {"port": 9, "connect_timeout": 0.1, name: value},
    }
    line = node_process_error(spec, ENV)
    assert f"parameter '{name}'" in line and says in line, line


def report_orientation(controller, q) -> None:
    """Make the emulated controller report this orientation after every servo cycle (a broken controller)."""
    registers = mm.encode_block((0.0,) * 3 + tuple(q) + (0.0,) * 6)[6:14]

    def install():
        servo, cycle = controller.servo, controller.servo.cycle

        def broken_cycle(now):
            cycle(now)
            servo.inputs[mm.IR_ACTUAL + 6 : mm.IR_ACTUAL + 14] = registers

        servo.cycle = broken_cycle

    controller.call(install)


def test_a_controller_reporting_no_rotation_is_refused_at_setup(controller):
    from dockhil.errors import DeviceError

    report_orientation(controller, (0.0, 0.0, 0.0, 0.0))  # orientation registers left at zero
    wait_for(lambda: controller.call(lambda: controller.servo.inputs[mm.IR_ACTUAL + 12]) == 0, what="the zeros")
    node = RobotModbusDriver(
        NodeContext("robot", DT, sim_time=False, log=lambda line: None, clock=ManualClock(0.0)),
        port=controller.port,
        ft_timeout=0.0,
    )
    with pytest.raises(DeviceError) as err:
        node.setup()
    text = str(err.value)
    assert "\n" not in text and "actual orientation with |q| = 0, not a unit quaternion" in text, text
    # refused before anything was written: no claim, no hold
    assert controller.call(lambda: (controller.servo.owner_session, controller.servo.holding[mm.HR_CONTROL])) == (0, 0)


def test_a_non_unit_actual_orientation_trips_by_name(controller, make):
    drive = make()
    following(drive, controller)
    report_orientation(controller, (0.0, 0.0, 0.0, 0.5))
    stop = tripped(
        drive,
        controller,
        lambda: keep_stepping(drive, lambda d: {"command": command6(d)}),
        "non_unit_quaternion",
        "non-unit quaternion: actual orientation |q| = 0.5 ",
    )
    assert stop.value == pytest.approx(0.5)
