"""The discrete-time loop a scene actually runs, and whether its step resolves the contact.

The graph does not run the delay equation m s^2 + (b_d + b_h e^{-sh}) s + k_d + k_h e^{-sh} = 0;
it runs its sampled version, tick by tick (dockhil.contact.hilloop):

    [p, p']_{k+1} = Phi [p, p']_k + Gamma a_k            (the integrator, `substeps` steps of dt/n)
    a_k = -(k_d p_k + b_d p'_k) / m - (k_h r_k + b_h r'_k) / m
    r_k = p_{k-d}            (the robot: the command of d = round(h / dt) ticks ago; with a servo lag
                              tau, r_k = (1 - alpha) r_{k-1} + alpha p_{k-d}, alpha = 1 - e^{-dt/tau})

with the accelerations held over the step (zero-order hold). p is the relative coordinate x1 - x2,
m the reduced mass (m1 for a fixed target). In z, with P = Phi + Gamma c_d^T, c = -[k, b] / m, this
is the scalar polynomial

    Q(z) = (z - (1 - alpha)) z^d det(zI - P) - alpha z c_h^T adj(zI - P) Gamma

of degree d + 3, whose roots are exactly the eigenvalues of the loop's one-tick map (the matrix
determinant lemma on the rank-one delayed term). The loop is stable when every root lies inside
the unit circle; its growth rate is ln(spectral radius) / dt, the sampled counterpart of the
rightmost root of the delay equation.

The ideal model (ideal.yaml) integrates the contact inside the step instead: its one-tick map is
the integrator's own step matrix of the contact, Phi^n.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dockhil.contact.integrators import LinearSecondOrderSystem, step_matrices
from dockhil.contact.scenario import ContactModelError, check_finite, check_positive

DENSE_DEGREE = 600  # up to this degree the roots come from the companion matrix (all of them)
# The companion matrix is degree^2 complex numbers and its eigenvalues cost degree^3: at 15000 ticks
# of delay 3.6 GB and a minute. Above this degree, a loop whose dominant roots Newton cannot verify
# is refused (RootsNotResolved) instead.
DENSE_FALLBACK_DEGREE = 4000


class RootsNotResolved(ValueError):
    """The dominant roots of a long-delay loop could not be verified, and all of them cost too much."""


# The resolution criterion. Forces held over a step act on average dt/2 late, so the peak force of
# a contact errs by about 0.4 omega dt (measured from 1 to 200 kHz on the stiff case of issue 12:
# 2.61 -> +158 %, 0.26 -> +10.6 %, 0.026 -> +0.98 %). omega is the fastest pole of the contact.
REFUSE_OMEGA_DT = 0.25  # above: about 10 % peak-force error or worse, refuse
WARN_OMEGA_DT = 0.025  # above: about 1 % peak-force error, warn
REFUSE_SAMPLES = 10  # samples per contact (or per oscillation period) below which we refuse
WARN_SAMPLES = 100


@dataclass(frozen=True)
class SampledLoop:
    """The relative-motion loop of a scene as the graph runs it.

    m: reduced mass [kg]; k_direct/b_direct: stiffness/damping acting on the current state
    (virtual impedance, or the ideal contact inside the step); k_delayed/b_delayed: acting through
    the robot, `delay_ticks` ticks late (passive compliance); dt: tick [s]; method, substeps: the
    dynamics' integrator; lag: robot servo time constant [s]; held: forces held over the tick
    (the hybrid graph) or integrated inside the step (the ideal model)."""

    m: float
    k_direct: float
    b_direct: float
    k_delayed: float = 0.0
    b_delayed: float = 0.0
    dt: float = 1e-3
    delay_ticks: int = 0
    method: str = "exact"
    substeps: int = 1
    lag: float = 0.0
    held: bool = True

    def __post_init__(self) -> None:
        check_positive("m", self.m, "kg")
        check_positive("dt", self.dt, "s")
        for name in ("k_direct", "b_direct", "k_delayed", "b_delayed", "lag"):
            check_finite(name, getattr(self, name))
        if self.delay_ticks < 0 or self.substeps < 1:
            raise ContactModelError("delay_ticks must be >= 0 and substeps >= 1")

    @property
    def alpha(self) -> float:
        return 1.0 if self.lag == 0.0 else -math.expm1(-self.dt / self.lag)


# The longest delay, in ticks, whose sampled loop is analysed: its characteristic polynomial has
# that degree, and the root finding grows with it (30000 ticks took minutes and 11 GB).
MAX_DELAY_TICKS = 20000


def _tick_matrices(loop: SampledLoop, system: LinearSecondOrderSystem) -> tuple[np.ndarray, np.ndarray]:
    """Phi, Gamma of one tick made of `substeps` integrator steps with the input held."""
    phi1, gam1 = step_matrices(system, loop.method, loop.dt / loop.substeps)
    phi, gam = np.eye(2), np.zeros_like(gam1)
    for _ in range(loop.substeps):
        phi, gam = phi1 @ phi, phi1 @ gam + gam1
    return phi, gam


def one_tick_map(loop: SampledLoop) -> np.ndarray:
    """The loop's one-tick state matrix (augmented with the delay line and the servo state).
    Its eigenvalues are the roots of `characteristic_polynomial`; kept for cross-checks."""
    if not loop.held:
        system = LinearSecondOrderSystem([loop.m], [[loop.k_direct]], [[loop.b_direct]])
        return _tick_matrices(loop, system)[0]
    phi, gam = _tick_matrices(loop, LinearSecondOrderSystem.free([1.0]))
    d = loop.delay_ticks
    n = 2 * (d + 1) + 2  # [p, p']_k, ..., [p, p']_{k-d}, [r, r']_{k-1}
    a = np.zeros((n, n))
    c_d = -np.array([loop.k_direct, loop.b_direct]) / loop.m
    c_h = -np.array([loop.k_delayed, loop.b_delayed]) / loop.m
    al = loop.alpha
    # r_k = (1 - alpha) r_{k-1} + alpha [p, p']_{k-d}; a_k = c_d . x_k + c_h . r_k
    r_from_old = (1.0 - al) * np.eye(2)
    a[:2, :2] = phi + np.outer(gam[:, 0], c_d)
    a[:2, 2 * d : 2 * d + 2] += al * np.outer(gam[:, 0], c_h)
    a[:2, -2:] += np.outer(gam[:, 0], c_h) @ r_from_old
    a[2 : 2 * (d + 1), : 2 * d] = np.eye(2 * d)
    a[-2:, 2 * d : 2 * d + 2] = al * np.eye(2)
    a[-2:, -2:] = r_from_old
    return a


def characteristic_polynomial(loop: SampledLoop) -> np.ndarray:
    """Coefficients of Q(z), lowest power first (see the module docstring)."""
    if not loop.held:
        phi = one_tick_map(loop)
        return np.array([np.linalg.det(phi), -np.trace(phi), 1.0])
    phi, gam = _tick_matrices(loop, LinearSecondOrderSystem.free([1.0]))
    g = gam[:, 0]
    c_d = -np.array([loop.k_direct, loop.b_direct]) / loop.m
    c_h = -np.array([loop.k_delayed, loop.b_delayed]) / loop.m
    p = phi + np.outer(g, c_d)
    det_poly = np.array([np.linalg.det(p), -np.trace(p), 1.0])
    # c_h^T adj(zI - P) g = e1 z + e0
    e1 = c_h @ g
    e0 = c_h[0] * (-p[1, 1] * g[0] + p[0, 1] * g[1]) + c_h[1] * (p[1, 0] * g[0] - p[0, 0] * g[1])
    d, al = loop.delay_ticks, loop.alpha
    q = np.zeros(d + 4)
    q[d + 1 : d + 4] += det_poly  # z * z^d det
    q[d : d + 3] -= (1.0 - al) * det_poly  # -(1 - alpha) z^d det
    q[1] -= al * e0
    q[2] -= al * e1
    return q


def _q_and_derivative(q: np.ndarray, z: complex) -> tuple[complex, complex]:
    """Q(z), Q'(z) for a sparse coefficient vector (lowest first)."""
    idx = np.nonzero(q)[0]
    powers = np.array([z ** int(i) for i in idx])
    val = complex(np.sum(q[idx] * powers))
    dval = complex(np.sum(q[idx][idx > 0] * idx[idx > 0] * powers[idx > 0] / z)) if z != 0 else complex(q[1])
    return val, dval


