"""Target contacts the HIL loop reproduces: the linear spring-dashpot of Eq. 1 and the nonlinear
Hunt-Crossley contact (Hunt and Crossley, J. Appl. Mech. 1975; Marhefka and Orin, IEEE T-SMC 1999)

    F = kcs p^n (1 + alpha p')      (p > 0: penetration [m], p' its rate; compressive F [N])

and the ideal contact of either, integrated on the relative coordinate.

Hunt-Crossley's restitution does not depend on kcs, n or the mass: along the contact
m v dv / dp = -kcs p^n (1 + alpha v), so m v dv / (1 + alpha v) = -kcs p^n dp, and the same
potential kcs p^(n+1) / (n+1) is reached coming in at v0 and leaving at -e v0:

    alpha v0 - ln(1 + alpha v0) = -alpha e v0 - ln(1 - alpha e v0)

(the left side is the work of the approach, the right side that of the rebound, both over
m / alpha^2). `restitution` solves it for e, `alpha_for_restitution` for alpha. Unlike the linear
contact, F vanishes with p at both ends (no jump at impact, no pull before separation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dockhil.contact.scenario import ContactModelError

CONTACTS = ("linear", "hunt_crossley")


@dataclass(frozen=True)
class TargetContact:
    """The contact to reproduce: kind 'linear' (F = kcs p + bcs p') or 'hunt_crossley'
    (F = kcs p^n (1 + alpha p'), kcs in N/m^n, alpha in s/m); compressive, 0 while apart."""

    kind: str
    kcs: float
    bcs: float = 0.0
    n: float = 1.5
    alpha: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in CONTACTS:
            raise ContactModelError(f"contact must be one of {', '.join(CONTACTS)}, got {self.kind!r}")
        for name, lo in (("kcs", 0.0), ("bcs", 0.0), ("alpha", 0.0)):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= lo):
                raise ContactModelError(f"contact {self.kind}: {name} must be finite and >= {lo:g}, got {value!r}")
        if not (math.isfinite(self.n) and 1.0 <= self.n <= 3.0):
            raise ContactModelError(
                f"contact hunt_crossley: hc_n must be between 1 and 3 (1.5: Hertz's sphere), got {self.n!r}"
            )

    def force(self, p: float, pd: float) -> float:
        """Compressive force [N] at penetration p [m] and rate pd [m/s] (0 while p <= 0, but the
        linear dashpot acts from the first instant of a contact at p = 0 closing in, as Eq. 1).
        Hunt-Crossley's is 0 where it would pull (alpha pd < -1): the exact contact never leaves
        faster than 1 / alpha, a loop that makes energy can."""
        if p < 0.0 or (p == 0.0 and pd <= 0.0):
            return 0.0
        if self.kind == "linear":
            return self.kcs * p + self.bcs * pd
        return self.kcs * p**self.n * max(1.0 + self.alpha * pd, 0.0)

    def stiffness(self, p: float) -> float:
        """dF/dp [N/m] at rest at penetration p: the local stiffness (kcs for the linear contact)."""
        if self.kind == "linear":
            return self.kcs
        return self.n * self.kcs * max(p, 0.0) ** (self.n - 1.0)

    def potential(self, p: float) -> float:
        """[J] the elastic energy the contact holds at penetration p."""
        if p <= 0.0:
            return 0.0
        return 0.5 * self.kcs * p * p if self.kind == "linear" else self.kcs * p ** (self.n + 1.0) / (self.n + 1.0)


def hunt_crossley_omega(contact: TargetContact, m: float, v: float) -> float:
    """[rad/s] the frequency a phase lead is tuned at for a Hunt-Crossley target: sqrt(K / m) with K the
    secant stiffness F / p at the deepest penetration of an undamped impact at v [m/s]."""
    deepest = ((contact.n + 1.0) * m * v * v / (2.0 * contact.kcs)) ** (1.0 / (contact.n + 1.0))
    return math.sqrt(contact.kcs * deepest ** (contact.n - 1.0) / m)


def linear_equivalent(contact: TargetContact, m: float, v: float) -> tuple[float, float]:
    """(stiffness [N/m], damping [N s/m]) of the linear contact with a Hunt-Crossley target's frequency
    (hunt_crossley_omega at the closing velocity v [m/s], reduced mass m [kg]) and its restitution at v:
    what the linear analyses (the scene check, the stability maps) judge the target as."""
    stiffness = m * hunt_crossley_omega(contact, m, v) ** 2
    return stiffness, linear_damping_for_restitution(restitution(contact.alpha, v), m, stiffness)


def _work(x: float) -> float:
    """x - ln(1 + x): the approach's work over m / alpha^2 at alpha v = x (series near 0: no cancellation)."""
    return x - math.log1p(x) if abs(x) > 1e-4 else x * x / 2.0 - x**3 / 3.0 + x**4 / 4.0


def restitution(alpha: float, v0: float) -> float:
    """Hunt-Crossley's coefficient of restitution at closing velocity v0 [m/s] (> 0), by bisection of
    alpha v0 - ln(1 + alpha v0) = -alpha e v0 - ln(1 - alpha e v0) on e in (0, 1]."""
    if not (math.isfinite(v0) and v0 > 0.0):
        raise ContactModelError(f"closing velocity must be > 0 m/s, got {v0!r}")
    x = alpha * v0
    if x == 0.0:
        return 1.0
    target = _work(x)
    lo, hi = 0.0, min(1.0, (1.0 - 1e-15) / x)  # the rebound's side grows with e, to infinity at alpha e v0 = 1
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _work(-mid * x) < target:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-16:
            break
    return 0.5 * (lo + hi)


def alpha_for_restitution(e: float, v0: float) -> float:
    """The damping alpha [s/m] whose Hunt-Crossley contact rebounds with restitution e (0 < e <= 1)
    from closing velocity v0 [m/s] (restitution falls monotonically with alpha)."""
    if not (0.0 < e <= 1.0):
        raise ContactModelError(f"restitution must be in (0, 1], got {e!r}")
    if e == 1.0:
        return 0.0
    lo, hi = 0.0, 1.0 / v0
    while restitution(hi, v0) > e:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if restitution(mid, v0) > e:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-15 * hi:
            break
    return 0.5 * (lo + hi)


def linear_damping_for_restitution(e: float, m: float, kcs: float) -> float:
    """bcs [N s/m] of the linear contact with restitution e (0 < e <= 1): e = exp(-pi zeta / sqrt(1 - zeta^2)),
    zeta = bcs / (2 sqrt(kcs m)), so zeta = -ln e / sqrt(pi^2 + ln^2 e)."""
    if not (0.0 < e <= 1.0):
        raise ContactModelError(f"restitution must be in (0, 1], got {e!r}")
    le = math.log(e)
    return 2.0 * math.sqrt(kcs * m) * (-le / math.sqrt(math.pi**2 + le * le))


@dataclass(frozen=True)
class IdealRun:
    """The ideal contact sampled per tick (t, p, pd, force: lists) with what happened between the
    samples located inside the substeps: the first contact's restitution, peak force [N], duration [s]
    and impulse [N s] (None where the bodies did not part)."""

    t: list
    p: list
    pd: list
    force: list
    restitution: float | None
    peak_force: float
    duration: float | None
    impulse: float


def ideal_relative_run(
    contact: TargetContact,
    m: float,
    v0: float,
    dt: float,
    n_ticks: int,
    p0: float = 0.0,
    accel: float = 0.0,
    substeps: int = 20,
) -> IdealRun:
    """The ideal contact on the relative coordinate p (reduced mass m [kg], p0 [m] and closing velocity
    v0 [m/s] at t = 0, a constant relative acceleration `accel` [m/s^2] from thrust), RK4 with
    `substeps` steps per tick and the contact's start and end located inside a step (linear
    interpolation of the crossing of p = 0)."""
    h = dt / substeps
    p, v = float(p0), float(v0)

    def acc(p_, v_):
        return accel - contact.force(p_, v_) / m

    def rk4(p_, v_, h_):
        k1p, k1v = v_, acc(p_, v_)
        k2p, k2v = v_ + 0.5 * h_ * k1v, acc(p_ + 0.5 * h_ * k1p, v_ + 0.5 * h_ * k1v)
        k3p, k3v = v_ + 0.5 * h_ * k2v, acc(p_ + 0.5 * h_ * k2p, v_ + 0.5 * h_ * k2v)
        k4p, k4v = v_ + h_ * k3v, acc(p_ + h_ * k3p, v_ + h_ * k3v)
        return p_ + h_ / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p), v_ + h_ / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)

    def crossing(p_, q_):
        """(time into the step, velocity) where p crosses 0: secant on partial steps from the step's start."""
        lo, hi, plo, phi = 0.0, h, p_, q_
        s, w_ = lo, v
        for _ in range(30):
            s = lo - plo * (hi - lo) / (phi - plo)
            ps_, w_ = rk4(p_, v, s)
            if abs(ps_) <= 1e-15 * (abs(p_) + abs(q_)) or hi - lo < 1e-15 * h:
                break
            if (ps_ > 0.0) == (plo > 0.0):
                lo, plo = s, ps_
            else:
                hi, phi = s, ps_
        return s, w_

    ts, ps, vs, fs = [], [], [], []
    peak = 0.0
    touching = p > 0.0 or (p == 0.0 and v > 0.0)
    start = 0.0 if touching else None
    end: float | None = None
    entry_v = v if touching else None
    exit_v = None
    t = 0.0
    for tick in range(n_ticks):
        ts.append(tick * dt)
        ps.append(p)
        vs.append(v)
        f = contact.force(p, v)
        fs.append(f)
        peak = max(peak, f)
        if tick == n_ticks - 1:
            break
        for _ in range(substeps):
            q, w = rk4(p, v, h)
            if start is None and q > 0.0 >= p:
                s, at = crossing(p, q)
                start, entry_v = t + s, at
            elif start is not None and end is None and p > 0.0 >= q:
                s, at = crossing(p, q)
                end, exit_v = t + s, at
            p, v, t = q, w, t + h
            if end is None and start is not None:
                peak = max(peak, contact.force(p, v))
    e = None if exit_v is None or not entry_v else -exit_v / entry_v
    impulse = 0.0  # of the contact force over the first contact (to the run's end if it lasts): m dv less the thrust's
    if start is not None and entry_v is not None:
        last_v, last_t = (exit_v, end) if exit_v is not None and end is not None else (v, t)
        impulse = m * (entry_v - last_v) + m * accel * (last_t - start)
    return IdealRun(ts, ps, vs, fs, e, peak, None if end is None or start is None else end - start, impulse)
