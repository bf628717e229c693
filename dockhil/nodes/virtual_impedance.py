"""virtual-impedance: k1, b1, k2, b2 on a virtual wall at the centre of mass; the loop's energy
account, and optionally the passivity controller against the energy the delay makes."""

from __future__ import annotations

from dockhil import physical
from dockhil.node import Input, Node, Output, Param
from dockhil.msgs import BodyWrenches, Energy, SatelliteState, Vector3, Wrench, WrenchStamped


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
            help="passivity: add the damping that dissipates the energy the "
            "delay and the sampling make (time-domain passivity, needs k); none: as published",
            choices=("none", "passivity"),
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
        if params["compensation"] == "passivity":
            from dockhil.contact.passivity import Passivity
            from dockhil.contact.scenario import ContactModelError
            from dockhil.errors import ParamError

            try:
                Passivity(params["k"], params["max_damping"], params["force_deadband"])
            except ContactModelError as exc:
                raise ParamError(f"virtual_impedance: {exc}") from None
        return cls.inputs, cls.outputs

    def setup(self):
        import warnings

        from operator import attrgetter

        from dockhil.contact.hilloop import virtual_wrench
        from dockhil.contact.hybrid import VirtualImpedance as Impedance
        from dockhil.contact.passivity import ENERGY_FIELDS, EnergyMonitor, Passivity

        self.virtual_wrench = virtual_wrench  # bound once: an import statement in step costs every tick
        # The account's values in the message's field order: Energy(header, *values) costs less than
        # half of Energy(header=..., **vars(account)), and this tick path runs every tick.
        if Energy.__struct_fields__ != ("header", *ENERGY_FIELDS):
            raise AssertionError("msgs.Energy and passivity.EnergyTick must list the same fields in one order")
        self.energy_values = attrgetter(*ENERGY_FIELDS)
        p = self.p
        if p.mode == "given":
            self.impedance = Impedance(p.k1, p.b1, p.k2, p.b2)
            how = "given"
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
        self.passivity = Passivity(p.k, p.max_damping, p.force_deadband) if p.compensation == "passivity" else None
        self.monitor = EnergyMonitor(p.m1, p.m2, p.k, imp, self.passivity)
        self.log(
            f"impedance ({how}): k1={imp.k1:.6g} N/m b1={imp.b1:.6g} N s/m k2={imp.k2:.6g} N/m b2={imp.b2:.6g} N s/m"
        )

    def step(self, tick, inputs):
        state, ft = inputs["state"], inputs.get("ft")
        f1 = f2 = 0.0
        out = {}
        if state is not None and len(state.bodies) >= 2:
            c, t = state.bodies[0], state.bodies[1]
            x1, x2, v1, v2 = c.pose.position.x, t.pose.position.x, c.twist.linear.x, t.twist.linear.x
            f1, f2 = self.virtual_wrench(x1, x2, v1, v2, self.p.m1, self.p.m2, self.impedance)
            # The force the dynamics apply over the next tick; as dockhil.contact.hilloop.simulate_hil.
            fs = ft.wrench.force.x if ft is not None else 0.0
            fc, account = self.monitor.step(x1, x2, v1, v2, fs, f1, f2, tick.dt)
            if self.passivity is not None:
                f1, f2 = f1 + fc, f2 - fc
            out["energy"] = Energy(tick.header("world"), *self.energy_values(account))
        out["wrench"] = BodyWrenches(header=tick.header("world"), wrenches=(Wrench(Vector3(f1)), Wrench(Vector3(f2))))
        return out
