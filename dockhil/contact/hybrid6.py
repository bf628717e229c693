"""The hybrid 6-DOF model: a passive 6x6 compliance on the robots plus a
virtual 6x6 impedance of each body on a virtual wall at the system's centre
of mass, so that passive + virtual reproduce the ideal contact (contact6).
Derivation in docs/sixdof.md.

Mobility. A wrench W (generalized force q, W = -S q on body 1 at o_A, see
contact6) accelerates the interface coordinates, to first order (velocity
products left out), by e'' = -(G1 + G2) q with G_i the mobility of body i at
the contact point o_A in the generalized coordinates:

    G_i = P T [[1/m_i - [rho]x I^-1 [rho]x, -[rho]x I^-1], [I^-1 [rho]x, I^-1]] T^T P^T

rho = o_A - x_i (lever arm from the CoM), I^-1 the world inverse inertia,
T = diag(R_B^T, R_B^T), P = diag(1, J_l(theta)^-1). For a point mass G = 1/m.

Virtual wall. In the 1-DOF model body 1 sits at x1 - w = (m2 / M) p from the
wall at the CoM; the 6-DOF analogue splits the relative displacement in
proportion to the mobilities: y_1 = D_1 (e - e_0), y_2 = -D_2 (e - e_0),
D_i = G_i (G1 + G2)^-1 (D_1 + D_2 = 1; D_1 = m2 / M for point masses). The
virtual impedances act on these:

    q_1 = K_1 D_1 (e - e_0) + C_1 D_1 e'      (on body 1: W = -S q_1)
    q_2 = K_2 D_2 (e - e_0) + C_2 D_2 e'      (on body 2: W = +S q_2)

Closed form: passive + virtual = ideal on both bodies requires
K_i D_i = K - K_p, C_i D_i = C - C_p, i.e.

    K_1 = (K - K_p)(1 + G_2 G_1^-1),   K_2 = (K - K_p)(1 + G_1 G_2^-1)   (and C alike)

which per axis, with the interface on principal axes through both CoMs, is
k_1 = (kcs - k)(1 + m1/m2) for a translation (NOTES) and
k_1 = (k_r - k_rp)(1 + I1/I2) for a rotation; a lever arm couples a
translation with the rotations about the perpendicular axes. With D_i frozen
at the contact onset the model is exact in continuous time for every motion
(the D_i cancel); they matter where a wall is integrated as its own body
(an approximation: see docs/sixdof.md) and in the fit below.

The model reproduces a frictionless ideal contact; friction is the hardware's.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np

from dockhil.contact import rigid
from dockhil.contact.contact6 import Contact6, MatVec6, Recorder, Run6
from dockhil.contact.impedance6 import Impedance6, check_frictionless, impedance_closed_form6, mobility
from dockhil.contact.interface6 import (
    InterfaceGeometry,
    add6,
    left_jacobian_inverse3,
    mat3_vec,
    mat3t_vec,
    sensor_wrench_checked,
    sub6,
)
from dockhil.contact.rigid import HeldWrench, Motion
from dockhil.contact.rigidbody import BodyState, RigidBody, check_vector
from dockhil.contact.rotations import (
    COMPILED,
    Quat,
    Vec3,
    add3,
    check_unit_quaternion,
    cross3,
    normalised,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_to_matrix,
    rotate,
    rotate_back,
    rotvec3,
    sub3,
)
from dockhil.contact.scenario import ContactModelError, check_positive

if TYPE_CHECKING:
    pass


# --- the sampled loop, one tick at a time -------------------------------------------------
# The graph's 6-DOF nodes (nodes/*6.py) call these same functions on the values their
# messages carry, so the graph and `simulate_hybrid6` compute the same numbers bit for bit.

IDENTITY = (0.0, 0.0, 0.0, 1.0)


class RelativePose(NamedTuple):
    """The robot command: pose and twist of the chaser's interface A in the target's B.
    position d [m] and velocity d' [m/s] in B axes, attitude of A in B (x, y, z, w),
    relative angular velocity R_B^T (omega_1 - omega_2) [rad/s] in B axes. 3-tuples of floats."""

    position: tuple
    orientation: tuple
    velocity: tuple
    angular_velocity: tuple


ZERO3 = (0.0, 0.0, 0.0)
ZERO6 = (0.0,) * 6
NO_VIRTUAL = (ZERO3,) * 4  # the virtual wall's wrenches out of contact
FREE_FLIGHT = HeldWrench(ZERO3, ZERO3, ZERO3, ZERO3)


def published_body(m: Motion) -> tuple:
    """(CoM position, body-frame attitude, CoM velocity, world angular velocity): what the
    dynamics publish for one body (tuples of floats)."""
    q = m.q if m.body._bp_identity else quat_multiply(m.q, quat_conjugate(m.body._q_bp))
    return m.x, q, m.v, m.omega3()


def principal_attitude(body: RigidBody, orientation: Quat) -> tuple:
    """The integrator's (principal-frame) attitude of a published body-frame attitude."""
    return normalised(orientation if body._bp_identity else quat_multiply(orientation, body._q_bp))


