"""Stability of the hybrid loop: part of the contact acts on the simulator's own state (the
virtual impedance, direct) and part behind the robot's delay (the passive compliance):

    m s^2 + b_d s + k_d + (k_h + b_h s) e^{-sh} = 0

Its rightmost roots (Chebyshev collocation refined by Newton, as `stability.characteristic_roots`,
which is the case k_d = 0), its imaginary-axis crossings and critical delay in closed form, the
critical delay of its Pade approximants, and everything `dockhil stability` prints for it, with
the loop sampled at a rate (dockhil.contact.sampled).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import Polynomial

from dockhil.contact.scenario import check_finite, check_nonnegative, check_positive
from dockhil.contact.stability import chebyshev, pade_coefficients, poly_stable


def _check_hybrid(m, k_direct, b_direct, k_delayed, b_delayed, h):
    m = check_positive("m", m, "kg")
    vals = [
        check_finite(n, v, u)
        for n, v, u in (
            ("k_direct", k_direct, "N/m"),
            ("b_direct", b_direct, "N s/m"),
            ("k_delayed", k_delayed, "N/m"),
            ("b_delayed", b_delayed, "N s/m"),
        )
    ]
    return (m, *vals, check_nonnegative("h", h, "s"))


def _hybrid_char(lam: complex, kd: float, bd: float, kh: float, bh: float) -> tuple[complex, complex]:
    """lambda^2 + bd lambda + kd + (kh + bh lambda) e^{-lambda} and its derivative (dimensionless)."""
    e = np.exp(-lam)
    f = lam * lam + bd * lam + kd + (kh + bh * lam) * e
    return f, 2.0 * lam + bd + bh * e - (kh + bh * lam) * e


def hybrid_roots(
    m: float, k_direct: float, b_direct: float, k_delayed: float, b_delayed: float, h: float, count: int = 6
) -> np.ndarray:
    """The `count` rightmost roots s [1/s] of the hybrid loop
        m s^2 + b_d s + k_d + (k_h + b_h s) e^{-sh} = 0
    (virtual impedance on the simulator's state, passive compliance behind the robot's delay),
    rightmost first: Chebyshev collocation, then Newton on the exact equation, as
    `characteristic_roots` (which is the case k_d = 0 with the damper on either side)."""
    m, kd, bd, kh, bh, h = _check_hybrid(m, k_direct, b_direct, k_delayed, b_delayed, h)
    if h == 0.0:
        roots = np.roots([m, bd + bh, kd + kh]).astype(complex)
        return roots[np.argsort(-roots.real)][:count]
    # Dimensionless: lambda = s h, kappa = k h^2 / m, beta = b h / m.
    kd_, kh_ = kd * h * h / m, kh * h * h / m
    bd_, bh_ = bd * h / m, bh * h / m
    nodes = int(min(400, 32 + 3.0 * math.sqrt(abs(kd_) + abs(kh_)) + 2.0 * (abs(bd_) + abs(bh_))))
    x, d = chebyshev(nodes)
    gen = np.kron(2.0 * d, np.eye(2))
    gen[:2, :] = 0.0
    gen[:2, :2] = [[0.0, 1.0], [-kd_, -bd_]]
    gen[:2, -2:] = [[0.0, 0.0], [-kh_, -bh_]]
    eig = np.linalg.eigvals(gen)
    eig = eig[np.argsort(-eig.real)][: max(2 * count, 8)]
    refined: list[complex] = []
    for lam in eig:
        z = complex(lam)
        for _ in range(50):
            f, df = _hybrid_char(z, kd_, bd_, kh_, bh_)
            if df == 0:
                break
            step = f / df
            z -= step
            if abs(step) <= 1e-15 * (1.0 + abs(z)):
                break
        f, _ = _hybrid_char(z, kd_, bd_, kh_, bh_)
        z = z if abs(f) < 1e-9 * (1.0 + abs(z) ** 2) else complex(lam)
        if all(abs(z - r) > 1e-9 * (1.0 + abs(z)) for r in refined):
            refined.append(z)
    roots = np.array(refined) / h
    return roots[np.argsort(-roots.real)][:count]


def hybrid_rightmost(
    m: float, k_direct: float, b_direct: float, k_delayed: float, b_delayed: float, h: float
) -> complex:
    root = complex(hybrid_roots(m, k_direct, b_direct, k_delayed, b_delayed, h, count=1)[0])
    return complex(root.real, abs(root.imag))


@dataclass(frozen=True)
class DelayCrossing:
    """An imaginary-axis crossing s = j omega of the hybrid loop: at the delays
    h_n = h0 + 2 pi n / omega; `destabilizing` when roots cross into the right half-plane there."""

    omega: float
    h0: float
    destabilizing: bool


def delay_crossings(
    m: float, k_direct: float, b_direct: float, k_delayed: float, b_delayed: float
) -> list[DelayCrossing]:
    """Closed-form crossing frequencies and critical delays of
    m s^2 + b_d s + k_d + (k_h + b_h s) e^{-sh} = 0 (the method of Zebenay, Boge, Krenn and
    Choukroun, arXiv 1309.3512, for the docking simulator's loop): at s = j w the moduli of
    the direct and the delayed part must agree,
        |k_d - m w^2 + j b_d w| = |k_h + j b_h w|
        m^2 w^4 + (b_d^2 - b_h^2 - 2 m k_d) w^2 + k_d^2 - k_h^2 = 0,
    a quadratic in w^2; each positive root w gives e^{-j w h} = -(k_d - m w^2 + j b_d w) / (k_h + j b_h w),
    hence h0 in [0, 2 pi / w). Where the quadratic's derivative in w^2 is positive the roots
    cross to the right with growing h (Cooke and van den Driessche)."""
    m, kd, bd, kh, bh, _ = _check_hybrid(m, k_direct, b_direct, k_delayed, b_delayed, 0.0)
    a, b, c = m * m, bd * bd - bh * bh - 2.0 * m * kd, kd * kd - kh * kh
    out: list[DelayCrossing] = []
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        return out
    for sign in (1.0, -1.0):
        w2 = (-b + sign * math.sqrt(disc)) / (2.0 * a)
        if w2 <= 0.0 or (sign < 0.0 and disc == 0.0):
            continue
        w = math.sqrt(w2)
        delayed = complex(kh, bh * w)
        if delayed == 0:
            continue
        e = -complex(kd - m * w2, bd * w) / delayed
        h0 = (-math.atan2(e.imag, e.real)) % (2.0 * math.pi) / w
        out.append(DelayCrossing(w, h0, (2.0 * a * w2 + b) > 0.0))
    return out


def unstable_root_count(
    m: float, k_direct: float, b_direct: float, k_delayed: float, b_delayed: float, h: float
) -> int:
    """Roots in the open right half-plane at delay h: those of the undelayed polynomial, plus two
    per destabilizing crossing at or below h, minus two per stabilizing one (exact, closed form)."""
    m, kd, bd, kh, bh, h = _check_hybrid(m, k_direct, b_direct, k_delayed, b_delayed, h)
    n = int(np.sum(np.roots([m, bd + bh, kd + kh]).real > 0.0))
    for c in delay_crossings(m, kd, bd, kh, bh):
        if c.h0 <= h and c.h0 > 0.0:
            crossings = int(math.floor((h - c.h0) * c.omega / (2.0 * math.pi))) + 1
            n += (2 if c.destabilizing else -2) * crossings
    return max(n, 0)


def critical_delay(
    m: float, k_direct: float, b_direct: float, k_delayed: float, b_delayed: float
) -> tuple[float | None, float | None]:
    """(h*, omega*): the smallest delay [s] at which the loop, stable without delay, loses
    stability, and the frequency [rad/s] it then oscillates at; (inf, None) when no delay
    destabilizes it; (None, None) when it is unstable already without delay."""
    m, kd, bd, kh, bh, _ = _check_hybrid(m, k_direct, b_direct, k_delayed, b_delayed, 0.0)
    if np.any(np.roots([m, bd + bh, kd + kh]).real >= 0.0):
        return None, None
    ups = [c for c in delay_crossings(m, kd, bd, kh, bh) if c.destabilizing]
    if not ups:
        return math.inf, None
    c = min(ups, key=lambda c: c.h0 if c.h0 > 0.0 else 2.0 * math.pi / c.omega)
    return (c.h0 if c.h0 > 0.0 else 2.0 * math.pi / c.omega), c.omega


def _pade_hybrid_stable(m: float, kd: float, bd: float, kh: float, bh: float, h: float, order: int) -> bool:
    c = pade_coefficients(order)
    num = Polynomial(c * (-h) ** np.arange(c.size))  # N(s h), e^{-sh} ~ N / D
    den = Polynomial(c * h ** np.arange(c.size))
    poly = Polynomial([kd, bd, m]) * den + Polynomial([kh, bh]) * num
    return poly_stable(poly)


def pade_critical_delay(
    m: float, k_direct: float, b_direct: float, k_delayed: float, b_delayed: float, order: int = 1, h_max: float = 100.0
) -> float | None:
    """The smallest delay [s] at which the loop with e^{-sh} replaced by its order-n Pade
    approximant is unstable (found by scanning and bisection); inf when none up to h_max;
    None when unstable without delay."""
    m, kd, bd, kh, bh, _ = _check_hybrid(m, k_direct, b_direct, k_delayed, b_delayed, 0.0)
    if not poly_stable(Polynomial([kd + kh, bd + bh, m])):
        return None
    grid = np.geomspace(1e-7, h_max, 400)
    prev = 0.0
    for h in grid:
        if not _pade_hybrid_stable(m, kd, bd, kh, bh, h, order):
            lo, hi = prev, h
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if _pade_hybrid_stable(m, kd, bd, kh, bh, mid, order) else (lo, mid)
            return hi
        prev = h
    return math.inf


def hybrid_report(
    m: float,
    k_direct: float,
    b_direct: float,
    k_delayed: float,
    b_delayed: float,
    h: float,
    rate: float | None = None,
    pade_order: int | None = None,
) -> dict:
    """Everything `dockhil stability` prints for the hybrid loop, as a JSON-ready dict: the
    closed-form crossings and critical delay, Pade critical delays, the rightmost root, the
    paper's verdict when the whole contact is delayed, and the sampled loop at `rate`."""
    m, kd, bd, kh, bh, h = _check_hybrid(m, k_direct, b_direct, k_delayed, b_delayed, h)
    h_star, w_star = critical_delay(m, kd, bd, kh, bh)
    # The sampled loop first: a long delay whose roots cannot be verified is refused (RootsNotResolved)
    # before the rest is computed.
    sampled = None if rate is None else _sampled_report(m, kd, bd, kh, bh, h, rate, h_star)
    crossings = delay_crossings(m, kd, bd, kh, bh)
    root = hybrid_rightmost(m, kd, bd, kh, bh, h)
    whole = hybrid_rightmost(m, 0.0, 0.0, kd + kh, bd + bh, h)
    fin = lambda v: None if v is None or not math.isfinite(v) else v  # noqa: E731
    out = {
        "m": m,
        "k_direct": kd,
        "b_direct": bd,
        "k_delayed": kh,
        "b_delayed": bh,
        "h": h,
        "equation": "m s^2 + b_d s + k_d + (k_h + b_h s) e^(-sh) = 0",
        "crossings": [{"omega": c.omega, "h0": c.h0, "destabilizing": c.destabilizing} for c in crossings],
        "critical_delay": fin(h_star),
        "critical_frequency": w_star,
        "stable_without_delay": h_star is not None,
        "no_delay_destabilizes": h_star is not None and math.isinf(h_star),
        "pade1_critical_delay": fin(pade_critical_delay(m, kd, bd, kh, bh, 1)),
        "rightmost_root": [root.real, root.imag],
        "growth_rate": root.real,
        "stable": bool(root.real < 0.0),
        "unstable_roots": unstable_root_count(m, kd, bd, kh, bh, h),
        "whole_delayed_growth_rate": whole.real,
    }
    if pade_order is not None:
        out["pade_order"] = int(pade_order)
        out["pade_n_critical_delay"] = fin(pade_critical_delay(m, kd, bd, kh, bh, pade_order))
    if sampled is not None:
        out["sampled"] = sampled
    return out


def _sampled_report(
    m: float, kd: float, bd: float, kh: float, bh: float, h: float, rate: float, h_star: float | None
) -> dict:
    """The hybrid loop sampled at `rate`: its spectral radius at round(h rate) ticks and the smallest
    delay in whole ticks at which it grows (near the exact critical delay h_star)."""
    from dockhil.contact.sampled import SampledLoop, sampled_roots

    dt = 1.0 / rate
    d = int(round(h / dt))
    guesses = [np.exp(s * dt) for s in hybrid_roots(m, kd, bd, kh, bh, h, count=4)]

    def radius(ticks: int) -> float:
        z = sampled_roots(SampledLoop(m, kd, bd, kh, bh, dt=dt, delay_ticks=ticks), guesses)[0]
        return float(abs(z))

    rho = radius(d)
    sampled = {
        "rate": rate,
        "dt": dt,
        "delay_ticks": d,
        "spectral_radius": rho,
        "growth_rate": math.log(rho) * rate if rho > 0 else None,
        "stable": bool(rho < 1.0),
    }
    # The smallest delay in whole ticks at which the sampled loop grows, near the exact one.
    if h_star is not None and math.isfinite(h_star) and h_star * rate < 20000:
        start = max(0, int(h_star * rate) - 6)
        if radius(start) < 1.0:
            ticks = start
            while ticks < start + 40 and radius(ticks) < 1.0:
                ticks += 1
            sampled["critical_delay_ticks"] = ticks
            sampled["critical_delay"] = ticks * dt
    return sampled
