"""The device is the clock: the Modbus link sends the latest setpoint on its own cycle, at most one
cycle's travel from the last value sent (from the actual pose after a hold, a reconnect or a stall),
and the controller takes control and setpoint writes only from the connection that holds a live claim.

Most tests here run the link (ModbusLink.cycle_once), the controller's servo (ServoModel.cycle) and
the graph's ticks in one thread on times the test chooses, through a Modbus client stand-in that
reaches the servo directly: a stalled controller, a late reconnect and bunched ticks are then the
same on an idle and a busy machine. One wall-time test stops a real emulator process (SIGSTOP)."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.driver import RobotModbusDriver
from dockhil.devices.modbus_robot.emulator import FOLLOW, ServoModel
from dockhil.devices.modbus_robot.link import ModbusLink, SetpointLimiter, verify_and_hold
from dockhil.node import ManualClock, NodeContext, ParamError
from tests.test_hardware_modbus import ENV, ROOT, Drive, driver, end, start_emulator
from tests.test_hardware_safety import (
    DT,
    Recorded,
    following,
    largest_step,
    make,  # noqa: F401 - a fixture
    mode,  # noqa: F401 - a fixture
    read_holding,
)

MAX_SPEED, MAX_CYCLE, MAX_ACTUAL_SPEED = 0.1, 0.005, 0.2  # the driver's defaults
COUNT = 1.0 / mm.POSITION_COUNTS  # one register count of position
SESSION = 0x1234
# The servo reports its speed over a window of about 10 ms (VELOCITY_WINDOW_S); a robot moving in
# stairs of one link cycle (2 ms) at max_speed can show one stair more than the window's time:
# at most 6 stairs in 10 ms.
STAIRS = 1.2


# -- the limiter alone ---------------------------------------------------------------------------


def pose(x: float) -> mm.PoseTwist:
    return (x,) + mm.HOLD_POSE[1:]


def test_the_limiter_starts_from_the_actual_pose_and_moves_one_cycle_at_a_time():
    lim = SetpointLimiter(MAX_SPEED, 0.5, MAX_CYCLE)
    assert lim.next(pose(0.05), pose(0.01), 0.002)[0] == pytest.approx(0.01 + 0.1 * 0.002)  # from the actual
    assert lim.next(pose(0.05), pose(0.0), 0.004)[0] == pytest.approx(0.0102 + 0.1 * 0.004)  # from the last sent
    late = 0.0106 + 0.1 * MAX_CYCLE
    assert lim.next(pose(0.05), pose(0.0), 1.0)[0] == pytest.approx(late)  # a late cycle: credited one
    assert lim.lag(pose(0.05)) == pytest.approx((0.05 - late, 0.0))
    lim.reset()
    assert lim.lag(pose(0.05)) is None and lim.next(pose(0.05), pose(0.02), 0.001)[0] == pytest.approx(0.0201)
    # A turn likewise: 0.5 rad/s for 2 ms about z toward a 0.3 rad turn.
    q = (0.0, 0.0, math.sin(0.15), math.cos(0.15))
    sent = lim.next(pose(0.0201)[:3] + q + mm.HOLD_POSE[7:], pose(0.0201), 0.002)
    assert 2 * math.atan2(sent[5], sent[6]) == pytest.approx(0.001)
    assert lim.next(sent, pose(0.0), 0.001) == sent and lim.lag(sent) == (0.0, 0.0)  # reached: nothing left


# -- link and servo on chosen times ---------------------------------------------------------------


class Answer:
    def __init__(self, registers=None, error: bool = False):
        self.registers = registers
        self.error = error

    def isError(self) -> bool:  # noqa: N802 - pymodbus's name
        return self.error


class ServoClient:
    """A Modbus client reaching a ServoModel in this thread, as one connection. While `stalled` (the
    controller stopped) nothing answers: requests time out and connects fail."""

    def __init__(self, model: ServoModel, connection: str):
        self.model = model
        self.connection = connection
        self.stalled = False
        self.sent: list[tuple[float, float]] = []  # (time, x) of every setpoint the controller took

    def connect(self) -> bool:
        return not self.stalled

    def close(self) -> None:
        pass

    def _answer(self):
        if self.stalled:
            raise TimeoutError("no answer within the timeout")

    def write_registers(self, address, values, device_id=1):
        self._answer()
        ok = self.model.host_wrote(address, list(values), self.connection)
        if ok and address == 0 and len(values) == mm.HR_COUNT:
            self.sent.append((self.now, mm.decode_holding(values).setpoint[0]))
        return Answer(error=not ok)

    def write_register(self, address, value, device_id=1):
        return self.write_registers(address, [value], device_id)

    def read_input_registers(self, address, count, device_id=1):
        self._answer()
        regs = self.model.inputs + self.model.owner_inputs()
        return Answer(regs[address : address + count])

    now = 0.0


class Bench:
    """Graph ticks, the link's cycles and the servo's cycles interleaved on one clock of 0.5 ms steps."""

    def __init__(self, tau: float = 0.0):
        self.clock = ManualClock(0.0)
        self.model = ServoModel(tau=tau, heartbeat_timeout=0.2)
        self.client = ServoClient(self.model, "driver")
        self.p = SimpleNamespace(
            device_id=1,
            timeout=0.1,
            reconnect_min=0.05,
            reconnect_max=1.0,
            poll_period=0.002,
            max_speed=MAX_SPEED,
            max_angular_speed=0.5,
            max_cycle=MAX_CYCLE,
        )
        claim = mm.encode_owner(SESSION, "graph@here")
        reading = verify_and_hold(self.client, 1, 0, claim)
        self.link = ModbusLink(self.client, "robot", self.p, lambda: "refused", claim, self.clock, reading)
        self.link_at = 0.0  # when the link runs next
        self.speeds: list[tuple[float, float]] = []  # (time, the servo's measured speed)
        self.lags: list[float] = []

    def run(self, seconds: float, command, stall=(math.inf, math.inf), ticks_late: int = 1) -> None:
        """Run for `seconds`; `command(t)` is the commanded x at graph time t; the graph's 1 ms ticks come
        `ticks_late` at a time (bunched); the controller is stopped during `stall` (start, end)."""
        end_t = self.clock() + seconds
        while self.clock() < end_t - 1e-12:
            t = self.clock.advance(0.0005)
            self.client.now = t
            stalled = stall[0] <= t < stall[1]
            self.client.stalled = stalled
            k = round(t / DT, 6)
            if k == int(k) and int(k) % ticks_late == 0:  # the graph's late ticks, all at one instant
                for i in range(ticks_late - 1, -1, -1):
                    self.link.submit(pose(command(t - i * DT)))
            if t >= self.link_at - 1e-12:
                self.link_at = t + self.link.cycle_once()
                if self.link.lag is not None:
                    self.lags.append(self.link.lag[0])
            if not stalled and k == int(k):
                self.model.cycle(t)  # a 1 ms servo, stopped with the controller
                self.speeds.append((t, math.sqrt(sum(v * v for v in self.model.linear))))

    def steps(self, after: float = 0.0) -> float:
        """The largest step between two setpoints the controller took (from `after` on)."""
        return largest_step([x for t, x in self.client.sent if t >= after])

    def top_speed(self, after: float) -> float:
        return max(v for t, v in self.speeds if t >= after)


def ramp(t: float) -> float:
    """A docking approach: rest, then 0.05 m/s."""
    return 0.05 * max(t - 0.05, 0.0)


@pytest.mark.parametrize("stall", [0.15, 0.3, 1.0])
def test_after_a_controller_stall_the_robot_moves_on_from_its_actual_pose_within_the_limits(stall):
    bench = Bench()
    bench.run(0.3, ramp)
    # Following, a few cycles behind (the link's 2 ms cycle, the servo's 1 ms one).
    assert bench.model.mode == FOLLOW and bench.model.position[0] == pytest.approx(ramp(0.3), abs=3e-4)
    begin = bench.clock()
    bench.run(stall + 1.0, ramp, stall=(begin, begin + stall))
    link, model = bench.link, bench.model
    assert link.reconnects == 1 and any("connection lost" in n for n in link.take_notes())
    # The command ran on during the stall; the robot catches up at max_speed, never in a jump.
    assert bench.top_speed(begin) <= STAIRS * MAX_SPEED < MAX_ACTUAL_SPEED
    assert bench.steps() <= MAX_SPEED * MAX_CYCLE + COUNT
    assert link.largest_step <= MAX_SPEED * MAX_CYCLE + 1e-12
    catch_up = stall / (MAX_SPEED / 0.05 - 1)  # the command's lead over the speed difference
    if stall + catch_up < 0.9:
        assert model.position[0] == pytest.approx(ramp(bench.clock()), abs=3e-4)
    # A controller that stopped longer than its heartbeat timeout held and let the claim go; the link
    # claimed it again before it wrote anything, and nothing it wrote was refused.
    assert model.owner_session == SESSION and model.refused == 0


def test_bunched_graph_ticks_never_step_further_than_a_device_cycle_allows():
    bench = Bench()
    fast = 0.095  # just under max_speed: five ticks at one instant are 0.475 mm
    bench.run(1.0, lambda t: fast * t, ticks_late=5)
    assert bench.steps() <= MAX_SPEED * MAX_CYCLE + COUNT
    # Each write moved at most max_speed times the device cycle's time since the one before.
    sent = bench.client.sent
    assert all(abs(x1 - x0) <= MAX_SPEED * (t1 - t0) + COUNT for (t0, x0), (t1, x1) in zip(sent, sent[1:]))
    assert bench.top_speed(0.0) <= STAIRS * MAX_SPEED
    # The command is never further ahead than the bunch: far from the driver's max_speed trip
    # (max_speed x stall_timeout = 20 mm).
    assert max(bench.lags) <= 5 * fast * DT + 1e-9
    assert bench.model.position[0] == pytest.approx(fast * 1.0, abs=6 * fast * DT)


def test_a_hold_and_a_reconnect_resume_from_the_actual_pose():
    bench = Bench(tau=0.05)  # a lagging servo: the actual pose trails the setpoint
    bench.run(0.3, ramp)
    bench.link.submit(None)  # hold (the F/T data stopped, or the command disabled)
    bench.run(0.002, lambda t: ramp(0.3))
    bench.link.submit(None)
    held_at = bench.model.position[0]
    assert bench.client.sent[-1][1] > held_at + 1e-3  # the last setpoint was well ahead of the robot
    n = len(bench.client.sent)
    bench.run(0.01, lambda t: ramp(0.3))
    first = bench.client.sent[n][1]
    assert abs(first - held_at) <= MAX_SPEED * MAX_CYCLE + COUNT  # from where the robot stood, one cycle on


# -- the controller's claim ------------------------------------------------------------------------


def test_the_controller_refuses_setpoints_from_a_connection_without_a_live_claim():
    lines: list[str] = []
    model = ServoModel(heartbeat_timeout=0.2)
    model.log = lines.append
    intruder = mm.encode_write(mm.CONTROL_ENABLE, 1, pose(0.456))
    assert not model.host_wrote(0, intruder, "raw")  # nobody owns it: still no claim, no motion
    assert model.host_wrote(mm.HR_SESSION, mm.encode_owner(SESSION, "graph@here"), "driver")
    assert model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, 2, pose(0.001)), "driver")
    model.cycle(0.0)
    model.cycle(0.001)
    assert model.mode == FOLLOW and model.position[0] == pytest.approx(0.001)
    model.cycle(0.5)  # the owner stalled past the heartbeat timeout: the claim lapsed, the robot holds
    assert model.owner_session == 0
    for i in range(278):  # a raw client that never claims
        assert not model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, 100 + i, pose(0.456)), "raw")
        model.cycle(0.501 + i * 0.001)
    assert model.position[0] == pytest.approx(0.001) and model.mode != FOLLOW
    assert model.unclaimed == 279 and model.refused == 279
    assert len(lines) == 1 and "from connection raw: it holds no live claim" in lines[0]
    # The owner's own connection, its claim lapsed, is refused too until it claims again.
    assert not model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, 9, pose(0.002)), "driver")
    assert model.host_wrote(mm.HR_SESSION, mm.encode_owner(SESSION, "graph@here"), "driver")
    assert model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, 10, pose(0.002)), "driver")


def test_an_unclaimed_client_is_refused_over_modbus_tcp(controller):
    from pymodbus.client import ModbusTcpClient

    raw = ModbusTcpClient("127.0.0.1", port=controller.port, timeout=1.0, retries=0)
    assert raw.connect()
    try:
        answer = raw.write_registers(0, mm.encode_write(mm.CONTROL_ENABLE, 1, pose(0.05)), device_id=1)
        assert answer.isError() and answer.exception_code == 6
        time.sleep(0.01)
        assert controller.call(lambda: (controller.servo.unclaimed, controller.servo.position[0])) == (1, 0.0)
        assert read_holding(controller.port).setpoint == mm.HOLD_POSE
    finally:
        raw.close()


# -- the driver, on its clock ------------------------------------------------------------------------


def test_bunched_ticks_do_not_trip_the_driver(controller, make):  # noqa: F811 - the fixture
    drive = make(max_speed=0.1, max_following_error=0.0)
    following(drive, controller)
    link = drive.node.link
    link.client = rec = Recorded(link.client)
    x = 0.0
    for _ in range(60):  # 0.09 m/s in ticks that come five at one instant, 5 ms late
        for i in range(5):
            x += 0.09 * DT
            drive.step(command=drive.command(x=x), dt=0.005 if i == 0 else 0.0)
        time.sleep(0.006)  # the driver's clock no faster than the controller's (real) one
    assert drive.node.tripped is None and mode(controller) == FOLLOW
    assert largest_step(rec.xs) <= 0.1 * drive.node.p.max_cycle + COUNT


def test_the_link_parameters_have_physical_ranges():
    for name, value in (
        ("max_cycle", 0.0),
        ("max_cycle", 1.0),
        ("poll_period", 5.0),
        ("x_max", 1e4),
        ("max_speed", 100.0),
        ("timeout", 60.0),
    ):
        with pytest.raises(ParamError, match=f"parameter '{name}'"):
            RobotModbusDriver(NodeContext("robot", DT, sim_time=False), **{name: value})


# -- a real emulator process, stopped -------------------------------------------------------------------


@pytest.mark.wall_time
@pytest.mark.parametrize("stall", [0.15, 0.3, 1.0])
def test_a_sigstopped_controller_resumes_without_a_jump(stall):
    proc, port = start_emulator(0)  # no lag: the robot goes where it is sent, so a jump would show
    logs: list[str] = []
    # A generous request timeout and a wide velocity window are not needed: the limits under test are
    # the defaults (max_speed 0.1 m/s, max_actual_speed 0.2 m/s); only the stall watchdogs are opened,
    # this test stepping the driver from its own thread on the real clock.
    node = driver(port, logs, timeout=0.1, reconnect_timeout=10.0)
    try:
        node.setup()
        drive = Drive(node)
        link = node.link
        link.client = rec = Recorded(link.client)
        t0 = drive.now()

        def approach(d):
            return {"command": d.command(x=0.004 * min(d.now() - t0, 1.0), v=0.004)}

        drive.run(0.5, approach)
        os.kill(proc.pid, signal.SIGSTOP)
        try:
            drive.run(stall, approach)
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        resumed = len(drive.states)
        drive.until(lambda d: link.reconnects >= 1 and len(d.states) > resumed + 50, approach, timeout=30.0)
        drive.run(0.5, approach)
        speed = max(
            math.sqrt(s.twist.linear.x**2 + s.twist.linear.y**2 + s.twist.linear.z**2)
            for _, s in drive.states[resumed:]
        )
        step = largest_step(rec.xs)
        print(
            f"stall {stall} s: robot speed {speed:.4f} m/s, largest setpoint step {step * 1e3:.4f} mm, "
            f"reconnects {link.reconnects}"
        )
        assert node.tripped is None
        assert speed <= MAX_ACTUAL_SPEED
        assert step <= MAX_SPEED * node.p.max_cycle + COUNT
    finally:
        node.close()
        end(proc)


@pytest.mark.parametrize("arg, value", [("--cycle", "0"), ("--delay", "-0.1"), ("--heartbeat-timeout", "nan")])
def test_the_emulator_refuses_a_parameter_outside_its_range_before_it_listens(arg, value):
    proc = subprocess.run(
        [sys.executable, "-m", "dockhil.devices.modbus_robot.emulator", "--port", "0", arg, value],
        cwd=ROOT,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().startswith(f"robot emulator: error: {arg} {float(value)} is outside its range ")
    assert len(proc.stderr.strip().splitlines()) == 1
