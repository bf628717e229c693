"""`dockhil foxglove layout`: print the Foxglove layout of a docking run (to import in Foxglove)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="foxglove_command", metavar="SUBCOMMAND", required=True)
    sub.add_parser(
        "layout",
        help="print the layout: a 3D panel (/tf, /scene), force, position and velocity plots, raw messages",
        description="Print a Foxglove layout (JSON) for a run served live (dockhil launch ... "
        "--foxglove) or a bag with /tf and /scene (dockhil bag export --foxglove): "
        "dockhil foxglove layout > layout.json, then in Foxglove: Layouts, Import from file.",
    )


def run(args: argparse.Namespace) -> int:
    from importlib import resources

    print(resources.files("dockhil.bags").joinpath("foxglove-layout.json").read_text(), end="")
    return 0