def motion_from_published(
    body: RigidBody, position: Vec3, orientation: Quat, velocity: Vec3, omega_world: Vec3
) -> Motion:
    """The integrator's variables rebuilt from a published body state (what a node downstream sees)."""
    q_p = principal_attitude(body, orientation)
    i1, i2, i3 = body._moments
    w = rotate_back(q_p, omega_world)
    return Motion(body, tuple(position), tuple(velocity), q_p, (i1 * w[0], i2 * w[1], i3 * w[2]))


def relative_interface(
    m1: Motion, m2: Motion, omega1: Vec3, omega2: Vec3
) -> tuple[InterfaceGeometry, tuple, RelativePose]:
    """(geometry, e', robot command) for published states; omega_i world angular velocities."""
    g = InterfaceGeometry(m1, m2)
    rate, w_rel = g.rates(m1.v, omega1, m2.v, omega2)
    return g, rate, RelativePose(g.e[:3], g.q_rel, rate[:3], w_rel)


def published_interface(
    body1: RigidBody, published1: tuple, body2: RigidBody, published2: tuple
) -> tuple[InterfaceGeometry, tuple, tuple]:
    """(geometry, d', relative angular velocity in B) of two published body states (`published_body`):
    `relative_interface` without rebuilding the momenta, which neither the command nor the wall
    reads (the per-tick path of the sampled loop; e' is `g.rate_from(d', angular velocity)`).

    It remembers its last answer: each tick, the dynamics (for the robot command) and the virtual
    impedance (for its wall) ask it the same question, and in one process the second is answered
    without the arithmetic. Equal bodies (their `_key`) and equal states give equal numbers, so the
    answer is the one it would compute; its readers only read the geometry (what it computes on
    first use, theta and J_l^-1, is the same whoever asks first)."""
    key = (body1._key, published1, body2._key, published2)
    last = _LAST_INTERFACE[0]
    if last is not None and last[0] == key:
        return last[1]
    x1, q1, v1, w1 = published1
    x2, q2, v2, w2 = published2
    if COMPILED is not None:  # the same arithmetic in C (rotations.COMPILED), the same bits
        g = InterfaceGeometry.__new__(InterfaceGeometry)
        q1, q2, g.arm1, g.arm2, g.point, g.r, g.q_b, g.q_rel, g.d, velocity, spin = COMPILED.interface(
            body1._frames, body2._frames, x1, q1, v1, w1, x2, q2, v2, w2
        )
        g.pose1, g.pose2 = (body1, x1, q1), (body2, x2, q2)
    else:
        g = InterfaceGeometry.between(
            body1, x1, principal_attitude(body1, q1), body2, x2, principal_attitude(body2, q2)
        )
        velocity, spin = g.rates3(v1, w1, v2, w2)
    answer = (g, velocity, spin)
    _LAST_INTERFACE[0] = (key, answer)
    return answer


_LAST_INTERFACE: list = [None]  # (key, answer) of published_interface's last call


def robot_command(body1: RigidBody, published1: tuple, body2: RigidBody, published2: tuple) -> tuple[tuple, bool]:
    """(robot command as RelativePose's fields (d, attitude, d', angular velocity), touching) of two
    published body states: what the dynamics publish besides the states."""
    g, velocity, spin = published_interface(body1, published1, body2, published2)
    return (g.d, g.q_rel, velocity, spin), _touching(g.d[0], velocity[0])


def _touching(penetration: float, closing: float) -> bool:
    """Penetrating, or at the surface and closing in (as the 1-DOF loop)."""
    return penetration > 0.0 or (penetration == 0.0 and closing > 0.0)


