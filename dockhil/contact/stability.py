"""Stability of the delayed contact loop (Sec. 4, Eqs. 7-12).

The loop of Fig. 6: a free-floating (reduced) mass m, a contact stiffness K
and damper b closed through the robot's response delay h:

    delayed damper (the paper):    m s^2 + (K + b s) e^{-sh} = 0
    undelayed damper:              m s^2 + b s + K e^{-sh} = 0
      (the virtual damper acts on the simulator's own velocity, so only the
      hardware spring is seen through the delay)

With lambda = s h, beta = b h / m and kappa = K h^2 / m both become
lambda^2 + (beta lambda + kappa) e^{-lambda} = 0 (resp. lambda^2 + beta lambda
+ kappa e^{-lambda} = 0): every bound is kappa_max(beta), i.e.
K_max = (m / h^2) kappa_max(b h / m). That is why the map of Fig. 7 is cheap.

Bounds provided:
* Eq. 12 (first-order Pade + Routh):  0 < K < b (4m - 2bh) / (h (4m - bh)),
  defined for b h < 2 m;
* Pade of any order n (Routh replaced by the roots of the polynomial);
* the exact boundary, from the imaginary-axis crossing s = j w:
    delayed:   b h / m = theta sin(theta),  K = (m / h^2) theta^2 cos(theta)
    undelayed: b h / m = theta tan(theta),  K = (m / h^2) theta^2 / cos(theta)
  with theta = w h in (0, pi/2). For the delayed damper no theta exists when
  b h / m >= pi/2: then no K > 0 stabilizes the loop at all, while Eq. 12 can
  still print a positive bound (for pi/2 <= b h / m < 2).
The rightmost characteristic root (growth rate) comes from a Chebyshev
collocation of the delay equation, refined by Newton on the exact equation.
The hybrid loop, with part of the contact direct and part behind the delay, is
dockhil.contact.hybrid_stability's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.polynomial import Polynomial

from dockhil.contact.scenario import ContactModelError, check_finite, check_nonnegative, check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

DAMPERS = ("delayed", "undelayed")
HALF_PI = 0.5 * math.pi


def _check_loop(m: float, b: float, h: float, damper: str) -> tuple[float, float, float]:
    if damper not in DAMPERS:
        raise ContactModelError(f"damper must be one of {', '.join(DAMPERS)}, got {damper!r}")
    return (
        check_positive("m", m, "kg"),
        check_nonnegative("b", b, "N s/m"),
        check_nonnegative("h", h, "s"),
    )


def pade1_bound(m: float, b: float, h: float, damper: str = "delayed") -> float | None:
    """Upper stiffness bound [N/m] from the first-order Pade approximation and
    Routh: Eq. 12 for the delayed damper; None when Routh admits no K > 0.

    For the undelayed damper the same steps give K < 2b (2m + bh) / (h (4m + bh)).
    """
    m, b, h = _check_loop(m, b, h, damper)
    if h == 0.0:
        return math.inf if b > 0.0 else None
    if b == 0.0:
        return None
    if damper == "delayed":
        if b * h >= 2.0 * m:  # Routh: the s^2 coefficient 2m - bh must be > 0
            return None
        return b * (4.0 * m - 2.0 * b * h) / (h * (4.0 * m - b * h))
    return 2.0 * b * (2.0 * m + b * h) / (h * (4.0 * m + b * h))


def pade_coefficients(order: int) -> np.ndarray:
    """c_k of the [n/n] Pade approximant e^{-x} ~ sum c_k (-x)^k / sum c_k x^k."""
    n = int(order)
    if n < 1:
        raise ContactModelError(f"Pade order must be >= 1, got {order!r}")
    f = math.factorial
    return np.array([f(2 * n - k) * f(n) / (f(2 * n) * f(k) * f(n - k)) for k in range(n + 1)])


def _pade_polys(beta: float, order: int, damper: str) -> tuple[Polynomial, Polynomial]:
    """A, B with characteristic polynomial A + kappa B (dimensionless lambda = s h)."""
    c = pade_coefficients(order)
    num = Polynomial(c * (-1.0) ** np.arange(c.size))  # P(lambda) ~ e^{-lambda} numerator
    den = Polynomial(c)
    lam = Polynomial([0.0, 1.0])
    if damper == "delayed":
        return lam * lam * den + beta * lam * num, num
    return (lam * lam + beta * lam) * den, num


def poly_stable(poly: Polynomial) -> bool:
    """Every root of `poly` in the open left half-plane (by a margin relative to the largest root)."""
    roots = poly.roots()
    return bool(roots.size) and bool(np.all(roots.real < -1e-12 * max(1.0, float(np.max(np.abs(roots))))))


def pade_bound(m: float, b: float, h: float, order: int = 1, damper: str = "delayed") -> float | None:
    """Upper stiffness bound [N/m] with e^{-sh} replaced by its order-n Pade
    approximant; None when no K > 0 is stable. order=1 reproduces Eq. 12."""
    m, b, h = _check_loop(m, b, h, damper)
    if h == 0.0:
        return math.inf if b > 0.0 else None
    beta = b * h / m
    a_poly, b_poly = _pade_polys(beta, order, damper)
    # Crossings lambda = j w: A(jw) conj(B(jw)) must be real (then kappa = -A/B).
    b_coef = cast(np.ndarray, b_poly.coef)  # real: the stubs allow object coefficients
    cross = a_poly * Polynomial(b_coef * (-1.0) ** np.arange(b_coef.size))
    odd = np.zeros(cross.coef.size)
    for k in range(1, cross.coef.size, 2):
        odd[k] = cross.coef[k] * (-1.0) ** ((k - 1) // 2)
    kappas = []
    if np.any(odd):
        for w in cast(np.ndarray, Polynomial(odd).roots()):  # numbers: the stubs allow objects
            if abs(w.imag) < 1e-9 * max(1.0, abs(w)) and w.real > 0.0:
                jw = 1j * w.real
                kappa = -(a_poly(jw) / b_poly(jw)).real
                if kappa > 0.0:
                    kappas.append(kappa)
    edges = sorted(set(kappas))
    first = edges[0] if edges else 1.0
    if not poly_stable(a_poly + 0.5 * first * b_poly):
        return None
    return float(edges[0]) * m / (h * h) if edges else math.inf


def _solve_theta(beta: ArrayLike, damper: str) -> np.ndarray:
    """theta in (0, pi/2) with theta sin(theta) = beta (delayed) or
    theta tan(theta) = beta (undelayed), by vectorized bisection; nan where
    there is none. Both left-hand sides increase on (0, pi/2)."""
    beta = np.asarray(beta, dtype=float)
    if damper == "delayed":
        valid = (beta > 0.0) & (beta < HALF_PI)
        lo = np.zeros_like(beta)
        hi = np.full_like(beta, HALF_PI)
        # theta sin(theta) <= theta^2, so the root is >= sqrt(beta)
        lo = np.where(valid, np.sqrt(np.clip(beta, 0.0, None)), lo)
        lo = np.minimum(lo, hi)
        fun = lambda th: th * np.sin(th)  # noqa: E731
    else:
        valid = beta > 0.0
        lo = np.zeros_like(beta)
        # theta tan(theta) >= theta^2, so the root is <= sqrt(beta)
        hi = np.minimum(np.sqrt(np.clip(beta, 0.0, None)), np.nextafter(HALF_PI, 0.0))
        fun = lambda th: th * np.tan(th)  # noqa: E731
    for _ in range(56):
        mid = 0.5 * (lo + hi)
        above = fun(mid) >= beta
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return np.where(valid, 0.5 * (lo + hi), np.nan)


def exact_kappa(beta: ArrayLike, damper: str = "delayed") -> np.ndarray:
    """Dimensionless exact bound kappa_max = K_max h^2 / m at beta = b h / m; nan where no K > 0 is stable."""
    theta = _solve_theta(beta, damper)
    if damper == "delayed":
        return theta * theta * np.cos(theta)
    return theta * theta / np.cos(theta)


@dataclass(frozen=True)
class StabilityBound:
    """Exact stiffness bound of the delayed loop.

    k_max [N/m]: stable for 0 < K < k_max; None when no K > 0 is stable; inf
    without delay. crossing_frequency [rad/s]: the frequency at which the loop
    oscillates at K = k_max. beta = b h / m. reason: one plain sentence.
    """

    k_max: float | None
    crossing_frequency: float | None
    beta: float
    damper: str
    reason: str


def no_stabilizing_stiffness_reason(m: float, b: float, h: float, damper: str = "delayed") -> str | None:
    """Why no K > 0 stabilizes the loop, or None when some K does."""
    m, b, h = _check_loop(m, b, h, damper)
    if h == 0.0:
        return None if b > 0.0 else "without damping (b = 0) the contact is an undamped oscillator for every K"
    if b == 0.0:
        return (
            "no stiffness K > 0 stabilizes this loop: without damping (b = 0) the delayed spring"
            " always feeds energy into the oscillation (m s^2 + K e^{-sh} = 0 has a root with a"
            " positive real part for every K > 0); add damping b > 0"
        )
    beta = b * h / m
    if damper == "delayed" and beta >= HALF_PI:
        return (
            f"no stiffness K > 0 stabilizes this loop: b h / m = {beta:.4g} >= pi/2, so the delayed"
            f" damper alone already oscillates with growing amplitude (m s + b e^(-sh) = 0 has roots"
            f" in the right half-plane) and a spring only adds more delayed force; use"
            f" b < pi m / (2 h) = {HALF_PI * m / h:.6g} N s/m, a delay h < pi m / (2 b) ="
            f" {HALF_PI * m / b:.6g} s, or a damper on the undelayed simulator velocity"
            f" (damper 'undelayed')"
        )
    return None


def exact_bound(m: float, b: float, h: float, damper: str = "delayed") -> StabilityBound:
    """The exact stiffness bound of m s^2 + (K + b s) e^{-sh} = 0 (damper
    "delayed") or m s^2 + b s + K e^{-sh} = 0 (damper "undelayed")."""
    m, b, h = _check_loop(m, b, h, damper)
    equation = "m s^2 + (K + b s) e^(-sh) = 0" if damper == "delayed" else "m s^2 + b s + K e^(-sh) = 0"
    beta = b * h / m
    why_not = no_stabilizing_stiffness_reason(m, b, h, damper)
    if why_not is not None:
        return StabilityBound(None, None, beta, damper, why_not)
    if h == 0.0:
        return StabilityBound(math.inf, None, 0.0, damper, "no delay: every K > 0 is stable with b > 0")
    theta = float(_solve_theta(np.array(beta), damper))
    kappa = theta * theta * (math.cos(theta) if damper == "delayed" else 1.0 / math.cos(theta))
    k_max = kappa * m / (h * h)
    omega = theta / h
    reason = (
        f"{equation} has roots on the imaginary axis at s = +-j {omega:.6g} rad/s when"
        f" K = {k_max:.6g} N/m (b h / m = {beta:.4g}); stable for 0 < K < {k_max:.6g} N/m"
    )
    return StabilityBound(k_max, omega, beta, damper, reason)


def critical_stiffness_map(
    m: float, b_values: ArrayLike, h_values: ArrayLike, bound: str = "pade1", damper: str = "delayed"
) -> np.ndarray:
    """K_max [N/m] over a grid, shape (len(h_values), len(b_values)); nan where
    no K > 0 is stable. bound: "pade1" (Eq. 12, Fig. 7) or "exact". Vectorized."""
    m = check_positive("m", m, "kg")
    if damper not in DAMPERS:
        raise ContactModelError(f"damper must be one of {', '.join(DAMPERS)}, got {damper!r}")
    b = np.asarray(b_values, dtype=float)[None, :]
    h = np.asarray(h_values, dtype=float)[:, None]
    if np.any(~np.isfinite(b)) or np.any(b < 0.0):
        raise ContactModelError("b values must be finite and >= 0 N s/m")
    if np.any(~np.isfinite(h)) or np.any(h <= 0.0):
        raise ContactModelError("h values must be finite and > 0 s")
    beta = b * h / m
    if bound == "pade1":
        if damper == "delayed":
            with np.errstate(divide="ignore", invalid="ignore"):
                k = b * (4.0 * m - 2.0 * b * h) / (h * (4.0 * m - b * h))
            return np.where((beta < 2.0) & (b > 0.0), k, np.nan)
        k = 2.0 * b * (2.0 * m + b * h) / (h * (4.0 * m + b * h))
        return np.where(b > 0.0, k, np.nan)
    if bound == "exact":
        return exact_kappa(beta, damper) * m / (h * h)
    raise ContactModelError(f"bound must be 'pade1' or 'exact', got {bound!r}")


def chebyshev(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Chebyshev points x_j = cos(j pi / n) and differentiation matrix (Trefethen)."""
    x = np.cos(np.pi * np.arange(n + 1) / n)
    c = np.ones(n + 1)
    c[0] = c[-1] = 2.0
    c *= (-1.0) ** np.arange(n + 1)
    dx = x[:, None] - x[None, :]
    d = np.outer(c, 1.0 / c) / (dx + np.eye(n + 1))
    d -= np.diag(d.sum(axis=1))
    return x, d


