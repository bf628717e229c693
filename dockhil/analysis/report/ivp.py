"""The contact integrated by scipy's solve_ivp: the unilateral two-body contact, its passive
compliance seen through a pure delay, by the method of steps (the report's solve_ivp rows and the
implicit solvers of its stiff cases)."""

from __future__ import annotations

import bisect
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.integrators import LinearSecondOrderSystem
from dockhil.contact.scenario import ContactModelError, ContactScenario

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

IVP_METHODS = ("RK45", "DOP853", "Radau", "LSODA")


class DelayedContactRun:
    """The unilateral two-body contact integrated by scipy's solve_ivp, with the
    passive compliance seen through a pure delay h (h = 0: the ideal contact or
    the undelayed hybrid model).

        m1 x1'' = fs(t) + fv1(x(t)),   m2 x2'' = -fs(t) + fv2(x(t))
        fs(t) = -k max(p(t - h), 0) for t >= h, else 0   (no robot pose yet)

    with fv the contact forces acting while the bodies touch (the virtual
    impedance, or the ideal spring-dashpot). This is the limit of the sampled
    HIL loop (`simulate_hil`) as its step goes to zero. Contact onset and
    separation are terminal events; the integration also stops at each
    event time + h, where the delayed passive force has a kink, so that
    high-order methods keep their order.
    """

    def __init__(
        self,
        scenario: ContactScenario,
        *,
        impedance: VirtualImpedance | None = None,
        delay: float = 0.0,
        t_end: float,
        method: str = "DOP853",
        rtol: float = 1e-12,
        atol: float = 1e-16,
        gap: float = 0.0,
    ):
        from scipy.integrate import solve_ivp

        if method not in IVP_METHODS:
            raise ContactModelError(f"unknown solve_ivp method {method!r}; choose one of {', '.join(IVP_METHODS)}")
        scn = scenario
        self.scenario, self.impedance, self.delay = scn, impedance, float(delay)
        m1, m2 = scn.m1, scn.m2
        free = LinearSecondOrderSystem.free([m1, m2])
        if impedance is None:
            contact = LinearSecondOrderSystem.ideal_contact(scn)
            self.k_delayed = 0.0
        elif self.delay == 0.0:
            contact = LinearSecondOrderSystem.hybrid_contact(scn, impedance)
            self.k_delayed = 0.0
        else:
            # The passive part comes through the delay; only the virtual part acts now.
            contact = LinearSecondOrderSystem.hybrid_contact(scn.replace(k=0.0), impedance)
            self.k_delayed = scn.k
        self.contact_system = contact
        self.push = np.array([0.0, 0.0, 1.0 / m1, -1.0 / m2])  # accelerations per newton of fs
        self.segments: list[tuple[float, float, bool, Callable[[Any], np.ndarray]]] = []  # (t0, t1, touching, dense)
        self._starts: list[float] = []
        self.events: list[float] = []

        def penetration(_t, y):
            return y[0] - y[1]

        penetration.terminal = True  # type: ignore[attr-defined]  # solve_ivp reads an event's flags from it
        x = np.array([-gap, 0.0, scn.v1, scn.v2])
        touching = bool(x[0] - x[1] > 0.0 or (x[0] == x[1] and x[2] > x[3]))
        breaks = [self.delay] if 0.0 < self.delay < t_end else []
        t0 = 0.0
        self.steps = 0
        while t0 < t_end:
            system = contact if touching else free
            a = system.A
            t1 = min([b for b in breaks if b > t0 * (1 + 1e-15) + 1e-300] + [t_end])
            if self.k_delayed:
                t1 = min(t1, t0 + self.delay)  # method of steps: t - h must fall in a finished segment
            penetration.direction = -1.0 if touching else 1.0  # type: ignore[attr-defined]  # as terminal
            if self.k_delayed:

                def rhs(t, y, a=a, push=self.push):
                    return a @ y + push * self.passive(t)
            else:

                def rhs(_t, y, a=a):  # type: ignore[misc]  # no push: no delayed force
                    return a @ y

            options = {"jac": lambda _t, _y, a=a: a} if method in ("Radau", "LSODA") else {}
            sol = solve_ivp(
                rhs, (t0, t1), x, method=method, rtol=rtol, atol=atol, events=penetration, dense_output=True, **options
            )
            if sol.status == -1:
                raise ContactModelError(f"solve_ivp ({method}) failed at t = {sol.t[-1]:.6g} s: {sol.message}")
            self.steps += len(sol.t) - 1
            self.segments.append((t0, float(sol.t[-1]), touching, sol.sol))
            self._starts.append(t0)
            if sol.status == 1:
                t0 = float(sol.t_events[0][0])
                x = sol.y_events[0][0]
                touching = not touching
                self.events.append(t0)
                if self.delay > 0.0 and t0 + self.delay < t_end:
                    bisect.insort(breaks, t0 + self.delay)
            else:
                t0 = t1
                x = sol.y[:, -1]
            if len(self.segments) > 10_000:
                raise ContactModelError("more than 10000 contact events (chatter); check the parameters")

    def _segment(self, t: float) -> tuple[float, float, bool, Callable[[Any], np.ndarray]]:
        i = max(0, bisect.bisect_right(self._starts, t) - 1)
        return self.segments[i]

    def penetration_at(self, t: float) -> float:
        y = self._segment(t)[3](t)
        return float(y[0] - y[1])

    def passive(self, t: float) -> float:
        """Delayed passive force on the chaser [N] (along +x) at time t."""
        if t <= self.delay or not self.k_delayed:  # p(0) <= 0: the run starts at or before contact
            return 0.0
        p = self.penetration_at(t - self.delay)
        return -self.k_delayed * p if p > 0.0 else 0.0

    def sample(self, t: ArrayLike) -> dict:
        """States, contact flags and forces at times t [s]."""
        t = np.asarray(t, dtype=float)
        ends = np.array([seg[1] for seg in self.segments[:-1]])
        which = np.searchsorted(ends, t, side="right")  # a sample at an event belongs to the next phase
        states = np.empty((4, t.size))
        touching = np.empty(t.size, dtype=bool)
        for k in np.unique(which):
            sel = which == k
            _, _, mode, dense = self.segments[k]
            states[:, sel] = dense(t[sel])
            touching[sel] = mode
        fs = np.array([self.passive(float(tt)) for tt in t]) if self.k_delayed else np.zeros(t.size)
        return {
            "t": t,
            "x1": states[0],
            "x2": states[1],
            "v1": states[2],
            "v2": states[3],
            "p": states[0] - states[1],
            "pd": states[2] - states[3],
            "touching": touching,
            "fs": fs,
        }
