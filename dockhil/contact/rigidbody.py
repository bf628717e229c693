"""A rigid body's parameters and state, checked: mass, inertia and its principal frame, where
the centre of mass and the docking interface are (`RigidBody`), a body's state in world
(`BodyState`), and the checks of vectors and symmetric matrices that the 6-DOF parameters share.

Conventions (derivation in docs/sixdof.md):
* A body's own frame is any frame fixed to it. Its parameters say where the
  centre of mass (CoM) and the docking interface are in that frame.
* The state of a body: CoM position and velocity in world [m, m/s], attitude
  of the body frame, angular velocity in the body frame [rad/s].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from dockhil.contact.rotations import IDENTITY, check_unit_quaternion, matrix_to_quat, quat_conjugate, quat_multiply
from dockhil.contact.scenario import ContactModelError, check_positive


def check_vector(name: str, v: object, size: int = 3, unit: str = "") -> np.ndarray:
    arr = np.asarray(v, dtype=float) if is_numeric(v) else None
    if arr is None or arr.shape != (size,) or not np.all(np.isfinite(arr)):
        unit_text = f" [{unit}]" if unit else ""
        raise ContactModelError(f"{name} must be {size} finite numbers{unit_text}, got {v!r}")
    return arr


def is_numeric(v: object) -> bool:
    try:
        np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def check_symmetric(name: str, matrix: object, size: int, definite: bool, unit: str = "") -> np.ndarray:
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
    if TYPE_CHECKING:  # also set in __post_init__, as attributes only: what the per-tick arithmetic reads
        _moments: tuple[float, ...] = field(init=False)  # principal moments
        _q_bp: tuple[float, float, float, float] = field(init=False)  # principal frame in the body frame
        _r_p: tuple[float, ...] = field(init=False)  # CoM -> interface, principal axes
        _q_pi: tuple[float, float, float, float] = field(init=False)  # interface in the principal frame
        _bp_identity: bool = field(init=False)
        _pi_identity: bool = field(init=False)
        _com: tuple[float, ...] = field(init=False)
        _frames: tuple = field(init=False)  # what the compiled interface geometry reads
        _key: tuple = field(init=False)  # equal bodies, one object

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
