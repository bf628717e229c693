"""Virtual impedance determination (Sec. 3.3): k1, b1, k2, b2 such that the
hybrid model (passive k + virtual impedance) moves like the ideal contact.

Two ways that must agree:

* the closed form, from the CoM frame (relative motion of Eqs. 2-3):
      k1 = (kcs - k)(1 + m1/m2)    b1 = bcs (1 + m1/m2)
      k2 = (kcs - k)(1 + m2/m1)    b2 = bcs (1 + m2/m1)
* the paper's two-time fit (Eqs. 5-6): take the ideal model's states at two
  times t1, t2 inside the contact and solve, for each body, the 2x2 system
      [-(x1 - w)  -(x1' - w')] [k1 b1]^T = m1 x1'' + k (x1 - x2)
      [-(x2 - w)  -(x2' - w')] [k2 b2]^T = m2 x2'' - k (x1 - x2)
  at t = t1, t2, with w the CoM position (= V_CoM t from the contact point).
  These are the paper's Eqs. 5-6 with their sign slips fixed (Eq. 6's
  "-x2' - V_CoM", Eq. 3's wall term) and with the passive compliance k on
  the right-hand side where the paper prints kcs, bcs: the hybrid model's
  hardware part is the passive spring k, not the ideal contact.

Neither depends on the initial velocities: the fit rows are proportional to
(p, p') and the right-hand sides to (kcs - k) p + bcs p', both scaled by the
closing velocity, which cancels.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.ideal import contact_duration, ideal_trajectory, modes
from dockhil.contact.integrators import METHODS, Integrator, LinearSecondOrderSystem, simulate_reference
from dockhil.contact.scenario import (
    ContactModelError,
    ContactScenario,
    FitError,
    NegativeVirtualStiffnessWarning,
    check_finite,
    check_positive,
)

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

STATE_SOURCES = ("exact", "closed_form", "rk4", "symplectic_euler", "euler", "solve_ivp")
# The fit's matrices are compared after scaling the position column by the
# contact's natural frequency (so both columns are velocities). Above this
# condition number the solution loses more than 6 of 16 digits: refuse.
DEFAULT_MAX_CONDITION = 1e6


def impedance_closed_form(scenario: ContactScenario, warn: bool = True) -> VirtualImpedance:
    """k1, b1, k2, b2 from the CoM-frame closed form (no fit, no simulation).
    Warns (NegativeVirtualStiffnessWarning) when kcs < k, unless warn=False."""
    scn = scenario
    message = negative_stiffness_message(scn) if warn else None
    if message is not None:
        warnings.warn(message, NegativeVirtualStiffnessWarning, stacklevel=2)
    chaser_factor = 1.0 + scn.m1 / scn.m2
    target_factor = 1.0 + scn.m2 / scn.m1
    return VirtualImpedance(
        k1=(scn.kcs - scn.k) * chaser_factor,
        b1=scn.bcs * chaser_factor,
        k2=(scn.kcs - scn.k) * target_factor,
        b2=scn.bcs * target_factor,
    )


def negative_stiffness_message(scenario: ContactScenario) -> str | None:
    """The warning text when kcs < k (virtual springs must be negative), else None."""
    if scenario.kcs >= scenario.k:
        return None
    return (
        f"kcs = {scenario.kcs:g} N/m is below the passive stiffness k = {scenario.k:g} N/m:"
        " the virtual stiffnesses k1, k2 come out negative, so the software must soften the"
        " hardware; a negative virtual spring behind the robot's delay can destabilize the loop"
        " (check 'dockhil stability'), or use a softer passive compliance (k <= kcs)"
    )


def _deepest_penetration_time(scenario: ContactScenario) -> float:
    """Time [s] after onset at which p' = 0 (inf for a pure damper)."""
    mo = modes(scenario.reduced_mass, scenario.kcs, scenario.bcs)
    if mo.underdamped:
        return math.atan2(mo.omega_d, mo.sigma) / mo.omega_d
    if mo.mu == 0.0:
        return 1.0 / mo.sigma
    fast = mo.sigma + mo.mu
    if 2.0 * mo.mu >= fast:  # kcs = 0: the slow root is 0, p never peaks
        return math.inf
    return -math.log1p(-2.0 * mo.mu / fast) / (2.0 * mo.mu)


def _fit_window(scenario: ContactScenario) -> tuple[float, float, float]:
    """(recommended t1, t2, contact duration) for the fit."""
    m = scenario.reduced_mass
    duration = contact_duration(m, scenario.kcs, scenario.bcs)
    if math.isfinite(duration) and scenario.damping_ratio < 0.5:
        # A quarter period apart: the rows (omega p, p') are then nearly orthogonal.
        return 0.25 * duration, 0.75 * duration, duration
    # Heavier damping: the motion dies out long before p returns to zero (if
    # ever), so use half the time of deepest penetration and that time itself,
    # where p' = 0 and the row isolates the stiffness that damping would swamp.
    t_ref = _deepest_penetration_time(scenario)
    if not math.isfinite(t_ref):  # pure damper: its time constant
        t_ref = scenario.reduced_mass / scenario.bcs
    return 0.5 * t_ref, t_ref, duration


