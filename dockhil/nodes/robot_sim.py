"""robot-command driver (simulated): a servo that follows the command with a lag."""

from __future__ import annotations

from dockhil import physical
from dockhil.node import Input, Node, Output, Param
from dockhil.msgs import Pose, RobotCommand, RobotState, Twist, Vector3


class RobotSim(Node):
    """Follows /robot/command with a first-order lag (0: exactly); publishes the actual pose."""

    inputs = {"command": Input(RobotCommand, "/robot/command", help="probe pose setpoint")}
    outputs = {"state": Output(RobotState, "/robot/state", help="actual probe pose")}
    params = {"lag": Param(float, 0.0, unit="s", help="servo time constant (0: follows exactly)", ge=0.0,
                        scale=physical.TIME)}

    def setup(self):
        from dockhil.contact.hilloop import Servo

        self.servo = Servo(self.p.lag, self.ctx.dt)

    def step(self, tick, inputs):
        cmd = inputs["command"]
        if cmd is None:  # no command yet (the delay has not passed): report no pose
            return {}
        x, v = self.servo.step(cmd.pose.position.x, cmd.twist.linear.x)
        return {"state": RobotState(header=tick.header("target"), pose=Pose(Vector3(x)), twist=Twist(Vector3(v)))}