class VirtualWall6:
    """The virtual impedance of both bodies on the wall (the virtual-impedance node).

    At the first tick in contact it takes the spring rest pose (that tick's e
    with the normal entry 0) and, unless `impedance` is given, the closed form
    from the two bodies' mobilities there; while touching it returns the
    wrenches q_i = K_i D_i (e - e_0) + C_i D_i e' mapped by S to each CoM.
    """

    def __init__(self, ideal: Contact6, passive: Contact6, impedance: Impedance6 | None = None):
        check_frictionless(ideal)
        self.ideal, self.passive, self.impedance = ideal, passive, impedance
        self.anchor: tuple | None = None
        self.touching = False
        self._products: tuple[MatVec6, ...] | None = (
            None  # K_i D_i, C_i D_i as MatVec6, fixed at the first tick in contact
        )

    def wrenches(self, g: InterfaceGeometry, velocity: tuple, spin: Vec3, normal: float = 0.0) -> tuple:
        """(F_1, T_1, F_2, T_2): world forces [N] and torques [N m] about each CoM (tuples), for the
        geometry between the published states and its rates (`published_interface`); `normal` [N]: a
        force on the chaser along the normal (the target gets its opposite) at o_A, a delay
        compensation's (`NormalCompensation6`), which acts touching or not."""
        self.touching = _touching(g.d[0], velocity[0])
        if not self.touching:
            if normal == 0.0:
                return ZERO3, ZERO3, ZERO3, ZERO3
            q = (-normal, 0.0, 0.0, 0.0, 0.0, 0.0)
            return _wall_wrenches(g, q, q)
        rate = g.rate_from(velocity, spin)
        if self.anchor is None:
            self.anchor = (0.0,) + tuple(g.e[1:])
            if self.impedance is None:
                self.impedance = impedance_closed_form6(
                    self.ideal, self.passive, mobility(*g.pose1, g.point, g), mobility(*g.pose2, g.point, g)
                )
                # The closed form makes K_i D_i = K - K_p and C_i D_i = C - C_p: take them as they are
                # (the D_i cancel) rather than as products that carry the inverse's rounding.
                dk = MatVec6(self.ideal.stiffness - self.passive.stiffness)
                dc = MatVec6(self.ideal.damping - self.passive.damping)
                self._products = (dk, dc, dk, dc)
            else:
                imp = self.impedance
                self._products = tuple(
                    MatVec6(a @ d) for a, d in ((imp.k1, imp.d1), (imp.c1, imp.d1), (imp.k2, imp.d2), (imp.c2, imp.d2))
                )
        k1, c1, k2, c2 = cast(tuple[MatVec6, ...], self._products)  # fixed with the anchor
        de = sub6(g.e, self.anchor)
        q1 = add6(k1(de), c1(rate))
        # The closed form gives both bodies the same products.
        q2 = q1 if k2 is k1 and c2 is c1 else add6(k2(de), c2(rate))
        if self.ideal.normal is not None:  # a Hunt-Crossley normal: its force less the passive's normal row
            row = self.ideal.normal_force(de[0], rate[0]) - _normal_row(self.passive, de, rate)
            same = q2 is q1
            q1 = (row,) + tuple(q1[1:])
            q2 = q1 if same else (row,) + tuple(q2[1:])
        if normal != 0.0:  # on the chaser along the normal is -q[0] (W = -S q)
            q1 = (q1[0] - normal,) + tuple(q1[1:])
            q2 = (q2[0] - normal,) + tuple(q2[1:])
        return _wall_wrenches(g, q1, q2)


def _normal_row(model: Contact6, de: Sequence[float], rate: Sequence[float]) -> float:
    """[N] the normal entry of K de + C e' of `model` (the passive compliance's normal force)."""
    k, c = model.stiffness_of.rows[0], model.damping_of.rows[0]
    return sum(a * b for a, b in zip(k, de)) + sum(a * b for a, b in zip(c, rate))


def _wall_wrenches(g: InterfaceGeometry, q1: Sequence[float], q2: Sequence[float]) -> tuple:
    """(F_1, T_1, F_2, T_2) of the generalized forces q1 on the chaser and q2 on the target at o_A."""
    # W = -S q on body 1 and +S q on body 2 at o_A: force R_B q_t, moment R_B J^-T q_r.
    qb, jinv = g.q_b, g.jinv3
    f2 = rotate(qb, q1[:3])
    moment2 = rotate(qb, mat3t_vec(jinv, q1[3:]))
    f1 = (-f2[0], -f2[1], -f2[2])
    t1 = sub3(cross3(g.arm1, f1), moment2)  # the negative of body 1's moment acts on it
    if q2 is not q1:
        f2 = rotate(qb, q2[:3])
        moment2 = rotate(qb, mat3t_vec(jinv, q2[3:]))
    return f1, t1, f2, add3(moment2, cross3(sub3(g.point, g.pose2[1]), f2))


