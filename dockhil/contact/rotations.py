"""Rotations on plain floats: unit quaternions, rotation matrices and rotation vectors, and
3-vectors as tuples of floats, the per-tick arithmetic of the 6-DOF loop.

Conventions (derivation in docs/sixdof.md): quaternions are scalar-last (x, y, z, w), as
msgs.Quaternion; an attitude quaternion q maps body-frame vectors to world: v_world = q v_body q*.

rotate, rotate_back, quat_multiply and rotvec3 are compiled where built (`COMPILED`), the same
bits as their *_python twins here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from dockhil.compiled import twin
from dockhil.contact.scenario import ContactModelError

Vec3 = Sequence[float] | np.ndarray  # a 3-vector: a tuple, a list or an array
Quat = Sequence[float] | np.ndarray  # a quaternion (x, y, z, w), as a Vec3

UNIT_TOLERANCE = 1e-9  # |q| may differ from 1 by this much in a parameter
IDENTITY = (0.0, 0.0, 0.0, 1.0)


# --- quaternions (x, y, z, w), plain floats -------------------------------------------------


def quat_multiply_python(a: Quat, b: Quat) -> tuple[float, float, float, float]:
    """Hamilton product a b (scalar last); `quat_multiply` is it compiled where built (see `COMPILED`)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def quat_conjugate(q: Quat) -> tuple[float, float, float, float]:
    return (-q[0], -q[1], -q[2], q[3])


def quat_to_matrix(q: Quat) -> np.ndarray:
    """Rotation matrix of a unit quaternion (body -> world)."""
    x, y, z, w = q
    return np.array(
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(r: Sequence[Sequence[float]] | np.ndarray) -> tuple[float, float, float, float]:
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


def quat_from_rotvec(v: Vec3) -> tuple[float, float, float, float]:
    """Quaternion of the rotation by |v| [rad] about v."""
    x, y, z = (float(c) for c in v)
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-8:
        half = 0.5 - angle * angle / 48.0  # sin(a/2)/a
        return normalised((half * x, half * y, half * z, 1.0 - angle * angle / 8.0))
    s = math.sin(0.5 * angle) / angle
    return (s * x, s * y, s * z, math.cos(0.5 * angle))


def quat_to_rotvec(q: Quat) -> np.ndarray:
    """Rotation vector (axis times angle in [0, pi]) of a unit quaternion."""
    return np.array(rotvec3(q))


def rotvec3_python(q: Quat) -> tuple[float, float, float]:
    """`quat_to_rotvec` as a tuple of floats; `rotvec3` is it compiled where built."""
    x, y, z, w = q
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    s = math.sqrt(x * x + y * y + z * z)
    angle = 2.0 * math.atan2(s, w)
    scale = 2.0 / w * (1.0 + s * s / (3.0 * w * w)) if s < 1e-8 else angle / s
    return (scale * x, scale * y, scale * z)


def cross(a: Vec3, b: Vec3) -> np.ndarray:
    """a x b for 3-vectors (np.cross costs ~10x more on vectors this small)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0))


# --- 3-vectors as tuples of floats: the per-tick arithmetic of the sampled loop ----------------
# numpy costs about a microsecond per call on vectors this small; plain floats cost a fraction.


def cross3(a: Vec3, b: Vec3) -> tuple[float, float, float]:
    a0, a1, a2 = a
    b0, b1, b2 = b
    return (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)


def add3(a: Vec3, b: Vec3) -> tuple[float, float, float]:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub3(a: Vec3, b: Vec3) -> tuple[float, float, float]:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def rotate_python(q: Quat, v: Vec3) -> tuple[float, float, float]:
    """R(q) v for a unit quaternion q (x, y, z, w): v + w t + u x t with t = 2 u x v, u = (x, y, z);
    `rotate` is it compiled where built (see `COMPILED`)."""
    x, y, z, w = q
    v0, v1, v2 = v
    t0 = 2.0 * (y * v2 - z * v1)
    t1 = 2.0 * (z * v0 - x * v2)
    t2 = 2.0 * (x * v1 - y * v0)
    return (v0 + w * t0 + y * t2 - z * t1, v1 + w * t1 + z * t0 - x * t2, v2 + w * t2 + x * t1 - y * t0)


def rotate_back_python(q: Quat, v: Vec3) -> tuple[float, float, float]:
    """R(q)^T v (the inverse rotation); `rotate_back` is it compiled where built."""
    x, y, z, w = q
    v0, v1, v2 = v
    t0 = 2.0 * (z * v1 - y * v2)
    t1 = 2.0 * (x * v2 - z * v0)
    t2 = 2.0 * (y * v0 - x * v1)
    return (v0 + w * t0 - y * t2 + z * t1, v1 + w * t1 - z * t0 + x * t2, v2 + w * t2 - x * t1 + y * t0)


def normalised(q: Quat) -> tuple[float, float, float, float]:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def check_unit_quaternion(name: str, q: Any) -> tuple[float, float, float, float]:  # q: anything, checked here
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


# --- compiled twins --------------------------------------------------------------------------

# dockhil/contact/_rigid.c: rotate, rotate_back, quat_multiply, rotvec3 here (and rigid's drift and
# kick, interface6's left_jacobian_inverse3, hybrid6's interface geometry) in C, the same IEEE
# operations in the same order as their *_python twins; None where not built (dockhil.compiled.twin).
COMPILED = twin("dockhil.contact._rigid")
rotate = COMPILED.rotate if COMPILED else rotate_python
rotate_back = COMPILED.rotate_back if COMPILED else rotate_back_python
quat_multiply = COMPILED.quat_multiply if COMPILED else quat_multiply_python
rotvec3 = COMPILED.rotvec3 if COMPILED else rotvec3_python
