"""Safety limits of the robot driver, each against the controller emulator over Modbus TCP:
a violation holds the robot, raises SafetyStop with one line naming the limit and
the value, and nothing is commanded afterwards.

The driver's time is a ManualClock the test advances by one period per step, so every
verdict here ("the watchdog holds after 0.04 s", "a 0.25 s gap is a stall") is the same on
an idle and on a loaded machine. Only the Modbus link and the controller run in real time;
the tests wait for their effects (a write, a mode) with deadlines."""

from __future__ import annotations

import math
import time

import pytest

from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.driver import RobotModbusDriver
from dockhil.devices.modbus_robot.emulator import FOLLOW, HOLD
from dockhil.errors import DockhilError, SafetyStop
from dockhil.msgs import EStop, Header, Pose, RobotCommand, Twist, Vector3, Wrench, WrenchStamped
from dockhil.node import ManualClock, NodeContext, Tick
from tests.conftest import wait_for
from tests.test_hardware_modbus import read_holding

DT = 0.001


class ClockedDrive:
    """Steps a driver on a ManualClock: each step is one period later on the driver's clock."""

    def __init__(self, node: RobotModbusDriver, clock: ManualClock):
        self.node = node
        self.clock = clock
        self.k = 0
        self.states = []

    def now(self) -> float:
        return self.clock()

    def command(self, x: float = 0.0, v: float = 0.0, stamp: float | None = None) -> RobotCommand:
        return RobotCommand(
            header=Header(stamp=self.now() if stamp is None else stamp, tick=self.k, seq=self.k),
            pose=Pose(position=Vector3(x=x)),
            twist=Twist(linear=Vector3(x=v)),
        )

    def wrench(self, fx: float, fy: float = 0.0) -> WrenchStamped:
        return WrenchStamped(
            header=Header(stamp=self.now(), tick=self.k, seq=self.k), wrench=Wrench(force=Vector3(x=fx, y=fy))
        )

    def step(self, command=None, wrench=None, estop=None, dt: float = DT):
        self.clock.advance(dt)
        out = self.node.step(Tick(self.k, self.now(), DT), {"command": command, "wrench": wrench, "estop": estop})
        self.k += 1
        if "state" in out:  # a step may publish the device cycles alone, without a fresh pose
            self.states.append(out["state"])
        return out

    def run(self, ticks: int, make=lambda d: {}):
        for _ in range(ticks):
            self.step(**make(self))


@pytest.fixture
def make(controller):
    made = []

    def make_driver(**params):
        params.setdefault("ft_timeout", 0.0)
        # 1 s per request, as in test_hardware_modbus.py: the controller is a thread of this process, and on
        # a machine with both cores busy its answer can outlast the 0.1 s default, which the link rightly
        # takes for a lost connection (dropping the setpoint handed over); none of these limits is about it.
        params.setdefault("timeout", 1.0)
        clock = ManualClock(100.0)
        node = RobotModbusDriver(
            NodeContext("robot", DT, sim_time=False, log=lambda line: None, clock=clock), port=controller.port, **params
        )
        node.setup()
        made.append(node)
        return ClockedDrive(node, clock)

    yield make_driver
    for node in made:
        node.close()


def mode(controller) -> str:
    return controller.call(lambda: controller.servo.mode)


def following(drive: ClockedDrive, controller, make=lambda d: {"command": d.command()}) -> None:
    """Step until the controller follows (the link writes in real time; the driver's clock moves per step)."""
    deadline = time.monotonic() + 5.0
    while mode(controller) != FOLLOW:
        assert time.monotonic() < deadline, "the controller never followed"
        drive.step(**make(drive))
        time.sleep(0.002)


def settled(drive: ClockedDrive, make=None) -> int:
    """The link's write count once the last setpoint handed over is written and reached. The link moves
    the setpoint at most one device cycle's travel per write, its cycles timed on the driver's clock, so
    `make` (inputs for a step) keeps the clock moving until the setpoint sent has caught up."""
    link = drive.node.link
    deadline = time.monotonic() + 5.0
    while link.fresh or link.lag != (0.0, 0.0):  # None: a cycle under way
        assert time.monotonic() < deadline, "the link never took or reached the last setpoint"
        if make is not None:
            drive.step(**make(drive))
        time.sleep(0.001)
    seen = link.readings
    while link.readings < seen + 2:  # a whole cycle begun after the hand-over: its write is counted
        assert time.monotonic() < deadline, "the link stopped cycling"
        time.sleep(0.001)
    return link.writes


AT_REST = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # origin, identity, no motion


