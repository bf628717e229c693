"""The whole hardware loop without a lab: robot driver -> Modbus TCP -> controller
emulator; its actual pose -> F/T emulator -> slcan on a pseudo-terminal -> F/T driver
-> the robot driver's force limit."""

from __future__ import annotations

import threading
import time

import pytest

from dockhil.devices.can_ft.driver import FtCanDriver
from dockhil.devices.can_ft.emulator import FtSensorEmulator
from dockhil.devices.modbus_robot.driver import RobotModbusDriver
from dockhil.devices.modbus_robot.emulator import HOLD, RobotControllerEmulator
from dockhil.errors import SafetyStop
from dockhil.msgs import Header, Pose, RobotCommand, Twist, Vector3
from dockhil.node import ManualClock, NodeContext, Tick


def test_pushing_into_the_compliance_measures_k_x_and_trips_the_force_limit(tmp_path):
    """The drivers run on a ManualClock advanced 1 ms per loop, and each loop waits (with a deadline)
    for the F/T sample of this loop's pose: the verdicts (the trip at 4 N, no watchdog firing) and the
    pairs compared do not depend on how busy the machine is. Only the controller's servo runs in real
    time, as a controller does."""
    k_sheet = 1000.0
    link = str(tmp_path / "ft.slcan")
    logs: list[str] = []
    clock = ManualClock()

    def ctx(name):
        return NodeContext(name, 0.001, sim_time=False, log=logs.append, clock=clock)

    controller = RobotControllerEmulator(port=0, tau=0.005)
    controller.start_thread()
    sensor = FtSensorEmulator(ctx("ft_emulator"), channel=link, k=k_sheet, bias=0.75)
    ft = FtCanDriver(ctx("ft"), channel=link, tare_samples=20)
    robot = RobotModbusDriver(ctx("robot"), port=controller.port, max_force=4.0, ft_timeout=0.05, max_speed=0.05)
    state = [None]
    streaming = [True]

    def stream_for_the_tare():  # the sensor streams on its own while the driver opens and tares
        k = 0
        while streaming[0]:
            sensor.step(Tick(k, k * 0.001, 0.001), {"state": None})
            k += 1
            time.sleep(0.001)

    sensor.setup()
    streamer = threading.Thread(target=stream_for_the_tare, daemon=True)
    streamer.start()
    pairs = []
    try:
        ft.setup()
        streaming[0] = False
        streamer.join()
        robot.setup()
        assert ft.bias_force[0] == pytest.approx(0.75)
        wrench = None
        with pytest.raises(SafetyStop) as err:
            for k in range(3000):
                t = clock.advance(0.001)
                # 20 ms out of contact first, then press on at 10 mm/s (of the drivers' time): free
                # samples whatever the controller's servo did in real time before the first read
                x = 0.01 * (t - 0.02)
                cmd = RobotCommand(
                    header=Header(stamp=t, tick=k, seq=k),
                    pose=Pose(position=Vector3(x=x)),
                    twist=Twist(linear=Vector3(x=0.01)),
                )
                out = robot.step(Tick(k, t, 0.001), {"command": cmd, "wrench": wrench, "estop": None})
                if "state" in out:  # a step may publish the device cycles alone, without a fresh pose
                    state[0] = out["state"]
                sensor.step(Tick(k, t, 0.001), {"state": state[0]})  # one sample of the pose just read
                deadline = time.monotonic() + 5.0
                while not (out := ft.step(Tick(k, t, 0.001), {})):
                    assert time.monotonic() < deadline, "the F/T sample never arrived"
                    time.sleep(0.0002)
                wrench = out["wrench"]
                if state[0] is not None:
                    pairs.append((state[0].pose.position.x, wrench.wrench.force.x))
                time.sleep(0.0005)  # let the controller's servo move in its own time
        stop = err.value
        assert stop.limit == "max_force" and 4.0 < stop.value < 4.5
        assert "max_force: contact force |F| = 4." in str(stop) and str(stop).endswith("; robot held")
        deadline = time.monotonic() + 5.0
        while controller.call(lambda: controller.servo.mode) != HOLD:
            assert time.monotonic() < deadline
            time.sleep(0.002)
        # Each sample is -k x of the pose it was made from, with the tared bias gone: only the
        # frame's force resolution separates them.
        in_contact = [(x, f) for x, f in pairs if x > 0.0005]
        assert in_contact and in_contact[-1][1] < -3.5  # pressed through to the trip
        resolution = FtSensorEmulator.params["force_resolution"].default
        for x, f in in_contact:
            assert f == pytest.approx(-k_sheet * x, abs=resolution)
        free = [f for x, f in pairs if x <= 0.0]
        assert free and all(abs(f) <= resolution for f in free)
    finally:
        streaming[0] = False
        streamer.join()
        robot.close()
        ft.close()
        sensor.close()
        controller.stop_thread()
