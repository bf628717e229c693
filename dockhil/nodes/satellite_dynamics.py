"""satellite-dynamics: two free-floating bodies on one axis under measured + virtual forces."""

from __future__ import annotations

from typing import Any

from dockhil import physical
from dockhil.msgs import BodyState, BodyWrenches, Pose, RobotCommand, SatelliteState, Twist, Vector3, WrenchStamped
from dockhil.node import Input, Node, Output, Param, Tick


class SatelliteDynamics(Node):
    """Integrates chaser and target under F/T + virtual + thrust forces; publishes states and the robot command."""

    inputs = {
        "ft": Input(
            WrenchStamped,
            "/ft/wrench",
            feedthrough=False,
            help="contact force on the chaser, measured (the target feels its opposite)",
        ),
        "impedance": Input(BodyWrenches, "/impedance/wrench", feedthrough=False, help="virtual forces per body"),
    }
    outputs = {
        "state": Output(SatelliteState, "/satellite/state", help="chaser and target, chaser first"),
        "command": Output(RobotCommand, "/robot/command", help="probe pose relative to the target, x > 0 = contact"),
    }
    params = {
        "m1": Param(float, 750.0, unit="kg", help="chaser mass", gt=0.0, scale=physical.MASS),
        "m2": Param(
            float, 1e6, unit="kg", help="target mass; 0 fixes the target to the ground", ge=0.0, scale=physical.MASS
        ),
        "x1": Param(float, 0.0, unit="m", help="chaser initial position (contact point at 0)", scale=physical.DISTANCE),
        "x2": Param(float, 0.0, unit="m", help="target initial position", scale=physical.DISTANCE),
        "v1": Param(float, 0.03, unit="m/s", help="chaser initial velocity", scale=physical.SPEED),
        "v2": Param(float, 0.0, unit="m/s", help="target initial velocity", scale=physical.SPEED),
        "thrust": Param(float, 0.0, unit="N", help="constant thrust on the chaser along +x", scale=physical.FORCE),
        "method": Param(
            str, "exact", help="integrator of the model tool", choices=("exact", "rk4", "symplectic_euler", "euler")
        ),
        "model": Param(
            str,
            "hybrid",
            help="hybrid: forces come from the F/T and impedance topics; "
            "ideal: the ideal spring-dashpot (kcs, bcs) acts inside the node",
            choices=("hybrid", "ideal"),
        ),
        "kcs": Param(
            float, 3000.0, unit="N/m", help="ideal contact stiffness (model=ideal)", ge=0.0, scale=physical.STIFFNESS
        ),
        "bcs": Param(
            float, 40.0, unit="N s/m", help="ideal contact damping (model=ideal)", ge=0.0, scale=physical.DAMPING
        ),
        "substeps": Param(
            int,
            1,
            help="integrator steps per tick (forces held over the tick; the ideal contact is integrated inside each)",
            ge=1,
            le=1000,
        ),
        "allow_coarse": Param(
            bool,
            False,
            help="run even where the step does not resolve the contact (the summary then carries the warning)",
        ),
        "max_gap": Param(
            float,
            0.0,
            unit="m",
            help="the robot command follows the gap between the bodies up to this distance and waits there "
            "while they are farther apart (no contact can happen there; it keeps a long run in the robot's "
            "workspace); 0: follows everywhere",
            ge=0.0,
            le=physical.DISTANCE[1],
        ),
    }

    @classmethod
    def ports(cls, params):
        if params["model"] == "ideal":  # the ideal scene needs no sensor and no impedance
            return {}, cls.outputs
        return cls.inputs, cls.outputs

    def setup(self):
        from dockhil.contact.hilloop import Bodies

        p = self.p
        ideal = (p.kcs, p.bcs) if p.model == "ideal" else None
        self.bodies = Bodies(p.m1, p.m2, p.x1, p.x2, p.v1, p.v2, p.method, ideal=ideal)
        self.started = False
        self.parked = False  # the command waits at max_gap

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        p = self.p
        if not self.started:
            # Wall time with hardware: the simulated clock starts when the sensor answers, so the robot
            # is not asked to jump to where the simulation went while the drivers were still starting.
            self.started = self.ctx.sim_time or p.model == "ideal" or inputs.get("ft") is not None
            if not self.started:  # hold the robot at the start pose; no state until the run begins
                return {"command": self._publish(tick)["command"]}
        elif tick.index > 0:
            if p.model == "ideal":
                f1, f2 = p.thrust, 0.0
            else:
                ft, imp = inputs.get("ft"), inputs.get("impedance")
                fs = ft.wrench.force.x if ft is not None else 0.0
                fv1, fv2 = (imp.wrenches[0].force.x, imp.wrenches[1].force.x) if imp is not None else (0.0, 0.0)
                # The same sums, in the same order, as dockhil.contact.hilloop.simulate_hil.
                f1 = fs + fv1 + p.thrust
                f2 = -fs + fv2
            h = tick.dt / p.substeps
            for _ in range(p.substeps):
                self.bodies.step(f1, f2, h)
        return self._publish(tick)

    def _publish(self, tick):
        p = self.p
        x1, x2, v1, v2 = self.bodies.positions()
        header = tick.header("world")
        state = SatelliteState(
            header=header,
            bodies=(
                BodyState("chaser", p.m1, Pose(Vector3(x1)), Twist(Vector3(v1))),
                BodyState("target", p.m2, Pose(Vector3(x2)), Twist(Vector3(v2))),
            ),
            in_contact=self.bodies.touching(),
        )
        gap, closing = x1 - x2, v1 - v2
        if p.max_gap and gap < -p.max_gap:  # apart beyond it: the robot waits there until the bodies come back
            gap, closing = -p.max_gap, 0.0
            if not self.parked:
                self.log(f"bodies {x2 - x1:.3g} m apart: the robot waits at the gap max_gap = {p.max_gap:g} m")
        self.parked = gap == -p.max_gap
        command = RobotCommand(header=tick.header("target"), pose=Pose(Vector3(gap)), twist=Twist(Vector3(closing)))
        return {"state": state, "command": command}
