"""dockhil message types: msgspec Structs, msgpack on the wire.

Every top-level message starts with a Header. Geometry is 6-DOF shaped
(3-D force, torque, position, quaternion orientation, velocity) even where
a scene uses one axis, so more degrees of freedom need no new wire format.
Units are SI: m, m/s, rad, rad/s, N, N m, kg, s.

Physical fields are `Finite`: decoding refuses NaN and Inf.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

_MAX = 1.7976931348623157e308
Finite = Annotated[float, msgspec.Meta(ge=-_MAX, le=_MAX, description="finite real number")]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=_MAX, description="finite, >= 0")]
Count = Annotated[int, msgspec.Meta(ge=0)]


class _Field(msgspec.Struct, frozen=True, forbid_unknown_fields=True, gc=False):
    """Base of nested values: a misspelt field is refused, not ignored. Frozen, holding numbers,
    strings, other messages and tuples of them, a message cannot be part of a reference cycle, so
    the garbage collector need not track it (gc=False: cheaper to build, tens of them a tick)."""


class Message(_Field, tag_field="type", tag=lambda name: f"dockhil/{name}"):
    """Base of top-level messages. The encoded map carries "type": "dockhil/<Name>",
    so a message of another type is refused on decode; `header` is required."""


class Header(_Field):
    """stamp [s] (sim or wall time), tick (sim-time step index), seq (per publisher), frame."""

    stamp: NonNegative = 0.0
    tick: Count = 0
    seq: Count = 0
    frame: str = ""


class Vector3(_Field):
    x: Finite = 0.0
    y: Finite = 0.0
    z: Finite = 0.0


class Quaternion(_Field):
    """Unit quaternion, scalar last (x, y, z, w) as in ROS."""

    x: Finite = 0.0
    y: Finite = 0.0
    z: Finite = 0.0
    w: Finite = 1.0


class Pose(_Field):
    """position [m], orientation (unit quaternion)."""

    position: Vector3 = Vector3()
    orientation: Quaternion = Quaternion()


class Twist(_Field):
    """linear [m/s], angular [rad/s]."""

    linear: Vector3 = Vector3()
    angular: Vector3 = Vector3()


class Wrench(_Field):
    """force [N], torque [N m]."""

    force: Vector3 = Vector3()
    torque: Vector3 = Vector3()


class BodyState(_Field):
    """One free-floating body: mass [kg] (0 = fixed to the ground), pose, twist."""

    name: str = ""
    mass: NonNegative = 0.0
    pose: Pose = Pose()
    twist: Twist = Twist()


class SatelliteState(Message):
    """The bodies the satellite-dynamics node integrates, chaser first (a tuple: a message is
    frozen all through, so a reader in the same process cannot change what another reads)."""

    header: Header
    bodies: tuple[BodyState, ...] = ()
    in_contact: bool = False


class WrenchStamped(Message):
    """A wrench acting on the chaser (body 0); the target feels its opposite."""

    header: Header
    wrench: Wrench = Wrench()


class BodyWrenches(Message):
    """One wrench per body, in the order of SatelliteState.bodies (a tuple, as bodies)."""

    header: Header
    wrenches: tuple[Wrench, ...] = ()


class RobotCommand(Message):
    """Setpoint for the robot: the pose of the chaser's docking probe relative
    to the target's interface (x > 0 is penetration), with its velocity."""

    header: Header
    pose: Pose = Pose()
    twist: Twist = Twist()
    enable: bool = True


class RobotState(Message):
    """The robot's actual pose in the same frame as RobotCommand."""

    header: Header
    pose: Pose = Pose()
    twist: Twist = Twist()
    status: str = "ok"


class ImpedanceParams(Message):
    """Virtual impedance k1 [N/m], b1 [N s/m], k2, b2 and how they were found."""

    header: Header
    k1: Finite = 0.0
    b1: Finite = 0.0
    k2: Finite = 0.0
    b2: Finite = 0.0
    method: str = ""


class NodeStatus(Message):
    header: Header
    node: str = ""
    state: str = "running"
    ticks: Count = 0
    dropped: Count = 0
    message: str = ""


class EStop(Message):
    """Emergency stop: active=True stops commanding and holds the robot."""

    header: Header
    active: bool = False
    reason: str = ""


