"""F/T sensor (simulated), 6-DOF: the passive 6x6 compliance between the interfaces at the robot's pose."""

from __future__ import annotations

from typing import Any

from dockhil import physical
from dockhil.msgs import RobotState, Vector3, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Param, Tick
from dockhil.nodes.ft_sim import HARDWARE_TRUTH
from dockhil.nodes.robot_sim6 import relative_pose
from dockhil.scene.sixdof_params import MOUNT_PARAMS, PASSIVE_PARAMS, checked, passive_contact

NO_WRENCH = Wrench()  # msgs are frozen: one zero wrench serves every message that carries one


class FtSensorSim6(Node):
    """The passive 6x6 compliance (and friction) at the robot's pose, read by an F/T sensor on the target.

    Force and torque on the target, in the axes of the sensor mounted in the target's interface frame."""

    inputs = {"robot": Input(RobotState, "/robot/state", help="actual pose of A in B")}
    outputs = {"wrench": Output(WrenchStamped, "/ft/wrench", help="wrench on the target, sensor frame")}
    params = {
        **PASSIVE_PARAMS,
        "mu": Param(
            float, 0.0, help="tangential Coulomb friction of the hardware contact", ge=0.0, scale=physical.FRICTION
        ),
        "slip_velocity": Param(
            float, 1e-3, unit="m/s", help="friction regularising sliding speed", gt=0.0, scale=physical.SPEED
        ),
        **MOUNT_PARAMS,
        **HARDWARE_TRUTH,
    }

    def setup(self):
        from dockhil.contact.hilloop import DelayLine, delay_ticks
        from dockhil.contact.hybrid6 import PassiveSensor6

        p = self.p
        self.sensor = checked(
            self.ctx.name,
            lambda: PassiveSensor6(
                passive_contact(p, p.mu, p.slip_velocity, p.k_scale), p.sensor_position, p.sensor_orientation
            ),
        )
        ticks = delay_ticks(p.delay, self.ctx.dt)
        self.line = DelayLine(ticks) if ticks else None

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        robot = inputs["robot"]
        force, torque, _ = self.sensor.read(None if robot is None else relative_pose(robot))
        # The sensor's values are plain floats already (tuples): they go into the message as they are;
        # out of contact they are zero, and one frozen Wrench() carries them.
        wrench = Wrench(Vector3(*force), Vector3(*torque)) if self.sensor.touching else NO_WRENCH
        if self.line is not None:  # the sensor's own delay: what it read `delay` ago, none before
            late = self.line.push(wrench)
            wrench = NO_WRENCH if late is None else late
        return {"wrench": WrenchStamped(header=tick.header("ft_sensor"), wrench=wrench)}