def recommended_fit_times(scenario: ContactScenario) -> tuple[float, float]:
    """Two well-separated times [s] after onset inside the contact: T/4 and 3T/4
    of the contact duration T when the damping ratio is below 0.5; otherwise
    half the time of deepest penetration and that time itself."""
    t1, t2, _ = _fit_window(scenario)
    return t1, t2


@dataclass(frozen=True)
class IdealStates:
    """The ideal model's two-body states at some times after contact onset."""

    t: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    v1: np.ndarray
    v2: np.ndarray
    a1: np.ndarray
    a2: np.ndarray
    source: str


def ideal_states(scenario: ContactScenario, times: ArrayLike, source: str = "exact", dt: float = 1e-3) -> IdealStates:
    """States of the ideal model (contact from t = 0 at the origin) at `times`.

    source: "exact" (simulated with the exact step), "closed_form", a fixed-step
    method ("rk4", "symplectic_euler", "euler", step dt) or "solve_ivp".
    """
    times = np.atleast_1d(np.asarray(times, dtype=float))
    contact = LinearSecondOrderSystem.ideal_contact(scenario)
    if source == "closed_form":
        tr = ideal_trajectory(scenario, times)
        x1, x2, v1, v2 = tr.x1, tr.x2, tr.v1, tr.v2
    elif source == "solve_ivp":
        order = np.argsort(times)
        tr = simulate_reference(scenario, times[order])
        x1, x2, v1, v2 = (np.empty_like(times) for _ in range(4))
        x1[order], x2[order], v1[order], v2[order] = tr.x1, tr.x2, tr.v1, tr.v2
    elif source in METHODS:
        dt = check_positive("dt", dt, "s")
        # Contact mode throughout: the fit times lie inside the contact.
        integ = Integrator(contact, source)
        out = np.empty((times.size, 4))
        for j, t_target in enumerate(times):
            x = np.array([0.0, 0.0, scenario.v1, scenario.v2])
            steps, rest = divmod(t_target, dt) if source != "exact" else (0, t_target)
            for _ in range(int(steps)):
                x = integ.step(x, None, dt)
            if rest > 0.0:
                x = integ.step(x, None, rest) if source == "exact" else integ.step_uncached(x, np.zeros(2), rest)
            out[j] = x
        x1, x2, v1, v2 = out.T
    else:
        raise ContactModelError(f"unknown state source {source!r}; choose one of {', '.join(STATE_SOURCES)}")
    acc = np.array([contact.accelerations((a, b), (c, d)) for a, b, c, d in zip(x1, x2, v1, v2)])
    return IdealStates(times, x1, x2, v1, v2, acc[:, 0], acc[:, 1], source)


@dataclass(frozen=True)
class ImpedanceFit:
    """Result of the two-time fit, with what it was compared against."""

    impedance: VirtualImpedance
    closed_form: VirtualImpedance
    t1: float
    t2: float
    contact_duration: float
    states: str
    condition_chaser: float
    condition_target: float
    max_relative_deviation: float
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @property
    def agrees(self) -> bool:
        """Fit and closed form agree to 1e-6 (relative)."""
        return self.max_relative_deviation < 1e-6


def _solve_rows(rows: np.ndarray, rhs: np.ndarray, omega: float) -> tuple[np.ndarray, float]:
    scaled = rows * np.array([omega, 1.0])
    cond = float(np.linalg.cond(scaled))
    try:
        sol = np.linalg.solve(scaled, rhs) * np.array([omega, 1.0])
    except np.linalg.LinAlgError:  # exactly singular: refused by the caller
        return np.full(2, np.nan), math.inf
    return sol, cond if math.isfinite(cond) else math.inf


def _relative_deviation(fit: VirtualImpedance, ref: VirtualImpedance, scenario: ContactScenario) -> float:
    scn = scenario
    # Where the closed form is 0 (kcs == k) compare with the size of kcs instead.
    scales = {
        "k1": max(abs(ref.k1), scn.kcs * (1 + scn.m1 / scn.m2), 1e-300),
        "b1": max(abs(ref.b1), 1e-300),
        "k2": max(abs(ref.k2), scn.kcs * (1 + scn.m2 / scn.m1), 1e-300),
        "b2": max(abs(ref.b2), 1e-300),
    }
    worst = 0.0
    for name, scale in scales.items():
        a, b = getattr(fit, name), getattr(ref, name)
        worst = max(worst, abs(a - b) / scale if scale > 1e-300 else abs(a - b))
    return worst


