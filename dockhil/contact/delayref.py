"""An independent reference for the delayed hybrid contact: the continuous delay equation that the
sampled HIL loop converges to as its step goes to zero, solved by the method of steps.

    p'' = -c(p, p') - kr max(p(t - h), 0) [t >= h]
    c = (cp p + cv p') while the bodies touch (the virtual impedance), else 0

with p = x1 - x2, cp = (m2/M) k1/m1 + (m1/M) k2/m2 (and cv alike) and kr = k (1/m1 + 1/m2). The
passive force on the chaser is fs = -k max(p(t - h), 0); before h the robot has no pose and
pushes nothing.

It shares no code with the methods the report measures (no solve_ivp, no library integrator,
no sampled loop): classical RK4 written out on the scalar equation, the history kept as the
nodes' (t, p, p') and read back by cubic Hermite interpolation (fourth order, like the steps),
contact onset and separation located by secant iteration on the step length (each trial one
RK4 step from the last node), and the delay's breakpoints (each event + h and + 2h, and h
itself) landed on exactly, so that no step straddles a kink of the delayed force.
"""

from __future__ import annotations

import bisect
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from dockhil.contact.hybrid import VirtualImpedance


class DelayedContactReference:
    """The delayed hybrid contact, solved on [0, t_end] with steps of at most `dt` [s].

    m1, m2 [kg]; k1, b1, k2, b2: the virtual impedance; k: the passive compliance behind the
    delay h [s]; v0: closing velocity at t = 0 (p(0) = -gap)."""

    # The virtual impedance k1, b1, k2, b2 come from, where the maker keeps it with the reference
    # (the report's precision._delay_reference); the solver reads only the four numbers.
    impedance: VirtualImpedance

    def __init__(
        self,
        *,
        m1: float,
        m2: float,
        k1: float,
        b1: float,
        k2: float,
        b2: float,
        k: float,
        h: float,
        v0: float,
        t_end: float,
        dt: float = 1e-4,
        gap: float = 0.0,
    ):
        total = m1 + m2
        self.cp = (m2 / total) * k1 / m1 + (m1 / total) * k2 / m2
        self.cv = (m2 / total) * b1 / m1 + (m1 / total) * b2 / m2
        self.share = (m2 / total, k1, b1)  # the virtual force on the chaser: -(m2/M)(k1 p + b1 p')
        self.k, self.kr, self.h = k, k * (1.0 / m1 + 1.0 / m2), h
        if h == 0.0:  # no delay: the passive spring acts with the contact (p > 0 while touching)
            self.cp += self.kr
            self.kr = 0.0
        self.ts: list[float] = [0.0]
        self.ps: list[float] = [-gap]
        self.vs: list[float] = [v0]
        self.modes: list[bool] = []  # touching over (ts[i], ts[i+1])
        self.events: list[float] = []
        touching = gap == 0.0 and v0 > 0.0
        breaks = [h] if 0.0 < h < t_end else []
        t = 0.0
        while t < t_end * (1.0 - 1e-15):
            nxt = min([b for b in breaks if b > t * (1.0 + 1e-14) + 1e-300] + [t_end])
            step = min(dt, nxt - t)
            p, v = self.ps[-1], self.vs[-1]
            p1, v1 = self._rk4(t, p, v, step, touching)
            crossed = (p1 <= 0.0) if touching else (p1 > 0.0)
            if crossed:
                tau = self._locate(t, p, v, step, touching)
                p1, v1 = self._rk4(t, p, v, tau, touching)
                p1 = 0.0  # on the surface, to round-off
                self._append(t + tau, p1, v1, touching)
                t += tau
                touching = not touching
                self.events.append(t)
                for extra in (h, 2.0 * h):
                    if h > 0.0 and t + extra < t_end:
                        bisect.insort(breaks, t + extra)
                continue
            self._append(t + step, p1, v1, touching)
            t += step

    def _append(self, t: float, p: float, v: float, mode: bool) -> None:
        self.ts.append(t)
        self.ps.append(p)
        self.vs.append(v)
        self.modes.append(mode)

    def delayed(self, t: float) -> float:
        """max(p(t - h), 0) for t >= h, else 0 (h = 0: max(p(t), 0))."""
        if t < self.h:
            return 0.0
        p = self._hermite(t - self.h)[0]
        return p if p > 0.0 else 0.0

    def _hermite(self, t: float) -> tuple[float, float]:
        """p, p' at t from the stored nodes (cubic Hermite; exact at nodes)."""
        ts = self.ts
        i = min(max(bisect.bisect_right(ts, t) - 1, 0), len(ts) - 2)
        if i < 0 or len(ts) == 1:
            return self.ps[0], self.vs[0]
        t0, t1 = ts[i], ts[i + 1]
        w = t1 - t0
        s = 0.0 if w == 0.0 else (t - t0) / w
        p0, p1, v0, v1 = self.ps[i], self.ps[i + 1], self.vs[i] * w, self.vs[i + 1] * w
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        p = h00 * p0 + h10 * v0 + h01 * p1 + h11 * v1
        dp = (6 * s**2 - 6 * s) * p0 + (3 * s**2 - 4 * s + 1) * v0 + (-6 * s**2 + 6 * s) * p1 + (3 * s**2 - 2 * s) * v1
        return p, (dp / w if w else self.vs[i])

    def _acc(self, t: float, p: float, v: float, touching: bool) -> float:
        # Method of steps: a step never exceeds h, so t - h lies in the finished history.
        a = -(self.cp * p + self.cv * v) if touching else 0.0
        return a - self.kr * self.delayed(t) if self.kr else a

    def _rk4(self, t: float, p: float, v: float, dt: float, touching: bool) -> tuple[float, float]:
        a1 = self._acc(t, p, v, touching)
        p2, v2 = p + 0.5 * dt * v, v + 0.5 * dt * a1
        a2 = self._acc(t + 0.5 * dt, p2, v2, touching)
        p3, v3 = p + 0.5 * dt * v2, v + 0.5 * dt * a2
        a3 = self._acc(t + 0.5 * dt, p3, v3, touching)
        p4, v4 = p + dt * v3, v + dt * a3
        a4 = self._acc(t + dt, p4, v4, touching)
        return (p + dt / 6.0 * (v + 2 * v2 + 2 * v3 + v4), v + dt / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4))

    def _locate(self, t: float, p: float, v: float, step: float, touching: bool) -> float:
        """Step length to the zero of p (secant on the step length, bracketed)."""
        lo, hi = 0.0, step
        f_lo, f_hi = p, self._rk4(t, p, v, step, touching)[0]
        tau = step
        for _ in range(100):
            tau = hi - f_hi * (hi - lo) / (f_hi - f_lo) if f_hi != f_lo else 0.5 * (lo + hi)
            if not lo < tau < hi:
                tau = 0.5 * (lo + hi)
            f = self._rk4(t, p, v, tau, touching)[0]
            if f == 0.0 or hi - lo < 1e-15 * max(1.0, t):
                break
            if (f > 0.0) == (f_lo > 0.0):
                lo, f_lo = tau, f
            else:
                hi, f_hi = tau, f
            if abs(f) < 1e-18:
                break
        return tau

    def sample(self, t: ArrayLike) -> dict:
        """p, pd, touching, fs (passive force on the chaser along +x) and the compressive force
        on the chaser at times t [s]; a sample at an event belongs to the next phase."""
        t = np.asarray(t, float)
        p, pd, touching, fs = (np.empty(t.size) for _ in range(4))
        touching = np.empty(t.size, bool)
        for j, tt in enumerate(t.tolist()):
            p[j], pd[j] = self._hermite(tt)
            i = min(max(bisect.bisect_right(self.ts, tt) - 1, 0), len(self.modes) - 1)
            touching[j] = self.modes[i]
            fs[j] = -self.k * self.delayed(tt)
        share, k1, b1 = self.share
        virtual = np.where(touching, share * (k1 * p + b1 * pd), 0.0)
        return {"t": t, "p": p, "pd": pd, "touching": touching, "fs": fs, "force": virtual - fs}


def reference_error(run_a: DelayedContactReference, run_b: DelayedContactReference, t: ArrayLike) -> float:
    """Largest difference [N] of the compressive force between two reference runs at times t."""
    return float(np.max(np.abs(run_a.sample(t)["force"] - run_b.sample(t)["force"])))
