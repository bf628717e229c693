"""Safety limits of the robot driver, each against the controller emulator over Modbus TCP:
a violation holds the robot, raises SafetyStop with one line naming the limit and
the value, and nothing is commanded afterwards."""

from __future__ import annotations

import time

import pytest

from dockhil.errors import DockhilError
from dockhil.hardware import SafetyStop
from dockhil.hardware import modbus_map as mm
from dockhil.hardware.robot_emulator import FOLLOW, HOLD
from msgs import EStop, Header, Pose, RobotCommand, Vector3, Wrench, WrenchStamped
from tests.test_hardware_modbus import Drive, driver, read_holding


@pytest.fixture
def make(controller):
    made = []

    def make_driver(**params):
        node = driver(controller.port, **params)
        node.setup()
        made.append(node)
        return Drive(node)

    yield make_driver
    for node in made:
        node.close()


def wrench(drive: Drive, fx: float) -> WrenchStamped:
    return WrenchStamped(header=Header(stamp=drive.now(), tick=drive.k, seq=drive.k),
                         wrench=Wrench(force=Vector3(x=fx)))


def mode(controller) -> str:
    return controller.call(lambda: controller.servo.mode)


def tripped(drive: Drive, controller, run, limit: str, message: str, value=None) -> SafetyStop:
    """Run until the stop; check the line, the hold, and that nothing is commanded afterwards."""
    with pytest.raises(SafetyStop) as err:
        run()
    stop = err.value
    assert isinstance(stop, DockhilError)  # the runtime turns it into a non-zero exit
    text = str(stop)
    assert "\n" not in text and text.startswith("safety stop: ") and text.endswith("; robot held")
    assert message in text, text
    assert stop.limit == limit
    if value is not None:
        assert stop.value == pytest.approx(value, rel=1e-3)
    # the hold was written before the exception
    assert controller.call(lambda: controller.servo.holding[mm.HR_CONTROL]) == mm.CONTROL_ENABLE | mm.CONTROL_HOLD
    deadline = time.monotonic() + 1.0
    while mode(controller) != HOLD and time.monotonic() < deadline:
        time.sleep(0.002)
    assert mode(controller) == HOLD
    # latched: fresh commands are refused and never written
    writes = drive.node.link.writes
    for _ in range(3):
        with pytest.raises(SafetyStop) as again:
            drive.step(command=drive.command(x=0.0), wrench=wrench(drive, 0.0))
        assert again.value is stop
    time.sleep(0.02)
    assert drive.node.link.writes == writes
    return stop


def test_max_force(controller, make):
    drive = make(max_force=120.0, ft_timeout=0.05)
    drive.run(0.05, lambda d: {"command": d.command(), "wrench": wrench(d, -80.0)})
    assert mode(controller) == FOLLOW
    tripped(drive, controller, lambda: drive.step(command=drive.command(), wrench=wrench(drive, -150.5)),
            "max_force", "max_force: contact force |F| = 150.5 N > 120 N", 150.5)


def test_max_speed_of_the_commanded_twist(controller, make):
    drive = make(max_speed=0.05)
    drive.run(0.03, lambda d: {"command": d.command(v=0.05)})
    tripped(drive, controller, lambda: drive.step(command=drive.command(v=0.08)),
            "max_speed", "max_speed: commanded speed 0.080 m/s > 0.05 m/s", 0.08)


def test_max_speed_of_setpoint_steps(controller, make):
    drive = make(max_speed=0.05)

    def cmd(stamp, x):
        return RobotCommand(header=Header(stamp=stamp, tick=drive.k, seq=drive.k), pose=Pose(position=Vector3(x=x)))

    drive.step(command=cmd(1.000, 0.0))
    drive.step(command=cmd(1.001, 0.00004))  # 0.04 m/s: fine, whatever the (zero) twist says
    tripped(drive, controller, lambda: drive.step(command=cmd(1.002, 0.00014)),
            "max_speed", "max_speed: setpoint moved 0.0001 m in 0.0010 s (0.100 m/s) > 0.05 m/s", 0.1)
    assert read_holding(controller.port).setpoint[0] != pytest.approx(0.00014)


def test_max_actual_speed(controller, make):
    drive = make(max_actual_speed=0.2)
    drive.run(0.03, lambda d: {"command": d.command()})
    controller.call(controller.servo.teleport, (0.004, 0.0, 0.0))  # the robot lurches 4 mm in one cycle

    def run():
        drive.run(1.0, lambda d: {"command": d.command()})

    stop = tripped(drive, controller, run, "max_actual_speed", "max_actual_speed: measured speed ")
    assert stop.value > 0.2


