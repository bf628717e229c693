"""F/T sensor (simulated): the passive compliance k pressed by the robot's probe."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

from dockhil import physical
from dockhil.msgs import RobotState, Vector3, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Param, Tick
from dockhil.scene.schema import MAX_RATE

if TYPE_CHECKING:
    import numpy as np


# What a lab does not know of its sensor, apart from what the loop is told (the 6-DOF sensor's too).
HARDWARE_TRUTH = {
    "k_scale": Param(
        float,
        1.0,
        help="the hardware's true stiffness over the told one (what a lab does not know; hw_k_scale:=)",
        gt=0.0,
        le=100.0,
    ),
    "delay": Param(
        float,
        0.0,
        unit="s",
        help="the sensor's own delay: it reports what it reads this much later (zero before)",
        ge=0.0,
        scale=physical.TIME,
    ),
}


class FtSensorSim(Node):
    """Force of the passive compliance k against the robot pose, unilateral, with optional sensor defects."""

    inputs = {"robot": Input(RobotState, "/robot/state", help="actual probe pose relative to the target")}
    outputs = {"wrench": Output(WrenchStamped, "/ft/wrench", help="contact force on the chaser (+x)")}
    params = {
        "k": Param(
            float,
            1000.0,
            unit="N/m",
            help="passive compliance stiffness (metal sheet, sensor)",
            ge=0.0,
            scale=physical.STIFFNESS,
        ),
        "noise": Param(
            float, 0.0, unit="N", help="standard deviation of white force noise", ge=0.0, scale=physical.FORCE
        ),
        "bias": Param(float, 0.0, unit="N", help="constant offset added to the force", scale=physical.FORCE),
        "rate": Param(
            float, 0.0, unit="Hz", help="sample rate, held between samples (0: every tick)", ge=0.0, le=MAX_RATE
        ),
        "quantization": Param(float, 0.0, unit="N", help="force resolution (0: none)", ge=0.0, scale=physical.FORCE),
        "seed": Param(int, 0, help="noise seed: the same seed gives the same noise in every run"),
        **HARDWARE_TRUTH,
    }

    def setup(self):
        from dockhil.contact.hilloop import DelayLine, delay_ticks, sensor_force

        self.sensor_force = sensor_force  # bound once: an import statement in step costs every tick
        self.rng = None
        if self.p.noise:  # numpy only for a noisy sensor (a node process without it starts 0.1 s faster)
            import numpy as np

            self.rng = np.random.default_rng(self.p.seed)
        self.held = None
        self.next_sample = 0.0
        self.k = self.p.k * self.p.k_scale
        ticks = delay_ticks(self.p.delay, self.ctx.dt)
        self.line = DelayLine(ticks) if ticks else None

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        p = self.p
        if self.held is None or p.rate == 0.0 or tick.t >= self.next_sample - 1e-12:
            robot = inputs["robot"]
            force = self.sensor_force(None if robot is None else robot.pose.position.x, self.k)
            if p.noise:
                rng = cast("np.random.Generator", self.rng)  # setup made it: the sensor is noisy
                force += float(rng.normal(0.0, p.noise))
            if p.bias:
                force += p.bias
            if p.quantization:
                force = p.quantization * round(force / p.quantization)
            self.held = force
            if p.rate:
                self.next_sample += 1.0 / p.rate
        force = self.held
        if self.line is not None:  # as dockhil.contact.comploop.SensorSim
            late = self.line.push(force)
            force = 0.0 if late is None else late
        return {"wrench": WrenchStamped(header=tick.header("probe"), wrench=Wrench(Vector3(force)))}