def _char(lam: complex, kappa: float, beta: float, damper: str) -> tuple[complex, complex]:
    e = np.exp(-lam)
    if damper == "delayed":
        return lam * lam + (beta * lam + kappa) * e, 2.0 * lam + beta * e - (beta * lam + kappa) * e
    return lam * lam + beta * lam + kappa * e, 2.0 * lam + beta - kappa * e


def _newton(lam: complex, kappa: float, beta: float, damper: str) -> complex | None:
    for _ in range(50):
        f, df = _char(lam, kappa, beta, damper)
        if df == 0:
            return None
        step = f / df
        lam = lam - step
        if abs(step) <= 1e-15 * (1.0 + abs(lam)):
            return complex(lam)
    f, _ = _char(lam, kappa, beta, damper)
    return complex(lam) if abs(f) < 1e-10 * (1.0 + abs(lam) ** 2) else None


def characteristic_roots(m: float, K: float, b: float, h: float, damper: str = "delayed", count: int = 6) -> np.ndarray:
    """The `count` rightmost roots s [1/s] of the loop's characteristic equation,
    rightmost first. Chebyshev collocation of the delay equation (Breda, Maset
    and Vermiglio's infinitesimal-generator method), each root then refined
    by Newton on the exact equation."""
    m, b, h = _check_loop(m, b, h, damper)
    K = check_finite("K", K, "N/m")
    if h == 0.0:
        roots = np.roots([m, b, K]).astype(complex)
        return roots[np.argsort(-roots.real)][:count]
    beta = b * h / m
    kappa = K * h * h / m
    # Enough nodes to resolve the loop's frequencies over one delay.
    nodes = int(min(400, 32 + 3.0 * math.sqrt(abs(kappa)) + 2.0 * beta))
    x, d = chebyshev(nodes)
    gen = np.kron(2.0 * d, np.eye(2))  # d/dtheta on theta = (x - 1) / 2 in [-1, 0]
    if damper == "delayed":
        now = np.array([[0.0, 1.0], [0.0, 0.0]])
        late = np.array([[0.0, 0.0], [-kappa, -beta]])
    else:
        now = np.array([[0.0, 1.0], [0.0, -beta]])
        late = np.array([[0.0, 0.0], [-kappa, 0.0]])
    gen[:2, :] = 0.0
    gen[:2, :2] = now  # theta = 0 (x = 1): the delay equation itself
    gen[:2, -2:] = late  # theta = -1 (x = -1): the delayed state
    eig = np.linalg.eigvals(gen)
    eig = eig[np.argsort(-eig.real)][: max(2 * count, 8)]
    refined: list[complex] = []
    for lam in eig:
        root = _newton(complex(lam), kappa, beta, damper)
        root = complex(lam) if root is None else root
        if all(abs(root - r) > 1e-9 * (1.0 + abs(root)) for r in refined):
            refined.append(root)
    roots = np.array(refined) / h
    return roots[np.argsort(-roots.real)][:count]