class NormalCompensation6:
    """A delay compensation of dockhil.contact.compensation on the contact's normal (B's x axis): the
    1-DOF loop's tick (dockhil.contact.comploop.ImpedanceStep, the methods unchanged) on the normal
    penetration p = d_x, its rate, the measured force on the chaser along the normal and the robot's
    reported normal pose, as a body of the reduced mass m1 m2 / (m1 + m2) against a fixed wall with the
    normal entries of the virtual impedance (K - K_p, C - C_p) for the energy account and the hold, or,
    for an ideal with a Hunt-Crossley normal (Contact6.normal), with that target as hil.yaml's
    contact:=hunt_crossley has it (no wall; the hold at its local stiffness).
    `force` returns the compensation's force on the chaser along the normal (the target gets its
    opposite); the virtual wall applies it at o_A, so off the axis it makes torques as the contact
    does. The other five axes are left as published: their delays are not compensated."""

    def __init__(
        self,
        ideal: Contact6,
        passive: Contact6,
        settings: Any,
        reduced_mass: float,
        dt: float,
        passivity: Any = None,
        sensor_orientation: Any = IDENTITY,
    ):
        from dockhil.contact.comploop import ImpedanceStep
        from dockhil.contact.hybrid import VirtualImpedance

        k = float(passive.stiffness[0, 0])
        if ideal.normal is not None:  # the target's force less k p acts, no wall (ImpedanceStep's target)
            self.normal = VirtualImpedance(0.0, 0.0, 0.0, 0.0)
        else:
            self.normal = VirtualImpedance(
                float(ideal.stiffness[0, 0]) - k, float(ideal.damping[0, 0] - passive.damping[0, 0]), 0.0, 0.0
            )
        self.mass = reduced_mass
        self.tick = ImpedanceStep(reduced_mass, 0.0, k, self.normal, ideal.normal, settings, dt, passivity)
        self.mount = check_unit_quaternion("sensor_orientation", sensor_orientation)
        self.account: Any = None

    def force(self, g: InterfaceGeometry, velocity: tuple, measured: Vec3, robot: tuple | None, dt: float) -> float:
        """[N] on the chaser along the normal over the next tick. measured: the F/T force on the target
        in the sensor's axes; robot: the robot's reported (normal pose, normal velocity) or None."""
        from dockhil.contact.hilloop import virtual_wrench

        on_target = measured if self.mount == IDENTITY else rotate(self.mount, measured)
        p, pd = g.d[0], velocity[0]
        f1, _f2, self.account = self.tick.step(p, 0.0, pd, 0.0, -on_target[0], robot, dt)
        # ImpedanceStep's force is the normal virtual spring-damper (or the Hunt-Crossley target less k p)
        # plus the compensation: the wall applies the first already.
        return f1 - virtual_wrench(p, 0.0, pd, 0.0, self.mass, 0.0, self.normal)[0] - self.tick.target_force(p, pd)


