"""The stability maps drawn: Fig. 7 (Eq. 12 and the exact bound over (b, h)) with the compensated
region, and the hybrid loop's map over (k, h)."""

from __future__ import annotations

from dockhil.analysis.plots.figure_file import save_figure


def plot_map(
    path: str, m: float, b, h, pade1, exact, damper: str, compensated: dict | None = None, passive=None
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    bb, hh = np.meshgrid(b, h * 1e3)
    panels = 2 if compensated is None else 3
    fig = plt.figure(figsize=(6 * panels, 5))
    ax = fig.add_subplot(1, panels, 1, projection="3d")
    ax.plot_surface(bb, hh, pade1, cmap="viridis", linewidth=0, antialiased=False)
    ax.set_xlabel("b [N s/m]")
    ax.set_ylabel("h [ms]")
    ax.set_zlabel("K_max [N/m]")
    ax.set_title(f"Eq. 12 critical stiffness, m = {m:g} kg (Fig. 7)")
    ax2 = fig.add_subplot(1, panels, 2)
    filled = ax2.contourf(bb, hh, exact, levels=20, cmap="viridis")
    fig.colorbar(filled, ax=ax2, label="exact K_max [N/m]")
    with np.errstate(invalid="ignore", divide="ignore"):
        percent = 100.0 * (pade1 - exact) / exact
    if np.any(np.isfinite(percent)):
        lines = ax2.contour(bb, hh, percent, colors="white", linewidths=0.8, levels=6)
        ax2.clabel(lines, fmt="%.2g %%", fontsize=7)
    if passive is not None and np.any(np.isfinite(passive)):
        with np.errstate(invalid="ignore", divide="ignore"):
            share = 100.0 * passive / exact
        lines = ax2.contour(bb, hh, share, colors="red", linestyles="dashed", linewidths=0.8, levels=5)
        ax2.clabel(lines, fmt="%.3g %%", fontsize=7)
    ax2.set_xlabel("b [N s/m]")
    ax2.set_ylabel("h [ms]")
    passivity = (
        "red: passivity bound b/h, % of exact"
        if passive is not None and np.any(np.isfinite(passive))
        else "no K passive (damper behind the delay)"
    )
    ax2.set_title(f"exact bound ({damper} damper); white: Eq. 12 excess [%]; {passivity}", fontsize=8)
    if compensated is not None:
        plot_region(fig.add_subplot(1, panels, 3), compensated)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def plot_region(ax, r: dict) -> None:
    """The compensated region: per (b, h) point, the largest multiple of the exact bound stable."""
    import numpy as np
    from matplotlib.colors import BoundaryNorm, ListedColormap

    largest = np.array([[np.nan if x is None else x for x in row] for row in r["largest_stable_multiple"]])
    levels = [0.0, *r["multiples"]]
    colors = ["#f4c7c3", *[_green(i, len(r["multiples"])) for i in range(len(r["multiples"]))]]
    edges = [-0.5] + [(a + b) / 2 for a, b in zip(levels, levels[1:])] + [levels[-1] + 1.0]
    mesh = ax.pcolormesh(
        np.array(r["b"]),
        np.array(r["h"]) * 1e3,
        largest,
        shading="nearest",
        cmap=ListedColormap(colors),
        norm=BoundaryNorm(edges, len(colors)),
    )
    bar = ax.figure.colorbar(mesh, ax=ax, ticks=levels, label="largest K stable [x exact bound]")
    bar.ax.set_yticklabels(["none", *[f"{x:g}x" for x in r["multiples"]]])
    if len(r["b"]) <= 12:
        for i, h in enumerate(r["h"]):
            for j, b in enumerate(r["b"]):
                if not np.isnan(largest[i, j]):
                    label = f"{largest[i, j]:g}x" if largest[i, j] > 0 else "none"
                    ax.text(b, h * 1e3, label, ha="center", va="center", fontsize=7)
    ax.set_xlabel("b [N s/m]")
    ax.set_ylabel("h [ms]")
    ax.set_title(
        f"passivity compensation (max_damping {r['max_damping']:g} N s/m), simulated:\n"
        "largest K that neither grows nor saturates (undelayed damper)",
        fontsize=9,
    )


def _green(i: int, n: int) -> str:
    """The i-th of n greens, light to dark."""
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    return to_hex(colormaps["Greens"](0.3 + 0.6 * i / max(1, n - 1)))


def plot_hybrid(path, m, kcs, bcs, rate, ks, hs, exact, sampled, eq12) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    kk, hh = np.meshgrid(ks, hs * 1e3)
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 5), sharey=True)
    a.contourf(kk, hh, exact.astype(float), levels=[-0.5, 0.5, 1.5], colors=["#f4c7c3", "#b7e1cd"])
    if sampled.any() and not sampled.all():
        a.contour(kk, hh, sampled.astype(float), levels=[0.5], colors="k", linewidths=1.2)
    a.set_title(
        f"hybrid loop, kcs = {kcs:g} N/m, bcs = {bcs:g} N s/m, m = {m:g} kg\n"
        f"green: stable (exact); black: sampled boundary at {rate:g} Hz",
        fontsize=9,
    )
    a.set_xlabel("passive stiffness k [N/m] (virtual: kcs - k)")
    a.set_ylabel("delay h [ms]")
    b.contourf(
        kk,
        hh,
        np.repeat(eq12[:, None], ks.size, axis=1).astype(float),
        levels=[-0.5, 0.5, 1.5],
        colors=["#f4c7c3", "#b7e1cd"],
    )
    b.set_title("Eq. 12 on the paper's loop (all of kcs behind the delay)\ngreen: kcs < K_max(bcs, h)", fontsize=9)
    b.set_xlabel("passive stiffness k [N/m] (Eq. 12 does not depend on it)")
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