def never_written(controller, last_good=AT_REST) -> None:
    """The controller's setpoint registers still hold the last good setpoint: the refused one never reached
    them. (Not a count of writes: the link rewrites the good setpoint every cycle until the hold, and on a
    busy machine a cycle can fall between the test's last look and the refused step.)"""
    assert read_holding(controller.port).setpoint == pytest.approx(last_good, abs=1e-9)


def tripped(drive: ClockedDrive, controller, run, limit: str, message: str, value=None) -> SafetyStop:
    """Run until the stop; check the line, the hold, and that nothing is commanded afterwards."""
    with pytest.raises(SafetyStop) as err:
        run()
    stop = err.value
    assert isinstance(stop, DockhilError)  # the runtime turns it into a non-zero exit
    text = str(stop)
    assert "\n" not in text and text.startswith("safety stop: ") and text.endswith("; robot held"), text
    assert message in text, text
    assert stop.limit == limit
    if value is not None:
        assert stop.value == pytest.approx(value, rel=1e-3)
    # the hold was written before the exception
    assert controller.call(lambda: controller.servo.holding[mm.HR_CONTROL]) == mm.CONTROL_ENABLE | mm.CONTROL_HOLD
    wait_for(lambda: mode(controller) == HOLD, what="HOLD")
    # latched: fresh commands are refused and never written
    writes = drive.node.link.writes
    for _ in range(3):
        with pytest.raises(SafetyStop) as again:
            drive.step(command=drive.command(x=0.0), wrench=drive.wrench(0.0))
        assert again.value is stop
    time.sleep(0.02)
    assert drive.node.link.writes == writes
    return stop


def test_max_force(controller, make):
    drive = make(max_force=120.0, ft_timeout=0.05)
    following(drive, controller, lambda d: {"command": d.command(), "wrench": d.wrench(-80.0)})
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(), wrench=drive.wrench(-150.5)),
        "max_force",
        "max_force: contact force |F| = 150.5 N > 120 N",
        150.5,
    )


def test_max_force_is_the_norm_of_the_force(controller, make):
    drive = make(max_force=4.0, ft_timeout=0.05)
    following(drive, controller, lambda d: {"command": d.command(), "wrench": d.wrench(-2.0)})
    drive.step(command=drive.command(), wrench=drive.wrench(-3.0, 2.6))  # |F| = 3.97 N: under the limit
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(), wrench=drive.wrench(-3.0, 2.7)),
        "max_force",
        "max_force: contact force |F| = 4.0 N > 4 N",
        math.hypot(3.0, 2.7),
    )


def test_max_speed_of_the_commanded_twist(controller, make):
    drive = make(max_speed=0.05)
    following(drive, controller, lambda d: {"command": d.command(v=0.05)})
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(v=0.08)),
        "max_speed",
        "max_speed: commanded speed 0.080 m/s > 0.05 m/s",
        0.08,
    )


class Recorded:
    """The link's Modbus client, recording every setpoint written (position x)."""

    def __init__(self, client):
        self.client = client
        self.xs: list[float] = []

    def write_registers(self, address, values, **kw):
        if address == 0 and len(values) == mm.HR_COUNT:
            self.xs.append(mm.decode_holding(values).setpoint[0])
        return self.client.write_registers(address, values, **kw)

    def __getattr__(self, name):
        return getattr(self.client, name)


def recorded(drive: ClockedDrive) -> Recorded:
    link = drive.node.link
    link.client = Recorded(link.client)
    return link.client


def largest_step(xs: list[float]) -> float:
    return max((abs(b - a) for a, b in zip(xs, xs[1:])), default=0.0)


def test_a_command_faster_than_max_speed_is_sent_at_max_speed_then_stops(controller, make):
    drive = make(max_speed=0.05, max_following_error=0.0, stall_timeout=0.2, max_cycle=0.01)
    following(drive, controller)
    rec = recorded(drive)

    # 0.2 m/s, whatever the stamps say: the setpoint sent moves at most 0.05 m/s on the driver's clock, one
    # device cycle (at most max_cycle) at a time; the command runs ahead until it is 0.05 m/s x 0.2 s ahead.
    def run():
        for _ in range(1000):
            drive.step(command=drive.command(x=0.0002 * drive.k, stamp=0.0))
            time.sleep(0.001)

    stop = tripped(drive, controller, run, "max_speed", "max_speed: the command ran 0.0")
    assert "m ahead of the setpoint sent at 0.05 m/s" in str(stop) and stop.value > 0.01
    assert rec.xs and largest_step(rec.xs) <= 0.05 * 0.01 + 1e-6  # one count of rounding
    # Never more than max_speed over the driver's time: the command went 0.2 m/s for the time it took.
    assert max(rec.xs) <= 0.05 * drive.k * DT + 1e-6