class PassiveSensor6:
    """The passive compliance (K_p, C_p) between the robots' interfaces and the F/T
    sensor that reads it (the F/T simulation node).

    The sensor sits at `mount_position` [m] with `mount_orientation` in the
    target's interface frame B (default: at B) and reports the wrench on the
    target, force and moment about its origin in its own axes. The compliance's
    non-normal springs rest at the first pose in contact (normal entry 0).
    Friction (mu > 0) is contact6's regularised Coulomb law on A's sliding in B.
    """

    def __init__(self, passive: Contact6, mount_position: object = (0.0, 0.0, 0.0), mount_orientation: Any = IDENTITY):
        self.passive = passive
        self.mount_position = tuple(check_vector("sensor_position", mount_position, unit="m").tolist())
        self.mount_orientation = check_unit_quaternion("sensor_orientation", mount_orientation)
        self.anchor: tuple | None = None
        self.touching = False  # at the last reading
        # At B's origin along B's axes (the default) the frame change is the identity, skipped.
        self._at_b = self.mount_position == ZERO3 and self.mount_orientation == IDENTITY

    def read(self, pose: RelativePose | None) -> tuple[tuple, tuple, tuple]:
        """(force [N], torque [N m]) in the sensor frame and the generalized passive force (tuples),
        all zero when not touching. pose: a RelativePose, or a plain tuple of its four fields."""
        self.touching = False
        if pose is None:
            return ZERO3, ZERO3, ZERO6
        position, orientation, velocity, angular_velocity = pose
        if not _touching(position[0], velocity[0]):
            return ZERO3, ZERO3, ZERO6
        self.touching = True
        theta = rotvec3(orientation)
        jinv = left_jacobian_inverse3(theta)
        e = tuple(position) + theta
        if self.anchor is None:
            self.anchor = (0.0,) + e[1:]
        damping = self.passive.damping_of
        # e' only where a damping reads it (a zero one returns zeros whatever e' is)
        rate = ZERO6 if damping.zero else tuple(velocity) + mat3_vec(jinv, angular_velocity)
        q = add6(self.passive.stiffness_of(sub6(e, self.anchor)), damping(rate))
        # The wrench on the target: +S q at o_A, i.e. in B's axes, moment about B's origin.
        force_b = q[:3]
        if self.passive.mu > 0.0:  # the hardware's friction opposes A sliding on B (contact6's law)
            u1, u2 = velocity[1], velocity[2]
            scale = self.passive.mu * max(q[0], 0.0) / math.sqrt(u1 * u1 + u2 * u2 + self.passive.slip_velocity**2)
            force_b = (force_b[0], force_b[1] + scale * u1, force_b[2] + scale * u2)
        moment_b = add3(mat3t_vec(jinv, q[3:]), cross3(position, force_b))
        if self._at_b:
            return force_b, moment_b, q
        qm = self.mount_orientation
        return (rotate_back(qm, force_b), rotate_back(qm, sub3(moment_b, cross3(self.mount_position, force_b))), q)


def sensor_mount_in_body(
    body2: RigidBody, mount_position: object = (0.0, 0.0, 0.0), mount_orientation: Any = IDENTITY
) -> tuple:
    """The sensor's pose in the target's body frame, from its pose in the interface frame B."""
    p = check_vector("sensor_position", mount_position, unit="m")
    q = check_unit_quaternion("sensor_orientation", mount_orientation)
    position = body2.interface_position + quat_to_matrix(body2.interface_orientation) @ p
    return tuple(position.tolist()), quat_multiply(body2.interface_orientation, q)


def held_wrench(m1: Motion, m2: Motion, mount: tuple, force: Vec3, torque: Vec3, virtual: tuple) -> HeldWrench:
    """The dynamics' wrench for the next tick: the F/T reading (sensor on the target at
    `mount`, body frame) moved to both CoMs, plus the virtual wrenches (about the CoMs)."""
    if force == torque == ZERO3 and virtual == NO_VIRTUAL:  # out of contact: a free flight
        return FREE_FLIGHT
    # The mount is checked by sensor_mount_in_body and the reading is finite floats (a message, or
    # PassiveSensor6): the per-tick path skips the checks, the numbers are the same.
    f2, t2, f1, t1 = sensor_wrench_checked(m2, m1, mount[0], mount[1], force, torque)
    fv1, tv1, fv2, tv2 = virtual
    return HeldWrench(add3(f1, fv1), add3(t1, tv1), add3(f2, fv2), add3(t2, tv2))


class Servo6:
    """The robot's first-order lag on a 6-DOF pose (time constant tau; 0 follows exactly).

    Position and the velocities as the 1-DOF `hilloop.Servo` (exact for a target held
    over the step); the attitude moves the same fraction of the way along the
    geodesic: q <- q exp(alpha log(q^-1 q_target)).
    """

    def __init__(self, tau: float, dt: float):
        self.alpha = 1.0 if tau == 0.0 else -math.expm1(-dt / tau)
        self.pose: RelativePose | None = None

    def step(self, target: RelativePose) -> RelativePose:
        """The pose reached this tick (with no lag, `target` itself); target: a RelativePose, or a
        plain tuple of its four fields."""
        a, p = self.alpha, self.pose
        if p is None or a == 1.0:
            self.pose = target
            return target
        position, orientation, velocity, angular_velocity = target
        turn = rotvec3(quat_multiply(quat_conjugate(p[1]), orientation))
        self.pose = RelativePose(
            _toward(p[0], position, a),
            normalised(quat_multiply(p[1], quat_from_rotvec((a * turn[0], a * turn[1], a * turn[2])))),
            _toward(p[2], velocity, a),
            _toward(p[3], angular_velocity, a),
        )
        return self.pose


