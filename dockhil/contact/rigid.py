"""Two free-floating rigid bodies in six degrees of freedom, and their integrator.

Conventions (derivation in docs/sixdof.md):
* Quaternions are scalar-last (x, y, z, w), as msgs.Quaternion; an attitude
  quaternion q maps body-frame vectors to world: v_world = q v_body q*.
* A body's own frame is any frame fixed to it. Its parameters say where the
  centre of mass (CoM) and the docking interface are in that frame.
* The state of a body: CoM position and velocity in world [m, m/s], attitude
  of the body frame, angular velocity in the body frame [rad/s].

Integrator. Internally each body is carried in its principal frame (CoM,
principal axes of inertia) as (x, v, q_p, L_p), L_p the angular momentum in
principal axes. One step of h is a symmetric composition

    D(h/2) K(h) D(h/2)

D: the free flight. Translation is exact; the rotation of the free rigid body
is split into its three principal-axis parts T = sum L_i^2 / (2 I_i), each
solved exactly (a rotation about axis i by L_i h / I_i, of the body and, the
other way, of L_p), composed 1-2-3-2-1 (McLachlan 1993; Reich 1994;
Dullweber, Leimkuhler and McLachlan 1997). Every part is an exact rotation,
so the spatial angular momentum R L_p is conserved to round-off, the
quaternion stays unit to round-off (renormalised each step), and the energy
error stays bounded (symplectic, no drift).
K: the contact wrench held at fixed poses, by the implicit midpoint rule on
the momenta (exact when the wrench does not depend on velocity). Because the
wrench acts on both bodies at one point, equal and opposite, every kick
conserves total linear and angular momentum exactly; a drift does too.

D K D is symmetric and of order 2; `order=4` composes three of them with
Yoshida's triple-jump weights (symmetric, order 4): the default, since it
brings the torque-free energy error of a 1 kHz run to ~1e-13 and the 6-DOF
contact within 1e-9 of the 1-DOF closed form.

A wrench held over the step (the sampled loop's, `HeldWrench`) is applied as
K(h/2) D(h) K(h/2) instead (`held_step`): as symmetric and of the same order,
with one free flight a composition instead of two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dockhil.compiled import twin
from dockhil.contact.scenario import ContactModelError, StepTooLargeError, check_positive

UNIT_TOLERANCE = 1e-9  # |q| may differ from 1 by this much in a parameter
IDENTITY = (0.0, 0.0, 0.0, 1.0)


# --- quaternions (x, y, z, w), plain floats -------------------------------------------------


def quat_multiply_python(a, b) -> tuple[float, float, float, float]:
    """Hamilton product a b (scalar last); `quat_multiply` is it compiled where built (see `COMPILED`)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def quat_conjugate(q) -> tuple[float, float, float, float]:
    return (-q[0], -q[1], -q[2], q[3])


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (body -> world)."""
    x, y, z, w = q
    return np.array(
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(r) -> tuple[float, float, float, float]:
    """Unit quaternion (w >= 0) of a proper rotation matrix (Shepperd's method)."""
    r = np.asarray(r, float).tolist()  # plain floats: a numpy scalar here would slow every later product with q
    tr = r[0][0] + r[1][1] + r[2][2]
    if tr > max(r[0][0], r[1][1], r[2][2]):
        s = 2.0 * math.sqrt(1.0 + tr)
        q = ((r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s, 0.25 * s)
    elif r[0][0] >= r[1][1] and r[0][0] >= r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[0][0] - r[1][1] - r[2][2])
        q = (0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s, (r[2][1] - r[1][2]) / s)
    elif r[1][1] >= r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[1][1] - r[0][0] - r[2][2])
        q = ((r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s, (r[0][2] - r[2][0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2][2] - r[0][0] - r[1][1])
        q = ((r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s, (r[1][0] - r[0][1]) / s)
    q = normalised(q)
    return q if q[3] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def quat_from_rotvec(v) -> tuple[float, float, float, float]:
    """Quaternion of the rotation by |v| [rad] about v."""
    x, y, z = (float(c) for c in v)
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-8:
        half = 0.5 - angle * angle / 48.0  # sin(a/2)/a
        return normalised((half * x, half * y, half * z, 1.0 - angle * angle / 8.0))
    s = math.sin(0.5 * angle) / angle
    return (s * x, s * y, s * z, math.cos(0.5 * angle))


def quat_to_rotvec(q) -> np.ndarray:
    """Rotation vector (axis times angle in [0, pi]) of a unit quaternion."""
    return np.array(rotvec3(q))


def rotvec3_python(q) -> tuple[float, float, float]:
    """`quat_to_rotvec` as a tuple of floats; `rotvec3` is it compiled where built."""
    x, y, z, w = q
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    s = math.sqrt(x * x + y * y + z * z)
    angle = 2.0 * math.atan2(s, w)
    scale = 2.0 / w * (1.0 + s * s / (3.0 * w * w)) if s < 1e-8 else angle / s
    return (scale * x, scale * y, scale * z)


def cross(a, b) -> np.ndarray:
    """a x b for 3-vectors (np.cross costs ~10x more on vectors this small)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0))


# --- 3-vectors as tuples of floats: the per-tick arithmetic of the sampled loop ----------------
# numpy costs about a microsecond per call on vectors this small; plain floats cost a fraction.


def cross3(a, b) -> tuple[float, float, float]:
    a0, a1, a2 = a
    b0, b1, b2 = b
    return (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)


def add3(a, b) -> tuple[float, float, float]:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub3(a, b) -> tuple[float, float, float]:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def rotate_python(q, v) -> tuple[float, float, float]:
    """R(q) v for a unit quaternion q (x, y, z, w): v + w t + u x t with t = 2 u x v, u = (x, y, z);
    `rotate` is it compiled where built (see `COMPILED`)."""
    x, y, z, w = q
    v0, v1, v2 = v
    t0 = 2.0 * (y * v2 - z * v1)
    t1 = 2.0 * (z * v0 - x * v2)
    t2 = 2.0 * (x * v1 - y * v0)
    return (v0 + w * t0 + y * t2 - z * t1, v1 + w * t1 + z * t0 - x * t2, v2 + w * t2 + x * t1 - y * t0)


def rotate_back_python(q, v) -> tuple[float, float, float]:
    """R(q)^T v (the inverse rotation); `rotate_back` is it compiled where built."""
    x, y, z, w = q
    v0, v1, v2 = v
    t0 = 2.0 * (z * v1 - y * v2)
    t1 = 2.0 * (x * v2 - z * v0)
    t2 = 2.0 * (y * v0 - x * v1)
    return (v0 + w * t0 - y * t2 + z * t1, v1 + w * t1 - z * t0 + x * t2, v2 + w * t2 - x * t1 + y * t0)


def normalised(q) -> tuple[float, float, float, float]:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def check_unit_quaternion(name: str, q) -> tuple[float, float, float, float]:
    """q as a unit quaternion (x, y, z, w), or one clear ContactModelError."""
    try:
        values = tuple(float(c) for c in q)
    except (TypeError, ValueError):
        raise ContactModelError(f"{name} must be a quaternion (x, y, z, w), got {q!r}") from None
    if len(values) != 4 or not all(math.isfinite(c) for c in values):
        raise ContactModelError(f"{name} must be 4 finite numbers (x, y, z, w), got {q!r}")
    norm = math.sqrt(sum(c * c for c in values))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise ContactModelError(
            f"{name} must be a unit quaternion (x, y, z, w), got norm {norm:.12g};"
            f" divide it by its norm or give (0, 0, 0, 1) for no rotation"
        )
    return normalised(values)


def check_vector(name: str, v, size: int = 3, unit: str = "") -> np.ndarray:
    arr = np.asarray(v, dtype=float) if is_numeric(v) else None
    if arr is None or arr.shape != (size,) or not np.all(np.isfinite(arr)):
        unit_text = f" [{unit}]" if unit else ""
        raise ContactModelError(f"{name} must be {size} finite numbers{unit_text}, got {v!r}")
    return arr


def is_numeric(v) -> bool:
    try:
        np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def check_symmetric(name: str, matrix, size: int, definite: bool, unit: str = "") -> np.ndarray:
    """A size x size symmetric matrix, positive definite (definite) or
    semi-definite, or one clear ContactModelError."""
    arr = np.asarray(matrix, dtype=float) if is_numeric(matrix) else None
    if arr is None or arr.shape != (size, size) or not np.all(np.isfinite(arr)):
        shape = None if arr is None else arr.shape
        raise ContactModelError(f"{name} must be a finite {size}x{size} matrix [{unit}], got shape {shape}")
    scale = float(np.max(np.abs(arr))) or 1.0
    asym = float(np.max(np.abs(arr - arr.T)))
    if asym > 1e-12 * scale:
        i, j = np.unravel_index(int(np.argmax(np.abs(arr - arr.T))), arr.shape)
        raise ContactModelError(
            f"{name} must be symmetric: entry [{i}][{j}] = {float(arr[i, j])!r} but [{j}][{i}] = {float(arr[j, i])!r}"
        )
    arr = 0.5 * (arr + arr.T)
    low = float(np.linalg.eigvalsh(arr)[0])
    if definite and low <= 0.0:
        raise ContactModelError(f"{name} must be positive definite: its smallest eigenvalue is {low!r} {unit}")
    if not definite and low < -1e-12 * scale:
        raise ContactModelError(f"{name} must be positive semi-definite: its smallest eigenvalue is {low!r} {unit}")
    return arr


# --- bodies ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class RigidBody:
    """Mass [kg], inertia about the CoM in the body frame [kg m^2] (3x3,
    symmetric positive definite), CoM and docking-interface pose in the body
    frame [m], interface orientation as a unit quaternion (x, y, z, w)."""

    mass: float
    inertia: np.ndarray
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    interface_position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    interface_orientation: tuple = (0.0, 0.0, 0.0, 1.0)
    name: str = "body"
    # Derived in __post_init__: principal moments [kg m^2] and axes (columns, body frame).
    principal_moments: np.ndarray = field(init=False, repr=False)
    principal_axes: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = self.name
        object.__setattr__(self, "mass", check_positive(f"{n}.mass", self.mass, "kg"))
        inertia = check_symmetric(f"{n}.inertia", self.inertia, 3, definite=True, unit="kg m^2")
        moments, axes = np.linalg.eigh(inertia)
        # A rigid body's principal moments obey the triangle inequality (I1 + I2 >= I3).
        if moments[0] + moments[1] < moments[2] * (1.0 - 1e-12):
            raise ContactModelError(
                f"{n}.inertia is not a rigid body's: principal moments {moments.tolist()} break I1 + I2 >= I3"
            )
        if np.linalg.det(axes) < 0.0:
            axes[:, 2] = -axes[:, 2]
        object.__setattr__(self, "inertia", inertia)
        object.__setattr__(self, "com", check_vector(f"{n}.com", self.com, unit="m"))
        object.__setattr__(
            self, "interface_position", check_vector(f"{n}.interface_position", self.interface_position, unit="m")
        )
        q_bi = check_unit_quaternion(f"{n}.interface_orientation", self.interface_orientation)
        object.__setattr__(self, "interface_orientation", q_bi)
        # Principal frame: columns of `axes` are the principal axes in body coordinates.
        q_bp = matrix_to_quat(axes)
        object.__setattr__(self, "principal_moments", moments)
        object.__setattr__(self, "_moments", tuple(float(v) for v in moments))
        object.__setattr__(self, "principal_axes", axes)
        object.__setattr__(self, "_q_bp", q_bp)
        # The interface seen from the CoM, in principal axes.
        object.__setattr__(self, "_r_p", tuple(float(c) for c in axes.T @ (self.interface_position - self.com)))
        object.__setattr__(self, "_q_pi", quat_multiply(quat_conjugate(q_bp), q_bi))
        # Most bodies have principal axes along the body axes and the interface along them: the
        # per-tick frame changes then skip a product by the identity (the same numbers).
        object.__setattr__(self, "_bp_identity", q_bp == IDENTITY)
        object.__setattr__(self, "_pi_identity", self._q_pi == IDENTITY)
        object.__setattr__(self, "_com", tuple(float(c) for c in self.com))
        # What the compiled interface geometry reads (None: the identity, whose product is skipped).
        object.__setattr__(
            self, "_frames", (self._r_p, None if self._pi_identity else self._q_pi, None if self._bp_identity else q_bp)
        )
        # What the per-tick geometry and mobilities read of the body: two bodies with equal keys
        # give them equal numbers (hybrid6.published_interface remembers its last answer by it).
        # Equal keys are one object, so that comparing them is an identity check.
        key = (self.mass, self._moments, self._com, self._r_p, q_bp, self._q_pi)
        object.__setattr__(self, "_key", _BODY_KEYS.setdefault(key, key))

    def interface_offset_body(self) -> np.ndarray:
        """Interface origin relative to the CoM, body frame [m]."""
        return self.interface_position - self.com


_BODY_KEYS: dict = {}  # RigidBody._key by value: one object for equal bodies


@dataclass
class BodyState:
    """CoM position [m] and velocity [m/s] in world, attitude of the body frame
    (unit quaternion x, y, z, w; body -> world), angular velocity in the body frame [rad/s]."""

    position: np.ndarray
    orientation: tuple
    velocity: np.ndarray
    angular_velocity: np.ndarray

    def __post_init__(self) -> None:
        self.position = check_vector("position", self.position, unit="m")
        self.orientation = check_unit_quaternion("orientation", self.orientation)
        self.velocity = check_vector("velocity", self.velocity, unit="m/s")
        self.angular_velocity = check_vector("angular_velocity", self.angular_velocity, unit="rad/s")


class Motion:
    """A body's state in the integrator's variables: principal frame (x, v, q_p, L_p).

    x, v [m, m/s] (world) and L [kg m^2/s] (principal axes) are 3-tuples of floats, q_p a
    4-tuple: the integrator runs on plain floats (see `drift`)."""

    __slots__ = ("body", "x", "v", "q", "L")

    def __init__(self, body: RigidBody, x, v, q, L):
        self.body, self.x, self.v, self.q, self.L = body, x, v, q, L

    @classmethod
    def from_state(cls, body: RigidBody, state: BodyState) -> "Motion":
        q_p = normalised(quat_multiply(state.orientation, body._q_bp))
        omega_p = body.principal_axes.T @ state.angular_velocity
        return cls(
            body, _floats3(state.position), _floats3(state.velocity), q_p, _floats3(body.principal_moments * omega_p)
        )

    def copy(self) -> "Motion":
        return Motion(self.body, self.x, self.v, self.q, self.L)  # tuples: nothing shared can change

    def state(self) -> BodyState:
        b = self.body
        q_b = normalised(quat_multiply(self.q, quat_conjugate(b._q_bp)))
        return BodyState(
            np.array(self.x), q_b, np.array(self.v), b.principal_axes @ (np.array(self.L) / b.principal_moments)
        )

    # World-frame quantities used by contact models.
    def rotation(self) -> np.ndarray:
        return quat_to_matrix(self.q)

    def omega3(self) -> tuple[float, float, float]:
        """Angular velocity in world axes [rad/s], plain floats."""
        i1, i2, i3 = self.body._moments
        l1, l2, l3 = self.L
        return rotate(self.q, (l1 / i1, l2 / i2, l3 / i3))

    def omega_world(self) -> np.ndarray:
        return np.array(self.omega3())

    def interface_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Interface origin [m] and rotation matrix (interface -> world)."""
        return (
            np.array(add3(self.x, rotate(self.q, self.body._r_p))),
            quat_to_matrix(quat_multiply(self.q, self.body._q_pi)),
        )

    def point_velocity(self, point) -> np.ndarray:
        return np.array(add3(self.v, cross3(self.omega3(), sub3(point, self.x))))

    def momentum(self) -> np.ndarray:
        return self.body.mass * np.array(self.v)

    def angular_momentum(self, about=None) -> np.ndarray:
        """World angular momentum [kg m^2/s] about the point `about` (the origin by default)."""
        ref = np.zeros(3) if about is None else np.asarray(about, float)
        return cross(np.array(self.x) - ref, self.momentum()) + self.rotation() @ np.array(self.L)

    def kinetic_energy(self) -> float:
        b = self.body
        v, L, i = self.v, self.L, b._moments
        return 0.5 * b.mass * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + 0.5 * (
            L[0] * L[0] / i[0] + L[1] * L[1] / i[1] + L[2] * L[2] / i[2]
        )


def _floats3(v) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


# --- the free flight: exact translation, rotation split about principal axes ----------------


def drift_python(m: Motion, t: float) -> None:
    """Free flight for t [s]: translation exact, rotation by the symmetric
    1-2-3-2-1 splitting. Each part is the exact flow of T_i = L_i^2 / (2 I_i):
    in body axes L' = L x omega turns L by -phi about axis i while the body
    turns by +phi, phi = L_i t / I_i. The hot loop: unrolled, plain floats, two
    trigonometric calls a part (cos phi, sin phi from the half angle).

    `drift` is it compiled where built (see `COMPILED`)."""
    x, v = m.x, m.v
    m.x = (x[0] + t * v[0], x[1] + t * v[1], x[2] + t * v[2])
    i1, i2, i3 = m.body._moments
    l1, l2, l3 = m.L
    qx, qy, qz, qw = m.q
    half, quarter = 0.5 * t, 0.25 * t  # half angles of the t and t/2 parts, per unit rate
    sin, cos = math.sin, math.cos
    # axis 1 for t/2
    a = l1 / i1 * quarter
    hs, hc = sin(a), cos(a)
    c, s = hc * hc - hs * hs, 2.0 * hs * hc
    l2, l3 = c * l2 + s * l3, c * l3 - s * l2
    qx, qy, qz, qw = qw * hs + qx * hc, qy * hc + qz * hs, qz * hc - qy * hs, qw * hc - qx * hs
    # axis 2 for t/2
    a = l2 / i2 * quarter
    hs, hc = sin(a), cos(a)
    c, s = hc * hc - hs * hs, 2.0 * hs * hc
    l3, l1 = c * l3 + s * l1, c * l1 - s * l3
    qx, qy, qz, qw = qx * hc - qz * hs, qw * hs + qy * hc, qz * hc + qx * hs, qw * hc - qy * hs
    # axis 3 for t
    a = l3 / i3 * half
    hs, hc = sin(a), cos(a)
    c, s = hc * hc - hs * hs, 2.0 * hs * hc
    l1, l2 = c * l1 + s * l2, c * l2 - s * l1
    qx, qy, qz, qw = qx * hc + qy * hs, qy * hc - qx * hs, qw * hs + qz * hc, qw * hc - qz * hs
    # axis 2 for t/2
    a = l2 / i2 * quarter
    hs, hc = sin(a), cos(a)
    c, s = hc * hc - hs * hs, 2.0 * hs * hc
    l3, l1 = c * l3 + s * l1, c * l1 - s * l3
    qx, qy, qz, qw = qx * hc - qz * hs, qw * hs + qy * hc, qz * hc + qx * hs, qw * hc - qy * hs
    # axis 1 for t/2
    a = l1 / i1 * quarter
    hs, hc = sin(a), cos(a)
    c, s = hc * hc - hs * hs, 2.0 * hs * hc
    l2, l3 = c * l2 + s * l3, c * l3 - s * l2
    qx, qy, qz, qw = qw * hs + qx * hc, qy * hc + qz * hs, qz * hc - qy * hs, qw * hc - qx * hs
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    m.q = (qx / n, qy / n, qz / n, qw / n)
    m.L = (l1, l2, l3)


_CBRT2 = 2.0 ** (1.0 / 3.0)
_YOSHIDA = (1.0 / (2.0 - _CBRT2), -_CBRT2 / (2.0 - _CBRT2), 1.0 / (2.0 - _CBRT2))
ORDERS = (2, 4)


def _weights(order: int) -> tuple[float, ...]:
    if order == 2:
        return (1.0,)
    if order == 4:
        return _YOSHIDA
    raise ContactModelError(f"order must be one of {ORDERS}, got {order!r}")


def free_step(m: Motion, h: float, order: int = 4) -> None:
    """One torque-free step of h [s] (the composition with no kick)."""
    for w in _weights(order):
        drift(m, w * h)


class Wrench:
    """What a kick needs from a wrench model. `prepare(m1, m2)` is called once
    per kick (poses are fixed during a kick) and returns the point c [m] where
    the wrench acts and a function of the bodies' world velocities
    (v1, omega1, v2, omega2) giving force F [N] and moment M [N m] (world,
    about c) on body 1; body 2 gets -F, -M at c. `velocity_dependent` says
    whether the implicit midpoint must iterate."""

    velocity_dependent = True

    def prepare(self, m1: "Motion", m2: "Motion"):
        raise NotImplementedError


class HeldWrench(Wrench):
    """A wrench held constant over a step (a sampled loop's zero-order hold):
    forces and torques about each body's CoM fixed in world, 3-tuples of floats. `step`
    applies it as K D K (see there); `zero` says it is all zeros, a free flight."""

    velocity_dependent = False

    def __init__(self, force1, torque1, force2, torque2):
        self.f1, self.t1, self.f2, self.t2 = force1, torque1, force2, torque2
        self.zero = force1 == torque1 == force2 == torque2 == (0.0, 0.0, 0.0)


def _apply(m1: Motion, m2: Motion, w: Wrench, h: float) -> None:
    """Kick both bodies by the wrench for h, poses fixed: implicit midpoint on the momenta."""
    point, wrench_of = w.prepare(m1, m2)
    arm1, arm2 = sub3(point, m1.x), sub3(point, m2.x)
    f, mom = wrench_of(m1.v, m1.omega3(), m2.v, m2.omega3())
    if w.velocity_dependent:
        f, mom = _midpoint_wrench(wrench_of, f, mom, m1, m2, arm1, arm2, h)
    kick(m1, m2, f, add3(mom, cross3(arm1, f)), (-f[0], -f[1], -f[2]), sub3(cross3(f, arm2), mom), h)


def kick_python(m1: Motion, m2: Motion, f1, t1, f2, t2, h: float) -> None:
    """Momenta += h (force, torque) for forces and torques about each CoM (world); `kick` is it
    compiled where built."""
    b1, b2 = m1.body, m2.body
    k1, k2 = h / b1.mass, h / b2.mass
    v, L, tb = m1.v, m1.L, rotate_back(m1.q, t1)
    m1.v = (v[0] + k1 * f1[0], v[1] + k1 * f1[1], v[2] + k1 * f1[2])
    m1.L = (L[0] + h * tb[0], L[1] + h * tb[1], L[2] + h * tb[2])
    v, L, tb = m2.v, m2.L, rotate_back(m2.q, t2)
    m2.v = (v[0] + k2 * f2[0], v[1] + k2 * f2[1], v[2] + k2 * f2[2])
    m2.L = (L[0] + h * tb[0], L[1] + h * tb[1], L[2] + h * tb[2])


def _midpoint_wrench(wrench_of, f, mom, m1, m2, arm1, arm2, h):
    """The wrench at the midpoint momenta of a kick of h: z = Phi(z) for z = (F, M).
    Fixed-point iteration first (contracts when h c / m is small, c the damping);
    Newton with a finite-difference Jacobian when it does not (stiff friction)."""
    half = 0.5 * h
    b1, b2 = m1.body, m2.body
    (i1, i2, i3), (j1, j2, j3) = b1._moments, b2._moments
    q1, q2, v1, v2, L1, L2 = m1.q, m2.q, m1.v, m2.v, m1.L, m2.L
    k1, k2 = half / b1.mass, half / b2.mass

    def phi(z):
        fz, mz = z[:3], z[3:]
        t1 = rotate_back(q1, add3(mz, cross3(arm1, fz)))  # body axes
        t2 = rotate_back(q2, sub3(cross3(fz, arm2), mz))
        omega1 = rotate(q1, ((L1[0] + half * t1[0]) / i1, (L1[1] + half * t1[1]) / i2, (L1[2] + half * t1[2]) / i3))
        omega2 = rotate(q2, ((L2[0] + half * t2[0]) / j1, (L2[1] + half * t2[1]) / j2, (L2[2] + half * t2[2]) / j3))
        g, nm = wrench_of(
            (v1[0] + k1 * fz[0], v1[1] + k1 * fz[1], v1[2] + k1 * fz[2]),
            omega1,
            (v2[0] - k2 * fz[0], v2[1] - k2 * fz[1], v2[2] - k2 * fz[2]),
            omega2,
        )
        return tuple(g) + tuple(nm)

    z = tuple(f) + tuple(mom)
    for _ in range(12):
        nz = phi(z)
        change = max(abs(a - b) for a, b in zip(nz, z))
        z = nz
        if change <= 4e-16 * max(max(abs(c) for c in z), 1e-300):
            return z[:3], z[3:]
    z = np.array(z)
    previous = math.inf
    for _ in range(40):
        pz = np.array(phi(tuple(z.tolist())))
        res = z - pz
        scale = max(float(np.max(np.abs(z))), 1e-300)
        size = float(np.max(np.abs(res)))
        # Converged: at round-off, or no longer shrinking once well below the solution's size.
        if size <= 64.0 * np.finfo(float).eps * scale or (size <= 1e-12 * scale and size >= previous):
            z = tuple(z.tolist())
            return z[:3], z[3:]
        previous = size
        jac = np.eye(6)
        for k in range(6):
            dz = 1e-7 * max(abs(z[k]), scale * 1e-3)
            zk = z.copy()
            zk[k] += dz
            jac[:, k] -= (np.array(phi(tuple(zk.tolist()))) - pz) / dz
        try:
            z = z - np.linalg.solve(jac, res)
        except np.linalg.LinAlgError:
            break
    raise StepTooLargeError(
        f"the contact's damping or friction is too stiff for a step of {h:.6g} s (the implicit"
        " midpoint does not converge); use a smaller dt or a larger slip_velocity"
    )


def step(m1: Motion, m2: Motion, wrench: Wrench | None, h: float, order: int = 4) -> None:
    """Advance both bodies by h [s] under `wrench` (None: free flight), in place: D K D, and K D K
    for a HeldWrench (`held_step`)."""
    if type(wrench) is HeldWrench:
        held_step(m1, m2, wrench, h, order)
        return
    for w in _weights(order):
        hw = w * h
        half = 0.5 * hw
        drift(m1, half)
        drift(m2, half)
        if wrench is not None:
            _apply(m1, m2, wrench, hw)
        drift(m1, half)
        drift(m2, half)


def total_momentum(m1: Motion, m2: Motion) -> np.ndarray:
    return m1.momentum() + m2.momentum()


def total_angular_momentum(m1: Motion, m2: Motion, about=None) -> np.ndarray:
    return m1.angular_momentum(about) + m2.angular_momentum(about)


def held_step(m1: Motion, m2: Motion, w: HeldWrench, h: float, order: int = 4) -> None:
    """Advance both bodies by h [s] under a wrench held over the step: K(h/2) D(h) K(h/2).

    Symmetric and of order 2 as D K D, and the same map for the translation (exact either way
    under a constant force); the world angular momentum gains h T exactly in both. A held wrench
    depends on no pose or velocity, so its kicks need no midpoint solve and cost two rotations,
    while a free flight costs ten sin/cos and over a hundred products: K D K flies each body once a
    composition where D K D flies it twice. Between the compositions of order 4 two half kicks
    meet and are one. A zero wrench is a free flight."""
    if w.zero:
        for c in _weights(order):
            drift(m1, c * h)
            drift(m2, c * h)
        return
    f1, t1, f2, t2 = w.f1, w.t1, w.f2, w.t2
    carried = 0.0
    for c in _weights(order):
        hw = c * h
        kick(m1, m2, f1, t1, f2, t2, carried + 0.5 * hw)
        drift(m1, hw)
        drift(m2, hw)
        carried = 0.5 * hw
    kick(m1, m2, f1, t1, f2, t2, carried)


# --- compiled twins --------------------------------------------------------------------------

# dockhil/contact/_rigid.c: drift, kick, rotate, rotate_back, quat_multiply, rotvec3 (and contact6's
# left_jacobian_inverse3, hybrid6's interface geometry) in C, the same IEEE operations in the same
# order as their *_python twins here; None where not built (dockhil.compiled.twin).
COMPILED = twin("dockhil.contact._rigid")
drift = COMPILED.drift if COMPILED else drift_python
kick = COMPILED.kick if COMPILED else kick_python
rotate = COMPILED.rotate if COMPILED else rotate_python
rotate_back = COMPILED.rotate_back if COMPILED else rotate_back_python
quat_multiply = COMPILED.quat_multiply if COMPILED else quat_multiply_python
rotvec3 = COMPILED.rotvec3 if COMPILED else rotvec3_python
