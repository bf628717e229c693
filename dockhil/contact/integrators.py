"""Integrators for the two-body contact, and the unilateral contact simulation.

Between contact events every model here is linear time-invariant,
    M q'' + C q' + K q = u      (state x = [q, v], u held constant over a step),
so each method's step is a fixed affine map x+ = Phi(dt) x + Gamma(dt) u.
`Integrator` builds Phi and Gamma once per step size and then steps with one
matrix-vector product, which is what a simulation node wants per tick:

    integ = Integrator(LinearSecondOrderSystem.free([m1, m2]), "exact")
    state = integ.step(state, forces, dt)

Methods: "exact" (matrix exponential, zero-order hold on u: exact for
piecewise-constant inputs), "rk4", "symplectic_euler" (semi-implicit: new
velocity first, then position with it) and "euler" (explicit). The explicit
ones refuse a step outside their stability region for the system's stiffness
and name the largest stable step (or warn, with on_unstable="warn").
`simulate_reference` integrates with scipy's solve_ivp and locates contact
events; it is the only function here that imports scipy.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.linalg import expm
from dockhil.contact.scenario import (
    ContactModelError,
    ContactScenario,
    StepTooLargeError,
    Trajectory,
    UnstableStepWarning,
    check_finite,
    check_positive,
)

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

METHODS = ("exact", "rk4", "symplectic_euler", "euler")
_METHOD_NAMES = {
    "exact": "the exact (matrix exponential) step",
    "rk4": "RK4",
    "symplectic_euler": "semi-implicit (symplectic) Euler",
    "euler": "explicit Euler",
}


class LinearSecondOrderSystem:
    """M q'' + C q' + K q = u for n bodies moving along one axis.

    masses [kg] (n,), stiffness K [N/m] and damping C [N s/m] (n, n), u the
    external forces [N]. The state is x = [q, v] (2n,).
    """

    def __init__(self, masses: Sequence[float], stiffness: ArrayLike | None = None, damping: ArrayLike | None = None):
        m = np.array([check_positive(f"mass[{i}]", v, "kg") for i, v in enumerate(masses)], dtype=float)
        n = m.size
        k = np.zeros((n, n)) if stiffness is None else np.array(stiffness, dtype=float)
        c = np.zeros((n, n)) if damping is None else np.array(damping, dtype=float)
        for name, mat in (("stiffness", k), ("damping", c)):
            if mat.shape != (n, n):
                raise ContactModelError(f"{name} must be a {n}x{n} matrix, got shape {mat.shape}")
            if not np.all(np.isfinite(mat)):
                raise ContactModelError(f"{name} must be finite, got {mat.tolist()}")
        self.masses, self.stiffness, self.damping = m, k, c
        self.n = n
        minv_k = k / m[:, None]
        minv_c = c / m[:, None]
        self.A = np.block([[np.zeros((n, n)), np.eye(n)], [-minv_k, -minv_c]])
        self.B = np.vstack([np.zeros((n, n)), np.diag(1.0 / m)])

    @classmethod
    def free(cls, masses: Sequence[float]) -> LinearSecondOrderSystem:
        """Free-floating bodies: only the external forces act."""
        return cls(masses)

    @classmethod
    def ideal_contact(cls, scenario: ContactScenario) -> LinearSecondOrderSystem:
        """Eq. 1 in two-body form: kcs and bcs between chaser and target."""
        link = np.array([[1.0, -1.0], [-1.0, 1.0]])
        return cls([scenario.m1, scenario.m2], scenario.kcs * link, scenario.bcs * link)

    @classmethod
    def hybrid_contact(cls, scenario: ContactScenario, impedance: VirtualImpedance) -> LinearSecondOrderSystem:
        """Eqs. 2-4 in contact: passive k plus the virtual impedance on the CoM wall
        (see dockhil.contact.hybrid: x1 - w = m2 p / M, x2 - w = -m1 p / M)."""
        m1, m2, total = scenario.m1, scenario.m2, scenario.total_mass
        link = np.array([[1.0, -1.0], [-1.0, 1.0]])
        # Row i: force on body i per unit of (x1 - x2) from the virtual parts.
        virt_k = np.array([[m2 / total * impedance.k1] * 2, [m1 / total * impedance.k2] * 2]) * link
        virt_c = np.array([[m2 / total * impedance.b1] * 2, [m1 / total * impedance.b2] * 2]) * link
        return cls([m1, m2], scenario.k * link + virt_k, virt_c)

    def accelerations(self, q: ArrayLike, v: ArrayLike, u: ArrayLike | None = None) -> np.ndarray:
        """q'' [m/s^2] for positions q, velocities v and external forces u."""
        force = -(self.stiffness @ np.asarray(q, float)) - self.damping @ np.asarray(v, float)
        if u is not None:
            force = force + np.asarray(u, float)
        return force / self.masses

    def flexible_basis(self) -> np.ndarray:
        """Orthonormal basis (2n, r) of the state space without the rigid-body
        motions (directions where neither K nor C acts). Those motions are exact
        and marginal (eigenvalue 1, a Jordan block) for every method, so the
        stability check leaves them out rather than fight their round-off."""
        n = self.n
        _, sv, vt = np.linalg.svd(np.vstack([self.stiffness, self.damping]))
        scale = sv[0] if sv.size and sv[0] > 0 else 1.0
        rank = int(np.sum(sv > 1e-12 * scale)) if sv.size and sv[0] > 0 else 0
        rigid = vt[rank:].T  # (n, n - rank)
        zero = np.zeros_like(rigid)
        rigid_states = np.hstack([np.vstack([rigid, zero]), np.vstack([zero, rigid])])
        if rigid_states.shape[1] == 0:
            return np.eye(2 * n)
        q, _ = np.linalg.qr(np.hstack([rigid_states, np.eye(2 * n)]))
        return q[:, rigid_states.shape[1] : 2 * n]


def step_matrices(system: LinearSecondOrderSystem, method: str, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Phi, Gamma of one step x+ = Phi x + Gamma u of `method` with step dt [s]."""
    a, b = system.A, system.B
    size, n = a.shape[0], system.n
    if method == "exact":
        aug = np.zeros((size + n, size + n))
        aug[:size, :size] = a * dt
        aug[:size, size:] = b * dt
        e = expm(aug)
        return e[:size, :size], e[:size, size:]
    ident = np.eye(size)
    if method == "euler":
        return ident + dt * a, dt * b
    if method == "rk4":
        ha = dt * a
        ha2 = ha @ ha
        ha3 = ha2 @ ha
        phi = ident + ha + ha2 / 2.0 + ha3 / 6.0 + ha3 @ ha / 24.0
        gamma = dt * (ident + ha / 2.0 + ha2 / 6.0 + ha3 / 24.0) @ b
        return phi, gamma
    if method == "symplectic_euler":
        minv_k = -a[n:, :n]
        minv_c = -a[n:, n:]
        eye_n = np.eye(n)
        v_row = np.hstack([-dt * minv_k, eye_n - dt * minv_c])
        q_row = np.hstack([eye_n, np.zeros((n, n))]) + dt * v_row
        minv = b[n:, :]
        return np.vstack([q_row, v_row]), np.vstack([dt * dt * minv, dt * minv])
    raise ContactModelError(f"unknown integration method {method!r}; choose one of {', '.join(METHODS)}")


