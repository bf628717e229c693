"""The compensation benchmark's figures: the error against omega h per method, and the method map."""

from __future__ import annotations

import math

METHOD_COLORS = {
    "none": "#444444",
    "passivity": "#1f77b4",
    "phase_lead": "#ff7f0e",
    "smith": "#2ca02c",
    "predictor": "#d62728",
    "energy": "#9467bd",
    "phase_lead+passivity": "#8c564b",
}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def error_figure(rows: list[dict], path: str) -> str:
    """One panel per scene and target: |restitution error| (push: |energy residual|) against omega h, a line
    per method, solid with the hardware mismatched, dotted as told."""
    from dockhil.analysis.plots.figure_file import save_figure

    plt = _pyplot()
    keys = sorted({(r["scene"], r["target"]) for r in rows})
    cols = min(4, len(keys))
    nrows = math.ceil(len(keys) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.2 * nrows), squeeze=False)
    for ax, key in zip(axes.flat, keys):
        metric = "energy_residual" if key[0] == "push" else "restitution_error"
        for method, color in METHOD_COLORS.items():
            for hw, style in (("mismatch", "-"), ("as_told", ":")):
                pts = sorted(
                    (r["omega_h_grid"], abs(r[metric]))
                    for r in rows
                    if (r["scene"], r["target"]) == key
                    and r["method"] == method
                    and r["hardware"] == hw
                    and r.get(metric) is not None
                )
                if pts:
                    ax.plot(
                        [p[0] for p in pts],
                        [max(p[1], 1e-7) for p in pts],
                        style,
                        color=color,
                        marker="o" if style == "-" else None,
                        ms=3,
                        label=method if hw == "mismatch" else None,
                    )
        ax.axhline(0.02, color="k", lw=0.6, ls="--")
        ax.set_yscale("log")
        ax.set_title(f"{key[0]}: {key[1]}", fontsize=9)
        ax.set_xlabel("omega h [rad]")
        ax.set_ylabel("|energy residual|" if metric == "energy_residual" else "|restitution error|")
    for ax in list(axes.flat)[len(keys) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("error against omega h: solid hardware 30 % softer, 20 % later, 0.2 N, 2 ms F/T; dotted as told")
    fig.tight_layout()
    save_figure(fig, path)
    return path


def map_figure(best_map: dict, path: str) -> str:
    """Which method is best (smallest worst normalised error) at each omega h, per scene and target."""
    from matplotlib.colors import ListedColormap

    from dockhil.analysis.plots.figure_file import save_figure

    plt = _pyplot()
    methods = list(METHOD_COLORS)
    fig, axes = plt.subplots(1, len(best_map), figsize=(7 * len(best_map), 4.5), squeeze=False)
    for ax, (hw, table) in zip(axes.flat, best_map.items()):
        keys = list(table)
        omegas = sorted({w for v in table.values() for w in v})
        grid = [[methods.index(table[k][w]) if table[k].get(w) else math.nan for w in omegas] for k in keys]
        ax.imshow(grid, cmap=ListedColormap(list(METHOD_COLORS.values())), vmin=-0.5, vmax=len(methods) - 0.5)
        ax.set_xticks(range(len(omegas)), [f"{w:g}" for w in omegas])
        ax.set_yticks(range(len(keys)), keys, fontsize=8)
        ax.set_xlabel("omega h [rad]")
        ax.set_title(f"best method, hardware {hw}")
        for i, k in enumerate(keys):
            for j, w in enumerate(omegas):
                m = table[k].get(w)
                if m:
                    ax.text(
                        j,
                        i,
                        m.replace("phase_lead", "lead").replace("+passivity", "+p"),
                        ha="center",
                        va="center",
                        fontsize=6,
                        color="w",
                    )
    fig.tight_layout()
    save_figure(fig, path)
    return path