def rightmost_root(m: float, K: float, b: float, h: float, damper: str = "delayed") -> complex:
    """The characteristic root s [1/s] with the largest real part (of a
    complex pair, the one with positive imaginary part)."""
    root = complex(characteristic_roots(m, K, b, h, damper, count=1)[0])
    return complex(root.real, abs(root.imag))


def growth_rate(m: float, K: float, b: float, h: float, damper: str = "delayed") -> float:
    """Real part [1/s] of the rightmost root: < 0 decays (stable), > 0 grows."""
    return rightmost_root(m, K, b, h, damper).real


def stability_report(
    m: float,
    b: float,
    h: float,
    K: float | None = None,
    damper: str = "delayed",
    pade_order: int | None = None,
) -> dict:
    """Everything `dockhil stability` prints, as a JSON-ready dict."""
    m, b, h = _check_loop(m, b, h, damper)
    pade1 = pade1_bound(m, b, h, damper)
    exact = exact_bound(m, b, h, damper)
    report: dict = {
        "m": m,
        "b": b,
        "h": h,
        "damper": damper,
        "beta": exact.beta,
        "pade1": None if pade1 is None or math.isinf(pade1) else pade1,
        "pade1_formula": "Eq. 12: b (4m - 2bh) / (h (4m - bh))"
        if damper == "delayed"
        else "2b (2m + bh) / (h (4m + bh))",
        "exact": None if exact.k_max is None or math.isinf(exact.k_max) else exact.k_max,
        "crossing_frequency": exact.crossing_frequency,
        "reason": exact.reason,
    }
    if pade1 is None:
        report["pade1_reason"] = "first-order Pade + Routh admit no K > 0" + (
            f" (needs b h < 2 m, here b h / m = {exact.beta:.4g})" if b > 0.0 else " without damping"
        )
    elif exact.k_max is None:
        report["pade1_reason"] = (
            "Eq. 12 claims a stable range, but the exact delay equation has none: the"
            " first-order Pade approximation is too coarse at this b h / m"
        )
    elif exact.k_max is not None and math.isfinite(exact.k_max):
        report["pade1_error"] = (pade1 - exact.k_max) / exact.k_max
    if pade_order is not None:
        pn = pade_bound(m, b, h, pade_order, damper)
        report["pade_order"] = int(pade_order)
        report["pade_n"] = None if pn is None or math.isinf(pn) else pn
    if K is not None:
        root = rightmost_root(m, K, b, h, damper)
        report["K"] = float(K)
        report["growth_rate"] = root.real
        report["rightmost_root"] = [root.real, root.imag]
        report["stable"] = bool(root.real < 0.0)
    return report
