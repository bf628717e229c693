"""What a campaign found, drawn: the empirical stability map (stable/unstable per run,
from the simulated growth rate) over the Eq. 12 and exact boundaries, and errors
against the swept parameters.

The stability scene (stability.yaml) runs the loop with the virtual damper on the
simulated, undelayed velocity, sampled at dt with forces held over a step: its own
exact boundary is that of m s^2 + b s + K e^{-s h'} = 0 with h' = h + dt/2. The
paper's Eq. 12 and the exact boundary of its delayed-damper loop are drawn beside it.
"""

from __future__ import annotations

import json
import math

import numpy as np

from dockhil.analysis.plots.figure_file import save_figure
from dockhil.analysis.sweep.results import METADATA_KEY
from dockhil.errors import DockhilError

MAP_ARGS = ("k", "b", "delay", "m")  # the stability scene's names for K, b, h, m
NEAR = 0.02  # points this close to the exact boundary (relative in K) are not counted


def read_results(path: str) -> tuple[dict[str, list], dict]:
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except FileNotFoundError:
        raise DockhilError(
            f"{path}: no such results file; run 'dockhil sweep CAMPAIGN.yaml --out {path}' first"
        ) from None
    except Exception as exc:
        raise DockhilError(f"{path}: not a readable Parquet file ({type(exc).__name__}: {exc})") from None
    meta = json.loads((table.schema.metadata or {}).get(METADATA_KEY, b"{}"))
    return table.to_pydict(), meta


def sampled_bound(m: float, b: float, h: float, dt: float) -> float | None:
    """K_max [N/m] of the loop the stability scene runs (undelayed damper, h + dt/2)."""
    from dockhil.contact.stability import exact_bound

    return exact_bound(m, b, h + dt / 2, damper="undelayed").k_max


def map_agreement(cols: dict[str, list], dt: float) -> dict:
    """Runs classified as the sampled loop's exact boundary says, among ok runs more than
    NEAR from it; `near` counts the ok runs within NEAR."""
    agree = disagree = near = 0
    wrong = []
    for k, b, h, m, status, stable in zip(*(cols[a] for a in MAP_ARGS), cols["status"], cols["stable"]):
        if status != "ok" or stable is None:
            continue
        kmax = sampled_bound(m, b, h, dt)
        expect = kmax is not None and k < kmax
        if kmax is not None and abs(k / kmax - 1.0) <= NEAR:
            near += 1
        elif bool(stable) == expect:
            agree += 1
        else:
            disagree += 1
            wrong.append((k, b, h, m))
    return {"agree": agree, "disagree": disagree, "near": near, "wrong": wrong}


def _numeric(values: list) -> bool:
    return all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in values) and any(
        v is not None for v in values
    )


# What a column is, with its unit, for the axes (a column not named here keeps its own name).
LABELS = {
    "error.peak_force_N": "peak force error [N]",
    "error.exit_velocity_mps": "exit velocity error [m/s]",
    "growth_rate_per_s": "growth rate [1/s]",
    "delay": "robot delay h [s]",
    "lag": "servo lag [s]",
    "k": "passive stiffness k [N/m]",
    "kcs": "contact stiffness kcs [N/m]",
    "bcs": "contact damping bcs [N s/m]",
    "b": "virtual damper b [N s/m]",
    "m": "mass m [kg]",
    "m1": "chaser mass m1 [kg]",
    "m2": "target mass m2 [kg]",
    "v1": "approach velocity v1 [m/s]",
    "rate": "tick rate [Hz]",
    "ft_noise": "F/T noise [N]",
    "thrust": "thrust [N]",
}


def label(column: str) -> str:
    return LABELS.get(column, column)


