"""The whole hardware loop without a lab: robot driver -> Modbus TCP -> controller
emulator; its actual pose -> F/T emulator -> slcan on a pseudo-terminal -> F/T driver
-> the robot driver's force limit."""

from __future__ import annotations

import threading
import time

import pytest

from dockhil.hardware import SafetyStop
from dockhil.hardware.robot_emulator import HOLD, RobotControllerEmulator
from dockhil.node import NodeContext, Tick
from msgs import Header, Pose, RobotCommand, Twist, Vector3
from nodes.ft_can import FtCanDriver
from nodes.ft_emulator import FtSensorEmulator
from nodes.robot_modbus import RobotModbusDriver


def test_pushing_into_the_compliance_measures_k_x_and_trips_the_force_limit(tmp_path):
    k_sheet = 1000.0
    link = str(tmp_path / "ft.slcan")
    logs: list[str] = []

    def ctx(name):
        return NodeContext(name, 0.001, sim_time=False, log=logs.append)

    controller = RobotControllerEmulator(port=0, tau=0.005)
    controller.start_thread()
    sensor = FtSensorEmulator(ctx("ft_emulator"), channel=link, k=k_sheet, bias=0.75)
    ft = FtCanDriver(ctx("ft"), channel=link, tare_samples=20)
    robot = RobotModbusDriver(ctx("robot"), port=controller.port, max_force=4.0, ft_timeout=0.05,
                              max_speed=0.05)
    state = [None]
    running = [True]

    def sensor_clock():  # the sensor streams on its own, as hardware does
        k = 0
        t0 = time.monotonic()
        while running[0]:
            sensor.step(Tick(k, time.monotonic() - t0, 0.001), {"state": state[0]})
            k += 1
            time.sleep(max(0.0, t0 + k * 0.001 - time.monotonic()))

    sensor.setup()
    streamer = threading.Thread(target=sensor_clock, daemon=True)
    streamer.start()
    pairs = []
    try:
        ft.setup()
        robot.setup()
        assert ft.bias_force[0] == pytest.approx(0.75)
        t0 = time.monotonic()
        wrench = None
        with pytest.raises(SafetyStop) as err:
            for k in range(3000):
                t = time.monotonic() - t0
                x = 0.01 * t  # press on at 10 mm/s
                cmd = RobotCommand(header=Header(stamp=t, tick=k, seq=k), pose=Pose(position=Vector3(x=x)),
                                   twist=Twist(linear=Vector3(x=0.01)))
                out = robot.step(Tick(k, t, 0.001), {"command": cmd, "wrench": wrench, "estop": None})
                if out:
                    state[0] = out["state"]
                out = ft.step(Tick(k, t, 0.001), {})
                if out:
                    wrench = out["wrench"]
                    if state[0] is not None:
                        pairs.append((state[0].pose.position.x, wrench.wrench.force.x))
                time.sleep(0.001)
        stop = err.value
        assert stop.limit == "max_force" and 4.0 < stop.value < 4.5
        assert "max_force: contact force |F| = 4." in str(stop) and str(stop).endswith("; robot held")
        time.sleep(0.01)
        assert controller.call(lambda: controller.servo.mode) == HOLD
        # measured force = -k x of the actual pose, up to one sample of latency at 10 mm/s and quantization
        in_contact = [(x, f) for x, f in pairs if x > 0.0005]
        assert len(in_contact) > 100
        errors = sorted(abs(f + k_sheet * x) for x, f in in_contact)
        assert errors[len(errors) // 2] < 0.05  # median: within 50 um of travel
        assert errors[-1] < 0.3
    finally:
        running[0] = False
        streamer.join()
        robot.close()
        ft.close()
        sensor.close()
        controller.stop_thread()
