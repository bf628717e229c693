"""The ideal 1-DOF spring-dashpot contact of Eq. 1, with unilateral contact.

During contact the penetration p = x1 - x2 obeys
    m p'' + bcs p' + kcs p = 0,   m = m1 m2 / (m1 + m2),
which has a closed form from onset (p = 0, p' = v1 - v2).

Unilateral contact: the force acts while p > 0 and the contact ends when p
returns to 0. The force stays the linear kcs p + bcs p' throughout, so it
pulls slightly (bcs p' < 0) just before separation. We keep that pull on
purpose: it is what Eq. 1 integrates, so the closed form, the exit velocity
and the hybrid model fitted to it (Eqs. 5-6) all describe the same motion.
Clipping the force at zero would end the contact earlier than Eq. 1 says and
make every comparison with the paper model-dependent.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from dockhil.contact.scenario import ContactModelError, ContactScenario, Trajectory

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


def ideal_contact_force(
    penetration: float | np.ndarray, penetration_rate: float | np.ndarray, kcs: float, bcs: float
) -> float | np.ndarray:
    """Compressive contact force [N] of Eq. 1: kcs p + bcs p' while p > 0, else 0.

    Scalars give a float (cheap enough to call every step); arrays give an array.
    """
    if np.ndim(penetration) == 0 and np.ndim(penetration_rate) == 0:
        if penetration <= 0.0:
            return 0.0
        return kcs * float(penetration) + bcs * float(penetration_rate)
    p = np.asarray(penetration, dtype=float)
    return np.where(p > 0.0, kcs * p + bcs * np.asarray(penetration_rate, dtype=float), 0.0)


@dataclass(frozen=True)
class _Modes:
    """Decay and frequency of m p'' + bcs p' + kcs p = 0."""

    sigma: float  # bcs / (2 m) [1/s]
    omega_d: float  # damped frequency [rad/s], 0 unless underdamped
    mu: float  # sqrt(sigma^2 - kcs/m) [1/s], 0 unless overdamped

    @property
    def underdamped(self) -> bool:
        return self.omega_d > 0.0


def modes(m: float, kcs: float, bcs: float) -> _Modes:
    sigma = bcs / (2.0 * m)
    disc = kcs / m - sigma * sigma
    if disc > 0.0:
        return _Modes(sigma, math.sqrt(disc), 0.0)
    return _Modes(sigma, 0.0, math.sqrt(-disc))