def max_stable_step(system: LinearSecondOrderSystem, method: str) -> float:
    """Largest step [s] for which `method` does not amplify the system's motion
    more than the exact flow does: inf for "exact" and for systems without
    stiffness or damping, 0.0 when no practical step is stable (explicit Euler
    on an undamped oscillation)."""
    if method not in METHODS:
        raise ContactModelError(f"unknown integration method {method!r}; choose one of {', '.join(METHODS)}")
    if method == "exact":
        return math.inf
    basis = system.flexible_basis()
    if basis.shape[1] == 0:
        return math.inf
    lam = np.linalg.eigvals(basis.T @ system.A @ basis)
    scale = float(np.max(np.abs(lam)))
    if scale == 0.0:
        return math.inf
    # Growing physical modes (e.g. a negative virtual spring) are not the
    # method's fault: that many step eigenvalues may exceed 1; the rest may not.
    growing = int(np.sum(lam.real > 1e-12 * scale))

    def stable(dt: float) -> bool:
        phi = step_matrices(system, method, dt)[0]
        mags = np.sort(np.abs(np.linalg.eigvals(basis.T @ phi @ basis)))[::-1]
        return bool(np.all(mags[growing:] <= 1.0 + 1e-14))

    grid = np.geomspace(1e-6, 1e3, 271) / scale
    if not stable(grid[0]):
        return 0.0
    lo = float(grid[0])
    hi = None
    for dt in grid[1:]:
        if not stable(float(dt)):
            hi = float(dt)
            break
        lo = float(dt)
    if hi is None:
        return math.inf
    while hi - lo > 1e-13 * hi:
        mid = 0.5 * (lo + hi)
        if stable(mid):
            lo = mid
        else:
            hi = mid
    return lo


