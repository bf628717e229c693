"""robot-command driver (simulated), 6-DOF: a servo that follows the full interface pose with a lag."""

from __future__ import annotations

from dockhil.node import Input, Node, Output, Param
from dockhil.msgs import Pose, RobotCommand, RobotState, Twist
from dockhil.nodes.satellite_dynamics6 import array3, quaternion, vector


def relative_pose(msg):
    """hybrid6.RelativePose of a RobotCommand or RobotState."""
    from dockhil.contact.hybrid6 import RelativePose

    o = msg.pose.orientation
    return RelativePose(array3(msg.pose.position), (o.x, o.y, o.z, o.w), array3(msg.twist.linear),
                        array3(msg.twist.angular))


class RobotSim6(Node):
    """Follows the 6-DOF /robot/command (A's pose and twist in B) with a first-order lag (0: exactly).

    Position and velocities per axis, attitude along the geodesic (dockhil.contact.hybrid6.Servo6)."""

    inputs = {"command": Input(RobotCommand, "/robot/command", help="interface pose setpoint, in B")}
    outputs = {"state": Output(RobotState, "/robot/state", help="actual interface pose, in B")}
    params = {"lag": Param(float, 0.0, unit="s", help="servo time constant (0: follows exactly)", ge=0.0)}

    def setup(self):
        from dockhil.contact.hybrid6 import Servo6

        self.servo = Servo6(self.p.lag, self.ctx.dt)

    def step(self, tick, inputs):
        cmd = inputs["command"]
        if cmd is None:  # no command yet (the delay has not passed): report no pose
            return {}
        pose = self.servo.step(relative_pose(cmd))
        return {"state": RobotState(header=tick.header("target_interface"),
                                    pose=Pose(vector(pose.position), quaternion(pose.orientation)),
                                    twist=Twist(vector(pose.velocity), vector(pose.angular_velocity)))}
