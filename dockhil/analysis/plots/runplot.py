"""Figures of recorded runs (`dockhil plot`, `dockhil analyze --png`): the contact force and the relative
velocity against time, like the paper's Fig. 9, beside the ideal contact of the scene each bag recorded
(dockhil.bags.runinfo), and the energy the delay made when the bags hold /energy. A run of the ideal model
(launch/ideal.yaml) publishes no force: its force is the recorded scene's kcs p + bcs p' (or --kcs, --bcs)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from dockhil.analysis.plots.figure_file import save_figure
from dockhil.errors import DockhilError

if TYPE_CHECKING:
    import numpy as np
    from matplotlib.axes import Axes

    from dockhil.analysis.summary.common import Samples
    from dockhil.bags.runinfo import RunInfo
    from dockhil.scene.graph import Graph


def bag_graph(path: str, overrides: dict | None = None, info: RunInfo | None = None) -> Graph | None:
    """The graph of the scene a bag recorded (info: its runinfo.RunInfo, read if not given), rebuilt
    from its texts; None for a bag without them. LaunchError (one line) if it does not rebuild here."""
    from dockhil.bags import runinfo
    from dockhil.errors import LaunchError
    from dockhil.scene.graph import build
    from dockhil.scene.provenance import rebuild

    info = info or runinfo.read_path(path)
    if not info.texts or not info.run.get("scene"):
        return None
    scene = rebuild(info.run, info.texts, overrides, origin=path)
    try:
        return build(scene)
    except LaunchError as exc:  # a node type not installed here, say
        raise LaunchError(f"{path}: recorded scene: {exc}") from None


def is_sixdof(graph: Graph | None) -> bool:
    from dockhil.analysis.scenecheck import first_node

    return graph is not None and first_node(graph, "satellite_dynamics6") is not None


def load_samples(path: str, ideal_force: tuple[float, float] | None = None, dt: float | None = None) -> Samples:
    from dockhil.analysis.summary import samples_from_bag

    s = samples_from_bag(path, ideal_force, dt)
    if not len(s.t):
        raise DockhilError(f"{path}: no /satellite/state messages; record the dynamics' state to plot a run")
    return s


def load_energy(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t [s], generated_J, net_generated_J) arrays of a bag's /energy, or None without it."""
    import numpy as np

    from dockhil.bags.reader import BagReader

    rows = []
    with BagReader(path) as bag:
        for _topic, _t, msg in bag.decoded(["/energy"]):
            rows.append((msg.header.stamp, msg.generated_J, msg.net_generated_J))
    if not rows:
        return None
    t, made, net = (np.array(v) for v in zip(*rows))
    return t - t[0], made, net


def ideal_curves(graph, t):
    """(force [N], relative velocity [m/s]) of the scene's ideal contact on the times t, or None when
    the scene has no free contact to compare with (the ideal model itself, a body held on a sheet)."""
    import numpy as np

    from dockhil.analysis.summary import scene_reference
    from dockhil.contact.ideal import ideal_trajectory
    from dockhil.contact.scenario import ContactScenario

    ideal = scene_reference(graph).get("ideal") if graph is not None else None
    if ideal is None:
        return None
    scn = ContactScenario(ideal["m1"], ideal["m2"], ideal["kcs"], ideal["bcs"], 0.0, ideal["v1"], ideal["v2"])
    traj = ideal_trajectory(scn, t, gap=max(0.0, ideal["x2"] - ideal["x1"]))
    force = np.where(traj.in_contact, scn.kcs * traj.penetration + scn.bcs * traj.penetration_rate, 0.0)
    return force, traj.penetration_rate


def plot_runs(
    bags: list[str],
    png: str,
    labels: list[str] | None = None,
    kcs_bcs: tuple[float, float] | None = None,
    topics: list[str] | None = None,
    graphs: list[Graph | None] | None = None,
) -> None:
    """The force and velocity figure of 1-DOF bags; graphs: each bag's recorded graph (or None)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dockhil.analysis.summary import scene_reference

    graphs = graphs or [None] * len(bags)
    energies = [load_energy(path) for path in bags]
    has_energy = any(e is not None for e in energies)
    panels = 2 + has_energy + bool(topics)
    fig, axes = plt.subplots(panels, 1, sharex=True, figsize=(8, 2.6 * panels + 0.6))
    drawn: set = set()
    for i, path in enumerate(bags):
        graph = graphs[i]
        ref = scene_reference(graph) if graph is not None else {}
        s = load_samples(path, kcs_bcs or ref.get("ideal_force"), graph.scene.dt if graph is not None else None)
        label = labels[i] if labels else path.rsplit("/", 1)[-1]
        axes[0].plot(s.t, s.force, label=label)
        axes[1].plot(s.t, s.pd, label=label)
        ideal = ref.get("ideal")
        key = tuple(sorted(ideal.items())) if ideal else None
        if ideal and key not in drawn:  # one curve per distinct ideal contact
            drawn.add(key)
            force, velocity = ideal_curves(graph, s.t)
            text = f"ideal (kcs {ideal['kcs']:g} N/m, bcs {ideal['bcs']:g} N s/m)"
            axes[0].plot(s.t, force, "k--", lw=1, label=text)
            axes[1].plot(s.t, velocity, "k--", lw=1, label=text)
        energy = energies[i]
        if energy is not None:
            t, made, net = energy
            (line,) = axes[2].plot(t, made, label=f"{label}: made by delay and sampling")
            if any(net != made):
                axes[2].plot(t, net, "--", color=line.get_color(), label=f"{label}: left after compensation")
        if topics:
            _plot_topics(axes[-1], path, topics, label)
    axes[0].set_ylabel("contact force on chaser [N]")
    axes[1].set_ylabel("relative velocity [m/s]")
    if has_energy:
        axes[2].set_ylabel("energy [J]")
    axes[-1].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Contact force and velocity profiles")
    fig.tight_layout()
    save_figure(fig, png, dpi=120)


def _plot_topics(ax: Axes, path: str, topics: list[str], label: str) -> None:
    from dockhil.bags.reader import BagReader
    from dockhil.bags.tools import flatten

    with BagReader(path) as bag:
        series: dict[str, tuple[list, list]] = {}
        for topic, _t_ns, msg in bag.decoded(topics):
            for name, value in flatten(msg).items():
                if isinstance(value, float) and not name.startswith("header."):
                    xs, ys = series.setdefault(f"{topic} {name}", ([], []))
                    xs.append(msg.header.stamp)
                    ys.append(value)
    if not series:
        raise DockhilError(f"{path}: none of {', '.join(topics)} has numeric fields recorded")
    for name, (xs, ys) in series.items():
        if any(ys):  # all-zero fields (unused axes) would only clutter the panel
            ax.plot(xs, ys, label=f"{label}: {name}")
