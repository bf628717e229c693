"""virtual-impedance, 6-DOF: K_1, C_1, K_2, C_2 (6x6) on the virtual wall at the system's CoM."""

from __future__ import annotations

from dockhil.node import Input, Node, Output
from dockhil.msgs import BodyWrenches, SatelliteState, Wrench
from dockhil.nodes.satellite_dynamics6 import array3, vector
from dockhil.nodes.sixdof_params import BODY_PARAMS, IDEAL_PARAMS, PASSIVE_PARAMS, bodies, checked, ideal_contact, \
    passive_contact


def published(body):
    """(position, orientation, velocity, world angular velocity) of a msgs.BodyState."""
    o = body.pose.orientation
    return (array3(body.pose.position), (o.x, o.y, o.z, o.w), array3(body.twist.linear),
            array3(body.twist.angular))


class VirtualImpedance6(Node):
    """Virtual 6x6 impedances of both bodies on the wall at the CoM, so that passive + virtual = the ideal contact.

    K_i, C_i come from the closed form of dockhil.contact.hybrid6 at the first tick in contact,
    from both bodies' mobilities there."""

    inputs = {"state": Input(SatelliteState, "/satellite/state")}
    outputs = {"wrench": Output(BodyWrenches, "/impedance/wrench",
                                help="virtual wrench on chaser, target (world, about each CoM)")}
    params = {**BODY_PARAMS, **IDEAL_PARAMS, **PASSIVE_PARAMS}

    def setup(self):
        from dockhil.contact import hybrid6

        p = self.p
        self.b1, self.b2, self.wall = checked(
            self.ctx.name, lambda: (*bodies(p), hybrid6.VirtualWall6(ideal_contact(p), passive_contact(p))))
        self.lib = hybrid6
        self.logged = False

    def step(self, tick, inputs):
        lib = self.lib
        state = inputs["state"]
        forces = None
        if state is not None and len(state.bodies) >= 2:
            x1, q1, v1, w1 = published(state.bodies[0])
            x2, q2, v2, w2 = published(state.bodies[1])
            s1 = lib.motion_from_published(self.b1, x1, q1, v1, w1)
            s2 = lib.motion_from_published(self.b2, x2, q2, v2, w2)
            g, rate, _ = lib.relative_interface(s1, s2, w1, w2)
            forces = self.wall.wrenches(s1, s2, g, rate)
            if self.wall.impedance is not None and not self.logged:
                self.logged = True
                per_axis = self.wall.impedance.per_axis()
                self.log("impedance (closed form at first contact), diagonal: " + " ".join(
                    f"{a}: k1={v['k1']:.6g} c1={v['c1']:.6g}" for a, v in per_axis.items()))
        if forces is None:
            return {"wrench": BodyWrenches(header=tick.header("world"), wrenches=[Wrench(), Wrench()])}
        f1, t1, f2, t2 = forces
        return {"wrench": BodyWrenches(header=tick.header("world"),
                                       wrenches=[Wrench(vector(f1), vector(t1)), Wrench(vector(f2), vector(t2))])}
