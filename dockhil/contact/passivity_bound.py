"""The passivity boundary beside the stability boundary: the least undelayed damping b that makes the
delayed port k_h + b_h s (behind a delay h) passive, with or without sampling.

Continuous: the port's impedance (force over velocity) is Z(jw) = b + (k_h / (jw) + b_h) e^{-jwh}, and
the port is passive when Re Z >= 0 at every w:

    b >= max over w of (k_h / w) sin(w h) - b_h cos(w h)          (mass-independent)

At w -> 0 this is k_h h - b_h (energy matching's k h); at w h = pi, 3 pi, ... it is b_h, so a delayed
damper always needs at least its own value again undelayed.

Sampled (Colgate and Schenkel, 1997): a body under a force held over each step T of the discrete
impedance H(z) (force over position) is passive when

    b >= (T / 2) Re[(1 - e^{-j theta}) H(e^{j theta})] / (1 - cos theta)   for theta in (0, pi]

which for H = K + B (1 - z^-1) / T is Colgate's b > K T / 2 + |B|. Here H(z) = k_d + z^-d (k_h + b_h
(1 - z^-1) / T): the port d = round(h / T) samples late, and the undelayed spring k_d (the virtual
impedance's) held too; at theta -> 0 it is k_d T / 2 + k_h (d + 1/2) T - b_h (the delay and the hold's
half step). The undelayed damping b is the virtual impedance's: it damps with the body's own velocity at
each sample, which over a step dissipates as a physical damper does to first order.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from dockhil.contact.scenario import ContactModelError, check_finite

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


def _refine(fun: Callable[[float], float], grid: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """(max, argmax) of fun, from its values on a grid, refined by golden section around the best point."""
    i = int(np.argmax(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = fun(a), fun(b)
    for _ in range(80):
        if fa > fb:
            hi, b, fb = b, a, fa
            a = hi - g * (hi - lo)
            fa = fun(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = fun(b)
    best = max((float(values[i]), float(grid[i])), (fa, a), (fb, b))
    return best


def passivity_min_damping(k_h: float, b_h: float, h: float) -> tuple[float, float | None]:
    """(least undelayed damping [N s/m], the frequency [rad/s] that asks for it; None: w -> 0) of the
    port k_h + b_h s behind the delay h [s]."""
    k_h, b_h, h = check_finite("k_h", k_h, "N/m"), check_finite("b_h", b_h, "N s/m"), check_finite("h", h, "s")
    if h < 0.0:
        raise ContactModelError(f"h must be >= 0 s, got {h!r}")
    if h == 0.0:
        return max(-b_h, 0.0) if k_h >= 0.0 else math.inf, None
    a = k_h * h

    def g(theta: float) -> float:  # in theta = w h
        return (a * math.sin(theta) / theta if theta > 0.0 else a) - b_h * math.cos(theta)

    # Past a few turns g only oscillates about 0 within b_h + |a| / theta: the largest value is in the first ones.
    theta = np.linspace(1e-9, 40.0 * math.pi, 40001)
    values = a * np.sin(theta) / theta - b_h * np.cos(theta)
    best, at = _refine(g, theta, values)
    if g(0.0) >= best - 1e-12 * max(abs(a), abs(b_h), 1.0):
        return g(0.0), None
    return float(best), float(at / h)


def sampled_passivity_min_damping(
    k_h: float, b_h: float, h: float, dt: float, k_direct: float = 0.0
) -> tuple[float, float | None]:
    """(least damping [N s/m], the frequency [rad/s] that asks for it) for the sampled port: the force
    k_h x + b_h (x_k - x_{k-1}) / T of d = round(h / T) samples ago and k_direct x now, held over each
    step T = dt."""
    k_h, b_h = check_finite("k_h", k_h, "N/m"), check_finite("b_h", b_h, "N s/m")
    if not (math.isfinite(dt) and dt > 0.0):
        raise ContactModelError(f"the step must be > 0 s, got {dt!r}")
    if not (math.isfinite(h) and h >= 0.0):
        raise ContactModelError(f"h must be >= 0 s, got {h!r}")
    d = int(round(h / dt))

    # With 1 - e^{-j theta} = 2j sin(theta/2) e^{-j theta/2} and 1 - cos theta = 2 sin^2(theta/2): no
    # cancellation at small theta.
    def ratio(theta, s, half, z1):
        H = k_direct + z1**d * (k_h + b_h * 2j * s * half / dt)
        return 0.5 * dt * (1j * half * H).real / s

    def g(theta: float) -> float:
        return float(ratio(theta, math.sin(0.5 * theta), cmath.exp(-0.5j * theta), cmath.exp(-1j * theta)))

    limit = 0.5 * k_direct * dt + k_h * (d + 0.5) * dt - b_h  # theta -> 0
    # Log-spaced below (a short step puts the delay's frequencies at small theta), linear above.
    theta = np.unique(np.concatenate([np.geomspace(1e-9, math.pi, 20000), np.linspace(1e-3, math.pi, 20000)]))
    values = ratio(theta, np.sin(0.5 * theta), np.exp(-0.5j * theta), np.exp(-1j * theta))
    best, at = _refine(g, theta, values)
    if limit >= best - 1e-12 * max(abs(limit), abs(b_h), 1.0):
        return limit, None
    return float(best), float(at / dt)


def passivity_report(
    k_h: float, b_h: float, h: float, b_undelayed: float, dt: float | None = None, k_direct: float = 0.0
) -> dict:
    """The passivity boundary of a loop whose delayed port is k_h + b_h s and whose undelayed damping is
    b_undelayed: JSON-ready, with the sampled loop's at step dt (its undelayed spring k_direct held too)."""
    need, at = passivity_min_damping(k_h, b_h, h)
    out = {
        "passivity_min_damping_Ns_per_m": need,
        "passivity_frequency_rad_s": at,
        "passivity_formula": "max over w of (k_h / w) sin(w h) - b_h cos(w h)",
        "passive": bool(b_undelayed >= need),
    }
    if dt is not None:
        sneed, sat = sampled_passivity_min_damping(k_h, b_h, h, dt, k_direct)
        out["sampled_passivity_min_damping_Ns_per_m"] = sneed
        out["sampled_passivity_frequency_rad_s"] = sat
        out["sampled_passive"] = bool(b_undelayed >= sneed)
        out["sampled_rate_Hz"] = 1.0 / dt
    return out


def passive_stiffness_map(b_values: ArrayLike, h_values: ArrayLike, damper: str, dt: float | None = None) -> np.ndarray:
    """The largest K [N/m] whose delayed port the undelayed damper b makes passive, over a grid
    (shape (len(h), len(b))): b / h, or b / ((d + 1/2) dt) sampled at dt; NaN everywhere for the delayed
    damper (the paper's loop), whose port no undelayed damping backs."""
    b = np.asarray(b_values, dtype=float)[None, :]
    h = np.asarray(h_values, dtype=float)[:, None]
    if damper == "delayed":
        return np.full((h.size, b.size), np.nan)
    late = h if dt is None else (np.round(h / dt) + 0.5) * dt
    return b / late
