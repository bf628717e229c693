"""Modbus TCP: the controller emulator's servo and rules, the robot driver against
it over loopback (in a subprocess and in a thread), missing and lost connections.

The driver and the controller run on their own clocks here: a test waits for what it
expects with a deadline (Drive.until), so a busy machine makes it slower, not wrong."""

from __future__ import annotations

import math
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pymodbus  # noqa: F401  - a hard dependency: missing, the tests fail
import pytest

from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.driver import RobotModbusDriver
from dockhil.devices.modbus_robot.emulator import FOLLOW, HOLD, RobotControllerEmulator, ServoModel
from dockhil.errors import DeviceError, LaunchError
from dockhil.msgs import Header, Pose, RobotCommand, Twist, Vector3
from dockhil.node import NodeContext, Tick
from tests.conftest import free_port, node_process_error

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
SETPOINT = (0.004, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


# -- the servo and the controller's rules (no I/O, chosen times) -----------------


def write(model: ServoModel, control: int, heartbeat: int, setpoint=None) -> None:
    assert model.host_wrote(0, mm.encode_write(control, heartbeat, setpoint)), "refused"


def claimed(model: ServoModel) -> ServoModel:
    """The model claimed by a host (the test's writes, connection None), as the driver does first."""
    assert model.host_wrote(mm.HR_SESSION, mm.encode_owner(1, "test"))
    return model


def test_servo_follows_after_the_delay_with_first_order_lag():
    model = claimed(ServoModel(delay=0.02, tau=0.01, heartbeat_timeout=1.0))
    write(model, mm.CONTROL_ENABLE, 1, SETPOINT)
    xs = {}
    for i in range(0, 101):  # 1 ms cycles for 0.1 s
        t = i * 0.001
        model.cycle(t)
        xs[i] = model.position[0]
    assert model.mode == FOLLOW
    assert xs[20] == 0.0  # nothing moves before the delay
    # first-order lag from t = delay: x = sp * (1 - exp(-(t - delay) / tau))
    for i in (30, 50, 100):
        assert xs[i] == pytest.approx(0.004 * (1 - math.exp(-(i - 20) * 0.001 / 0.01)), rel=1e-9)
    # Velocity is the mean over the emulator's velocity window (10 cycles of 1 ms here).
    from dockhil.devices.modbus_robot.emulator import VELOCITY_WINDOW_S

    cycles = round(VELOCITY_WINDOW_S / 0.001)
    assert model.linear[0] == pytest.approx((xs[100] - xs[100 - cycles]) / VELOCITY_WINDOW_S)
    reading = mm.decode_inputs(model.inputs)
    assert reading.actual[0] == pytest.approx(xs[100], abs=1e-6)
    assert reading.status & mm.STATUS_FOLLOWING and reading.heartbeat == 1 and reading.cycle == 101


def test_controller_holds_on_heartbeat_loss_and_resumes_only_on_a_fresh_setpoint():
    model = claimed(ServoModel(heartbeat_timeout=0.1))  # no delay, no lag: the pose is the target of the last cycle
    write(model, mm.CONTROL_ENABLE, 1, SETPOINT)
    model.cycle(0.0)
    model.cycle(0.001)
    assert model.mode == FOLLOW and model.position[0] == pytest.approx(0.004)
    model.cycle(0.15)  # the host went quiet
    assert model.mode == HOLD and model.heartbeat_lost
    assert mm.decode_inputs(model.inputs).status & mm.STATUS_HEARTBEAT_LOST
    assert model.owner_session == 0  # the claim lapsed with the heartbeat: nothing moves the robot until a claim
    assert not model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, 2, SETPOINT))
    assert model.unclaimed == 1
    claimed(model)
    write(model, mm.CONTROL_ENABLE, 2)  # heartbeat back, but no setpoint since the stop
    for i in range(5):
        model.cycle(0.16 + i * 0.001)
    assert model.mode == HOLD and not model.heartbeat_lost
    model.host_wrote(mm.HR_SETPOINT, mm.encode_block((0.009,) + SETPOINT[1:]))
    model.cycle(0.17)
    model.cycle(0.171)
    assert model.mode == FOLLOW and model.position[0] == pytest.approx(0.009)  # a fresh setpoint re-arms
    write(model, mm.CONTROL_ENABLE | mm.CONTROL_HOLD, 3)
    model.cycle(0.172)
    x_hold = model.position[0]
    assert model.mode == HOLD
    write(model, mm.CONTROL_ENABLE, 4)  # HOLD cleared, but the setpoint registers are old
    for i in range(5):
        model.cycle(0.18 + i * 0.001)
    assert model.mode == HOLD and model.position[0] == x_hold
    write(model, mm.CONTROL_ENABLE, 5, SETPOINT)
    model.cycle(0.19)
    model.cycle(0.191)
    assert model.mode == FOLLOW and model.position[0] == pytest.approx(0.004)


