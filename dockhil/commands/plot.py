"""`dockhil plot BAG [BAG ...] --png FILE`: contact force and velocity profiles, like the paper's Fig. 9,
and the energy the delay made (with and without compensation) when the bags hold /energy."""

from __future__ import annotations

from dockhil.argtypes import nonnegative
from dockhil.errors import DockhilError
from dockhil.analysis.figure_file import save_figure


def add_arguments(p) -> None:
    p.add_argument("bags", nargs="+", metavar="BAG", help="one or more recorded runs (MCAP); each is one curve")
    p.add_argument("--png", required=True, metavar="FILE", help="where to write the figure")
    p.add_argument("--labels", nargs="+", metavar="LABEL", help="legend label per bag (default: file names)")
    p.add_argument("--kcs", type=nonnegative, help="ideal runs: contact stiffness [N/m] to compute the force from the state")
    p.add_argument("--bcs", type=nonnegative, help="ideal runs: contact damping [N s/m]")
    p.add_argument("--topics", nargs="+", metavar="TOPIC",
                   help="extra topics to plot in a third panel: every numeric field over time")
    p.add_argument("--6dof", dest="six", action="store_true",
                   help="6-DOF runs (launch/hil6.yaml): F/T force and torque, relative pose, angular rates")


def load_samples(path: str, ideal_force=None):
    from dockhil.analysis.summary import samples_from_bag

    s = samples_from_bag(path, ideal_force)
    if not len(s.t):
        raise DockhilError(f"{path}: no /satellite/state messages; record the dynamics' state to plot a run")
    return s


def load_energy(path: str):
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


def run(args) -> int:
    # A refused command line is refused before matplotlib is imported (half a CPU-second).
    if args.labels and len(args.labels) != len(args.bags):
        raise DockhilError(f"--labels has {len(args.labels)} labels for {len(args.bags)} bags; give one per bag")
    six = getattr(args, "six", False)
    if not six and (args.kcs is None) != (args.bcs is None):
        raise DockhilError("--kcs and --bcs go together (the ideal contact force is kcs p + bcs p')")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if six:
        from dockhil.analysis.plot6 import plot6

        plot6(args.bags, args.png, args.labels)
        print(f"wrote {args.png}")
        return 0
    ideal = (args.kcs, args.bcs) if args.kcs is not None else None
    energies = [load_energy(path) for path in args.bags]
    has_energy = any(e is not None for e in energies)
    panels = 2 + has_energy + bool(args.topics)
    fig, axes = plt.subplots(panels, 1, sharex=True, figsize=(8, 2.6 * panels + 0.6))
    for i, path in enumerate(args.bags):
        s = load_samples(path, ideal)
        label = args.labels[i] if args.labels else path.rsplit("/", 1)[-1]
        axes[0].plot(s.t, s.force, label=label)
        axes[1].plot(s.t, s.pd, label=label)
        if energies[i] is not None:
            t, made, net = energies[i]
            line, = axes[2].plot(t, made, label=f"{label}: made by delay and sampling")
            if any(net != made):
                axes[2].plot(t, net, "--", color=line.get_color(), label=f"{label}: left after compensation")
        if args.topics:
            _plot_topics(axes[-1], path, args.topics, label)
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
    save_figure(fig, args.png, dpi=120)
    print(f"wrote {args.png}")
    return 0


def _plot_topics(ax, path, topics, label) -> None:
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
