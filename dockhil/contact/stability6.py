"""Stability of the multi-axis delayed loop (the 6-DOF hybrid simulator, linearised).

    M q'' + B_d q' + K_d q + (B_h q' + K_h q)(t - h) = 0
    characteristic equation:  det(M s^2 + B_d s + K_d + (B_h s + K_h) e^{-sh}) = 0

q: the relative interface coordinates (n of them, up to 6); M: the effective
mass at the interface, (G1 + G2)^-1 (hybrid6); direct terms: the virtual
impedance acting on the simulator's state (K - K_p, C - C_p); delayed terms:
the passive compliance the robots show h late (K_p, C_p). Along one axis with
no offset this is the 1-DOF hybrid loop of `hybrid_stability.hybrid_roots`.

Roots: Chebyshev collocation of the delay equation's infinitesimal generator
(Breda, Maset and Vermiglio), as `stability.characteristic_roots`, here for
a 2n-dimensional state; each root refined by Newton on det, with
d/ds ln det D(s) = tr(D^-1 D'). The mode of a root is the null vector of D(s)
(its smallest singular vector); its largest entry names the axis that drives it.

The stiffness margin scales the delayed stiffness K_h by alpha and finds the
alpha at which the rightmost root crosses the imaginary axis; the mode there
is what limits the stable stiffness. When all the matrices diagonalise in one
basis (principal axes through the CoMs, no lever arm) the loop splits into
independent 1-DOF loops, one per mode: `modal_loops` says so, and the
margin is the smallest of theirs.

The 2-D case (the paper's planar analysis): the normal translation x and the
rotation about z, coupled through the lateral lever arm of the contact point;
`planar_loop` builds it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from dockhil.contact.interface6 import AXES
from dockhil.contact.rigidbody import check_symmetric
from dockhil.contact.scenario import ContactModelError, check_nonnegative, check_positive
from dockhil.contact.stability import chebyshev

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from dockhil.contact.contact6 import Contact6

MAX_NODES = 120
TRACK_WIDTH = 0.02  # relative bracket of the stiffness margin below which bisection follows the crossing roots
TRACK_ROOTS = 12  # at most this many of them (more: all the roots, every step)


@dataclass(frozen=True)
class MultiAxisLoop:
    """The linearised delayed loop: n x n mass (symmetric positive definite),
    direct and delayed stiffness and damping, delay h [s], axis names."""

    mass: np.ndarray
    k_direct: np.ndarray
    b_direct: np.ndarray
    k_delayed: np.ndarray
    b_delayed: np.ndarray
    h: float
    axes: tuple = AXES

    def __post_init__(self) -> None:
        m = np.asarray(self.mass, float)
        n = m.shape[0] if m.ndim == 2 else 0
        object.__setattr__(self, "mass", check_symmetric("mass", m, n, definite=True, unit="kg, kg m^2"))
        for name in ("k_direct", "b_direct", "k_delayed", "b_delayed"):
            arr = np.asarray(getattr(self, name), float)
            if arr.shape != (n, n) or not np.all(np.isfinite(arr)):
                raise ContactModelError(f"{name} must be a finite {n}x{n} matrix, got shape {arr.shape}")
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "h", check_nonnegative("h", self.h, "s"))
        axes = tuple(self.axes)[:n] if len(self.axes) >= n else tuple(f"q{i}" for i in range(n))
        object.__setattr__(self, "axes", axes)

    @property
    def n(self) -> int:
        return self.mass.shape[0]

    def scaled(self, alpha: float) -> MultiAxisLoop:
        """The same loop with the delayed stiffness times alpha."""
        return MultiAxisLoop(
            self.mass, self.k_direct, self.b_direct, alpha * self.k_delayed, self.b_delayed, self.h, self.axes
        )

    def matrix(self, s: complex) -> np.ndarray:
        """D(s) = M s^2 + B_d s + K_d + (B_h s + K_h) e^{-sh}."""
        e = np.exp(-s * self.h)
        return self.mass * s * s + self.b_direct * s + self.k_direct + (self.b_delayed * s + self.k_delayed) * e


@dataclass(frozen=True)
class Root:
    """A characteristic root s [1/s], its mode shape (unit vector over the axes)
    and the axis with the largest entry of the mode."""

    s: complex
    mode: np.ndarray
    axis: str


def _newton(loop: MultiAxisLoop, s: complex) -> complex | None:
    h = loop.h
    for _ in range(60):
        d = loop.matrix(s)
        e = np.exp(-s * h)
        dd = 2.0 * loop.mass * s + loop.b_direct + loop.b_delayed * e - h * (loop.b_delayed * s + loop.k_delayed) * e
        try:
            trace = complex(np.trace(np.linalg.solve(d, dd)))
        except np.linalg.LinAlgError:
            return s
        if trace == 0:
            return None
        step = 1.0 / trace
        s = s - step
        if abs(step) <= 1e-14 * (1.0 + abs(s)):
            return s
    return None


def _mode(loop: MultiAxisLoop, s: complex) -> Root:
    _, _, vh = np.linalg.svd(loop.matrix(s))
    v = vh[-1].conj()
    v = v / v[int(np.argmax(np.abs(v)))]
    v = v / np.linalg.norm(v)
    return Root(complex(s.real, abs(s.imag)), v, loop.axes[int(np.argmax(np.abs(v)))])


def roots(loop: MultiAxisLoop, count: int = 6) -> list[Root]:
    """The `count` rightmost characteristic roots, rightmost first (of a complex pair
    the one with positive imaginary part)."""
    n = loop.n
    minv = np.linalg.inv(loop.mass)
    if loop.h == 0.0:
        a = np.block(
            [
                [np.zeros((n, n)), np.eye(n)],
                [-minv @ (loop.k_direct + loop.k_delayed), -minv @ (loop.b_direct + loop.b_delayed)],
            ]
        )
        eig = np.linalg.eigvals(a)
    else:
        h = loop.h
        # Dimensionless time tau = t / h: x' = h A0 x + h A1 x(tau - 1).
        a0 = np.block([[np.zeros((n, n)), h * np.eye(n)], [-h * minv @ loop.k_direct, -h * minv @ loop.b_direct]])
        a1 = np.block([[np.zeros((n, 2 * n))], [-h * minv @ loop.k_delayed, -h * minv @ loop.b_delayed]])
        speed = float(np.max(np.abs(np.linalg.eigvals(minv @ (np.abs(loop.k_direct) + np.abs(loop.k_delayed))))))
        damp = float(np.max(np.abs(np.linalg.eigvals(minv @ (np.abs(loop.b_direct) + np.abs(loop.b_delayed))))))
        nodes = int(min(MAX_NODES, 24 + 3.0 * math.sqrt(speed) * h + 2.0 * damp * h))
        _, d = chebyshev(nodes)
        size = 2 * n
        gen = np.kron(2.0 * d, np.eye(size))
        gen[:size, :] = 0.0
        gen[:size, :size] = a0
        gen[:size, -size:] = a1
        eig = np.linalg.eigvals(gen) / h
    eig = eig[np.argsort(-eig.real)][: max(4 * count, 12)]
    found: list[complex] = []
    for lam in eig:
        z = complex(lam)
        if loop.h > 0.0:
            refined = _newton(loop, z)
            z = z if refined is None else refined
        z = complex(z.real, abs(z.imag))
        if all(abs(z - r) > 1e-8 * (1.0 + abs(z)) for r in found):
            found.append(z)
    found.sort(key=lambda z: -z.real)
    return [_mode(loop, z) for z in found[:count]]


def rightmost(loop: MultiAxisLoop) -> Root:
    return roots(loop, count=1)[0]


@dataclass(frozen=True)
class Margin:
    """The largest factor alpha on the delayed stiffness that keeps the loop stable,
    the crossing frequency [rad/s] and the mode (and axis) that crosses there."""

    alpha: float | None
    omega: float | None
    root: Root | None
    reason: str


def stiffness_margin(loop: MultiAxisLoop, rel_tol: float = 1e-7) -> Margin:
    """Bisection on the sign of the rightmost root's real part over alpha (K_h -> alpha K_h)."""

    def grows(alpha: float) -> bool:
        return rightmost(loop.scaled(alpha)).s.real > 0.0

    if loop.h == 0.0:
        return Margin(math.inf, None, None, "no delay: the delayed stiffness is not limited by the delay")
    lo, hi = 0.0, 1.0
    if grows(1e-9):
        return Margin(
            None,
            None,
            rightmost(loop.scaled(1e-9)),
            "unstable for any delayed stiffness: the direct terms or the damping seen through the delay destabilise it",
        )
    while not grows(hi):
        lo, hi = hi, 2.0 * hi
        if hi > 1e12:
            return Margin(math.inf, None, None, "stable for every scale of the delayed stiffness tried (up to 1e12)")
    if lo == 0.0:
        lo = 1e-9
        probe = 0.5
        while probe > 1e-9 and grows(probe):
            hi = probe
            probe *= 0.5
        lo = max(lo, probe)
    while hi - lo > max(rel_tol, TRACK_WIDTH) * hi:
        lo, hi = (lo, mid) if grows(mid := 0.5 * (lo + hi)) else (mid, hi)
    if hi - lo > rel_tol * hi:
        lo, hi = _bisect_on_crossing_roots(loop, lo, hi, rel_tol, grows)
    root = rightmost(loop.scaled(hi))
    reason = (
        f"the rightmost root crosses the imaginary axis at s = +-j {root.s.imag:.6g} rad/s when the delayed"
        f" stiffness is {lo:.6g} times the given one; the crossing mode is led by axis {root.axis}"
    )
    return Margin(lo, root.s.imag, root, reason)


