"""robot-command driver (simulated): a servo that follows the command with a lag."""

from __future__ import annotations

import math
from typing import Any

from dockhil import physical
from dockhil.msgs import EStop, Pose, RobotCommand, RobotState, Twist, Vector3
from dockhil.node import Input, Node, Output, Param, Tick

# Event topic, as the robot driver's: active holds the robot and stops the graph.
ESTOP = Input(EStop, "/estop", feedthrough=False, required=False, max_age=math.inf, help="emergency stop")


def estop_held(estop: EStop | None) -> None:
    """An active e-stop stops the simulated robot as it stops the robot driver: the pose holds (no state
    follows the command) and the graph stops with the driver's line."""
    if estop is not None and estop.active:
        from dockhil.errors import SafetyStop

        reason = estop.reason or "no reason given"
        raise SafetyStop(
            f"safety stop: estop: e-stop active ({reason}); simulated robot held", "estop", estop.reason or "active"
        )


class RobotSim(Node):
    """Follows /robot/command with a first-order lag (0: exactly); publishes the actual pose."""

    inputs = {"command": Input(RobotCommand, "/robot/command", help="probe pose setpoint"), "estop": ESTOP}
    outputs = {"state": Output(RobotState, "/robot/state", help="actual probe pose")}
    params = {
        "lag": Param(
            float, 0.0, unit="s", help="servo time constant (0: follows exactly)", ge=0.0, scale=physical.TIME
        ),
        "delay": Param(
            float,
            0.0,
            unit="s",
            help="response delay of its own (the scenes give it to a delay injector; with delay_scale this node "
            "delays the command by delay x delay_scale itself)",
            ge=0.0,
            scale=physical.ROBOT_DELAY,
        ),
        "delay_scale": Param(
            float,
            1.0,
            help="the hardware's true delay over the told `delay` (what a lab does not know; hw_delay_scale:=)",
            gt=0.0,
            le=100.0,
        ),
    }

    def setup(self):
        from dockhil.contact.hilloop import DelayLine, Servo, delay_ticks

        self.servo = Servo(self.p.lag, self.ctx.dt)
        ticks = delay_ticks(self.p.delay * self.p.delay_scale, self.ctx.dt)
        self.line = DelayLine(ticks) if ticks else None

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        estop_held(inputs.get("estop"))
        cmd = inputs["command"]
        if self.line is not None:
            cmd = self.line.push(cmd)
        if cmd is None:  # no command yet (the delay has not passed): report no pose
            return {}
        x, v = self.servo.step(cmd.pose.position.x, cmd.twist.linear.x)
        return {"state": RobotState(header=tick.header("target"), pose=Pose(Vector3(x)), twist=Twist(Vector3(v)))}
