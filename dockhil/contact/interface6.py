"""The docking interfaces seen from each other, and wrenches moved between frames: the interface
coordinates of the 6-DOF contact, their rates, and the F/T sensor's wrench at the centres of mass.

Interface coordinates (derivation in docs/sixdof.md). A is the chaser's
interface frame (body 1), B the target's (body 2); the normal axis is B's x
axis, pointing the way the chaser moves when it pushes in, so that, as in the
1-DOF library (p = x1 - x2), the penetration is positive while touching:

    d     = R_B^T (o_A - o_B)                 relative position in B   [m]
    theta = log(R_B^T R_A)                    relative rotation vector  [rad]
    e     = [d, theta],  penetration p = d_x

and their rate

    e' = [R_B^T (v_A - v_B + r x omega_B), J_l(theta)^{-1} R_B^T (omega_A - omega_B)]

with r = o_A - o_B, v_A, v_B the velocities of the two interface origins and
J_l the left Jacobian of SO(3). A generalized force q = [g, tau] on e is the
wrench F = -R_B g, M = -R_B J_l(theta)^{-T} tau on body 1 at o_A.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from dockhil.contact.rigid import Motion
from dockhil.contact.rigidbody import RigidBody, check_vector
from dockhil.contact.rotations import (
    COMPILED,
    IDENTITY,
    Quat,
    Vec3,
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

AXES = ("x", "y", "z", "rx", "ry", "rz")


def skew(v: Vec3) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def left_jacobian_inverse(theta: Vec3) -> np.ndarray:
    """J_l(theta)^{-1} of SO(3): d theta = J_l^{-1} d psi for R -> exp([d psi]x) R."""
    return np.array(left_jacobian_inverse3(theta))


def left_jacobian_inverse3_python(theta: Vec3) -> tuple:
    """`left_jacobian_inverse` as three rows of plain floats (`left_jacobian_inverse3` is it
    compiled where built, rotations.COMPILED):
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


def mat3_vec(a: Sequence[Vec3] | np.ndarray, v: Vec3) -> tuple[float, float, float]:
    """a v for a 3x3 matrix given as rows, plain floats."""
    r0, r1, r2 = a
    v0, v1, v2 = v
    return (
        r0[0] * v0 + r0[1] * v1 + r0[2] * v2,
        r1[0] * v0 + r1[1] * v1 + r1[2] * v2,
        r2[0] * v0 + r2[1] * v1 + r2[2] * v2,
    )


def mat3t_vec(a: Sequence[Vec3] | np.ndarray, v: Vec3) -> tuple[float, float, float]:
    """a^T v for a 3x3 matrix given as rows, plain floats."""
    r0, r1, r2 = a
    v0, v1, v2 = v
    return (
        r0[0] * v0 + r1[0] * v1 + r2[0] * v2,
        r0[1] * v0 + r1[1] * v1 + r2[1] * v2,
        r0[2] * v0 + r1[2] * v1 + r2[2] * v2,
    )


def add6(a: Sequence[float], b: Sequence[float]) -> tuple:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5])


def sub6(a: Sequence[float], b: Sequence[float]) -> tuple:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4], a[5] - b[5])


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
    def between(cls, body1: RigidBody, x1: Vec3, q1: Quat, body2: RigidBody, x2: Vec3, q2: Quat) -> InterfaceGeometry:
        """The geometry of two CoM positions and principal-frame attitudes (no Motion needed)."""
        g = cls.__new__(cls)
        g._place(body1, x1, q1, body2, x2, q2)
        return g

    def _place(self, body1: RigidBody, x1: Vec3, q1: Quat, body2: RigidBody, x2: Vec3, q2: Quat) -> None:
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

    def rate(self, v1: Vec3, w1: Vec3, v2: Vec3, w2: Vec3) -> tuple:
        """e' from CoM velocities and world angular velocities of both bodies."""
        return self.rates(v1, w1, v2, w2)[0]

    def rates(self, v1: Vec3, w1: Vec3, v2: Vec3, w2: Vec3) -> tuple[tuple, tuple]:
        """(e', relative angular velocity R_B^T (w1 - w2) in B axes)."""
        velocity, spin = self.rates3(v1, w1, v2, w2)
        return self.rate_from(velocity, spin), spin

    def rate_from(self, velocity: tuple, spin: Vec3) -> tuple:
        """e' from the two parts `rates3` returns."""
        return velocity + mat3_vec(self.jinv3, spin)

    def rates3(self, v1: Vec3, w1: Vec3, v2: Vec3, w2: Vec3) -> tuple[tuple, tuple]:
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


# --- the F/T sensor's wrench, moved to the centres of mass ---------------------------------


def sensor_wrench_to_bodies(
    carrier: Motion, other: Motion, sensor_position: object, sensor_orientation: Any, force: object, torque: object
) -> tuple[np.ndarray, ...]:
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


def sensor_wrench_checked(
    carrier: Motion, other: Motion, p_s: Vec3, q_s: Quat, f_s: Vec3, t_s: Vec3
) -> tuple[Vec3, Vec3, Vec3, Vec3]:
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


# dockhil/contact/_rigid.c computes it in C, the same bits (rotations.COMPILED).
left_jacobian_inverse3 = COMPILED.left_jacobian_inverse3 if COMPILED else left_jacobian_inverse3_python