class Integrator:
    """Steps a LinearSecondOrderSystem with one method; the step matrices of each
    step size are computed once and the stability check is done once per size.

    on_unstable: "raise" (default) refuses a step outside the method's stability
    region with StepTooLargeError naming the largest stable step; "warn" takes it
    and emits UnstableStepWarning once per step size.
    """

    _CACHE_SIZE = 8

    def __init__(self, system: LinearSecondOrderSystem, method: str = "exact", on_unstable: str = "raise"):
        if method not in METHODS:
            raise ContactModelError(f"unknown integration method {method!r}; choose one of {', '.join(METHODS)}")
        if on_unstable not in ("raise", "warn"):
            raise ContactModelError(f"on_unstable must be 'raise' or 'warn', got {on_unstable!r}")
        self.system = system
        self.method = method
        self.on_unstable = on_unstable
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._max_step: float | None = None
        self._zero_force = np.zeros(system.n)

    def max_stable_step(self) -> float:
        if self._max_step is None:
            self._max_step = max_stable_step(self.system, self.method)
        return self._max_step

    def check_step(self, dt: float) -> None:
        """Raise (or warn) if dt is outside the method's stability region."""
        if self.method == "exact":
            return
        limit = self.max_stable_step()
        if dt <= limit * (1.0 + 1e-9):
            return
        name = _METHOD_NAMES[self.method]
        if limit == 0.0:
            detail = (
                f"no step is stable: {name} amplifies every undamped oscillation of this system;"
                " use method 'symplectic_euler', 'rk4' or 'exact'"
            )
        else:
            detail = (
                f"the largest stable step is {limit:.6g} s; use dt <= {limit:.6g} s"
                " or method 'exact' (stable for every step)"
            )
        message = f"{name} with dt = {dt:.6g} s is outside its stability region for this stiffness: {detail}"
        if self.on_unstable == "raise":
            raise StepTooLargeError(message)
        warnings.warn(message, UnstableStepWarning, stacklevel=3)

    def step_matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        mats = self._cache.get(dt)
        if mats is None:
            dt = check_positive("dt", dt, "s")
            self.check_step(dt)
            mats = step_matrices(self.system, self.method, dt)
            if len(self._cache) >= self._CACHE_SIZE:
                self._cache.pop(next(iter(self._cache)))
            self._cache[dt] = mats
        return mats

    def step(self, state: np.ndarray, force: np.ndarray | None = None, dt: float = 1e-3) -> np.ndarray:
        """State [q, v] after one step of dt [s] with the external forces held constant."""
        phi, gamma = self.step_matrices(dt)
        return phi @ state + gamma @ (self._zero_force if force is None else force)

    def step_uncached(self, state: np.ndarray, force: np.ndarray, dt: float) -> np.ndarray:
        """One step without caching or stability check: for the sub-steps that
        end at a contact event, which are shorter than a checked step (so
        stable too) and whose lengths never repeat."""
        phi, gamma = step_matrices(self.system, self.method, dt)
        return phi @ state + gamma @ force


def _scenario_systems(
    scenario: ContactScenario, impedance: VirtualImpedance | None
) -> tuple[LinearSecondOrderSystem, LinearSecondOrderSystem]:
    free = LinearSecondOrderSystem.free([scenario.m1, scenario.m2])
    if impedance is None:
        return free, LinearSecondOrderSystem.ideal_contact(scenario)
    return free, LinearSecondOrderSystem.hybrid_contact(scenario, impedance)


def _default_end(scenario: ContactScenario, gap: float) -> float:
    from dockhil.contact.ideal import contact_duration

    v0 = scenario.closing_velocity
    if v0 <= 0.0:
        return 5.0
    duration = contact_duration(scenario.reduced_mass, scenario.kcs, scenario.bcs)
    if not math.isfinite(duration):
        duration = 10.0 * scenario.reduced_mass / scenario.bcs
    return gap / v0 + 1.25 * duration


def _contact_force(system: LinearSecondOrderSystem, state: np.ndarray, in_contact: bool) -> float:
    """Compressive force on the chaser [N]: minus the contact part of its force."""
    if not in_contact:
        return 0.0
    n = system.n
    return float(system.stiffness[0] @ state[:n] + system.damping[0] @ state[n:])


