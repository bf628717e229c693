"""`dockhil analyze RUN.mcap [--png DIR] [--json]`: the summary of a recorded run, from the bag alone."""

from __future__ import annotations

import argparse

from dockhil.argtypes import nonnegative
from dockhil.errors import DockhilError

EXIT_STATUS = """exit status:
  0  the recorded run is valid (or, where the bag records no verdict, its messages show no reason
     against it: the line under the table says which)
  2  bad input: not a bag, a scene that is not known (the line says what to pass), bad arguments
  3  INVALID: the run recorded is not valid (as the launch said, exit 3), failed, or did not finish"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    import argparse

    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.description = (
        "The summary of a recorded run, sim or lab, from its bag alone: the scene and launch "
        "arguments the bag records rebuild the graph, and the launch's summary code gives the same "
        "numbers (peak force, duration, entry and exit velocity, restitution against the scene's "
        "ideal contact, the energy account); the validity is the one recorded. A bag of an older "
        "dockhil holds no scene: name it with --scene, or the ideal contact with --kcs --bcs ..."
    )
    p.epilog = EXIT_STATUS
    p.add_argument("bag", metavar="RUN.mcap", help="a bag recorded by dockhil launch --bag (or dockhil bag record)")
    p.add_argument(
        "overrides",
        nargs="*",
        metavar="name:=value",
        help="launch arguments over the recorded ones (or those of --scene)",
    )
    p.add_argument("--scene", metavar="FILE", help="the scene the run ran, for a bag that does not record it")
    for name, unit, what in (
        ("kcs", "N/m", "ideal contact stiffness"),
        ("bcs", "N s/m", "ideal contact damping"),
        ("m1", "kg", "chaser mass"),
        ("m2", "kg", "target mass"),
        ("v1", "m/s", "chaser velocity at contact"),
        ("v2", "m/s", "target velocity at contact"),
    ):
        p.add_argument(
            f"--{name}",
            type=float if name in ("v1", "v2") else nonnegative,
            metavar="X",
            help=f"{what} [{unit}] (the same as {name}:=X)",
        )
    p.add_argument("--png", metavar="DIR", help="write the run's figures to this folder")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def run(args: argparse.Namespace) -> int:
    import json

    from dockhil.analysis.analyze import IDEAL_ARGS, analyze, figures, validity_line
    from dockhil.log import Log
    from dockhil.runtime.validity import INVALID_EXIT
    from dockhil.scene.launchfile import parse_overrides

    overrides: dict = parse_overrides(args.overrides)
    for name in IDEAL_ARGS:
        value = getattr(args, name)
        if value is not None:
            if name in overrides:
                raise DockhilError(
                    f"{name} is given twice (--{name} {value:g}, {name}:={overrides[name]}); give it once"
                )
            overrides[name] = value
    a = analyze(args.bag, args.scene, overrides)
    written = figures(a, args.bag, args.png) if args.png else []
    if args.json:
        print(json.dumps(a.summary, indent=1))
    else:
        from dockhil.analysis.summary import format_summary
        from dockhil.bags.runinfo import info_lines

        print("\n".join(info_lines(a.summary["run"] if a.info.recorded else None)[:3]))
        print(f"scene:     {a.scene}")
        print(format_summary(dict(a.summary, run_time_s=None, real_time_factor=None)))  # not in the bag
        print(validity_line(a))
    for png in written:
        Log("dockhil analyze:").info(f"wrote {png}")
    return 0 if a.valid else INVALID_EXIT