def test_a_step_after_a_short_gap_is_sent_at_max_speed(controller, make):
    drive = make(max_speed=0.05, max_following_error=0.0, max_cycle=0.01)
    following(drive, controller)
    rec = recorded(drive)
    drive.step(command=drive.command(x=0.006), dt=0.15)  # 6 mm after 0.15 s: below the stall timeout
    settled(drive, lambda d: {"command": d.command(x=0.006)})
    wait_for(lambda: read_holding(controller.port).setpoint[0] == pytest.approx(0.006), what="the write")
    # The gap is not credited as travel: at most one cycle's (max_cycle 10 ms at 0.05 m/s) per write.
    assert largest_step(rec.xs) <= 0.05 * 0.01 + 1e-6 and len(rec.xs) >= 12


def test_a_gap_longer_than_the_stall_timeout_holds_and_stops(controller, make):
    drive = make(stall_timeout=0.2)
    following(drive, controller)
    x_before = read_holding(controller.port).setpoint[0]
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(x=0.0001), dt=0.25),
        "stall",
        "stall: no step for 0.250 s > stall_timeout 0.2 s",
        0.25,
    )
    assert read_holding(controller.port).setpoint[0] == x_before  # the step after the gap was never written


def test_a_gap_just_under_the_stall_timeout_is_not_a_stall(controller, make):
    drive = make(stall_timeout=0.2)
    following(drive, controller)
    drive.step(command=drive.command(), dt=0.199)
    drive.step(command=drive.command())


def test_setpoints_that_stop_coming_while_moving_hold_and_stop(controller, make):
    drive = make(stall_timeout=0.1)
    following(drive, controller)
    last = drive.command()
    drive.step(command=last)
    drive.run(99, lambda d: {"command": last})  # the same message again for 0.099 s: the simulation stalled
    tripped(
        drive,
        controller,
        lambda: drive.step(command=last, dt=0.002),
        "stale_command",
        "stale command: no new setpoint for 0.101 s > stall_timeout 0.1 s",
        0.101,
    )


@pytest.mark.parametrize("field", ["x", "inf", "twist"])
def test_a_non_finite_setpoint_trips_by_name_before_it_is_written(controller, make, field):
    drive = make()
    following(drive, controller)
    settled(drive)
    bad = {"x": Pose(position=Vector3(x=math.nan)), "inf": Pose(position=Vector3(z=-math.inf)), "twist": Pose()}[field]
    twist = Twist(linear=Vector3(y=math.nan)) if field == "twist" else Twist()
    cmd = RobotCommand(header=Header(stamp=drive.now(), tick=drive.k, seq=drive.k), pose=bad, twist=twist)
    expect = {"x": "position.x = nan", "inf": "position.z = -inf", "twist": "linear velocity.y = nan"}[field]
    stop = tripped(
        drive, controller, lambda: drive.step(command=cmd), "non_finite", f"non-finite setpoint: commanded {expect}"
    )
    assert stop.value == expect
    never_written(controller)


def test_a_non_finite_force_trips_by_name(controller, make):
    drive = make(max_force=200.0, ft_timeout=0.05)
    following(drive, controller, lambda d: {"command": d.command(), "wrench": d.wrench(-1.0)})
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(), wrench=drive.wrench(math.nan)),
        "non_finite",
        "non-finite force: measured wrench force.x = nan",
    )


def test_max_actual_speed(controller, make):
    drive = make(max_actual_speed=0.2)
    following(drive, controller)

    def run():
        # The robot lurches 4 mm in one cycle, out and back every 50 ms: the controller reports its
        # speed over 10 ms, and a busy machine may hold the driver's poll past one such window.
        deadline, lurch, out = time.monotonic() + 5.0, 0.0, True
        while time.monotonic() < deadline:
            if time.monotonic() >= lurch:
                controller.call(controller.servo.teleport, (0.004 if out else 0.0, 0.0, 0.0))
                lurch, out = time.monotonic() + 0.05, not out
            drive.step(command=drive.command())
            time.sleep(0.001)

    stop = tripped(drive, controller, run, "max_actual_speed", "max_actual_speed: measured speed ")
    assert stop.value > 0.2


def test_workspace_refuses_a_commanded_pose_before_it_is_written(controller, make):
    drive = make(x_max=0.005)
    following(drive, controller)
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(x=0.0051)),
        "workspace",
        "workspace: commanded position.x = 0.0051 m above x_max 0.005 m",
        0.0051,
    )
    assert read_holding(controller.port).setpoint[0] == 0.0