def fit_impedance(
    scenario: ContactScenario,
    t1: float | None = None,
    t2: float | None = None,
    *,
    states: str = "exact",
    dt: float = 1e-3,
    max_condition: float = DEFAULT_MAX_CONDITION,
) -> ImpedanceFit:
    """The two-time fit of Eqs. 5-6 (signs corrected) on the ideal model's states.

    t1, t2: times [s] after contact onset, strictly inside the contact;
    default `recommended_fit_times` (T/4 and 3T/4 of the contact duration T
    for light damping). states: where the ideal states come from (see
    `ideal_states`). Refuses (FitError) equal times, times outside the
    contact or after it has died out, and ill-conditioned pairs, saying which
    times to choose. Warns (NegativeVirtualStiffnessWarning) when kcs < k.
    """
    scn = scenario
    if scn.closing_velocity <= 0.0:
        raise ContactModelError(
            f"no contact to fit: the chaser does not close in (v1 - v2 = {scn.closing_velocity!r} m/s,"
            " needs > 0); the result does not depend on the velocities, so any v1 > v2 will do"
        )
    rec1, rec2, duration = _fit_window(scn)
    where = f"inside the contact (0, {duration:.6g}) s" if math.isfinite(duration) else "after onset"
    spacing = ", about a quarter period apart" if scn.damping_ratio < 0.5 else ""
    advice = f"choose two distinct times {where}{spacing}, e.g. t1 = {rec1:.4g} s and t2 = {rec2:.4g} s"
    t1 = rec1 if t1 is None else check_finite("t1", t1, "s")
    t2 = rec2 if t2 is None else check_finite("t2", t2, "s")
    for name, t in (("t1", t1), ("t2", t2)):
        if not 0.0 < t < duration:
            raise FitError(
                f"{name} = {t:.10g} s is outside the contact (0, {duration:.6g}) s, where the ideal"
                f" model exerts no contact force to match; {advice}"
            )
    if t1 == t2:
        raise FitError(f"t1 = t2 = {t1:.10g} s gives two identical rows of Eqs. 5-6 (singular); {advice}")

    st = ideal_states(scn, [t1, t2], states, dt)
    omega = scn.natural_frequency if scn.kcs > 0.0 else scn.bcs / scn.reduced_mass
    activity = np.hypot(omega * (st.x1 - st.x2), st.v1 - st.v2) / scn.closing_velocity
    for name, t, level in (("t1", t1, activity[0]), ("t2", t2, activity[1])):
        # Below this the states are round-off around the CoM motion, not contact.
        if not level > 1e-7:
            raise FitError(
                f"at {name} = {t:.10g} s the contact motion has decayed to {level:.2g} of its"
                f" initial size, too little to fit; {advice}"
            )
    total = scn.total_mass
    # Offsets from the wall w = (m1 x1 + m2 x2) / M through the exact identities
    # x1 - w = (m2/M) p and x2 - w = -(m1/M) p: subtracting w itself would cancel
    # away the heavy body's tiny offset (about 1e-6 p for Table 1's target).
    p, p_rate = st.x1 - st.x2, st.v1 - st.v2
    passive = scn.k * p
    chaser, cond1 = _solve_rows(
        np.column_stack([-(scn.m2 / total) * p, -(scn.m2 / total) * p_rate]), scn.m1 * st.a1 + passive, omega
    )
    target, cond2 = _solve_rows(
        np.column_stack([(scn.m1 / total) * p, (scn.m1 / total) * p_rate]), scn.m2 * st.a2 - passive, omega
    )
    worst = max(cond1, cond2)
    if worst > max_condition:
        raise FitError(
            f"t1 = {t1:.10g} s and t2 = {t2:.10g} s give an ill-conditioned fit (condition number"
            f" {worst:.3g} > {max_condition:.3g}): the two states are nearly proportional; {advice}"
        )
    fitted = VirtualImpedance(k1=chaser[0], b1=chaser[1], k2=target[0], b2=target[1])
    closed = impedance_closed_form(scn, warn=False)
    notes = []
    message = negative_stiffness_message(scn)
    if message is not None:
        warnings.warn(message, NegativeVirtualStiffnessWarning, stacklevel=2)
        notes.append(message)
    return ImpedanceFit(
        impedance=fitted,
        closed_form=closed,
        t1=t1,
        t2=t2,
        contact_duration=duration,
        states=states,
        condition_chaser=cond1,
        condition_target=cond2,
        max_relative_deviation=_relative_deviation(fitted, closed, scn),
        warnings=tuple(notes),
    )