def test_workspace_refuses_a_commanded_pose_before_it_is_written(controller, make):
    drive = make(x_max=0.005)
    drive.run(0.03, lambda d: {"command": d.command(x=0.0)})
    tripped(drive, controller, lambda: drive.step(command=drive.command(x=0.0051)),
            "workspace", "workspace: commanded position.x = 0.0051 m above x_max 0.005 m", 0.0051)
    assert read_holding(controller.port).setpoint[0] == 0.0


def test_workspace_of_the_actual_pose(controller, make):
    drive = make(y_min=-0.01, max_actual_speed=0.0, max_following_error=0.0)  # only the workspace watches
    drive.run(0.03, lambda d: {"command": d.command()})
    controller.call(controller.servo.teleport, (0.0, -0.05, 0.0))  # the servo pulls it back from there
    stop = tripped(drive, controller, lambda: drive.run(1.0, lambda d: {"command": d.command()}),
                   "workspace", "workspace: actual position.y = -0.0")
    assert str(stop).endswith(" m below y_min -0.01 m; robot held") and -0.05 <= stop.value < -0.01


def test_max_following_error_catches_a_start_far_from_the_robot(controller, make):
    drive = make(max_following_error=0.01)
    drive.run(0.03, lambda d: {})  # the driver has read where the robot is
    tripped(drive, controller, lambda: drive.step(command=drive.command(x=-0.03)),
            "max_following_error", "max_following_error: setpoint 0.0300 m from the actual pose > 0.01 m", 0.03)
    assert controller.call(lambda: controller.servo.position[0]) == 0.0  # it never moved


def test_ft_watchdog_stops_when_the_wrench_goes_stale(controller, make):
    drive = make(ft_timeout=0.04)
    drive.run(0.05, lambda d: {"command": d.command(), "wrench": wrench(d, -5.0)})
    assert mode(controller) == FOLLOW
    last = wrench(drive, -5.0)
    t_last = drive.now()

    def run():
        drive.run(1.0, lambda d: {"command": d.command(), "wrench": last})  # the same message again: stale

    stop = tripped(drive, controller, run, "ft_timeout", "ft_timeout: no F/T data for 0.0")
    assert 0.04 < stop.value < 0.04 + 0.03
    assert drive.now() - t_last < 0.2


def test_ft_watchdog_holds_until_the_first_wrench_then_stops(controller, make):
    drive = make(ft_timeout=0.02, ft_grace=0.15)
    drive.run(0.1, lambda d: {"command": d.command(x=0.001)})
    assert mode(controller) == HOLD  # commands arrive, but without F/T data the robot stays put
    assert read_holding(controller.port).setpoint[0] == 0.0
    stop = tripped(drive, controller, lambda: drive.run(1.0, lambda d: {"command": d.command(x=0.001)}),
                   "ft_timeout", "ft_timeout: no F/T data 0.1")
    assert "after start (ft_grace 0.15 s + ft_timeout 0.02 s; connect /ft/wrench or set ft_timeout 0)" in str(stop)
    assert 0.17 < stop.value < 0.25


def test_estop(controller, make):
    drive = make()
    calm = EStop(header=Header(), active=False)
    drive.run(0.03, lambda d: {"command": d.command(), "estop": calm})
    assert mode(controller) == FOLLOW
    pressed = EStop(header=Header(stamp=drive.now()), active=True, reason="operator button")
    tripped(drive, controller, lambda: drive.step(command=drive.command(), estop=pressed),
            "estop", "estop: e-stop active (operator button)")


def test_a_stop_while_the_controller_is_unreachable_says_so(controller, make):
    drive = make(reconnect_timeout=0.0)
    drive.run(0.03, lambda d: {"command": d.command()})
    controller.stop_thread()
    deadline = time.monotonic() + 2.0
    while drive.node.link.connected and time.monotonic() < deadline:
        drive.step(command=drive.command())
        time.sleep(0.001)
    assert not drive.node.link.connected
    with pytest.raises(SafetyStop) as err:
        drive.step(command=drive.command(), estop=EStop(header=Header(), active=True))
    assert str(err.value).endswith(
        "; hold not confirmed (controller unreachable: its heartbeat timeout holds the robot)")
    assert drive.node.link.hold_latched  # a reconnect would write the hold first