class Energy(Message):
    """The HIL loop's energy account at one tick, in joules, cumulative from the start of the run
    (see dockhil.contact.passivity). The port is the hardware: the measured force on the chaser
    against the simulated relative interface motion p = x1 - x2.

    port_work_J: work of the measured force on the simulated bodies (> 0: the hardware gave energy);
    port_spring_J: F^2 / (2 k), what the passive compliance k carrying the measured force F holds;
    port_stored_J: what the delay-free compliance would hold at the simulated overlap, k p^2 / 2
        (p > 0; 0 apart): the store against which the port's work counts as made energy;
    kinetic_J: kinetic energy of the simulated bodies;
    virtual_work_J, virtual_stored_J, virtual_dissipated_J: the virtual impedance's work on the
        bodies, what its springs hold, what its dampers dissipated;
    generated_J: energy made by the delay and the sampling (port and virtual impedance), which a
        passive, delay-free loop would not make;
    compensation_dissipated_J: taken out by the passivity controller;
    net_generated_J: generated_J - compensation_dissipated_J (> 0: the loop made energy);
    damping_Ns_m: the controller's damping [N s/m] over the next tick; at_max_damping: it wanted
    more than its bound; port_loaded: the bodies touch or the port carries a force (above the
    controller's deadband): where the controller may act. Thrust is not in the account: kinetic_J changes by the work of the port,
    the virtual impedance and the thrust."""

    header: Header
    port_work_J: Finite = 0.0
    port_spring_J: Finite = 0.0
    port_stored_J: Finite = 0.0
    kinetic_J: Finite = 0.0
    virtual_work_J: Finite = 0.0
    virtual_stored_J: Finite = 0.0
    virtual_dissipated_J: Finite = 0.0
    generated_J: Finite = 0.0
    compensation_dissipated_J: Finite = 0.0
    net_generated_J: Finite = 0.0
    damping_Ns_m: NonNegative = 0.0
    at_max_damping: bool = False
    port_loaded: bool = False


class RobotCycle(_Field):
    """One exchange with the robot controller on the device's own cycle, as the driver's link made it.

    sent [s]: when the setpoint (or the hold, or the heartbeat alone) went to the device; read [s]: when
    the actual pose came back; both on the graph's clock (Unix time in a wall-time run), as stamps are.
    setpoint: the last setpoint written (this exchange's if `written`), after the per-cycle speed limit;
    actual: the actual pose read; both in the scene's robot frame, as /robot/state. written: this
    exchange gave the device a new setpoint (RSI: false for an answer the controller counted late, which
    it did not take; `setpoint` is then the correction it kept). device_cycle: the device's own count of
    the cycle that measured `actual`, 16 bits (Modbus: the controller's cycle counter; RSI: IPOC // the
    cycle in ms). taken: the device had taken this exchange's setpoint when it measured `actual` (Modbus:
    it echoed this exchange's heartbeat), so that cycle ran between `sent` and `read`; otherwise the next
    cycle takes it (RSI: always false, the datagram's pose comes before its answer, `read` before
    `sent`)."""

    sent: NonNegative = 0.0
    read: NonNegative = 0.0
    setpoint: Pose = Pose()
    written: bool = False
    actual: Pose = Pose()
    device_cycle: Count = 0
    taken: bool = False


class RobotCycles(Message):
    """The device cycles of the robot driver's link since its previous tick, oldest first: every exchange,
    none lost to the hand-over of latest values (calibrate times the robot's delay on them)."""

    header: Header
    cycles: tuple[RobotCycle, ...] = ()


# Wire type names, stable across releases: used in bags and by the launcher.
TYPES: dict[str, type[Message]] = {
    f"dockhil/{cls.__name__}": cls
    for cls in (
        SatelliteState,
        WrenchStamped,
        BodyWrenches,
        RobotCommand,
        RobotState,
        RobotCycles,
        ImpedanceParams,
        NodeStatus,
        EStop,
        Energy,
    )
}


def type_name(cls: type) -> str:
    return f"dockhil/{cls.__name__}"


def type_by_name(name: str) -> type[Message]:
    try:
        return TYPES[name]
    except KeyError:
        raise KeyError(f"unknown message type {name!r}; known: {', '.join(sorted(TYPES))}") from None