def test_fault_holds_until_reset():
    model = claimed(ServoModel())
    write(model, mm.CONTROL_ENABLE, 1, SETPOINT)
    model.cycle(0.0)
    model.fault = True
    write(model, mm.CONTROL_ENABLE, 2, SETPOINT)
    model.cycle(0.001)
    assert model.mode == HOLD and mm.describe_status(mm.decode_inputs(model.inputs).status) == "fault"
    write(model, mm.CONTROL_ENABLE | mm.CONTROL_RESET, 3, SETPOINT)
    model.cycle(0.002)
    assert not model.fault and model.holding[mm.HR_CONTROL] == mm.CONTROL_ENABLE


# -- helpers ----------------------------------------------------------------------


def start_emulator(port: int = 0, *args: str) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "dockhil.devices.modbus_robot.emulator", "--port", str(port), *args],
        cwd=ROOT,
        env=ENV,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    line = []
    reader = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(60)
    assert line and line[0].startswith("listening 127.0.0.1:"), proc.stderr.read() if proc.poll() is not None else ""
    return proc, int(line[0].rsplit(":", 1)[1])


def end(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=5)
    proc.stdout.close()
    proc.stderr.close()


class Drive:
    """Steps a driver in wall time, building fresh commands."""

    def __init__(self, node):
        self.node = node
        self.k = 0
        self.t0 = time.monotonic()
        self.states = []

    def now(self) -> float:
        return time.monotonic() - self.t0

    def command(self, x: float = 0.0, v: float = 0.0, y: float = 0.0, enable: bool = True) -> RobotCommand:
        t = self.now()
        return RobotCommand(
            header=Header(stamp=t, tick=self.k, seq=self.k),
            pose=Pose(position=Vector3(x=x, y=y)),
            twist=Twist(linear=Vector3(x=v)),
            enable=enable,
        )

    def step(self, command=None, wrench=None, estop=None):
        out = self.node.step(Tick(self.k, self.now(), 0.001), {"command": command, "wrench": wrench, "estop": estop})
        self.k += 1
        if "state" in out:  # a step may publish the device cycles alone, without a fresh pose
            self.states.append((self.now(), out["state"]))
        return out

    def run(self, seconds: float, make=lambda d: {}):
        end_t = time.monotonic() + seconds
        while time.monotonic() < end_t:
            self.step(**make(self))
            time.sleep(0.001)

    def until(self, done, make=lambda d: {}, timeout: float = 30.0):
        """Step (about every millisecond) until done(self); fail after `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while not done(self):
            if time.monotonic() > deadline:
                raise AssertionError(f"not done within {timeout} s; last states: {self.states[-3:]}")
            self.step(**make(self))
            time.sleep(0.001)

    def last(self):
        return self.states[-1][1] if self.states else None


def driver(port: int, logs: list | None = None, **params) -> RobotModbusDriver:
    log = logs.append if logs is not None else (lambda line: None)
    params.setdefault("ft_timeout", 0.0)
    # These tests step the driver from a test thread on the real clock, pausing it to kill and start
    # controllers; the stall watchdog is tested on a controlled clock in test_hardware_safety.py.
    params.setdefault("stall_timeout", 60.0)
    # 1 s per request: on a busy machine a round trip to the emulator can outlast the 0.1 s default,
    # which the driver would rightly take for a lost connection; that is tested on its own.
    params.setdefault("timeout", 1.0)
    return RobotModbusDriver(NodeContext("robot", 0.001, sim_time=False, log=log), port=port, **params)


def read_holding(port: int) -> mm.HostWrite:
    from pymodbus.client import ModbusTcpClient

    client = ModbusTcpClient("127.0.0.1", port=port, timeout=1.0, retries=0)
    assert client.connect()
    try:
        return mm.decode_holding(client.read_holding_registers(0, count=mm.HR_COUNT, device_id=1).registers)
    finally:
        client.close()


# -- driver and emulator across processes -------------------------------------------


@pytest.mark.wall_time
def test_driver_follows_through_the_emulator_across_processes():
    proc, port = start_emulator(0, "--delay", "0.02", "--tau", "0.01")
    # A busy machine hands the controller late setpoints in bursts, and the servo jumps: the
    # measured-speed limit would rightly stop the run; and this test's real-clock steps make
    # setpoint steps over jittered intervals (0.1 mm in 1.2 ms read as 0.116 m/s), which the
    # commanded-speed limit would. Both are tested on a controlled clock in test_hardware_safety.py.
    node = driver(port, max_actual_speed=0.0, max_speed=0.0)
    try:
        node.setup()
        drive = Drive(node)

        def ramp(d):  # rest, then 0.05 m/s for 0.2 s, then rest at 10 mm
            t = d.now() - 0.1
            x = min(max(t, 0.0) * 0.05, 0.01)
            return {"command": d.command(x=x, v=0.05 if 0 < t < 0.2 else 0.0)}

        drive.run(1.0, ramp)  # the ramp ends at 0.3 s; fresh poses must still come after 0.5 s
        times = [t for t, s in drive.states if s.pose.position.x > 1e-5]
        assert times, "the robot never moved"
        assert times[0] - 0.1 >= 0.02 - 0.003  # the servo delay shows (less one servo and one poll cycle)
        last = drive.states[-1][1]
        assert last.pose.position.x == pytest.approx(0.01, abs=2e-6)
        assert last.status == "ok" and last.pose.orientation.w == pytest.approx(1.0)
        ramp = [(t, s.twist.linear.x) for t, s in drive.states if 0.003 < s.pose.position.x < 0.007]
        # The reported speed averaged over the time of the ramp: a busy machine hands the controller
        # setpoints in bursts, so single readings jump and pause, but they add up to the ramp's
        # 0.05 m/s (a wrong unit would be 1000x).
        mean = sum(v * (t1 - t0) for (t0, v), (t1, _) in zip(ramp, ramp[1:])) / (ramp[-1][0] - ramp[0][0])
        assert mean == pytest.approx(0.05, rel=0.5)
        assert drive.states[-1][0] > 0.5  # fresh actual poses keep coming long after the ramp
        # At most one setpoint per device cycle: while the pose moves, each cycle writes the pose for its
        # own time (devices/handover.py), so a busy node thread stepping fewer times than the link cycles
        # does not bound the writes; the link's cycles do.
        assert 0 < node.link.writes <= node.link.readings
        assert read_holding(port).setpoint[0] == pytest.approx(0.01)
    finally:
        node.close()
        end(proc)


def test_lost_connection_reconnects_and_never_sends_a_stale_setpoint():
    lag = ("--tau", "0.05")  # a lagging servo: moving 2 mm takes no jump
    proc, port = start_emulator(0, *lag)
    logs: list[str] = []
    node = driver(port, logs)
    try:
        node.setup()
        drive = Drive(node)
        drive.until(
            lambda d: d.last() and d.last().pose.position.x == pytest.approx(0.002, rel=0.05),
            lambda d: {"command": d.command(x=0.002)},
        )
        end(proc)  # the controller dies
        n_before = len(drive.states)
        # Fresh commands keep coming while it is gone; none of them may reach the new controller.
        drive.run(0.3, lambda d: {"command": d.command(x=0.002)})
        assert len(drive.states) - n_before <= 2  # no actual pose, no state (one may have been in flight)
        assert [line for line in logs if "connection lost" in line][0].endswith("; reconnecting")
        proc, _ = start_emulator(port, *lag)  # a new controller on the same port, at x = 0
        held = drive.command(x=0.002)
        drive.until(lambda d: node.link.reconnects > 0, lambda d: {"command": held})  # the same message: not fresh
        assert node.link.reconnects == 1
        n_before = len(drive.states)
        drive.until(
            lambda d: len(d.states) > n_before + 5 and d.last().status == "holding", lambda d: {"command": held}
        )
        # Held at x = 0 (the new controller's first cycles may still miss our heartbeat: held too; and a
        # reading taken before its first servo cycle since the hold was written still says disabled).
        after = [(s.status, s.pose.position.x) for _, s in drive.states[n_before:]]
        assert all(status in ("holding", "heartbeat-lost", "disabled") and x == 0.0 for status, x in after), after
        assert read_holding(port).setpoint == mm.HOLD_POSE  # the restarted controller never got a setpoint
        assert any("reconnected after" in line for line in logs)
        drive.until(
            lambda d: d.last().status == "ok" and d.last().pose.position.x == pytest.approx(0.002, rel=0.05),
            lambda d: {"command": d.command(x=0.002)},
        )  # fresh commands move it again
    finally:
        node.close()
        end(proc)


def test_connection_lost_too_long_is_an_error():
    proc, port = start_emulator(0)
    node = driver(port, reconnect_timeout=0.3)
    try:
        node.setup()
        drive = Drive(node)
        drive.run(0.05, lambda d: {"command": d.command()})
        end(proc)
        with pytest.raises(DeviceError) as err:
            drive.run(30.0, lambda d: {"command": d.command()})
        text = str(err.value)
        assert "\n" not in text
        assert re.match(
            rf"robot controller \(Modbus TCP 127.0.0.1:{port}\): connection lost for \d+\.\d s "
            r"\(reconnect_timeout 0.3 s\): ",
            text,
        ), text
        gone = float(text.split("connection lost for ")[1].split()[0])
        assert gone >= 0.3
    finally:
        node.close()
        end(proc)


# -- missing or wrong device ----------------------------------------------------------


def test_missing_controller_fails_fast_with_one_line():
    port = free_port()
    node = driver(port, connect_timeout=0.5)
    t = time.monotonic()
    with pytest.raises(DeviceError) as err:
        node.setup()
    assert time.monotonic() - t < 1.5
    assert str(err.value) == (
        f"robot controller (Modbus TCP 127.0.0.1:{port}): no connection within 0.5 s: Connection refused"
    )


class ForeignDevice(RobotControllerEmulator):
    """A Modbus server with some other register map."""

    def _action(self, function, address, count, values, connection):
        return None  # registers read 0: no magic number


def test_a_device_with_another_register_map_is_refused():
    other = ForeignDevice(port=0)
    port = other.start_thread()
    try:
        with pytest.raises(DeviceError, match=r"not a dockhil robot controller: input registers 0-1 read 0x0000 0"):
            driver(port).setup()
    finally:
        other.stop_thread()


def test_node_process_exits_non_zero_with_one_line_when_the_controller_is_missing():
    port = free_port()
    spec = {
        "name": "robot",
        "type_name": "robot_modbus",
        "dt": 0.001,
        "clock": "wall",
        "params": {"port": port, "connect_timeout": 0.5},
    }
    line = node_process_error(spec, ENV)
    assert f"robot controller (Modbus TCP 127.0.0.1:{port})" in line and "Connection refused" in line


def test_emulator_refuses_a_busy_port_with_one_line():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        proc = subprocess.run(
            [sys.executable, "-m", "dockhil.devices.modbus_robot.emulator", "--port", str(port)],
            cwd=ROOT,
            env=ENV,
            capture_output=True,
            text=True,
            timeout=30,
        )
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"robot emulator: error: cannot listen on 127.0.0.1:{port}: Address already in use"


def test_sim_time_and_an_empty_workspace_are_refused():
    with pytest.raises(LaunchError, match="runs only in wall time"):
        RobotModbusDriver(NodeContext("robot", 0.001, sim_time=True)).setup()
    with pytest.raises(LaunchError, match="workspace y_min 0.1 must be below y_max 0.1"):
        driver(free_port(), y_min=0.1, y_max=0.1).setup()


def test_modules_do_not_import_pymodbus_until_setup():
    code = (
        "import sys, dockhil.devices.modbus_robot.driver, dockhil.devices.modbus_robot.emulator_node, "
        "dockhil.devices.modbus_robot.emulator; "
        "print(sorted(m for m in ('can', 'serial', 'pymodbus') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=30)
    assert out.stdout.strip() == "[]", out.stderr


# -- driver and emulator in one process ---------------------------------------------------


def test_close_holds_the_robot(controller):
    node = driver(controller.port)
    node.setup()
    drive = Drive(node)
    drive.until(
        lambda d: controller.call(lambda: controller.servo.mode) == FOLLOW, lambda d: {"command": d.command(x=0.001)}
    )
    node.close()
    assert controller.call(lambda: controller.servo.holding[mm.HR_CONTROL]) == mm.CONTROL_ENABLE | mm.CONTROL_HOLD
    deadline = time.monotonic() + 10  # the controller's next servo cycle holds
    while controller.call(lambda: controller.servo.mode) != HOLD and time.monotonic() < deadline:
        time.sleep(0.001)
    assert controller.call(lambda: controller.servo.mode) == HOLD


def test_disabled_command_holds_and_a_controller_fault_is_an_error(controller):
    node = driver(controller.port)
    node.setup()
    try:
        drive = Drive(node)
        drive.until(lambda d: d.last() and d.last().status == "ok", lambda d: {"command": d.command(x=0.0005)})
        drive.until(lambda d: d.last().status == "holding", lambda d: {"command": d.command(x=0.0005, enable=False)})
        controller.inject_fault()
        with pytest.raises(DeviceError, match=r"controller reports a fault \(status 0x0007\); holding"):
            drive.run(30.0, lambda d: {"command": d.command(x=0.0005)})
    finally:
        node.close()


def test_driver_logs_when_the_controller_lost_its_heartbeat(controller):
    logs: list[str] = []
    node = driver(controller.port, logs)
    node.setup()
    try:
        drive = Drive(node)
        drive.until(lambda d: d.last() is not None, lambda d: {"command": d.command()})
        timeout = controller.call(getattr, controller.servo, "heartbeat_timeout")
        for losses in (1, 2):  # twice: the controller loses our heartbeat (as if our writes stalled), then not
            controller.call(setattr, controller.servo, "heartbeat_timeout", 0.0)
            drive.until(lambda d, n=losses: node.heartbeat_losses >= n, lambda d: {"command": d.command()})
            controller.call(setattr, controller.servo, "heartbeat_timeout", timeout)
            drive.until(lambda d: d.last().status == "ok", lambda d: {"command": d.command()})
        assert any(s.status == "heartbeat-lost" for _, s in drive.states)
        assert [line for line in logs if "heartbeat" in line] == [
            f"warning: robot controller (Modbus TCP 127.0.0.1:{controller.port}): controller lost our heartbeat and "
            "holds; resuming on the next command"
        ]  # once, however often it flickers
    finally:
        node.close()
    # said at close, before the line that says whether the robot holds and where (a busy machine may
    # have dropped the connection, which close says between them)
    closing = logs[-3:] if "could not hold the robot at close" in logs[-2] else logs[-2:]
    assert node.heartbeat_losses > 1 and f"lost our heartbeat {node.heartbeat_losses} times" in closing[0]
    assert closing[-1].startswith(f"robot controller (Modbus TCP 127.0.0.1:{controller.port}): the ")
