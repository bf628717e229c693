"""The report's figures: error against run time, energy over a long run, the passivity controller's
energy over a contact and the lean scenes, drawn from the report's dict as PNG files next to
report.md."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def write_plots(report: dict, out_dir: Path) -> dict[str, str]:
    """PNG figures next to report.md; returns name -> file name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    quick = report["config"]["quick"]

    def save(fig: Figure, name: str) -> None:
        # The quick configuration's figures skip the layout pass (measuring every tick label:
        # a third of the plotting time) and are drawn at a lower resolution.
        if not quick:
            fig.tight_layout()
        fig.savefig(out_dir / name, dpi=72 if quick else 110)
        plt.close(fig)

    plots = {}
    floor = 1e-16  # errors at round-off are drawn here on the log scale
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8))
    for ax, model, title in (
        (axes[0], "ideal", "ideal contact, Table 1 (closed form)"),
        (axes[1], "ideal_stiff", "ideal contact, kcs = 3e6 N/m (closed form)"),
        (axes[2], "hybrid_delay", "hybrid loop, 32 ms delay"),
    ):
        methods = []
        for e in report["work_precision"]:
            if e["model"] == model and e["method"] not in methods:
                methods.append(e["method"])
        for method in methods:
            pts = [
                (e["run_time_s"], max(e["max_error_N"], floor))
                for e in report["work_precision"]
                if e["model"] == model and e["method"] == method and e["max_error_N"] is not None
            ]
            if pts:
                style = "s--" if method.startswith("solve_ivp") else "o-"
                ax.loglog(*zip(*sorted(pts)), style, label=method, markersize=4)
        ax.set_xlabel("run time [s]")
        ax.set_ylabel("max force error [N]")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    save(fig, "work_precision.png")
    plots["work_precision"] = "work_precision.png"

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in report["energy_drift"]["runs"]:
        if "t" in r:
            ax.semilogy(r["t"][1:], np.maximum(np.abs(r["relative_error"][1:]), floor), label=r["method"])
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel("|E - E0| / E0")
    ax.set_title("energy of an undamped contact over a long run")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    save(fig, "energy_drift.png")
    plots["energy_drift"] = "energy_drift.png"

    if "passivity" in report:
        fig, ax = plt.subplots(figsize=(8, 4.5))
        for comp, c in report["passivity"]["energy_32ms"].items():
            (line,) = ax.plot(c["t"], c["generated_J"], label=f"{comp}: made by the delay and the sampling")
            if comp == "passivity":
                ax.plot(c["t"], c["net_generated_J"], "--", color=line.get_color(), label="passivity: left in the loop")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("energy [J]")
        ax.set_title("Table 1 contact, 32 ms robot delay")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        save(fig, "passivity.png")
        plots["passivity"] = "passivity.png"

    if "lean" in report:
        rows = [r for r in report["lean"]["rows"] if r.get("startup_s") is not None and "rss_mb" in r]
        fig, axes = plt.subplots(1, 2, figsize=(12, 0.35 * len(rows) + 1.5))
        names = [r["node"] for r in rows]
        axes[0].barh(names, [r["startup_s"] for r in rows])
        axes[0].set_xlabel("start-up [s]")
        axes[1].barh(names, [r["rss_mb"] for r in rows])
        axes[1].set_xlabel("peak resident memory [MB]")
        axes[1].set_yticklabels([])
        for ax in axes:
            ax.invert_yaxis()
            ax.grid(True, axis="x", alpha=0.3)
        save(fig, "lean.png")
        plots["lean"] = "lean.png"
    return plots
