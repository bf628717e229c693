"""The ideal 6-DOF contact: a spring-dashpot between the two docking-interface
frames, unilateral on the normal axis, with optional regularised Coulomb
friction; interface wrenches from an F/T sensor; and the contact run.

Interface coordinates (derivation in docs/sixdof.md). A is the chaser's
interface frame (body 1), B the target's (body 2); the normal axis is B's x
axis, pointing the way the chaser moves when it pushes in, so that, as in the
1-DOF library (p = x1 - x2), the penetration is positive while touching:

    d     = R_B^T (o_A - o_B)                 relative position in B   [m]
    theta = log(R_B^T R_A)                    relative rotation vector  [rad]
    e     = [d, theta],  penetration p = d_x

The potential V = 1/2 e^T K e and the dissipation 1/2 e'^T C e' give, by
virtual work, the wrench on body 1 at the point o_A (body 2 gets its negative
at the same point, so momenta are conserved whatever K, C and friction are):

    g   = K_t e + C_t e'        (first three rows of K e + C e')
    tau = K_r e + C_r e'        (last three rows)
    F   = -R_B g,   M = -R_B J_l(theta)^{-T} tau

with e' = [R_B^T (v_A - v_B + r x omega_B), J_l(theta)^{-1} R_B^T (omega_A - omega_B)],
r = o_A - o_B, v_A, v_B the velocities of the two interface origins and
J_l the left Jacobian of SO(3). Along one axis this is the 1-DOF Eq. 1:
compressive force kcs p + bcs p'.

Unilateral: the whole spring-dashpot acts while the bodies touch (p > 0, or
p = 0 and closing) and vanishes when p returns to 0. The springs of the five
non-normal axes rest at the relative pose of first touch (e_0, with d_x = 0):
V = 1/2 (e - e_0)^T K (e - e_0), so a contact starts without a jump in force
or energy however far off-axis it is. The pull of the dashpot
just before separation is kept, as in the 1-DOF library. The potential stored
in the non-normal springs at separation is released with the contact (the
interface lets go), so energy is conserved through a whole contact when only
the normal axis is stiff; with full K it is conserved while touching.

Friction (optional): on the tangential sliding velocity u = (e'_y, e'_z),
    f_t = -mu max(g_x, 0) u / sqrt(|u|^2 + v_s^2)      (in B, on body 1, at o_A)
a Coulomb law regularised below the sliding speed v_s [m/s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dockhil.contact import rigid, rigidbody
from dockhil.contact.rigid import Motion, Wrench
from dockhil.contact.rigidbody import BodyState, RigidBody, check_symmetric, check_vector
from dockhil.contact.rotations import (
    IDENTITY,
    add3,
    check_unit_quaternion,
    cross3,
    quat_conjugate,
    quat_multiply,
    quat_to_matrix,
    rotate,
    rotate_back,
    rotvec3,
    sub3,
)
from dockhil.contact.scenario import ContactModelError, check_nonnegative, check_positive

AXES = ("x", "y", "z", "rx", "ry", "rz")


def skew(v) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def left_jacobian_inverse(theta) -> np.ndarray:
    """J_l(theta)^{-1} of SO(3): d theta = J_l^{-1} d psi for R -> exp([d psi]x) R."""
    return np.array(left_jacobian_inverse3(theta))


def left_jacobian_inverse3_python(theta) -> tuple:
    """`left_jacobian_inverse` as three rows of plain floats (`left_jacobian_inverse3` is it
    compiled where built, rigid.COMPILED):
    1 - [theta]x / 2 + c [theta]x^2, and [theta]x^2 = theta theta^T - |theta|^2 1."""
    x, y, z = theta
    sq = x * x + y * y + z * z
    angle = math.sqrt(sq)
    if angle < 1e-5:
        c = 1.0 / 12.0 + sq / 720.0
    else:
        c = 1.0 / sq - (1.0 + math.cos(angle)) / (2.0 * angle * math.sin(angle))
    hx, hy, hz = 0.5 * x, 0.5 * y, 0.5 * z
    cxy, cxz, cyz = c * x * y, c * x * z, c * y * z
    return (
        (1.0 + c * (x * x - sq), hz + cxy, cxz - hy),
        (cxy - hz, 1.0 + c * (y * y - sq), hx + cyz),
        (hy + cxz, cyz - hx, 1.0 + c * (z * z - sq)),
    )


def mat3_vec(a, v) -> tuple[float, float, float]:
    """a v for a 3x3 matrix given as rows, plain floats."""
    r0, r1, r2 = a
    v0, v1, v2 = v
    return (
        r0[0] * v0 + r0[1] * v1 + r0[2] * v2,
        r1[0] * v0 + r1[1] * v1 + r1[2] * v2,
        r2[0] * v0 + r2[1] * v1 + r2[2] * v2,
    )


def mat3t_vec(a, v) -> tuple[float, float, float]:
    """a^T v for a 3x3 matrix given as rows, plain floats."""
    r0, r1, r2 = a
    v0, v1, v2 = v
    return (
        r0[0] * v0 + r1[0] * v1 + r2[0] * v2,
        r0[1] * v0 + r1[1] * v1 + r2[1] * v2,
        r0[2] * v0 + r1[2] * v1 + r2[2] * v2,
    )


def add6(a, b) -> tuple:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5])


def sub6(a, b) -> tuple:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4], a[5] - b[5])


class MatVec6:
    """v -> A v for a fixed 6x6 matrix A on plain floats (the per-tick products of the
    contact matrices). A diagonal A costs six products; a zero one, none."""

    __slots__ = ("rows", "diagonal", "zero")

    def __init__(self, a):
        a = np.asarray(a, float)
        self.rows = tuple(tuple(float(c) for c in row) for row in a)
        off = a - np.diag(np.diag(a))
        self.diagonal = tuple(float(c) for c in np.diag(a)) if not off.any() else None
        self.zero = not a.any()

    def __call__(self, v) -> tuple:
        if self.zero:
            return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        v0, v1, v2, v3, v4, v5 = v
        if self.diagonal is not None:
            d = self.diagonal
            return (d[0] * v0, d[1] * v1, d[2] * v2, d[3] * v3, d[4] * v4, d[5] * v5)
        r0, r1, r2, r3, r4, r5 = self.rows
        return (
            r0[0] * v0 + r0[1] * v1 + r0[2] * v2 + r0[3] * v3 + r0[4] * v4 + r0[5] * v5,
            r1[0] * v0 + r1[1] * v1 + r1[2] * v2 + r1[3] * v3 + r1[4] * v4 + r1[5] * v5,
            r2[0] * v0 + r2[1] * v1 + r2[2] * v2 + r2[3] * v3 + r2[4] * v4 + r2[5] * v5,
            r3[0] * v0 + r3[1] * v1 + r3[2] * v2 + r3[3] * v3 + r3[4] * v4 + r3[5] * v5,
            r4[0] * v0 + r4[1] * v1 + r4[2] * v2 + r4[3] * v3 + r4[4] * v4 + r4[5] * v5,
            r5[0] * v0 + r5[1] * v1 + r5[2] * v2 + r5[3] * v3 + r5[4] * v4 + r5[5] * v5,
        )


def check_matrix6(name: str, value, unit: str) -> np.ndarray:
    """A 6x6 symmetric PSD matrix; a 6-vector means its diagonal."""
    arr = np.asarray(value, dtype=float) if rigidbody.is_numeric(value) else None
    if arr is not None and arr.shape == (6,):
        if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
            raise ContactModelError(f"{name} diagonal must be 6 finite numbers >= 0 [{unit}], got {arr.tolist()}")
        return np.diag(arr)
    return check_symmetric(name, value, 6, definite=False, unit=unit)


@dataclass(frozen=True)
class Contact6:
    """Spring-dashpot between the interfaces: stiffness [N/m, N/rad, coupled]
    and damping (6x6 symmetric PSD, or a 6-vector for the diagonal, axes
    x y z rx ry rz of the target's interface frame); friction coefficient mu
    and its regularising sliding speed [m/s]."""

    stiffness: np.ndarray
    damping: np.ndarray = field(default_factory=lambda: np.zeros(6))
    mu: float = 0.0
    slip_velocity: float = 1e-3

    def __post_init__(self) -> None:
        object.__setattr__(self, "stiffness", check_matrix6("stiffness", self.stiffness, "N/m, N m/rad"))
        object.__setattr__(self, "damping", check_matrix6("damping", self.damping, "N s/m, N m s/rad"))
        object.__setattr__(self, "mu", check_nonnegative("mu", self.mu))
        object.__setattr__(self, "slip_velocity", check_positive("slip_velocity", self.slip_velocity, "m/s"))
        # The per-tick products K v and C v on plain floats.
        object.__setattr__(self, "stiffness_of", MatVec6(self.stiffness))
        object.__setattr__(self, "damping_of", MatVec6(self.damping))

    @property
    def dissipative(self) -> bool:
        return bool(np.any(self.damping != 0.0) or self.mu > 0.0)


class InterfaceGeometry:
    """The pose-dependent part of the interface coordinates: e = [d, theta],
    the wrench point o_A, R_B, J_l(theta)^{-1}, and the lever arms."""

    # Tuples of plain floats (the per-tick path); rot_b and jinv as matrices for analysis.
    # theta, jinv3 and e are computed on first use (__getattr__): the robot command needs only
    # d and the relative attitude, and the trigonometry of theta is a large part of a tick.
    # pose1, pose2: (body, CoM position, principal-frame attitude) the geometry is between.
    __slots__ = ("d", "point", "q_b", "r", "arm1", "arm2", "q_rel", "pose1", "pose2", "theta", "jinv3", "e")

    def __init__(self, m1: Motion, m2: Motion):
        self._place(m1.body, m1.x, m1.q, m2.body, m2.x, m2.q)

    @classmethod
    def between(cls, body1: RigidBody, x1, q1, body2: RigidBody, x2, q2) -> "InterfaceGeometry":
        """The geometry of two CoM positions and principal-frame attitudes (no Motion needed)."""
        g = cls.__new__(cls)
        g._place(body1, x1, q1, body2, x2, q2)
        return g

    def _place(self, body1, x1, q1, body2, x2, q2) -> None:
        self.pose1, self.pose2 = (body1, x1, q1), (body2, x2, q2)
        self.arm1 = arm1 = rotate(q1, body1._r_p)  # CoM -> o_A, world
        self.arm2 = arm2 = rotate(q2, body2._r_p)  # CoM -> o_B
        self.point = o_a = (x1[0] + arm1[0], x1[1] + arm1[1], x1[2] + arm1[2])
        self.r = r = (o_a[0] - x2[0] - arm2[0], o_a[1] - x2[1] - arm2[1], o_a[2] - x2[2] - arm2[2])  # o_A - o_B
        q_a = q1 if body1._pi_identity else quat_multiply(q1, body1._q_pi)
        q_b = q2 if body2._pi_identity else quat_multiply(q2, body2._q_pi)
        self.q_b = q_b  # B -> world
        self.q_rel = quat_multiply(quat_conjugate(q_b), q_a)  # A's attitude in B
        self.d = rotate_back(q_b, r)  # o_A - o_B in B's axes: e[:3]

    def __getattr__(self, name):
        # Only for the slots not yet set: theta, jinv3, e (the same numbers, computed once, when asked).
        if name not in ("theta", "jinv3", "e"):
            raise AttributeError(name)
        self.theta = theta = rotvec3(self.q_rel)
        self.jinv3 = left_jacobian_inverse3(theta)
        self.e = self.d + theta
        return getattr(self, name)

    @property
    def rot_b(self) -> np.ndarray:
        """R_B (B -> world)."""
        return quat_to_matrix(self.q_b)

    @property
    def jinv(self) -> np.ndarray:
        return np.array(self.jinv3)

    def rate(self, v1, w1, v2, w2) -> tuple:
        """e' from CoM velocities and world angular velocities of both bodies."""
        return self.rates(v1, w1, v2, w2)[0]

    def rates(self, v1, w1, v2, w2) -> tuple[tuple, tuple]:
        """(e', relative angular velocity R_B^T (w1 - w2) in B axes)."""
        velocity, spin = self.rates3(v1, w1, v2, w2)
        return self.rate_from(velocity, spin), spin

    def rate_from(self, velocity, spin) -> tuple:
        """e' from the two parts `rates3` returns."""
        return velocity + mat3_vec(self.jinv3, spin)

    def rates3(self, v1, w1, v2, w2) -> tuple[tuple, tuple]:
        """(d' = e'[:3], relative angular velocity R_B^T (w1 - w2) in B axes): the robot command's
        rates, without J_l(theta)^{-1}."""
        # v_A - v_B + r x w2, with v_A = v1 + w1 x arm1 and v_B = v2 + w2 x arm2 (written out: the hot path)
        a, b, r = self.arm1, self.arm2, self.r
        p0, p1, p2 = w1
        s0, s1, s2 = w2
        u = (
            v1[0] + p1 * a[2] - p2 * a[1] - v2[0] - s1 * b[2] + s2 * b[1] + r[1] * s2 - r[2] * s1,
            v1[1] + p2 * a[0] - p0 * a[2] - v2[1] - s2 * b[0] + s0 * b[2] + r[2] * s0 - r[0] * s2,
            v1[2] + p0 * a[1] - p1 * a[0] - v2[2] - s0 * b[1] + s1 * b[0] + r[0] * s1 - r[1] * s0,
        )
        q_b = self.q_b
        return rotate_back(q_b, u), rotate_back(q_b, (p0 - s0, p1 - s1, p2 - s2))

    @property
    def penetration(self) -> float:
        return float(self.e[0])


def interface_state(m1: Motion, m2: Motion) -> tuple[InterfaceGeometry, tuple]:
    """(geometry, e') of the chaser's interface A in the target's B."""
    g = InterfaceGeometry(m1, m2)
    return g, g.rate(m1.v, m1.omega3(), m2.v, m2.omega3())


def generalized_to_wrench(g: InterfaceGeometry, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Force and moment (world, about o_A) on body 1 of the generalized force q = dV/de (+ C e')."""
    return -(g.rot_b @ q[:3]), -(g.rot_b @ (g.jinv.T @ q[3:]))


def contact_wrench(model: Contact6, g: InterfaceGeometry, rate, anchor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F, M, generalized force) on body 1 at o_A while touching; the springs
    pull toward `anchor` (the onset pose, normal axis 0)."""
    return tuple(np.array(v) for v in contact_wrench3(model, g, rate, anchor))


def contact_wrench3(model: Contact6, g: InterfaceGeometry, rate, anchor) -> tuple[tuple, tuple, tuple]:
    """`contact_wrench` on plain floats (the integrator's kicks): F = -R_B q_t, M = -R_B J^-T q_r."""
    q = add6(model.stiffness_of(sub6(g.e, anchor)), model.damping_of(rate))
    fx, fy, fz = rotate(g.q_b, q[:3])
    if model.mu > 0.0:  # regularised Coulomb friction on A's sliding (u = e'_y, e'_z), in B's axes
        u1, u2 = rate[1], rate[2]
        scale = model.mu * max(q[0], 0.0) / math.sqrt(u1 * u1 + u2 * u2 + model.slip_velocity**2)
        tx, ty, tz = rotate(g.q_b, (0.0, scale * u1, scale * u2))
        fx, fy, fz = fx + tx, fy + ty, fz + tz
    mx, my, mz = rotate(g.q_b, mat3t_vec(g.jinv3, q[3:]))
    return (-fx, -fy, -fz), (-mx, -my, -mz), q


class IdealContactWrench(Wrench):
    """The ideal contact as the integrator's wrench, active while `touching`."""

    def __init__(self, model: Contact6):
        self.model = model
        self.velocity_dependent = model.dissipative
        self.touching = False
        self.anchor = (0.0,) * 6

    def start(self, m1: Motion, m2: Motion) -> None:
        """Contact onset: the tangential and rotational springs rest at the pose of first touch."""
        self.touching = True
        self.anchor = (0.0,) + InterfaceGeometry(m1, m2).e[1:]

    def prepare(self, m1: Motion, m2: Motion):
        g = InterfaceGeometry(m1, m2)
        if not self.touching:
            zero = (0.0, 0.0, 0.0)
            return g.point, lambda v1, w1, v2, w2: (zero, zero)
        model, anchor = self.model, self.anchor

        def wrench_of(v1, w1, v2, w2):
            force, moment, _ = contact_wrench3(model, g, g.rate(v1, w1, v2, w2), anchor)
            return force, moment

        return g.point, wrench_of


def touching_at(m1: Motion, m2: Motion) -> bool:
    """Penetrating, or at the surface and closing in (as the 1-DOF library)."""
    g, rate = interface_state(m1, m2)
    return g.e[0] > 0.0 or (g.e[0] == 0.0 and rate[0] > 0.0)


# --- the F/T sensor's wrench, moved to the centres of mass ---------------------------------


def sensor_wrench_to_bodies(carrier: Motion, other: Motion, sensor_position, sensor_orientation, force, torque):
    """Forces and torques [N, N m] (world, about each CoM) on the body carrying
    the sensor and on the other body.

    The sensor sits on `carrier` at `sensor_position` [m] with
    `sensor_orientation` (x, y, z, w) in the carrier's body frame; it reports
    `force` and `torque` (about its origin, in its own axes) that the other
    body exerts on the carrier. The other body gets the opposite wrench at
    the same point: (F_c, T_c, F_o, T_o) with F_o = -F_c and equal and
    opposite moments about the sensor origin.
    """
    p_s = check_vector("sensor_position", sensor_position, unit="m")
    q_s = check_unit_quaternion("sensor_orientation", sensor_orientation)
    f_s = check_vector("force", force, unit="N")
    t_s = check_vector("torque", torque, unit="N m")
    return tuple(np.array(w) for w in sensor_wrench_checked(carrier, other, p_s, q_s, f_s, t_s))


def sensor_wrench_checked(carrier: Motion, other: Motion, p_s, q_s, f_s, t_s):
    """`sensor_wrench_to_bodies` for values already checked (3-vectors, a unit quaternion),
    as tuples of floats: the per-tick path of a sampled loop, whose mounting pose is checked once."""
    b = carrier.body
    # A product by the identity (principal axes along the body's, a sensor along the body axes)
    # changes no value: it is skipped (it may only turn a -0.0 into 0.0).
    q_body = carrier.q if b._bp_identity else quat_multiply(carrier.q, quat_conjugate(b._q_bp))  # body -> world
    q_sw = q_body if q_s == IDENTITY else quat_multiply(q_body, q_s)  # sensor -> world
    lever = rotate(q_body, sub3(p_s, b._com))  # CoM -> sensor origin
    f = rotate(q_sw, f_s)
    m = rotate(q_sw, t_s)
    t_c = add3(m, cross3(lever, f))
    t_o = sub3(cross3(sub3(other.x, add3(carrier.x, lever)), f), m)  # -m - (origin - x_o) x f
    return f, t_c, (-f[0], -f[1], -f[2]), t_o


# --- the contact run ------------------------------------------------------------------------


@dataclass
class Run6:
    """Samples of a two-body 6-DOF run at t = n dt.

    positions, velocities [m, m/s] (n, 2, 3) of the CoMs in world;
    orientations (n, 2, 4) of the body frames; omegas (n, 2, 3) in world [rad/s];
    force (n, 3) [N] on the chaser in world and torque (n, 3) [N m] on the chaser
    about its interface origin; e, rate (n, 6) interface coordinates;
    momentum (n, 3), angular_momentum (n, 3) about the world origin; energy (n,)
    kinetic + contact potential [J]; in_contact (n,); onset, exit [s] or None;
    generalized (n, 6): the contact's generalized force K (e - anchor) + C e'
    (its first entry is the compressive normal force); anchor: the spring
    rest pose of the (last) contact.
    """

    t: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    orientations: np.ndarray
    omegas: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    e: np.ndarray
    rate: np.ndarray
    momentum: np.ndarray
    angular_momentum: np.ndarray
    energy: np.ndarray
    in_contact: np.ndarray
    onset: float | None
    exit: float | None
    final: tuple
    generalized: np.ndarray | None = None
    anchor: np.ndarray | None = None
    impedance: object = None  # the hybrid loop's Impedance6

    @property
    def normal_force(self) -> np.ndarray:
        """Compressive force [N] along the target interface's normal (the 1-DOF 'force')."""
        return self.generalized[:, 0]

    def peak(self, what: str) -> float:
        return float(np.max(np.linalg.norm(getattr(self, what), axis=1)))


class Recorder:
    """Collects the samples of a run."""

    def __init__(self, steps: int):
        n = steps + 1
        self.t = np.empty(n)
        self.pos = np.empty((n, 2, 3))
        self.vel = np.empty((n, 2, 3))
        self.quat = np.empty((n, 2, 4))
        self.omega = np.empty((n, 2, 3))
        self.force = np.zeros((n, 3))
        self.torque = np.zeros((n, 3))
        self.e = np.empty((n, 6))
        self.rate = np.empty((n, 6))
        self.p = np.empty((n, 3))
        self.l = np.empty((n, 3))
        self.energy = np.empty(n)
        self.flag = np.zeros(n, dtype=bool)
        self.q = np.zeros((n, 6))

    def record(
        self, i: int, t: float, m1: Motion, m2: Motion, force, torque, q, potential: float, touching: bool
    ) -> None:
        g, rate = interface_state(m1, m2)
        self.t[i] = t
        for j, m in enumerate((m1, m2)):
            st = m.state()
            self.pos[i, j] = st.position
            self.vel[i, j] = st.velocity
            self.quat[i, j] = st.orientation
            self.omega[i, j] = m.omega_world()
        self.force[i], self.torque[i], self.q[i] = force, torque, q
        self.e[i], self.rate[i] = g.e, rate
        self.p[i] = rigid.total_momentum(m1, m2)
        self.l[i] = rigid.total_angular_momentum(m1, m2)
        self.energy[i] = m1.kinetic_energy() + m2.kinetic_energy() + potential
        self.flag[i] = touching

    def run(self, onset, exit_time, final, anchor, n: int | None = None) -> Run6:
        """The run of the first n samples (all by default)."""
        k = slice(None, n)
        return Run6(
            self.t[k],
            self.pos[k],
            self.vel[k],
            self.quat[k],
            self.omega[k],
            self.force[k],
            self.torque[k],
            self.e[k],
            self.rate[k],
            self.p[k],
            self.l[k],
            self.energy[k],
            self.flag[k],
            onset,
            exit_time,
            final,
            self.q[k],
            anchor,
        )


def _step_with_events(m1: Motion, m2: Motion, wrench: IdealContactWrench, h: float, order: int) -> list:
    """One step of h with contact onset/separation located inside it (bisection on the
    step map, as the 1-DOF library): returns [(time into the step, touching after)].
    A contact that starts and ends within one step is not seen."""
    events = []
    done = 0.0
    remaining = h
    for _ in range(16):
        start = (m1.copy(), m2.copy())
        rigid.step(m1, m2, wrench, remaining, order)
        if touching_at(m1, m2) == wrench.touching:
            return events
        lo, hi = 0.0, remaining
        while hi - lo > 4.0 * np.finfo(float).eps * max(1.0, hi):
            mid = 0.5 * (lo + hi)
            a, b = start[0].copy(), start[1].copy()
            rigid.step(a, b, wrench, mid, order)
            if touching_at(a, b) == wrench.touching:
                lo = mid
            else:
                hi = mid
        a, b = start
        rigid.step(a, b, wrench, hi, order)
        _assign(m1, a)
        _assign(m2, b)
        done += hi
        remaining -= hi
        if wrench.touching:
            wrench.touching = False
        else:
            wrench.start(m1, m2)
        events.append((done, wrench.touching))
        if remaining <= 0.0:
            return events
    raise ContactModelError(f"more than 16 contact events within one step of {h:.6g} s (chatter); use a smaller dt")


def _assign(dst: Motion, src: Motion) -> None:
    dst.x, dst.v, dst.q, dst.L = src.x, src.v, src.q, src.L


def potential_energy(model: Contact6, g: InterfaceGeometry, anchor, touching: bool) -> float:
    """1/2 (e - anchor)^T K (e - anchor) [J] while touching."""
    de = np.array(g.e) - anchor
    return 0.5 * float(de @ model.stiffness @ de) if touching else 0.0


def simulate_contact6(
    body1: RigidBody,
    body2: RigidBody,
    state1: BodyState,
    state2: BodyState,
    model: Contact6,
    *,
    dt: float = 1e-3,
    t_end: float = 2.0,
    order: int = 4,
    substeps: int = 1,
    until_exit: bool = False,
) -> Run6:
    """Fixed-step run of the ideal 6-DOF contact from the given states, samples
    every dt [s]; each sample interval is `substeps` integrator steps. With
    `until_exit` the run ends at the first sample after the contact ended (what
    follows is free flight), so its length is the contact's, not t_end's."""
    dt = check_positive("dt", dt, "s")
    t_end = check_positive("t_end", t_end, "s")
    if int(substeps) != substeps or substeps < 1:
        raise ContactModelError(f"substeps must be a whole number >= 1, got {substeps!r}")
    m1, m2 = Motion.from_state(body1, state1), Motion.from_state(body2, state2)
    wrench = IdealContactWrench(model)
    if touching_at(m1, m2):
        wrench.start(m1, m2)
    steps = int(math.ceil(t_end / dt - 1e-9))
    rec = Recorder(steps)
    onset = 0.0 if wrench.touching else None
    exit_time = None
    h = dt / substeps

    def sample(i):
        g, rate = interface_state(m1, m2)
        if wrench.touching:
            force, moment, q = contact_wrench(model, g, rate, wrench.anchor)
        else:
            force, moment, q = np.zeros(3), np.zeros(3), np.zeros(6)
        rec.record(
            i,
            i * dt,
            m1,
            m2,
            force,
            moment,
            q,
            potential_energy(model, g, wrench.anchor, wrench.touching),
            wrench.touching,
        )

    sample(0)
    for i in range(steps):
        for j in range(substeps):
            for offset, now in _step_with_events(m1, m2, wrench, h, order):
                t_event = i * dt + j * h + offset
                if now and onset is None:
                    onset = t_event
                elif not now and exit_time is None and onset is not None:
                    exit_time = t_event
        sample(i + 1)
        if until_exit and exit_time is not None:
            return rec.run(onset, exit_time, (m1.state(), m2.state()), np.array(wrench.anchor), n=i + 2)
    return rec.run(onset, exit_time, (m1.state(), m2.state()), np.array(wrench.anchor))


left_jacobian_inverse3 = rigid.COMPILED.left_jacobian_inverse3 if rigid.COMPILED else left_jacobian_inverse3_python
