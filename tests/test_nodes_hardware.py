"""The hardware drivers and the device emulators, each stepped with dockhil.testing.NodeHarness
(wall time: inputs hold their latest message; tick times are the test's).

The devices run on their own clocks (the controller emulator's servo, a CAN
stream): where the test waits for one, it waits for the outcome, with a deadline."""

from __future__ import annotations

import math
import struct
import time

import can
import pytest

from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.emulator import HOLD
from dockhil.errors import DeviceError, SafetyStop
from dockhil.testing import NodeHarness, estop, robot_command, robot_state, wrench
from tests.conftest import VirtualFtSensor


def until(h: NodeHarness, done, inputs=None, timeout: float = 30.0) -> dict:
    """Step (in wall time, about every millisecond) until done(outputs); the outputs that did it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = h.step(inputs() if callable(inputs) else inputs)
        if done(out):
            return out
        time.sleep(0.001)
    raise AssertionError(f"{h.name}: not done within {timeout} s (tick {h.k})")


# -- robot_modbus against the controller emulator -------------------------------------------
# (timeout=1.0: 1 s per Modbus request, so a busy machine's slow round trip is not a lost connection)


@pytest.fixture
def robot(controller):
    h = NodeHarness("robot_modbus", sim_time=False, port=controller.port, timeout=1.0).setup()
    yield h
    h.close()


def fresh(x=0.0, fx=0.0):
    return lambda: {"command": robot_command(x), "wrench": wrench(fx=fx)}


def test_robot_driver_moves_the_robot_to_the_commanded_pose_and_reports_it(robot, controller):
    out = until(robot, lambda o: "state" in o and abs(o["state"].pose.position.x - 0.002) < 1e-6, fresh(0.002))
    s = out["state"]
    assert s.status == "ok" and s.header.tick == robot.k - 1
    assert controller.call(lambda: controller.servo.mode) != HOLD
    robot.close()  # close() holds the robot
    control = controller.call(lambda: controller.servo.holding[mm.HR_CONTROL])
    assert control == mm.CONTROL_ENABLE | mm.CONTROL_HOLD


def test_robot_driver_holds_until_the_first_wrench_arrives(controller):
    with NodeHarness("robot_modbus", sim_time=False, port=controller.port, timeout=1.0) as h:
        for _ in range(50):  # commands, but no F/T data yet: the robot must not move blind
            h.step({"command": robot_command(0.002)})
            time.sleep(0.001)
        assert controller.call(lambda: controller.servo.position[0]) == 0.0
        until(h, lambda o: "state" in o and o["state"].pose.position.x > 0.001, fresh(0.002))


def test_robot_force_limit_reads_the_wrench_one_tick_late_and_trips_on_its_norm(robot, controller):
    until(robot, lambda o: "state" in o, fresh(0.0))
    # |F| of (150, 200, 0) N is 250 N > the 200 N default; the wrench input is not feedthrough.
    robot.step({"command": robot_command(0.0), "wrench": wrench(fx=150.0, fy=200.0)})
    with pytest.raises(SafetyStop) as err:
        robot.step({"command": robot_command(0.0)})
    text = str(err.value)
    assert text == "safety stop: max_force: contact force |F| = 250.0 N > 200 N; robot held", text
    assert err.value.limit == "max_force" and err.value.value == pytest.approx(math.hypot(150.0, 200.0))
    assert controller.call(lambda: controller.servo.holding[mm.HR_CONTROL]) & mm.CONTROL_HOLD
    with pytest.raises(SafetyStop):  # latched: nothing is commanded any more
        robot.step({"command": robot_command(0.0), "wrench": wrench()})


def test_robot_ft_watchdog_counts_on_the_tick_clock(controller):
    # dt 10 ms, ft_timeout 50 ms: the wrench of tick 0 is read at tick 1 (t = 0.01 s) and is
    # the last; the age first exceeds 0.05 s at tick 7 (0.06 s), however slowly the test steps.
    with NodeHarness("robot_modbus", sim_time=False, dt=0.01, port=controller.port, ft_timeout=0.05, timeout=1.0) as h:
        h.step({"wrench": wrench()})
        for _ in range(6):
            h.step()
        with pytest.raises(SafetyStop, match=r"ft_timeout: no F/T data for 0.060 s > 0.05 s; robot held"):
            h.step()
        assert h.k == 7


def test_robot_estop_holds_with_its_reason(robot):
    robot.step({"estop": estop(reason="door open")})
    with pytest.raises(SafetyStop, match=r"^safety stop: estop: e-stop active \(door open\); robot held$"):
        robot.step()


# -- robot_emulator: the controller as a node, driven by the driver as a node -------------


def test_robot_emulator_node_serves_the_driver_and_stops_serving_at_close():
    emulator = NodeHarness("robot_emulator", sim_time=False, port=0, tau=0.02).setup()
    port = emulator.node.emulator.port
    assert f"robot controller emulator listening on 127.0.0.1:{port}" in emulator.logs
    try:
        assert emulator.step() == {}  # the device runs on its own clock
        with NodeHarness("robot_modbus", sim_time=False, port=port, timeout=1.0) as driver:
            until(driver, lambda o: "state" in o and abs(o["state"].pose.position.x - 0.002) < 1e-6, fresh(0.002))
    finally:
        emulator.close()
    with pytest.raises(DeviceError, match=rf"127.0.0.1:{port}\): no connection within 0.2 s"):
        NodeHarness("robot_modbus", sim_time=False, port=port, connect_timeout=0.2).setup()


# -- ft_can on a python-can virtual bus -----------------------------------------------------


@pytest.fixture
def sensor(request):
    s = VirtualFtSensor(f"nodes-{request.node.name}")
    yield s
    s.close()


def ft_driver(sensor, **params):
    """An F/T driver set up against the streaming sensor (its offset tared away), the stream then stopped."""
    sensor.force = (1.5, -0.25, 0.5)  # the unloaded sensor's offset
    sensor.stream()
    h = NodeHarness(
        "ft_can", sim_time=False, interface="virtual", channel=sensor.channel, tare_samples=20, **params
    ).setup()
    sensor.quiet()
    h.step(t=0.0)  # take what the stream left
    return h


def test_ft_driver_tares_the_offset_and_publishes_each_new_sample(sensor):
    h = ft_driver(sensor)
    try:
        sensor.send(force=(11.5, 0.75, 0.5), torque=(0.0, 0.0, 0.125))
        w = h.step(t=0.001)["wrench"]
        assert (w.wrench.force.x, w.wrench.force.y, w.wrench.force.z) == pytest.approx((10.0, 1.0, 0.0))
        assert w.wrench.torque.z == pytest.approx(0.125) and w.header.tick == 1
        assert h.step(t=0.002) == {}  # nothing new: nothing published, no repeat
    finally:
        h.close()


def test_ft_driver_stale_data_counts_on_the_tick_clock(sensor):
    h = ft_driver(sensor, stale_timeout=0.05)
    try:
        assert h.step(t=0.05) == {}
        with pytest.raises(DeviceError, match=r"stale data: no new sample for 0.060 s \(stale_timeout 0.05 s\)"):
            h.step(t=0.06)
    finally:
        h.close()


# -- ft_emulator: the sensor's frames from the robot pose ---------------------------------------


def frames(bus, n: int, timeout: float = 30.0) -> list:
    got = []
    deadline = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        msg = bus.recv(0.05)
        if msg is not None:
            got.append(msg)
    return got


def test_ft_emulator_sends_minus_k_x_in_the_documented_frame_layout(request):
    channel = f"nodes-{request.node.name}"
    listener = can.Bus(interface="virtual", channel=channel)
    em = NodeHarness(
        "ft_emulator", sim_time=False, interface="virtual", channel=channel, k=1000.0, bias=0.5, force_resolution=0.01
    ).setup()
    try:
        for x in (0.012, -0.02):  # 12 mm into the sheet; then apart: a sheet does not pull
            assert em.step({"state": robot_state(x)}) == {}
        got = frames(listener, 4)
    finally:
        em.close()
        listener.shutdown()
    assert [m.arbitration_id for m in got] == [0x1A0, 0x1A1, 0x1A0, 0x1A1]
    # Layout (dockhil/devices/can_ft/frames.py): int16 x, y, z counts, little-endian; status; sequence.
    layout = struct.Struct("<hhhBB")
    force = [layout.unpack(bytes(m.data)) for m in got[0::2]]
    assert force[0] == (round((-1000.0 * 0.012 + 0.5) / 0.01), 0, 0, 0, 0)  # -11.5 N
    assert force[1] == (round(0.5 / 0.01), 0, 0, 0, 1)  # the bias alone, next sequence number
    assert em.node.sent == 2