def _toward(now: Sequence[float], goal: Sequence[float], a: float) -> tuple:
    """now + a (goal - now), per component."""
    return (now[0] + a * (goal[0] - now[0]), now[1] + a * (goal[1] - now[1]), now[2] + a * (goal[2] - now[2]))


def simulate_hybrid6(
    body1: RigidBody,
    body2: RigidBody,
    state1: BodyState,
    state2: BodyState,
    ideal: Contact6,
    passive: Contact6,
    *,
    dt: float = 1e-3,
    t_end: float = 2.0,
    delay_ticks: int = 0,
    impedance: Impedance6 | None = None,
    order: int = 4,
    lag: float = 0.0,
    sensor_position: object = (0.0, 0.0, 0.0),
    sensor_orientation: Any = IDENTITY,
    compensation: NormalCompensation6 | None = None,
    hardware: Contact6 | None = None,
) -> Run6:
    """The sampled hybrid loop, tick by tick, as the graph runs it.

    Tick k: the dynamics publish both bodies' states and the robot command
    (A's pose and twist in B); the virtual wall computes its wrenches from the
    published states (`VirtualWall6`); the robot follows the command of tick
    k - delay with its lag (`Servo6`); the F/T sensor reads the passive
    compliance at the robot's pose (`PassiveSensor6`, sensor at
    `sensor_position`/`sensor_orientation` in the target's interface frame);
    the dynamics move the reading to both CoMs, add the virtual wrenches
    (`held_wrench`) and hold the sum over the tick (zero-order hold). Contact
    is sensed per tick: penetrating, or at the surface and closing. `force`
    and `torque` record the total wrench on the chaser (torque about its
    interface origin); `generalized` the passive reading's generalized force.

    `compensation`: a delay compensation on the normal, fed each tick with the
    reading and the robot's reported pose (as the virtual-impedance node with
    `compensation:=`); `hardware`: the compliance the sensor truly reads, if not
    `passive` (what the virtual impedance is told).
    """
    dt = check_positive("dt", dt, "s")
    t_end = check_positive("t_end", t_end, "s")
    if int(delay_ticks) != delay_ticks or delay_ticks < 0:
        raise ContactModelError(f"delay_ticks must be a whole number >= 0, got {delay_ticks!r}")
    wall = VirtualWall6(ideal, passive, impedance)
    sensor = PassiveSensor6(passive if hardware is None else hardware, sensor_position, sensor_orientation)
    mount = sensor_mount_in_body(body2, sensor_position, sensor_orientation)
    servo = Servo6(lag, dt)
    m1, m2 = Motion.from_state(body1, state1), Motion.from_state(body2, state2)
    steps = int(math.ceil(t_end / dt - 1e-9))
    rec = Recorder(steps)
    commands: deque = deque([None] * delay_ticks, maxlen=delay_ticks + 1)
    onset = exit_time = None
    for i in range(steps + 1):
        # dynamics -> state, command; virtual impedance on the published state
        g, velocity, spin = published_interface(body1, published_body(m1), body2, published_body(m2))
        # delay injector -> robot -> F/T sensor
        commands.append(RelativePose(g.d, g.q_rel, velocity, spin))
        delayed = commands[0]
        actual = None if delayed is None else servo.step(delayed)
        force_s, torque_s, q_seen = sensor.read(actual)
        # virtual impedance on the published state (with a compensation: and the reading, the robot's pose)
        normal = 0.0
        if compensation is not None:
            robot = None if actual is None else (actual[0][0], actual[2][0])
            normal = compensation.force(g, velocity, force_s, robot, dt)
        virtual = wall.wrenches(g, velocity, spin, normal)
        wrench = held_wrench(m1, m2, mount, force_s, torque_s, virtual)
        if wall.touching and onset is None:
            onset = i * dt
        if not wall.touching and onset is not None and exit_time is None and i * dt > onset:
            exit_time = i * dt
        # Record the state of tick i and the wrench held over the next tick.
        rec.record(i, i * dt, m1, m2, wrench.f1, sub3(wrench.t1, cross3(g.arm1, wrench.f1)), q_seen, 0.0, wall.touching)
        if i < steps:
            rigid.step(m1, m2, wrench, dt, order)
    run = rec.run(onset, exit_time, (m1.state(), m2.state()), None if wall.anchor is None else np.array(wall.anchor))
    run.impedance = wall.impedance
    return run