def plot_results(path: str, png: str) -> list[str]:
    """Draw the figure; returns lines for the user (what the map shows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols, meta = read_results(path)
    n = len(cols.get("run", []))
    if n == 0:
        raise DockhilError(f"{path}: no rows to plot")
    dt = 1.0 / float(meta.get("rate", 1000.0))
    swept = [a for a in (*meta.get("grid", []), *meta.get("random", [])) if a in cols and _numeric(cols[a])]
    has_map = all(a in cols for a in MAP_ARGS) and "stable" in cols
    quantities = [
        q
        for q in ("error.peak_force_N", "error.exit_velocity_mps", "growth_rate_per_s")
        if q in cols and _numeric(cols[q])
    ]
    panels_map = []
    if has_map:
        panels_map = sorted({(float(m), float(h)) for m, h in zip(cols["m"], cols["delay"])})[:6]
    panels_q = [(q, a) for q in quantities for a in swept if a not in ("b",) or not has_map][:9]
    if not panels_map and not panels_q:
        raise DockhilError(
            f"{path}: nothing to plot: the rows have neither a stability classification "
            f"(k, b, delay, m, stable) nor error columns against a swept arg"
        )
    ncols = 3
    rows_map = math.ceil(len(panels_map) / ncols)
    rows_q = math.ceil(len(panels_q) / ncols)
    fig, axes = plt.subplots(rows_map + rows_q, ncols, figsize=(5 * ncols, 4 * (rows_map + rows_q)), squeeze=False)
    for ax in axes.flat:
        ax.set_visible(False)
    lines = []
    status = np.array(cols["status"], dtype=object)
    if has_map:
        from dockhil.contact.stability import critical_stiffness_map

        m_all, h_all = np.array(cols["m"], float), np.array(cols["delay"], float)
        k_all, b_all = np.array(cols["k"], float), np.array(cols["b"], float)
        stable = np.array([s is True for s in cols["stable"]])
        unstable = np.array([s is False for s in cols["stable"]])
        ok = status == "ok"
        for i, (m, h) in enumerate(panels_map):
            ax = axes.flat[i]
            ax.set_visible(True)
            sel = (m_all == m) & (h_all == h)
            bl = np.linspace(max(1e-9, b_all[sel].min()), b_all[sel].max(), 200)
            ax.plot(bl, critical_stiffness_map(m, bl, [h], "pade1", "delayed")[0], "k--", lw=1, label="Eq. 12")
            ax.plot(
                bl, critical_stiffness_map(m, bl, [h], "exact", "delayed")[0], "k:", lw=1, label="exact, delayed damper"
            )
            ax.plot(
                bl,
                critical_stiffness_map(m, bl, [h + dt / 2], "exact", "undelayed")[0],
                "g-",
                lw=1.2,
                label="exact, scene's loop (h + dt/2)",
            )
            ax.scatter(
                b_all[sel & ok & stable],
                k_all[sel & ok & stable],
                marker="o",
                s=14,
                c="tab:blue",
                label="simulated: stable",
            )
            ax.scatter(
                b_all[sel & ok & unstable],
                k_all[sel & ok & unstable],
                marker="x",
                s=16,
                c="tab:red",
                label="simulated: unstable",
            )
            other = sel & ~(ok & (stable | unstable))
            if other.any():
                ax.scatter(b_all[other], k_all[other], marker=".", s=10, c="0.6", label="not classified")
            if k_all[sel].max() > 10 * k_all[sel].min():  # a geometric K grid: show it evenly
                ax.set_yscale("log")
            ax.set_title(f"m = {m:g} kg, h = {h * 1e3:g} ms")
            ax.set_xlabel("virtual damper b [N s/m]")
            ax.set_ylabel("contact stiffness K [N/m]")
            ax.legend(fontsize=7, loc="upper left", framealpha=0.85)
        agreement = map_agreement(cols, dt)
        counted = agreement["agree"] + agreement["disagree"]
        lines.append(
            f"stability map: {agreement['agree']} of {counted} runs more than {NEAR:.0%} from the exact "
            f"boundary are classified as it says ({agreement['near']} within {NEAR:.0%} not counted)"
        )
        for k, b, h, m in agreement["wrong"][:5]:
            lines.append(f"  disagrees: k={k:g} b={b:g} delay={h:g} m={m:g}")
    for j, (q, a) in enumerate(panels_q):
        ax = axes.flat[rows_map * ncols + j]
        ax.set_visible(True)
        x = np.array([np.nan if v is None else v for v in cols[a]], float)
        y = np.array([np.nan if v is None else v for v in cols[q]], float)
        # Coloured by the other swept axis, so a second grid axis is told apart rather than stacked.
        other = next((o for o in swept if o != a), None)
        if other is not None:
            c = np.array([np.nan if v is None else v for v in cols[other]], float)
            dots = ax.scatter(x, y, s=12, c=c, cmap="viridis")
            fig.colorbar(dots, ax=ax).set_label(label(other), fontsize=8)
        else:
            ax.scatter(x, y, s=12)
        ax.axhline(0.0, color="0.7", lw=0.8)
        ax.set_xlabel(label(a))
        ax.set_ylabel(label(q))
        ax.set_title(f"{label(q).split(' [')[0]} against {label(a).split(' [')[0]}", fontsize=9)
    fig.suptitle(f"{meta.get('path', path)}: {n} runs ({int(np.sum(status == 'ok'))} ok)")
    fig.tight_layout()
    save_figure(fig, png)
    return lines
