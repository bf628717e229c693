"""`dockhil plot BAG [BAG ...] --png FILE`: contact force and velocity profiles, like the paper's Fig. 9,
beside the ideal contact of the scene each bag recorded, and the energy the delay made (with and without
compensation) when the bags hold /energy; a 6-DOF bag (by its recorded scene, or --6dof) its 6-DOF figure.
The drawing is dockhil/analysis/plots/runplot.py's."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from dockhil.argtypes import nonnegative
from dockhil.errors import DockhilError

if TYPE_CHECKING:
    from dockhil.scene.graph import Graph


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("bags", nargs="+", metavar="BAG", help="one or more recorded runs (MCAP); each is one curve")
    p.add_argument("--png", required=True, metavar="FILE", help="where to write the figure")
    p.add_argument("--labels", nargs="+", metavar="LABEL", help="legend label per bag (default: file names)")
    p.add_argument(
        "--kcs",
        type=nonnegative,
        help="ideal runs: contact stiffness [N/m] to compute the force from the state (default: the recorded scene's)",
    )
    p.add_argument(
        "--bcs", type=nonnegative, help="ideal runs: contact damping [N s/m] (default: the recorded scene's)"
    )
    p.add_argument(
        "--topics",
        nargs="+",
        metavar="TOPIC",
        help="extra topics to plot in a third panel: every numeric field over time",
    )
    p.add_argument(
        "--6dof",
        dest="six",
        action="store_true",
        help="6-DOF runs (launch/hil6.yaml): F/T force and torque, relative pose, angular rates "
        "(the default for bags whose recorded scene is 6-DOF)",
    )


def run(args: argparse.Namespace) -> int:
    # A refused command line is refused before matplotlib is imported (half a CPU-second).
    if args.labels and len(args.labels) != len(args.bags):
        raise DockhilError(f"--labels has {len(args.labels)} labels for {len(args.bags)} bags; give one per bag")
    if (args.kcs is None) != (args.bcs is None):
        raise DockhilError("--kcs and --bcs go together (the ideal contact force is kcs p + bcs p')")
    from dockhil.analysis.plots.runplot import is_sixdof, plot_runs

    # Each bag's recorded scene: its ideal contact, and whether it is a 6-DOF run.
    graphs = [_recorded_graph(path) for path in args.bags]
    six = [is_sixdof(g) for g in graphs]
    if args.six or all(six):
        flat = [path for path, g, s in zip(args.bags, graphs, six) if g is not None and not s]
        if flat:
            raise DockhilError(f"{flat[0]}: a 1-DOF run (its recorded scene); plot it apart from the 6-DOF bags")
        from dockhil.analysis.plots.plot6 import plot6

        plot6(args.bags, args.png, args.labels)
    elif any(six):
        raise DockhilError(
            f"{args.bags[six.index(True)]}: a 6-DOF run (its recorded scene); plot it apart from the 1-DOF bags"
        )
    else:
        plot_runs(
            args.bags, args.png, args.labels, None if args.kcs is None else (args.kcs, args.bcs), args.topics, graphs
        )
    print(f"wrote {args.png}")
    return 0


def _recorded_graph(path: str) -> Graph | None:
    """The bag's recorded scene; None, said in one line, when it does not rebuild here (a node type of
    a package not installed): the bag is then drawn as one without it."""
    from dockhil.analysis.plots.runplot import bag_graph
    from dockhil.bags.format import BagError
    from dockhil.log import Log

    try:
        return bag_graph(path)
    except BagError:
        raise
    except DockhilError as exc:
        Log("dockhil plot:").warning(f"{exc}; drawn without its recorded scene (give --kcs/--bcs, --6dof)")
        return None
