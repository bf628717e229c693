"""virtual-impedance, 6-DOF: K_1, C_1, K_2, C_2 (6x6) on the virtual wall at the system's CoM, and a delay
compensation along the contact's normal (dockhil.contact.hybrid6.NormalCompensation6)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from dockhil.msgs import BodyWrenches, SatelliteState, Vector3, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Tick
from dockhil.nodes.virtual_impedance import ROBOT
from dockhil.nodes.virtual_impedance import VirtualImpedance as VirtualImpedance1
from dockhil.scene.sixdof_params import (
    BODY_PARAMS,
    IDEAL_PARAMS,
    MOUNT_PARAMS,
    PASSIVE_PARAMS,
    bodies,
    checked,
    ideal_contact,
    passive_contact,
)

# The methods apply along the normal as on hil.yaml's axis: the 1-DOF node's parameters of them.
COMPENSATION_PARAMS = {
    name: VirtualImpedance1.params[name]
    for name in ("compensation", "delay", "lag", "lead_omega", "lead_tau", "ft_noise", "max_damping", "force_deadband")
}
# The target's law along the normal, as hil.yaml's on its axis (the other five axes stay linear).
CONTACT_PARAMS = {
    "contact": replace(
        VirtualImpedance1.params["contact"],
        help="the law on the normal axis (B's x): linear (stiffness, damping) or hunt_crossley "
        "(kcs d^hc_n (1 + hc_alpha d'), kcs the stiffness's normal entry in N/m^hc_n; its damping entry unused)",
    ),
    "hc_n": VirtualImpedance1.params["hc_n"],
    "hc_alpha": VirtualImpedance1.params["hc_alpha"],
    "v_close": replace(
        VirtualImpedance1.params["v_close"],
        help="contact hunt_crossley: the normal closing velocity its linear equivalent (the scene check's, a "
        "phase lead's frequency) is figured at",
    ),
}
FT = Input(
    WrenchStamped,
    "/ft/wrench",
    required=False,
    help="the F/T reading (on the target, sensor frame): its normal force is the compensation's port",
)

NO_WRENCH = Wrench()  # msgs are frozen: one zero wrench serves every message that carries one


def published(body):
    """(position, orientation, velocity, world angular velocity) of a msgs.BodyState."""
    pose, twist = body.pose, body.twist
    p, o, v, w = pose.position, pose.orientation, twist.linear, twist.angular
    return (p.x, p.y, p.z), (o.x, o.y, o.z, o.w), (v.x, v.y, v.z), (w.x, w.y, w.z)


class VirtualImpedance6(Node):
    """Virtual 6x6 impedances of both bodies on the wall at the CoM, so that passive + virtual = the ideal contact.

    K_i, C_i come from the closed form of dockhil.contact.hybrid6 at the first tick in contact,
    from both bodies' mobilities there."""

    inputs = {"state": Input(SatelliteState, "/satellite/state")}
    outputs = {
        "wrench": Output(
            BodyWrenches, "/impedance/wrench", help="virtual wrench on chaser, target (world, about each CoM)"
        )
    }
    params = {
        **BODY_PARAMS,
        **IDEAL_PARAMS,
        **CONTACT_PARAMS,
        **PASSIVE_PARAMS,
        **COMPENSATION_PARAMS,
        **MOUNT_PARAMS,
    }

    @classmethod
    def ports(cls, params):
        if params["compensation"] == "none" and params["contact"] == "linear":
            return cls.inputs, cls.outputs
        # Refused when the graph is built, before anything runs: one line.
        from types import SimpleNamespace

        given = SimpleNamespace(**params)
        checked("virtual_impedance", lambda: (ideal_contact(given), cls.compensation(given, 1e-3)))
        if params["compensation"] == "none":
            return cls.inputs, cls.outputs
        extra = {"ft": FT, "robot": ROBOT} if params["compensation"] == "predictor" else {"ft": FT}
        return {**cls.inputs, **extra}, cls.outputs

    @staticmethod
    def compensation(p, dt):
        """The NormalCompensation6 of the parameters `p` (a namespace), or None for compensation none: told
        the passive and ideal normal entries (or the Hunt-Crossley target), the delay, lag and F/T noise; a
        phase lead's frequency defaults to the normal's sqrt(kcs / m_r), m_r = m1 m2 / (m1 + m2), kcs the
        linear equivalent's for a Hunt-Crossley target (its secant stiffness: comploop.target_frequency)."""
        if p.compensation == "none":
            return None
        import math

        from dockhil.contact.compensation import CompensationSettings
        from dockhil.contact.hybrid6 import NormalCompensation6
        from dockhil.contact.passivity import Passivity

        ideal, passive = ideal_contact(p), passive_contact(p)
        k, kcs = float(passive.stiffness[0, 0]), float(ideal.stiffness[0, 0])
        reduced = p.m1 * p.m2 / (p.m1 + p.m2)
        omega = p.lead_omega or math.sqrt(max(kcs, 0.0) / reduced)
        settings = CompensationSettings(p.compensation, k, p.delay, p.lag, omega, p.lead_tau, p.ft_noise)
        passivity = Passivity(k, p.max_damping, p.force_deadband) if "passivity" in p.compensation else None
        return NormalCompensation6(ideal, passive, settings, reduced, dt, passivity, p.sensor_orientation)

    def setup(self):
        from dockhil.contact import hybrid6

        p = self.p
        self.b1, self.b2, self.wall = checked(
            self.ctx.name, lambda: (*bodies(p), hybrid6.VirtualWall6(ideal_contact(p), passive_contact(p)))
        )
        self.comp = checked(self.ctx.name, lambda: self.compensation(p, self.ctx.dt))
        self.lib = hybrid6
        self.logged = False
        if self.comp is not None:
            self.log(f"compensation {p.compensation} along the contact normal")

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        state = inputs["state"]
        forces, normal = None, 0.0
        if state is not None and len(state.bodies) >= 2:
            g, velocity, spin = self.lib.published_interface(
                self.b1, published(state.bodies[0]), self.b2, published(state.bodies[1])
            )
            normal = 0.0
            if self.comp is not None:
                ft, robot = inputs.get("ft"), inputs.get("robot")
                measured = (0.0, 0.0, 0.0) if ft is None else (ft.wrench.force.x, ft.wrench.force.y, ft.wrench.force.z)
                reported = None if robot is None else (robot.pose.position.x, robot.twist.linear.x)
                normal = self.comp.force(g, velocity, measured, reported, tick.dt)
            forces = self.wall.wrenches(g, velocity, spin, normal)
            if self.wall.impedance is not None and not self.logged:
                self.logged = True
                per_axis = self.wall.impedance.per_axis()
                self.log(
                    "impedance (closed form at first contact), diagonal: "
                    + " ".join(f"{a}: k1={v['k1']:.6g} c1={v['c1']:.6g}" for a, v in per_axis.items())
                )
        if forces is None or (not self.wall.touching and not normal):  # zero wrenches: one frozen Wrench() for them
            return {"wrench": BodyWrenches(header=tick.header("world"), wrenches=(NO_WRENCH, NO_WRENCH))}
        f1, t1, f2, t2 = forces
        # The wall's values are plain floats already (tuples): they go into the message as they are.
        return {
            "wrench": BodyWrenches(
                header=tick.header("world"),
                wrenches=(Wrench(Vector3(*f1), Vector3(*t1)), Wrench(Vector3(*f2), Vector3(*t2))),
            )
        }