def relative_motion(
    m: float, kcs: float, bcs: float, closing_velocity: float, t: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form penetration p(t) [m] and rate p'(t) [m/s] from contact onset
    (p(0) = 0, p'(0) = closing_velocity), valid while the contact lasts."""
    t = np.asarray(t, dtype=float)
    v0 = closing_velocity
    mo = modes(m, kcs, bcs)
    if mo.underdamped:
        decay = np.exp(-mo.sigma * t)
        s = np.sin(mo.omega_d * t) / mo.omega_d
        return v0 * decay * s, v0 * decay * (np.cos(mo.omega_d * t) - mo.sigma * s)
    # Written with expm1 around the slow root r1 so that it neither cancels
    # near critical damping nor overflows for long times.
    r1 = -mo.sigma + mo.mu
    r2 = -mo.sigma - mo.mu
    g = -np.expm1(-2.0 * mo.mu * t) / (2.0 * mo.mu) if mo.mu > 0.0 else t
    decay = np.exp(r1 * t)
    return v0 * decay * g, v0 * decay * (1.0 + r2 * g)


def contact_duration(m: float, kcs: float, bcs: float) -> float:
    """Time [s] from onset until the penetration returns to zero: pi / omega_d,
    or inf when the contact is critically or over-damped (p never returns)."""
    mo = modes(m, kcs, bcs)
    return math.pi / mo.omega_d if mo.underdamped else math.inf


def _force_stationary_time(m: float, kcs: float, bcs: float) -> float | None:
    """The time in the contact where dF/dt = 0 (F = kcs p + bcs p'), if any.

    dF/dt = kcs p' + bcs p'' = a p' - c p with a = kcs - bcs^2/m, c = bcs kcs/m.
    """
    a = kcs - bcs * bcs / m
    c = bcs * kcs / m
    mo = modes(m, kcs, bcs)
    if mo.underdamped:
        # a cos(wt) - (a sigma + c) sin(wt) / w = 0
        phase = math.atan2(a * mo.omega_d, a * mo.sigma + c) % math.pi
        return phase / mo.omega_d if phase > 0.0 else None
    # With p ~ e^{r1 t} g(t): a (1 + r2 g) - c g = 0, g increasing from 0 to 1/(2 mu).
    r2 = -mo.sigma - mo.mu
    denom = c - a * r2
    if denom == 0.0:
        return None
    g_star = a / denom
    if g_star <= 0.0:
        return None
    if mo.mu == 0.0:
        return g_star
    if 2.0 * mo.mu * g_star >= 1.0:
        return None
    return -math.log1p(-2.0 * mo.mu * g_star) / (2.0 * mo.mu)


@dataclass(frozen=True)
class ContactSummary:
    """What the ideal model predicts for one contact (closed form).

    peak_force [N] at time_of_peak [s] after onset; duration [s] (inf when the
    contact is not underdamped); exit velocities [m/s] after separation (the
    common CoM velocity when the bodies never separate); restitution =
    -exit relative velocity / closing velocity.
    """

    peak_force: float
    time_of_peak: float
    duration: float
    exit_v1: float
    exit_v2: float
    exit_relative_velocity: float
    restitution: float
    closing_velocity: float
    regime: str

    def as_dict(self) -> dict[str, float | str | None]:
        # JSON has no infinity: an endless contact is reported as None.
        return {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in asdict(self).items()}


def ideal_contact_summary(scenario: ContactScenario) -> ContactSummary:
    """Peak force, contact duration and exit velocities of the ideal model (closed form)."""
    scn = scenario
    v0 = scn.closing_velocity
    if v0 <= 0.0:
        raise ContactModelError(f"no contact: the chaser does not close in (v1 - v2 = {v0!r} m/s, needs > 0)")
    m = scn.reduced_mass
    mo = modes(m, scn.kcs, scn.bcs)
    duration = contact_duration(m, scn.kcs, scn.bcs)
    candidates = [0.0]
    t_star = _force_stationary_time(m, scn.kcs, scn.bcs)
    if t_star is not None and t_star < duration:
        candidates.append(t_star)
    p, pd = relative_motion(m, scn.kcs, scn.bcs, v0, np.array(candidates))
    forces = scn.kcs * p + scn.bcs * pd
    best = int(np.argmax(forces))
    if mo.underdamped:
        exit_rel = -v0 * math.exp(-mo.sigma * duration)
        regime = "underdamped"
    else:
        exit_rel = 0.0
        regime = "critically damped" if mo.mu == 0.0 else "overdamped"
    vcom = scn.com_velocity
    total = scn.total_mass
    return ContactSummary(
        peak_force=float(forces[best]),
        time_of_peak=float(candidates[best]),
        duration=duration,
        exit_v1=vcom + scn.m2 / total * exit_rel,
        exit_v2=vcom - scn.m1 / total * exit_rel,
        exit_relative_velocity=exit_rel,
        restitution=-exit_rel / v0,
        closing_velocity=v0,
        regime=regime,
    )


def ideal_trajectory(scenario: ContactScenario, t: ArrayLike, gap: float = 0.0) -> Trajectory:
    """Closed-form unilateral motion of the ideal model at times t [s]:
    approach at constant velocities, contact (Eq. 1), separation.

    At t = 0 the target's surface is at x2 = 0 and the chaser's at x1 = -gap,
    so with gap = 0 the contact starts at t = 0 at the origin (the frame of
    Eqs. 2-6, positions measured from the contact point).
    """
    scn = scenario
    gap = float(gap)
    if not math.isfinite(gap) or gap < 0.0:
        raise ContactModelError(f"gap must be a finite distance >= 0 m, got {gap!r}")
    t = np.asarray(t, dtype=float)
    v0 = scn.closing_velocity
    m = scn.reduced_mass
    total = scn.total_mass
    x_com = -scn.m1 * gap / total + scn.com_velocity * t
    p = -gap + v0 * t
    pd = np.full_like(t, v0)
    in_contact = np.zeros(t.shape, dtype=bool)
    onset = exit_time = None
    if v0 > 0.0:
        onset = gap / v0
        duration = contact_duration(m, scn.kcs, scn.bcs)
        exit_time = onset + duration if math.isfinite(duration) else None
        during = (t >= onset) & (t < onset + duration)
        pc, pdc = relative_motion(m, scn.kcs, scn.bcs, v0, t[during] - onset)
        p[during], pd[during] = pc, pdc
        in_contact = during & (p > 0.0)
        in_contact[during & (t == onset)] = True  # the onset instant is in contact (F = bcs v0)
        if exit_time is not None:
            after = t >= exit_time
            exit_rel = relative_motion(m, scn.kcs, scn.bcs, v0, duration)[1]
            p[after] = exit_rel * (t[after] - exit_time)
            pd[after] = exit_rel
    force = np.where(in_contact, scn.kcs * p + scn.bcs * pd, 0.0)
    v_com = scn.com_velocity
    return Trajectory(
        t=t,
        x1=x_com + scn.m2 / total * p,
        x2=x_com - scn.m1 / total * p,
        v1=v_com + scn.m2 / total * pd,
        v2=v_com - scn.m1 / total * pd,
        force=force,
        in_contact=in_contact,
        onset=onset,
        exit=exit_time,
        method="closed_form",
    )