def simulate_contact(
    scenario: ContactScenario,
    *,
    impedance: VirtualImpedance | None = None,
    method: str = "exact",
    dt: float = 1e-3,
    t_end: float | None = None,
    gap: float = 0.0,
    thrust: tuple[float, float] = (0.0, 0.0),
    on_unstable: str = "raise",
) -> Trajectory:
    """Fixed-step unilateral contact run: the ideal model (Eq. 1), or the hybrid
    model (Eqs. 2-4, no delay) when `impedance` is given.

    Contact onset and separation are located inside a step (bisection on the
    method's own step map) and the step is split there, so the samples stay on
    the grid t = n dt while the contact starts and ends at the right time.
    thrust: constant external forces [N] on chaser and target.
    Starts with the chaser's surface at -gap, the target's at 0.
    """
    dt = check_positive("dt", dt, "s")
    gap = check_finite("gap", gap, "m")
    if gap < 0.0:
        raise ContactModelError(f"gap must be >= 0 m, got {gap!r}")
    t_end = _default_end(scenario, gap) if t_end is None else check_positive("t_end", t_end, "s")
    u = np.array([check_finite("thrust[0]", thrust[0], "N"), check_finite("thrust[1]", thrust[1], "N")])
    free_sys, contact_sys = _scenario_systems(scenario, impedance)
    free = Integrator(free_sys, method, on_unstable)
    contact = Integrator(contact_sys, method, on_unstable)
    contact.step_matrices(dt)  # refuse an unstable step before running

    steps = int(math.ceil(t_end / dt - 1e-9))
    times = np.arange(steps + 1) * dt
    states = np.empty((steps + 1, 4))
    forces = np.empty(steps + 1)
    flags = np.empty(steps + 1, dtype=bool)
    x = np.array([-gap, 0.0, scenario.v1, scenario.v2])
    touching = bool(x[0] - x[1] > 0.0 or (x[0] == x[1] and x[2] > x[3]))
    onset = 0.0 if touching else None
    exit_time = None
    states[0], flags[0] = x, touching
    forces[0] = _contact_force(contact_sys, x, touching)
    omega = scenario.natural_frequency
    for i in range(steps):
        x, touching, events = step_with_events(free, contact, x, u, dt, touching, RELATIVE, omega)
        for offset, now_touching in events:
            if now_touching and onset is None:
                onset = times[i] + offset
            elif not now_touching and exit_time is None:
                exit_time = times[i] + offset
        states[i + 1], flags[i + 1] = x, touching
        forces[i + 1] = _contact_force(contact_sys, x, touching)
    return Trajectory.from_states(times, states, forces, flags, onset, exit_time, method)


class Penetration:
    """p = c . q + offset: how far the bodies overlap, as a linear function of positions q."""

    def __init__(self, c: ArrayLike, offset: float = 0.0):
        self.c = np.asarray(c, float)
        self.offset = offset

    def of(self, state: np.ndarray) -> float:
        return float(self.c @ state[: self.c.size]) + self.offset

    def rate(self, state: np.ndarray) -> float:
        return float(self.c @ state[self.c.size :])


RELATIVE = Penetration([1.0, -1.0])  # chaser minus target


def step_with_events(
    free: Integrator,
    contact: Integrator,
    x: np.ndarray,
    u: np.ndarray,
    dt: float,
    touching: bool,
    pen: Penetration,
    omega: float,
) -> tuple[np.ndarray, bool, list[tuple[float, bool]]]:
    """One step of dt with the contact switching on and off inside it.

    `omega` [rad/s] is the contact's natural frequency. Returns the new
    state, whether the bodies touch at its end, and the events [(time into
    the step, touching after)]. A step with no event is the plain cached
    step, so event handling changes no result where nothing happens. Events
    hidden inside a step (a contact shorter than dt) are found by sampling
    at a quarter of the contact period and, in free flight, at the vertex of
    the parabola the penetration follows."""
    events: list[tuple[float, bool]] = []
    done = 0.0
    remaining = dt
    for _ in range(16):  # more events in one step than this would be chatter
        integ = contact if touching else free
        end = integ.step(x, u, dt) if remaining == dt else integ.step_uncached(x, u, remaining)
        bracket = _event_bracket(integ, x, u, remaining, end, touching, pen, omega)
        if bracket is None:
            return end, touching, events
        tau = _locate_event(integ, x, u, bracket, touching, pen)
        x = integ.step_uncached(x, u, tau)
        done += tau
        remaining -= tau
        touching = not touching
        events.append((done, touching))
        if remaining <= 0.0:
            return x, touching, events
    raise ContactModelError(f"more than 16 contact events within one step of {dt:.6g} s (chatter); use a smaller dt")


def _side_changed(y: np.ndarray, touching: bool, pen: Penetration) -> bool:
    p = pen.of(y)
    return p <= 0.0 if touching else p > 0.0