VERIFY_MARGIN = 1e-4  # relative width of the annulus about the dominant roots checked for other zeros


def _zeros_outside(q: np.ndarray, radius: float, margin: float = VERIFY_MARGIN) -> int:
    """How many zeros of Q lie outside |z| = radius: the degree minus the winding number of
    Q(radius e^{i theta}) about 0 (argument principle). Sampled finely enough that a zero at
    least `margin` * radius away from the circle cannot slip between two samples."""
    deg = len(q) - 1
    n = int(max(8192, 64 * deg, 40.0 * math.pi / margin))
    # e^{i k theta_j} is the table's entry (k j mod n): one exp for all powers, and exact arguments.
    unit = np.exp((2.0j * math.pi / n) * np.arange(n))
    j = np.arange(n, dtype=np.int64)
    vals = np.zeros(n, complex)
    for i in np.nonzero(q)[0]:
        vals += (q[i] * radius ** int(i)) * unit[(int(i) * j) % n]
    # The winding number: the phase steps between neighbouring samples (each below pi), summed.
    inside = int(round(float(np.sum(np.angle(np.roll(vals, -1) * np.conj(vals)))) / (2.0 * math.pi)))
    return deg - inside


def sampled_roots(loop: SampledLoop, guesses: Sequence[complex] = ()) -> np.ndarray:
    """Roots z of the loop, largest modulus first. Up to degree DENSE_DEGREE: all of them
    (companion matrix). Above: the dominant ones, by Newton from `guesses` (e.g. e^{s dt} of the
    delay equation's rightmost roots), accepted only when the argument principle finds no zero
    outside the largest one found; otherwise all of them after all."""
    q = characteristic_polynomial(loop)
    q = np.trim_zeros(q, "b")
    if len(q) - 1 <= DENSE_DEGREE or not len(guesses):
        return _all_roots(q)
    found: list[complex] = []
    for z0 in guesses:
        z = complex(z0)
        for _ in range(60):
            f, df = _q_and_derivative(q, z)
            if df == 0:
                break
            step = f / df
            z -= step
            if abs(step) < 1e-15 * max(1.0, abs(z)):
                break
        if all(abs(z - w) > 1e-10 for w in found):
            found.append(z)
    found.sort(key=lambda z: -abs(z))
    if found:
        # Accepted when no zero lies outside the annulus about the largest found, and every zero
        # inside the annulus is one found.
        rho = abs(found[0])
        near = sum(1 for z in found if abs(z) > rho * (1.0 - VERIFY_MARGIN))
        if (
            _zeros_outside(q, rho * (1.0 + VERIFY_MARGIN)) == 0
            and _zeros_outside(q, rho * (1.0 - VERIFY_MARGIN)) == near
        ):
            return np.array(found)
    return _all_roots(q)


