"""Parameters of a 1-DOF two-body docking contact, their checks, and the
errors and warnings the contact model raises.

Conventions used across `dockhil.contact` (SI units everywhere):
x1, v1 are the chaser's contact surface position [m] and velocity [m/s];
x2, v2 the target's. Penetration p = x1 - x2: the bodies touch while p > 0.
"Contact force" F is the compressive force [N]: it pushes the chaser by -F
and the target by +F.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING

from dockhil.errors import DockhilError

if TYPE_CHECKING:
    import numpy as np


class ContactModelError(DockhilError):
    """An input the contact model refuses; the message names the argument."""


class FitError(ContactModelError):
    """The two-time impedance fit (Eqs. 5-6) cannot be solved reliably."""


class StepTooLargeError(ContactModelError):
    """An explicit integrator was asked for a step outside its stability region."""


class NegativeVirtualStiffnessWarning(UserWarning):
    """kcs < k: the virtual springs must be negative to soften the hardware."""


class UnstableStepWarning(RuntimeWarning):
    """A step outside the method's stability region was taken because the caller asked to."""


def check_finite(name: str, value: float, unit: str = "") -> float:
    """`value` as a float, or a ContactModelError naming `name` if it is not a finite number."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ContactModelError(f"{name} must be a number{_unit(unit)}, got {value!r}") from None
    if not math.isfinite(number):
        raise ContactModelError(f"{name} must be a finite number{_unit(unit)}, got {number!r}")
    return number


def check_positive(name: str, value: float, unit: str = "") -> float:
    number = check_finite(name, value, unit)
    if number <= 0.0:
        raise ContactModelError(f"{name} must be > 0{_after(unit)}, got {number!r}")
    return number


def check_nonnegative(name: str, value: float, unit: str = "") -> float:
    number = check_finite(name, value, unit)
    if number < 0.0:
        raise ContactModelError(f"{name} must be >= 0{_after(unit)}, got {number!r}")
    return number


def _unit(unit: str) -> str:
    return f" [{unit}]" if unit else ""


def _after(unit: str) -> str:
    return f" {unit}" if unit else ""


@dataclass(frozen=True)
class ContactScenario:
    """One docking contact: the ideal spring-dashpot (Eq. 1), the passive
    compliance k of the hardware, and the initial velocities.

    m1, m2: chaser and target masses [kg]; kcs [N/m], bcs [N s/m]: ideal
    contact stiffness and damping; k [N/m]: passive compliance on the robot;
    v1, v2: velocities before contact [m/s] (the chaser closes in when v1 > v2).
    """

    m1: float
    m2: float
    kcs: float
    bcs: float
    k: float = 0.0
    v1: float = 0.0
    v2: float = 0.0

    def __post_init__(self) -> None:
        checks = {
            "m1": (check_positive, "kg"),
            "m2": (check_positive, "kg"),
            "kcs": (check_nonnegative, "N/m"),
            "bcs": (check_nonnegative, "N s/m"),
            "k": (check_nonnegative, "N/m"),
            "v1": (check_finite, "m/s"),
            "v2": (check_finite, "m/s"),
        }
        for name, (check, unit) in checks.items():
            object.__setattr__(self, name, check(name, getattr(self, name), unit))
        if self.kcs == 0.0 and self.bcs == 0.0:
            raise ContactModelError("kcs and bcs are both 0: the ideal contact has no force")

    @property
    def total_mass(self) -> float:
        return self.m1 + self.m2

    @property
    def reduced_mass(self) -> float:
        """m = m1 m2 / (m1 + m2) [kg] (Eq. 8): the mass of the relative motion."""
        return self.m1 * self.m2 / (self.m1 + self.m2)

    @property
    def com_velocity(self) -> float:
        """V_CoM [m/s] (Eq. 4)."""
        return (self.m1 * self.v1 + self.m2 * self.v2) / (self.m1 + self.m2)

    @property
    def closing_velocity(self) -> float:
        """v1 - v2 [m/s]: the penetration rate at contact onset."""
        return self.v1 - self.v2

    @property
    def natural_frequency(self) -> float:
        """sqrt(kcs / m) [rad/s] of the ideal contact."""
        return math.sqrt(self.kcs / self.reduced_mass)

    @property
    def damping_ratio(self) -> float:
        """bcs / (2 sqrt(kcs m)); infinite for a pure damper (kcs = 0)."""
        if self.kcs == 0.0:
            return math.inf
        return self.bcs / (2.0 * math.sqrt(self.kcs * self.reduced_mass))

    def replace(self, **changes: float) -> ContactScenario:
        return replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


# The paper's Table 1 (ideal model column, and the measured metal-sheet k).
TABLE1 = ContactScenario(m1=750.0, m2=1.0e6, kcs=3000.0, bcs=40.0, k=1000.0, v1=0.03, v2=0.0)

# Table 1's hybrid column as printed (k2 is rounded there to 2668700).
TABLE1_PRINTED_IMPEDANCE = {"k1": 2001.5, "b1": 40.03, "k2": 2668700.0, "b2": 53373.0}


@dataclass(frozen=True)
class Trajectory:
    """Sampled states of a two-body contact run (numpy arrays of one length).

    force is the compressive contact force on the chaser [N] (0 out of
    contact); onset and exit are the start and end times [s] of the first
    contact, None when the run does not reach them.
    """

    t: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    v1: np.ndarray
    v2: np.ndarray
    force: np.ndarray
    in_contact: np.ndarray
    onset: float | None
    exit: float | None
    method: str

    @classmethod
    def from_states(
        cls,
        t: np.ndarray,
        states: np.ndarray,
        force: np.ndarray,
        in_contact: np.ndarray,
        onset: float | None,
        exit: float | None,
        method: str,
    ) -> Trajectory:
        """From rows of states [x1, x2, v1, v2]."""
        return cls(t, states[:, 0], states[:, 1], states[:, 2], states[:, 3], force, in_contact, onset, exit, method)

    @property
    def penetration(self):
        return self.x1 - self.x2

    @property
    def penetration_rate(self):
        return self.v1 - self.v2