def test_a_setpoint_the_register_map_cannot_carry_holds_the_robot_in_one_line(controller, make):
    # The speed limit off: the map itself refuses a twist past its +-2147 m/s.
    drive = make(max_speed=0.0, max_following_error=0.0)
    following(drive, controller)
    stop = tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(v=3000.0)),
        "register_range",
        "register map: setpoint linear.x = 3000 m/s does not fit the register map",
    )
    assert "connection lost" not in str(stop)
    assert read_holding(controller.port).setpoint[0] == 0.0


def test_workspace_of_the_actual_pose(controller, make):
    drive = make(y_min=-0.01, max_actual_speed=0.0, max_following_error=0.0)  # only the workspace watches
    following(drive, controller)

    def run():
        # A sustained push out of the workspace: the servo (tau 5 ms) pulls back, the push moves it out
        # again, so a busy machine's late poll still reads it out there.
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            controller.call(controller.servo.teleport, (0.0, -0.05, 0.0))
            drive.step(command=drive.command())
            time.sleep(0.001)

    stop = tripped(drive, controller, run, "workspace", "workspace: actual position.y = -0.0")
    assert str(stop).endswith(" m below y_min -0.01 m; robot held") and -0.05 <= stop.value < -0.01


def test_max_following_error_catches_a_start_far_from_the_robot(controller, make):
    drive = make(max_following_error=0.01)
    wait_for(lambda: drive.node.link.latest()[1] is not None, what="a reading")  # where the robot is
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(x=-0.03)),
        "max_following_error",
        "max_following_error: setpoint 0.0300 m from the actual pose > 0.01 m",
        0.03,
    )
    assert controller.call(lambda: controller.servo.position[0]) == 0.0  # it never moved


def test_ft_watchdog_stops_when_the_wrench_goes_stale(controller, make):
    drive = make(ft_timeout=0.04)
    following(drive, controller, lambda d: {"command": d.command(), "wrench": d.wrench(-5.0)})
    last = drive.wrench(-5.0)
    drive.step(command=drive.command(), wrench=last)
    drive.run(39, lambda d: {"command": d.command(), "wrench": last})  # the same message again: 0.039 s old
    stop = tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(), wrench=last, dt=0.002),
        "ft_timeout",
        "ft_timeout: no F/T data for 0.041 s > 0.04 s",
    )
    assert stop.value == pytest.approx(0.041)


def test_ft_watchdog_holds_until_the_first_wrench_then_stops(controller, make):
    drive = make(ft_timeout=0.02, ft_grace=0.15)
    drive.run(170, lambda d: {"command": d.command(x=0.001)})  # 0.169 s from the first step: within grace + timeout
    time.sleep(0.05)  # whatever the link does meanwhile: without F/T data it only holds
    assert mode(controller) == HOLD  # commands arrive, but without F/T data the robot stays put
    assert read_holding(controller.port).setpoint[0] == 0.0
    stop = tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(x=0.001), dt=0.002),
        "ft_timeout",
        "ft_timeout: no F/T data 0.171 s after start",
    )
    assert "after start (ft_grace 0.15 s + ft_timeout 0.02 s; connect /ft/wrench or set ft_timeout 0)" in str(stop)
    assert stop.value == pytest.approx(0.171)


def test_estop(controller, make):
    drive = make()
    calm = EStop(header=Header(), active=False)
    following(drive, controller, lambda d: {"command": d.command(), "estop": calm})
    pressed = EStop(header=Header(stamp=drive.now()), active=True, reason="operator button")
    tripped(
        drive,
        controller,
        lambda: drive.step(command=drive.command(), estop=pressed),
        "estop",
        "estop: e-stop active (operator button)",
    )


def test_a_stop_while_the_controller_is_unreachable_says_so(controller, make):
    drive = make(reconnect_timeout=0.0)
    following(drive, controller)
    controller.stop_thread()
    deadline = time.monotonic() + 2.0
    while drive.node.link.connected and time.monotonic() < deadline:
        drive.step(command=drive.command())
        time.sleep(0.001)
    assert not drive.node.link.connected
    with pytest.raises(SafetyStop) as err:
        drive.step(command=drive.command(), estop=EStop(header=Header(), active=True))
    assert str(err.value).endswith(
        "; hold not confirmed (controller unreachable: its heartbeat timeout holds the robot)"
    )
    assert drive.node.link.hold_latched  # a reconnect would write the hold first
