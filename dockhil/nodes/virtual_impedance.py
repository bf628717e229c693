"""virtual-impedance: k1, b1, k2, b2 on a virtual wall at the centre of mass, or the target's force less
the passive compliance's for a Hunt-Crossley target; the loop's energy account, and a delay
compensation (dockhil.contact.compensation; the tick is dockhil.contact.comploop.ImpedanceStep)."""

from __future__ import annotations

import math
from typing import Any

from dockhil import physical
from dockhil.msgs import BodyWrenches, Energy, RobotState, SatelliteState, Vector3, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Param, Tick

# As dockhil.contact.compensation.METHODS (not imported here: the node's class loads no science).
METHODS = ("none", "passivity", "phase_lead", "smith", "predictor", "energy", "phase_lead+passivity")
ROBOT = Input(
    RobotState,
    "/robot/state",
    required=False,
    help="the robot's reported pose (compensation predictor: the port is identified against it)",
)


class VirtualImpedance(Node):
    """Virtual spring-dampers tying each body to the CoM wall while in contact (paper Eqs. 2-4)."""

    inputs = {
        "state": Input(SatelliteState, "/satellite/state"),
        "ft": Input(
            WrenchStamped,
            "/ft/wrench",
            required=False,
            help="measured force on the chaser: the hardware port of the energy account",
        ),
    }
    outputs = {
        "wrench": Output(
            BodyWrenches,
            "/impedance/wrench",
            help="virtual force on chaser, target (with the passivity controller's damping)",
        ),
        "energy": Output(Energy, "/energy", help="the loop's energy account per tick [J]"),
    }
    params = {
        "mode": Param(
            str,
            "determine",
            help="determine: k1..b2 from kcs, bcs, k at start (closed form, "
            "checked against the two-time fit of Eqs. 5-6); given: use k1..b2 as set",
            choices=("determine", "given"),
        ),
        "m1": Param(float, 750.0, unit="kg", help="chaser mass", gt=0.0, scale=physical.MASS),
        "m2": Param(float, 1e6, unit="kg", help="target mass; 0 = fixed target", ge=0.0, scale=physical.MASS),
        "kcs": Param(
            float, 3000.0, unit="N/m", help="ideal contact stiffness to reproduce", ge=0.0, scale=physical.STIFFNESS
        ),
        "bcs": Param(
            float, 40.0, unit="N s/m", help="ideal contact damping to reproduce", ge=0.0, scale=physical.DAMPING
        ),
        "k": Param(float, 1000.0, unit="N/m", help="passive compliance on the robot", ge=0.0, scale=physical.STIFFNESS),
        "k1": Param(float, 0.0, unit="N/m", help="chaser virtual stiffness (mode=given)", scale=physical.STIFFNESS),
        "b1": Param(float, 0.0, unit="N s/m", help="chaser virtual damping (mode=given)", scale=physical.DAMPING),
        "k2": Param(float, 0.0, unit="N/m", help="target virtual stiffness (mode=given)", scale=physical.STIFFNESS),
        "b2": Param(float, 0.0, unit="N s/m", help="target virtual damping (mode=given)", scale=physical.DAMPING),
        "compensation": Param(
            str,
            "none",
            help="delay compensation (docs/compensation.md): passivity (time-domain passivity), phase_lead, smith "
            "(Smith predictor), predictor (port k, b identified online), energy (undelayed damper k h), "
            "phase_lead+passivity; none: as published",
            choices=METHODS,
        ),
        "contact": Param(
            str,
            "linear",
            help="the target contact: linear (kcs p + bcs p') or hunt_crossley (kcs p^hc_n (1 + hc_alpha p'))",
            choices=("linear", "hunt_crossley"),
        ),
        "hc_n": Param(float, 1.5, help="Hunt-Crossley exponent (1.5: Hertz)", ge=1.0, le=3.0),
        "hc_alpha": Param(float, 0.0, unit="s/m", help="Hunt-Crossley damping alpha", ge=0.0, le=1e4),
        "delay": Param(
            float,
            0.032,
            unit="s",
            help="the robot delay the compensation is told (the scene's delay)",
            ge=0.0,
            scale=physical.ROBOT_DELAY,
        ),
        "lag": Param(
            float, 0.0, unit="s", help="the servo lag the Smith predictor is told", ge=0.0, scale=physical.TIME
        ),
        "lead_omega": Param(
            float,
            0.0,
            unit="rad/s",
            help="phase_lead: the frequency it leads by omega h at (0: the target's, sqrt(kcs / m))",
            ge=0.0,
            le=1e5,
        ),
        "lead_tau": Param(
            float,
            0.0,
            unit="s",
            help="phase_lead: the filter's time constant (0: delay / 4; smaller leads closer to the delay, "
            "amplifies noise more)",
            ge=0.0,
            scale=physical.TIME,
        ),
        "v_close": Param(
            float,
            0.03,
            unit="m/s",
            help="phase_lead on a Hunt-Crossley target: the closing velocity its frequency is figured at",
            gt=0.0,
            scale=physical.SPEED,
        ),
        "ft_noise": Param(
            float, 0.0, unit="N", help="predictor: the F/T noise it is told", ge=0.0, scale=physical.FORCE
        ),
        "max_damping": Param(
            float,
            1e5,
            unit="N s/m",
            help="largest damping the passivity controller adds; energy it cannot take out marks the run invalid",
            ge=0.0,
            scale=physical.DAMPING,
        ),
        "force_deadband": Param(
            float,
            0.0,
            unit="N",
            help="passivity: once the bodies part, a measured force "
            "below this counts as none (set it above the sensor's noise)",
            ge=0.0,
            scale=physical.FORCE,
        ),
    }

    @classmethod
    def ports(cls, params):
        # Refused when the graph is built, before anything runs: one line.
        if params["compensation"] != "none" or params["contact"] != "linear":
            from dockhil.contact.scenario import ContactModelError
            from dockhil.errors import ParamError

            try:
                cls.settings(params)
            except ContactModelError as exc:
                raise ParamError(f"virtual_impedance: {exc}") from None
        if params["compensation"] == "predictor":
            return {**cls.inputs, "robot": ROBOT}, cls.outputs
        return cls.inputs, cls.outputs

    @staticmethod
    def settings(p):
        """(target contact or None, compensation settings, passivity or None) of the parameters `p` (a dict)."""
        from dockhil.contact.compensation import CompensationSettings
        from dockhil.contact.comploop import target_frequency
        from dockhil.contact.hunt_crossley import TargetContact
        from dockhil.contact.passivity import Passivity

        passivity = (
            Passivity(p["k"], p["max_damping"], p["force_deadband"]) if "passivity" in p["compensation"] else None
        )
        contact = None
        if p["contact"] == "hunt_crossley":
            contact = TargetContact("hunt_crossley", p["kcs"], n=p["hc_n"], alpha=p["hc_alpha"])
        elif p["mode"] == "determine":
            contact = TargetContact("linear", p["kcs"], p["bcs"])
        m = p["m1"] if p["m2"] == 0.0 else p["m1"] * p["m2"] / (p["m1"] + p["m2"])
        omega = p["lead_omega"]
        if omega == 0.0 and "phase_lead" in p["compensation"]:
            if contact is None:  # mode given: the sheet k and the given spring
                omega = math.sqrt(max(p["k"] + p["k1"], 0.0) / m)
            else:
                omega = target_frequency(contact, m, p["v_close"])
        settings = CompensationSettings(
            p["compensation"], p["k"], p["delay"], p["lag"], omega, p["lead_tau"], p["ft_noise"]
        )
        return contact, settings, passivity

    def setup(self):
        import warnings
        from operator import attrgetter

        from dockhil.contact.comploop import ImpedanceStep
        from dockhil.contact.hybrid import VirtualImpedance as Impedance
        from dockhil.contact.passivity import ENERGY_FIELDS

        # The account's values in the message's field order: Energy(header, *values) costs less than
        # half of Energy(header=..., **vars(account)), and this tick path runs every tick.
        if Energy.__struct_fields__ != ("header", *ENERGY_FIELDS):
            raise AssertionError("msgs.Energy and passivity.EnergyTick must list the same fields in one order")
        self.energy_values = attrgetter(*ENERGY_FIELDS)
        p = self.p
        if p.mode == "given":
            self.impedance = Impedance(p.k1, p.b1, p.k2, p.b2)
            how = "given"
        elif p.contact == "hunt_crossley":  # the target's force less k p acts on the relative motion, no wall
            self.impedance = Impedance(0.0, 0.0, 0.0, 0.0)
            how = f"none: the Hunt-Crossley target kcs p^{p.hc_n:g} (1 + {p.hc_alpha:g} p') less k p"
        else:
            from dockhil.contact.impedance import fit_impedance, impedance_closed_form
            from dockhil.contact.scenario import ContactScenario

            if p.m2 == 0.0:
                from dockhil.errors import ParamError

                raise ParamError(
                    f"node {self.ctx.name!r}: mode 'determine' needs a free target (m2 > 0); "
                    f"give k1, b1 with mode 'given' for a fixed target"
                )
            scenario = ContactScenario(p.m1, p.m2, p.kcs, p.bcs, p.k, 0.03, 0.0)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self.impedance = impedance_closed_form(scenario)
                fit = fit_impedance(scenario)  # its warning is the closed form's: said once, below
            for w in {str(w.message): w for w in caught}.values():
                self.log(f"warning: {w.message}")
            how = f"closed form; two-time fit agrees: {fit.agrees}"
        imp = self.impedance
        contact, settings, passivity = self.settings(vars(p))
        self.tick = ImpedanceStep(p.m1, p.m2, p.k, self.impedance, contact, settings, self.ctx.dt, passivity)
        self.log(
            f"impedance ({how}): k1={imp.k1:.6g} N/m b1={imp.b1:.6g} N s/m k2={imp.k2:.6g} N/m b2={imp.b2:.6g} N s/m"
            + (f"; compensation {p.compensation}" if p.compensation != "none" else "")
        )

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        state, ft = inputs["state"], inputs.get("ft")
        f1 = f2 = 0.0
        out: dict[str, Any] = {}
        if state is not None and len(state.bodies) >= 2:
            c, t = state.bodies[0], state.bodies[1]
            x1, x2, v1, v2 = c.pose.position.x, t.pose.position.x, c.twist.linear.x, t.twist.linear.x
            # The force the dynamics apply over the next tick; as dockhil.contact.comploop.simulate_compensated.
            fs = ft.wrench.force.x if ft is not None else 0.0
            robot = inputs.get("robot")
            reported = None if robot is None else (robot.pose.position.x, robot.twist.linear.x)
            f1, f2, account = self.tick.step(x1, x2, v1, v2, fs, reported, tick.dt)
            out["energy"] = Energy(tick.header("world"), *self.energy_values(account))
        out["wrench"] = BodyWrenches(header=tick.header("world"), wrenches=(Wrench(Vector3(f1)), Wrench(Vector3(f2))))
        return out