def _bisect_on_crossing_roots(
    loop: MultiAxisLoop, lo: float, hi: float, rel_tol: float, grows: Callable[[float], bool]
) -> tuple[float, float]:
    """The bisection of `stiffness_margin` inside a narrow bracket (lo stable, hi not), on the roots
    alone that are unstable at hi (those that cross in between), each followed by Newton from its
    value at the previous alpha: a few n x n solves per step instead of the 2n x nodes eigenvalue
    problem. Both ends found are checked with all the roots; should they disagree (a root jumped
    to another branch), the bisection is done with all the roots instead."""
    crossing = [r.s for r in roots(loop.scaled(hi), count=TRACK_ROOTS) if r.s.real > 0.0]
    a, b = lo, hi
    while crossing and len(crossing) < TRACK_ROOTS and b - a > rel_tol * b:
        mid = 0.5 * (a + b)
        moved = [_newton(loop.scaled(mid), z) for z in crossing]
        if any(z is None for z in moved):
            break
        crossing = cast(list[complex], moved)  # none is None
        a, b = (a, mid) if any(z.real > 0.0 for z in crossing) else (mid, b)
    if b - a <= rel_tol * b and (a == lo or not grows(a)) and (b == hi or grows(b)):
        return a, b
    while hi - lo > rel_tol * hi:
        lo, hi = (lo, mid) if grows(mid := 0.5 * (lo + hi)) else (mid, hi)
    return lo, hi