def _event_bracket(
    integ: Integrator,
    x: np.ndarray,
    u: np.ndarray,
    span: float,
    end: np.ndarray,
    touching: bool,
    pen: Penetration,
    omega: float,
) -> tuple[float, float] | None:
    """(lo, hi) with the penetration on the old side at lo and on the new side at hi, or None."""
    inner: list[float] = []
    if touching and omega * span > 0.5 * math.pi:
        # In contact p changes sign at most once per half period: look every quarter period.
        quarter = 0.5 * math.pi / omega
        inner = [quarter * j for j in range(1, int(span / quarter) + 1) if quarter * j < span]
    elif not touching:
        # In free flight p is a parabola: it may enter and leave contact within the step.
        n = integ.system.n
        v0 = pen.rate(x)
        a = float(pen.c @ integ.system.accelerations(x[:n], x[n:], u))
        if a < 0.0 < v0 and -v0 / a < span:
            inner = [-v0 / a]
    lo = 0.0
    for t in inner:
        if _side_changed(integ.step_uncached(x, u, t), touching, pen):
            return lo, t
        lo = t
    return (lo, span) if _side_changed(end, touching, pen) else None


def _locate_event(
    integ: Integrator, x: np.ndarray, u: np.ndarray, bracket: tuple[float, float], touching: bool, pen: Penetration
) -> float:
    """Sub-step length in (lo, hi] at which the penetration changes side:
    returns the first point found on the new side, so the mode switch is safe."""
    lo, hi = bracket
    resolution = 4.0 * np.finfo(float).eps * max(1.0, hi)
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        if _side_changed(integ.step_uncached(x, u, mid), touching, pen):
            hi = mid
        else:
            lo = mid
    return hi


def simulate_reference(
    scenario: ContactScenario,
    t_eval: ArrayLike,
    *,
    impedance: VirtualImpedance | None = None,
    gap: float = 0.0,
    thrust: tuple[float, float] = (0.0, 0.0),
    rtol: float = 1e-11,
    atol: float = 1e-14,
) -> Trajectory:
    """Reference run with scipy's solve_ivp (DOP853), contact onset and
    separation located as terminal events; states sampled at t_eval [s]."""
    from scipy.integrate import solve_ivp

    t_eval = np.asarray(t_eval, dtype=float)
    if t_eval.ndim != 1 or t_eval.size == 0 or np.any(np.diff(t_eval) < 0) or t_eval[0] < 0:
        raise ContactModelError("t_eval must be a non-empty increasing sequence of times >= 0 s")
    gap = check_finite("gap", gap, "m")
    u = np.array([float(thrust[0]), float(thrust[1])])
    free_sys, contact_sys = _scenario_systems(scenario, impedance)

    def penetration(_t, y):
        return y[0] - y[1]

    penetration.terminal = True  # type: ignore[attr-defined]  # solve_ivp reads an event's flags from it
    x = np.array([-gap, 0.0, scenario.v1, scenario.v2])
    touching = bool(x[0] - x[1] > 0.0 or (x[0] == x[1] and x[2] > x[3]))
    onset = 0.0 if touching else None
    exit_time = None
    t0, t_final = 0.0, float(t_eval[-1])
    phases = []
    while t0 < t_final:
        system = contact_sys if touching else free_sys
        penetration.direction = -1.0 if touching else 1.0  # type: ignore[attr-defined]  # as terminal
        a, b = system.A, system.B @ u
        sol = solve_ivp(
            lambda _t, y, a=a, b=b: a @ y + b,
            (t0, t_final),
            x,
            method="DOP853",
            rtol=rtol,
            atol=atol,
            events=penetration,
            dense_output=True,
        )
        phases.append((t0, sol.t[-1], touching, sol.sol))
        if sol.status != 1:
            break
        t0 = float(sol.t_events[0][0])
        x = sol.y_events[0][0]
        touching = not touching
        if touching and onset is None:
            onset = t0
        elif not touching and exit_time is None:
            exit_time = t0
    states = np.empty((t_eval.size, 4))
    flags = np.empty(t_eval.size, dtype=bool)
    ends = np.array([end for _start, end, _mode, _dense in phases[:-1]])
    # A sample at an event time belongs to the phase that starts there.
    which = np.searchsorted(ends, t_eval, side="right")
    for i, (t, k) in enumerate(zip(t_eval, which)):
        _start, _end, mode, dense = phases[k]
        states[i] = dense(t)
        flags[i] = mode
    forces = np.array([_contact_force(contact_sys, s, f) for s, f in zip(states, flags)])
    return Trajectory.from_states(t_eval, states, forces, flags, onset, exit_time, "solve_ivp")
