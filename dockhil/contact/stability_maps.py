"""Stability measured over runs and grids, for `dockhil stability`: stability.yaml's delayed loop
with the passivity controller simulated, at multiples of the exact stiffness bound for one (b, h)
(--compensation passivity) or over a (b, h) grid (map --compensation passivity); and the hybrid
loop's stable region over (k, h), exact and sampled (map --kcs --bcs)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, SupportsFloat

if TYPE_CHECKING:
    import numpy as np

    from dockhil.progress import Progress

THRUST, SECONDS, RATE = 10.0, 30.0, 1000.0  # stability.yaml's loop as the compensated runs simulate it
MULTIPLES = (1.0, 2.0, 3.0, 5.0, 10.0)  # of the exact bound: the stiffnesses a single (b, h) tries
MAX_DELAY_TICKS = 20000  # the grid's longest delay, in ticks at RATE


def compensated_runs(m: float, b: float, h: float, K: float | None, max_damping: float) -> dict:
    """The loop of stability.yaml (10 N thrust against a sheet K, damper b on the simulated velocity,
    delay h) with the passivity controller, simulated: growth rate and saturation per K."""
    import numpy as np

    from dockhil.contact.envelope import growth_rate
    from dockhil.contact.hilloop import simulate_hil
    from dockhil.contact.hybrid import VirtualImpedance
    from dockhil.contact.passivity import Passivity, left_in_loop
    from dockhil.contact.scenario import ContactModelError
    from dockhil.contact.stability import exact_bound

    bound = exact_bound(m, b, h, damper="undelayed").k_max
    stiffnesses = [] if bound is None else [(f"{x:g}x exact", x * bound) for x in MULTIPLES]
    if K is not None:
        stiffnesses.append(("--K", K))
    rows = []
    for label, k in stiffnesses:
        row: dict[str, Any] = {"label": label, "K": k, "growth_rate": None, "saturated": None, "diverged": False}
        try:
            run = simulate_hil(
                m1=m,
                m2=0.0,
                k=k,
                impedance=VirtualImpedance(0.0, b, 0.0, 0.0),
                dt=1 / RATE,
                n_ticks=int(SECONDS * RATE) + 1,
                delay=h,
                thrust=THRUST,
                x1=2 * THRUST / k,
                passivity=Passivity(k, max_damping),
            )
        except ContactModelError:
            row["diverged"] = True
            rows.append(row)
            continue
        left, allowed = left_in_loop(run.extra)
        row["saturated"] = bool(left > allowed)
        try:
            row["growth_rate"] = growth_rate(run.t, run.x1 - run.x2, about=THRUST / k)
        except ValueError:  # settled within a few periods
            row["growth_rate"] = None
            row["settled"] = bool(np.ptp((run.x1 - run.x2)[-1000:]) < 1e-6)
        rows.append(row)
    ok = [
        r["K"]
        for r in rows
        if not r["diverged"]
        and not r["saturated"]
        and (r["growth_rate"] is not None and r["growth_rate"] < 0 or r.get("settled"))
    ]
    return {
        "loop": "m s^2 + b s + K e^(-sh) = 0 (stability.yaml: damper on the simulated velocity), "
        f"sampled at {RATE:g} Hz, {THRUST:g} N thrust, {SECONDS:g} s simulated",
        "max_damping": max_damping,
        "exact_undelayed": bound,
        "runs": rows,
        "largest_decaying_K": max(ok) if ok else None,
    }


def compensated_region(
    m: float,
    b_range: tuple[float, float],
    h_range: tuple[float, float],
    n: int,
    multiples: list[float],
    max_damping: float,
    seconds: float,
    progress: Progress | None = None,
) -> dict:
    """Over a coarse n x n (b, h) grid, stability.yaml's loop with the passivity controller simulated at
    multiples of the exact bound (undelayed damper: the loop the scene runs), all points at once."""
    import numpy as np

    from dockhil.contact.sheet_sweep import simulate_sheets
    from dockhil.contact.stability import critical_stiffness_map

    bs, hs = np.linspace(*b_range, n), np.linspace(*h_range, n)
    bound = critical_stiffness_map(m, bs, hs, "exact", "undelayed")  # [h, b]
    hh, bb, xx = np.meshgrid(hs, bs, multiples, indexing="ij")
    kk = bound[:, :, None] * xx
    ok = np.isfinite(kk) & (kk > 0.0)
    start, cpu = time.perf_counter(), time.process_time()
    runs = simulate_sheets(
        m, bb[ok], kk[ok], hh[ok], max_damping, dt=1.0 / RATE, seconds=seconds, thrust=THRUST, progress=progress
    )
    stable = np.zeros(kk.shape, bool)
    stable[ok] = ~runs["grows"] & ~runs["saturated"]
    saturated = np.zeros(kk.shape, bool)
    saturated[ok] = runs["saturated"]
    # The largest multiple up to which every multiple tried is stable (0: not even the smallest).
    upto = np.cumprod(stable, axis=2).astype(bool)
    largest = np.where(upto.any(axis=2), np.array(multiples)[np.argmax(~upto, axis=2) - 1], 0.0)
    largest = np.where(upto.all(axis=2), multiples[-1], largest)
    largest = np.where(np.isfinite(bound), largest, np.nan)
    return {
        "loop": "m s^2 + b s + K e^(-sh) = 0 (stability.yaml: damper on the simulated velocity), sampled at "
        f"{RATE:g} Hz, {THRUST:g} N thrust, {seconds:g} s simulated per point",
        "max_damping": max_damping,
        "grid": [n, n],
        "b": bs.tolist(),
        "h": hs.tolist(),
        "multiples": multiples,
        "points": int(ok.sum()),
        "largest_stable_multiple": [[None if math.isnan(x) else float(x) for x in row] for row in largest],
        "stable_points": int(stable.sum()),
        "saturated_points": int(saturated.sum()),
        "wall_seconds": time.perf_counter() - start,
        "cpu_seconds": time.process_time() - cpu,
    }


def hybrid_map(
    m: float, kcs: float, bcs: float, rate: float, ks: np.ndarray, hs: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stable region of the hybrid loop m s^2 + bcs s + (kcs - k) + k e^(-sh) over (k, h): exact (closed-form
    crossings) and sampled at `rate` [h, k], and Eq. 12's verdict on the paper's loop (the whole kcs
    delayed) per h."""
    import numpy as np

    from dockhil.contact.hybrid_stability import unstable_root_count
    from dockhil.contact.sampled import SampledLoop, spectral_radius
    from dockhil.contact.stability import pade1_bound

    exact = np.zeros((hs.size, ks.size), bool)
    sampled = np.zeros_like(exact)
    for i, h in enumerate(hs):
        for j, k in enumerate(ks):
            exact[i, j] = unstable_root_count(m, kcs - k, bcs, k, 0.0, h) == 0
            loop = SampledLoop(m, kcs - k, bcs, k, 0.0, dt=1.0 / rate, delay_ticks=int(round(h * rate)))
            sampled[i, j] = spectral_radius(loop) < 1.0
    eq12 = np.array([(lambda kb: kb is not None and kcs < kb)(pade1_bound(m, bcs, h)) for h in hs])
    return exact, sampled, eq12


def nan_extreme(fn: Callable[[np.ndarray], SupportsFloat], values: np.ndarray) -> float | None:
    """fn (np.nanmin, np.nanmax) of values, None where every value is NaN."""
    import numpy as np

    if np.all(np.isnan(values)):
        return None
    out = float(fn(values))
    return None if math.isnan(out) else out
