"""robot-command driver (simulated), 6-DOF: a servo that follows the full interface pose with a lag."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

from dockhil import physical
from dockhil.msgs import Pose, Quaternion, RobotCommand, RobotState, Twist, Vector3
from dockhil.node import Input, Node, Output, Param, Tick
from dockhil.nodes.robot_sim import ESTOP, estop_held

if TYPE_CHECKING:
    from dockhil.contact.hybrid6 import RelativePose


def relative_pose(msg: RobotCommand | RobotState) -> RelativePose:
    """The fields of a hybrid6.RelativePose (position, orientation, velocity, angular velocity) of a
    RobotCommand or RobotState, as a plain tuple (what Servo6 and PassiveSensor6 take)."""
    pose, twist = msg.pose, msg.twist
    p, o, v, w = pose.position, pose.orientation, twist.linear, twist.angular
    # Its fields as a plain tuple: building the NamedTuple would cost every tick for nothing.
    return cast("RelativePose", ((p.x, p.y, p.z), (o.x, o.y, o.z, o.w), (v.x, v.y, v.z), (w.x, w.y, w.z)))


class RobotSim6(Node):
    """Follows the 6-DOF /robot/command (A's pose and twist in B) with a first-order lag (0: exactly).

    Position and velocities per axis, attitude along the geodesic (dockhil.contact.hybrid6.Servo6)."""

    inputs = {"command": Input(RobotCommand, "/robot/command", help="interface pose setpoint, in B"), "estop": ESTOP}
    outputs = {"state": Output(RobotState, "/robot/state", help="actual interface pose, in B")}
    params = {
        "lag": Param(float, 0.0, unit="s", help="servo time constant (0: follows exactly)", ge=0.0, scale=physical.TIME)
    }

    def setup(self):
        from dockhil.contact.hybrid6 import Servo6

        self.servo = Servo6(self.p.lag, self.ctx.dt)

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        estop_held(inputs.get("estop"))
        cmd = inputs["command"]
        if cmd is None:  # no command yet (the delay has not passed): report no pose
            return {}
        if self.servo.alpha == 1.0:  # no lag: Servo6 returns the command itself, so its (frozen) pose and twist serve
            pose, twist = cmd.pose, cmd.twist
        else:
            position, orientation, velocity, angular_velocity = self.servo.step(relative_pose(cmd))
            # Plain floats already (Servo6's): they go into the message as they are.
            pose = Pose(Vector3(*position), Quaternion(*orientation))
            twist = Twist(Vector3(*velocity), Vector3(*angular_velocity))
        return {"state": RobotState(header=tick.header("target_interface"), pose=pose, twist=twist)}
