"""virtual-impedance: k1, b1, k2, b2 on a virtual wall at the centre of mass."""

from __future__ import annotations

from dockhil.node import Input, Node, Output, Param
from msgs import BodyWrenches, SatelliteState, Vector3, Wrench


class VirtualImpedance(Node):
    """Virtual spring-dampers tying each body to the CoM wall while in contact (paper Eqs. 2-4)."""

    inputs = {"state": Input(SatelliteState, "/satellite/state")}
    outputs = {"wrench": Output(BodyWrenches, "/impedance/wrench", help="virtual force on chaser, target")}
    params = {
        "mode": Param(str, "determine", help="determine: k1..b2 from kcs, bcs, k at start (closed form, "
                      "checked against the two-time fit of Eqs. 5-6); given: use k1..b2 as set",
                      choices=("determine", "given")),
        "m1": Param(float, 750.0, unit="kg", help="chaser mass", gt=0.0),
        "m2": Param(float, 1e6, unit="kg", help="target mass; 0 = fixed target", ge=0.0),
        "kcs": Param(float, 3000.0, unit="N/m", help="ideal contact stiffness to reproduce", ge=0.0),
        "bcs": Param(float, 40.0, unit="N s/m", help="ideal contact damping to reproduce", ge=0.0),
        "k": Param(float, 1000.0, unit="N/m", help="passive compliance on the robot", ge=0.0),
        "k1": Param(float, 0.0, unit="N/m", help="chaser virtual stiffness (mode=given)"),
        "b1": Param(float, 0.0, unit="N s/m", help="chaser virtual damping (mode=given)"),
        "k2": Param(float, 0.0, unit="N/m", help="target virtual stiffness (mode=given)"),
        "b2": Param(float, 0.0, unit="N s/m", help="target virtual damping (mode=given)"),
    }

    def setup(self):
        import warnings

        from dockhil.contact.hybrid import VirtualImpedance as Impedance

        p = self.p
        if p.mode == "given":
            self.impedance = Impedance(p.k1, p.b1, p.k2, p.b2)
            how = "given"
        else:
            from dockhil.contact.impedance import fit_impedance, impedance_closed_form
            from dockhil.contact.scenario import ContactScenario

            if p.m2 == 0.0:
                from dockhil.errors import ParamError

                raise ParamError(f"node {self.ctx.name!r}: mode 'determine' needs a free target (m2 > 0); "
                                 f"give k1, b1 with mode 'given' for a fixed target")
            scenario = ContactScenario(p.m1, p.m2, p.kcs, p.bcs, p.k, 0.03, 0.0)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self.impedance = impedance_closed_form(scenario)
                fit = fit_impedance(scenario)  # its warning is the closed form's: said once, below
            for w in {str(w.message): w for w in caught}.values():
                self.log(f"warning: {w.message}")
            how = f"closed form; two-time fit agrees: {fit.agrees}"
        imp = self.impedance
        self.log(f"impedance ({how}): k1={imp.k1:.6g} N/m b1={imp.b1:.6g} N s/m "
                 f"k2={imp.k2:.6g} N/m b2={imp.b2:.6g} N s/m")

    def step(self, tick, inputs):
        from dockhil.contact.hilloop import virtual_wrench

        state = inputs["state"]
        f1 = f2 = 0.0
        if state is not None and len(state.bodies) >= 2:
            c, t = state.bodies[0], state.bodies[1]
            f1, f2 = virtual_wrench(c.pose.position.x, t.pose.position.x, c.twist.linear.x, t.twist.linear.x,
                                    self.p.m1, self.p.m2, self.impedance)
        return {"wrench": BodyWrenches(header=tick.header("world"),
                                       wrenches=[Wrench(Vector3(f1)), Wrench(Vector3(f2))])}
