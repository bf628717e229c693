"""virtual-impedance, 6-DOF: K_1, C_1, K_2, C_2 (6x6) on the virtual wall at the system's CoM."""

from __future__ import annotations

from typing import Any

from dockhil.msgs import BodyWrenches, SatelliteState, Vector3, Wrench
from dockhil.node import Input, Node, Output, Tick
from dockhil.scene.sixdof_params import (
    BODY_PARAMS,
    IDEAL_PARAMS,
    PASSIVE_PARAMS,
    bodies,
    checked,
    ideal_contact,
    passive_contact,
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
    params = {**BODY_PARAMS, **IDEAL_PARAMS, **PASSIVE_PARAMS}

    def setup(self):
        from dockhil.contact import hybrid6

        p = self.p
        self.b1, self.b2, self.wall = checked(
            self.ctx.name, lambda: (*bodies(p), hybrid6.VirtualWall6(ideal_contact(p), passive_contact(p)))
        )
        self.lib = hybrid6
        self.logged = False

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        state = inputs["state"]
        forces = None
        if state is not None and len(state.bodies) >= 2:
            g, velocity, spin = self.lib.published_interface(
                self.b1, published(state.bodies[0]), self.b2, published(state.bodies[1])
            )
            forces = self.wall.wrenches(g, velocity, spin)
            if self.wall.impedance is not None and not self.logged:
                self.logged = True
                per_axis = self.wall.impedance.per_axis()
                self.log(
                    "impedance (closed form at first contact), diagonal: "
                    + " ".join(f"{a}: k1={v['k1']:.6g} c1={v['c1']:.6g}" for a, v in per_axis.items())
                )
        if forces is None or not self.wall.touching:  # the wall's wrenches are zero: one frozen Wrench() for them
            return {"wrench": BodyWrenches(header=tick.header("world"), wrenches=(NO_WRENCH, NO_WRENCH))}
        f1, t1, f2, t2 = forces
        # The wall's values are plain floats already (tuples): they go into the message as they are.
        return {
            "wrench": BodyWrenches(
                header=tick.header("world"),
                wrenches=(Wrench(Vector3(*f1), Vector3(*t1)), Wrench(Vector3(*f2), Vector3(*t2))),
            )
        }