def _all_roots(q: np.ndarray) -> np.ndarray:
    deg = len(q) - 1
    if deg > DENSE_FALLBACK_DEGREE:
        raise RootsNotResolved(
            f"the sampled loop's dominant roots at degree {deg} (its ticks of delay) could not "
            f"be verified, and finding all {deg} roots is beyond the {DENSE_FALLBACK_DEGREE} "
            f"this check computes"
        )
    roots = np.roots(q[::-1])
    return roots[np.argsort(-np.abs(roots))]


def spectral_radius(loop: SampledLoop, guesses: Sequence[complex] = ()) -> float:
    return float(abs(sampled_roots(loop, guesses)[0]))


def sampled_growth_rate(loop: SampledLoop, guesses: Sequence[complex] = ()) -> float:
    """ln(spectral radius) / dt [1/s]: < 0 decays, > 0 grows (the sampled rightmost root)."""
    rho = spectral_radius(loop, guesses)
    return -math.inf if rho == 0.0 else math.log(rho) / loop.dt


def sampled_rightmost(loop: SampledLoop, guesses: Sequence[complex] = ()) -> complex:
    """The dominant root as s = ln(z) / dt [1/s], imaginary part >= 0."""
    z = complex(sampled_roots(loop, guesses)[0])
    if z == 0:
        return complex(-math.inf, 0.0)
    s = cmath.log(z) / loop.dt
    return complex(s.real, abs(s.imag))


def contact_poles_speed(m: float, k: float, b: float) -> float:
    """The fastest pole |s| [rad/s] of m s^2 + b s + k = 0 (sqrt(k/m) when underdamped)."""
    roots = np.roots([m, b, k]) if (k or b) else np.array([0.0])
    return float(np.max(np.abs(roots)))


@dataclass(frozen=True)
class Resolution:
    """How well a step resolves a contact: omega*dt and samples per contact (or per period)."""

    omega: float  # [rad/s] fastest pole the step must follow
    dt: float
    span: float  # [s] contact duration, or oscillation period of a lasting contact
    span_name: str  # "contact" or "period"

    @property
    def omega_dt(self) -> float:
        return self.omega * self.dt

    @property
    def samples(self) -> float:
        return self.span / self.dt

    @property
    def refused(self) -> bool:
        return self.omega_dt > REFUSE_OMEGA_DT or self.samples < REFUSE_SAMPLES

    @property
    def coarse(self) -> bool:
        return self.omega_dt > WARN_OMEGA_DT or self.samples < WARN_SAMPLES

    def fine_rate(self) -> float:
        """The lowest rate [Hz] (two significant digits, rounded up) at which the step is not coarse."""
        need = max(self.omega / WARN_OMEGA_DT, WARN_SAMPLES / self.span if self.span > 0 else 0.0)
        return round_up(need)

    def describe(self) -> str:
        return (
            f"omega*dt = {self.omega_dt:.3g} (omega = {self.omega:.4g} rad/s, dt = {self.dt:.3g} s), "
            f"{self.samples:.3g} samples per {self.span_name}"
        )


def round_up(rate: float) -> float:
    """rate rounded up to two significant digits."""
    if rate <= 0.0 or not math.isfinite(rate):
        return rate
    scale = 10.0 ** (math.floor(math.log10(rate)) - 1)
    return math.ceil(rate / scale - 1e-9) * scale