def modal_loops(loop: MultiAxisLoop, tol: float = 1e-9) -> list[dict] | None:
    """Per-mode scalar loops (unit mass) s^2 + b_d s + k_d + (b_h s + k_h) e^{-sh}
    when every M^-1 X diagonalises in one basis; None when the axes couple."""
    minv = np.linalg.inv(loop.mass)
    mats = [minv @ x for x in (loop.k_direct, loop.b_direct, loop.k_delayed, loop.b_delayed)]
    rng = np.random.default_rng(12345)  # a generic combination separates repeated eigenvalues
    combo = sum(c * x for c, x in zip(rng.uniform(1.0, 2.0, 4), mats))
    _, vecs = np.linalg.eig(combo)
    try:
        inv = np.linalg.inv(vecs)
    except np.linalg.LinAlgError:
        return None
    diag = [inv @ x @ vecs for x in mats]
    for x, dx in zip(mats, diag):
        scale = float(np.max(np.abs(x))) or 1.0
        if float(np.max(np.abs(dx - np.diag(np.diag(dx))))) > tol * scale:
            return None
    out = []
    for j in range(loop.n):
        vals = [complex(dx[j, j]) for dx in diag]
        if any(abs(v.imag) > tol * (1.0 + abs(v)) for v in vals):
            return None
        v = vecs[:, j]
        out.append(
            {
                "axis": loop.axes[int(np.argmax(np.abs(v)))],
                "k_direct": vals[0].real,
                "b_direct": vals[1].real,
                "k_delayed": vals[2].real,
                "b_delayed": vals[3].real,
            }
        )
    return out


def planar_loop(
    m: float,
    inertia: float,
    lever: float,
    k_normal: float,
    b_normal: float,
    h: float,
    k_rot: float = 0.0,
    b_rot: float = 0.0,
    direct: float = 0.0,
) -> MultiAxisLoop:
    """The 2-D loop: a free body (mass m [kg], inertia about z [kg m^2]) touching
    at a point `lever` [m] off its CoM along y; normal spring-dashpot
    (k_normal, b_normal) and rotational (k_rot, b_rot) seen through the delay h.
    `direct` in [0, 1] moves that fraction of the stiffness and damping to the
    undelayed (virtual) side. Coordinates q = (x at the contact point, rotation rz).

    The contact point moves by x_c = x - lever rz, so the mobility at it is
    [[1/m + lever^2 / I, -lever / I], [-lever / I, 1 / I]] and M = its inverse."""
    m = check_positive("m", m, "kg")
    inertia = check_positive("inertia", inertia, "kg m^2")
    g = np.array([[1.0 / m + lever * lever / inertia, -lever / inertia], [-lever / inertia, 1.0 / inertia]])
    mass = np.linalg.inv(g)
    k = np.diag([k_normal, k_rot])
    b = np.diag([b_normal, b_rot])
    return MultiAxisLoop(
        0.5 * (mass + mass.T), direct * k, direct * b, (1.0 - direct) * k, (1.0 - direct) * b, h, ("x", "rz")
    )


def hybrid_loop6(ideal: Contact6, passive: Contact6, g1: ArrayLike, g2: ArrayLike, h: float) -> MultiAxisLoop:
    """The 6-DOF hybrid loop at the contact's onset configuration: M = (G1 + G2)^-1,
    the virtual impedance (K - K_p, C - C_p) direct, the passive (K_p, C_p) delayed."""
    mass = np.linalg.inv(np.asarray(g1, float) + np.asarray(g2, float))
    return MultiAxisLoop(
        0.5 * (mass + mass.T),
        ideal.stiffness - passive.stiffness,
        ideal.damping - passive.damping,
        passive.stiffness,
        passive.damping,
        h,
    )
