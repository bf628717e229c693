"""Parameters shared by the 6-DOF nodes: the two rigid bodies and the contact matrices.

Lists in a launch file: an inertia is 3 numbers (principal moments along the
body axes) or a 3x3 matrix; a stiffness or damping is 6 numbers (diagonal,
axes x y z rx ry rz of the target's interface frame) or a 6x6 matrix;
positions are 3 numbers [m], orientations unit quaternions (x, y, z, w).
Each node checks what it is given at setup (one line per bad value).
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import TYPE_CHECKING, TypeVar

from dockhil import physical
from dockhil.errors import ParamError
from dockhil.node import Param

if TYPE_CHECKING:
    from dockhil.contact.contact6 import Contact6

T = TypeVar("T")

IDENTITY = [0.0, 0.0, 0.0, 1.0]

BODY_PARAMS = {
    "m1": Param(float, 750.0, unit="kg", help="chaser mass", gt=0.0, scale=physical.MASS),
    "m2": Param(float, 1e6, unit="kg", help="target mass", gt=0.0, scale=physical.MASS),
    "inertia1": Param(
        list,
        [300.0, 400.0, 500.0],
        unit="kg m^2",
        help="chaser inertia about its CoM, body axes: 3 principal moments or 3x3",
        scale=physical.INERTIA,
    ),
    "inertia2": Param(
        list,
        [4e6, 5e6, 6e6],
        unit="kg m^2",
        help="target inertia about its CoM, body axes: 3 principal moments or 3x3",
        scale=physical.INERTIA,
    ),
    "interface1": Param(
        list,
        [1.0, 0.0, 0.0],
        unit="m",
        help="chaser interface origin A from its CoM, body axes",
        scale=physical.DISTANCE,
    ),
    "interface2": Param(
        list,
        [-2.0, 0.0, 0.0],
        unit="m",
        help="target interface origin B from its CoM, body axes",
        scale=physical.DISTANCE,
    ),
    "interface_orientation1": Param(list, IDENTITY, help="chaser interface frame A in its body frame (x, y, z, w)"),
    "interface_orientation2": Param(
        list, IDENTITY, help="target interface frame B in its body frame (x, y, z, w); B's x axis is the contact normal"
    ),
}

IDEAL_PARAMS = {
    "stiffness": Param(
        list,
        [3000.0, 3000.0, 3000.0, 300.0, 300.0, 300.0],
        unit="N/m, N m/rad",
        help="ideal contact stiffness to reproduce: 6 (diagonal) or 6x6 symmetric",
        scale=physical.STIFFNESS,
    ),
    "damping": Param(
        list,
        [40.0, 40.0, 40.0, 4.0, 4.0, 4.0],
        unit="N s/m, N m s/rad",
        help="ideal contact damping to reproduce: 6 (diagonal) or 6x6 symmetric",
        scale=physical.DAMPING,
    ),
}

PASSIVE_PARAMS = {
    "passive_stiffness": Param(
        list,
        [1000.0, 1000.0, 1000.0, 100.0, 100.0, 100.0],
        unit="N/m, N m/rad",
        help="passive compliance on the robot: 6 (diagonal) or 6x6 symmetric",
        scale=physical.STIFFNESS,
    ),
    "passive_damping": Param(
        list,
        [0.0] * 6,
        unit="N s/m, N m s/rad",
        help="passive damping on the robot: 6 (diagonal) or 6x6 symmetric",
        scale=physical.DAMPING,
    ),
}

MOUNT_PARAMS = {
    "sensor_position": Param(
        list,
        [0.0, 0.0, 0.0],
        unit="m",
        help="F/T sensor origin in the target's interface frame B",
        scale=physical.DISTANCE,
    ),
    "sensor_orientation": Param(list, IDENTITY, help="F/T sensor axes in B (x, y, z, w)"),
}


def checked(node: str, build: Callable[[], T]) -> T:
    """Call `build()`; a model error (non-PD inertia, non-unit quaternion, asymmetric
    matrix...) becomes one ParamError line naming the node."""
    from dockhil.contact.scenario import ContactModelError

    try:
        return build()
    except ContactModelError as exc:
        raise ParamError(f"node {node!r}: {exc}") from None


def bodies(p):
    """(chaser, target) RigidBody from the BODY_PARAMS values (CoM at the body origin); errors name
    the body: `chaser.inertia` is the param inertia1, `target.interface_position` interface2."""
    from dockhil.contact.rigidbody import RigidBody

    return (
        RigidBody(
            p.m1,
            _inertia(p.inertia1),
            interface_position=p.interface1,
            interface_orientation=p.interface_orientation1,
            name="chaser",
        ),
        RigidBody(
            p.m2,
            _inertia(p.inertia2),
            interface_position=p.interface2,
            interface_orientation=p.interface_orientation2,
            name="target",
        ),
    )


def _inertia(value):
    """3 principal moments -> the diagonal matrix; anything else goes to RigidBody's check."""
    if isinstance(value, list) and len(value) == 3 and all(isinstance(v, (int, float)) for v in value):
        return [[float(value[0]), 0.0, 0.0], [0.0, float(value[1]), 0.0], [0.0, 0.0, float(value[2])]]
    return value


def ideal_contact(p):
    """The ideal contact of `p`; with contact hunt_crossley (the virtual impedance's params) the normal is
    the Hunt-Crossley target of kcs the stiffness's normal entry, hc_n, hc_alpha (contact6.hunt_crossley_normal,
    its linear equivalent for the reduced mass m1 m2 / (m1 + m2) at v_close)."""
    from dockhil.contact.contact6 import Contact6, hunt_crossley_normal

    linear = Contact6(_matrix(p.stiffness, "stiffness"), _matrix(p.damping, "damping"))
    if getattr(p, "contact", "linear") != "hunt_crossley":
        return linear
    from dockhil.contact.hunt_crossley import TargetContact

    target = TargetContact("hunt_crossley", float(linear.stiffness[0, 0]), n=p.hc_n, alpha=p.hc_alpha)
    return hunt_crossley_normal(linear, target, p.m1 * p.m2 / (p.m1 + p.m2), p.v_close)


def passive_contact(p: SimpleNamespace, mu: float = 0.0, slip_velocity: float = 1e-3, k_scale: float = 1.0) -> Contact6:
    """The passive compliance of `p`; k_scale: the hardware's true stiffness over the one given."""
    from dockhil.contact.contact6 import Contact6

    return Contact6(
        k_scale * _matrix(p.passive_stiffness, "passive_stiffness"),
        _matrix(p.passive_damping, "passive_damping"),
        mu=mu,
        slip_velocity=slip_velocity,
    )


def _matrix(value, name):
    """The value, named for its error: Contact6 says `stiffness`/`damping`, the launch file the param name."""
    from dockhil.contact.contact6 import check_matrix6

    return check_matrix6(name, value, "N/m, N m/rad" if "stiffness" in name else "N s/m, N m s/rad")
