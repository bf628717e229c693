"""The loop of launch/stability.yaml (a free body pressed by thrust against a sheet K behind the
robot's delay h, the virtual damper b on the simulated velocity), with or without the passivity
controller, simulated for many parameter points at once: one numpy lane per point, one tick of
all lanes per step. The stability map measures its compensated region with it.

Each lane does what `dockhil.contact.hilloop.simulate_hil` (m2 = 0, impedance (0, b, 0, 0)) and
`dockhil.contact.passivity.EnergyMonitor` do for that loop, in the same order; the tests hold the
two to the same trajectories. Verdicts per lane: `grows` (the oscillation about the equilibrium
thrust / K is larger over the last fifth of the run than over the second fifth), `saturated`
(energy left in the loop, as `passivity.left_in_loop`) and `diverged` (the state overflowed).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from dockhil.contact.passivity import RESIDUAL_TOLERANCE

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from dockhil.progress import Progress


def simulate_sheets(
    m: ArrayLike,
    b: ArrayLike,
    K: ArrayLike,
    h: ArrayLike,
    max_damping: ArrayLike,
    *,
    dt: float = 1e-3,
    seconds: float = 30.0,
    thrust: float = 10.0,
    progress: Progress | None = None,
    record: bool = False,
) -> dict:
    """Run every lane (arrays broadcast together: mass m [kg], damper b [N s/m], sheet K [N/m], delay
    h [s], the controller's bound max_damping [N s/m], 0 for no controller) for `seconds` from rest
    at twice the equilibrium compression. `progress`: a dockhil.progress.Progress, or None.

    Returns arrays per lane: grows, saturated, diverged, compensated (bool), growth_rate [1/s]
    (from the two windows' amplitudes), left_J and allowed_J (energy left in the loop and its
    tolerance); with `record`, also p [m], the relative position per tick and lane."""
    m, b, K, h, bound = (np.asarray(a, float) for a in np.broadcast_arrays(m, b, K, h, max_damping))
    m, b, K, h, bound = (a.ravel() for a in (m, b, K, h, bound))
    lanes = m.size
    n_ticks = int(round(seconds / dt)) + 1
    delay = np.rint(h / dt).astype(int)
    depth = int(delay.max()) + 1
    every = np.arange(lanes)
    history = np.zeros((depth, lanes))  # the delay line: relative positions pushed, depth ticks back
    compensated = bound > 0.0
    ceiling = np.minimum(np.where(compensated, bound, 0.0), m / dt)  # as EnergyMonitor: m_r / dt
    gamma_p, gamma_v = dt * dt / (2.0 * m), dt / m  # the free mass under a held force, exactly
    p = 2.0 * thrust / K
    v = np.zeros(lanes)
    f1 = np.zeros(lanes)
    # The energy account (EnergyMonitor's fields this loop needs; its virtual spring is zero and its
    # damper's work and dissipation cancel).
    work = np.zeros(lanes)
    dissipated = np.zeros(lanes)
    initial = 0.5 * K * np.maximum(p, 0.0) ** 2
    spring_max = np.zeros(lanes)
    left = np.full(lanes, -np.inf)
    prev = prev_loaded = None
    equilibrium = thrust / K
    windows = (n_ticks // 5, 2 * n_ticks // 5), (4 * n_ticks // 5, n_ticks)
    amplitude = np.zeros((2, lanes))
    diverged = np.zeros(lanes, bool)
    trace = np.empty((n_ticks, lanes)) if record else None
    with np.errstate(over="ignore", invalid="ignore"):
        for tick in range(n_ticks):
            if tick > 0:
                p, v = p + dt * v + gamma_p * f1, v + gamma_v * f1
            if trace is not None:  # record
                trace[tick] = p
            touching = (p > 0.0) | ((p == 0.0) & (v > 0.0))
            fv = np.where(touching, -(b * v), 0.0)
            history[tick % depth] = p
            rx = history[(tick - delay) % depth, every]
            fs = np.where(tick >= delay, -K * np.maximum(rx, 0.0), 0.0)
            if prev is not None:
                pp, pf, pfc = prev
                work += pf * (p - pp)
                dissipated -= pfc * (p - pp)
            net = work + 0.5 * K * np.maximum(p, 0.0) ** 2 - initial - dissipated
            loaded = touching | (fs != 0.0)
            if prev is not None:
                left = np.where(prev_loaded & ~loaded, np.maximum(left, net), left)
            spring_max = np.maximum(spring_max, fs * fs / (2.0 * K))
            q = p + v * dt
            energy = net + fs * v * dt + 0.5 * K * (np.maximum(q, 0.0) ** 2 - np.maximum(p, 0.0) ** 2)
            act = compensated & loaded & (energy > 0.0)
            want = np.where(v != 0.0, energy / (v * v * dt), np.inf)
            fc = np.where(act, -np.minimum(want, ceiling) * v, 0.0)
            prev, prev_loaded = (p, fs, fc), loaded
            f1 = fs + (fv + fc) + thrust
            for i, (lo, hi) in enumerate(windows):
                if lo <= tick < hi:
                    amplitude[i] = np.maximum(amplitude[i], np.abs(p - equilibrium))
            bad = ~np.isfinite(p) | ~np.isfinite(v)
            if bad.any():
                diverged |= bad
                p, v, f1 = np.where(bad, 0.0, p), np.where(bad, 0.0, v), np.where(bad, 0.0, f1)
            if progress is not None:
                progress.update(tick + 1)
    if progress is not None:
        progress.done()
    left = np.where(loaded, np.maximum(left, net), left)
    span = (windows[1][0] - windows[0][0]) * dt
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.log(amplitude[1] / amplitude[0]) / span
    allowed = RESIDUAL_TOLERANCE * spring_max
    grows = diverged | ~(amplitude[1] <= amplitude[0])
    out = {
        "grows": grows,
        "saturated": compensated & ~diverged & (left > allowed),
        "diverged": diverged,
        "compensated": compensated,
        "growth_rate": np.where(diverged, np.inf, rate),
        "left_J": left,
        "allowed_J": allowed,
    }
    if record:
        out["p"] = trace
    return out
