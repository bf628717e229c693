"""The `dockhil` command: one entry point, one module per subcommand.

Subcommand modules are imported only when their command runs, so
`dockhil --help` and light commands start fast and load no heavy packages.
Each module in `dockhil.commands` provides `add_arguments(parser)` and
`run(args) -> int`.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback
from typing import NoReturn

from dockhil.errors import DockhilError, one_line

# The analyses solve small eigenvalue problems, where BLAS worker threads only spin: on a busy
# 2-core machine `stability multi --scene hil6.yaml` took 4.1 CPU-s with them and 1.0 with one.
# Before numpy is imported; a user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# name -> (module, one-line help). Order is the order shown by --help.
COMMANDS: dict[str, tuple[str, str]] = {
    "launch": ("dockhil.commands.launch", "run a scene from a YAML launch file"),
    "graph": ("dockhil.commands.graph", "show what a launch file would start, or why it is refused"),
    "run": ("dockhil.commands.run", "start one node alone against a running graph"),
    "topic": ("dockhil.commands.topic", "list, echo or measure the rate of topics of a running graph"),
    "node": ("dockhil.commands.node", "list the nodes of running graphs"),
    "params": ("dockhil.commands.params", "virtual impedance k1, b1, k2, b2 from an ideal contact (paper Eqs. 5-6)"),
    "stability": ("dockhil.commands.stability", "stiffness bound for a delayed contact loop (paper Eq. 12 and exact)"),
    "bag": ("dockhil.commands.bag", "record, inspect, export and replay MCAP bags"),
    "foxglove": ("dockhil.commands.foxglove", "print the Foxglove layout of a docking run (3D view, plots)"),
    "plot": ("dockhil.commands.plot", "plot force and velocity profiles from a bag"),
    "analyze": ("dockhil.commands.analyze", "the summary and validity of a recorded run, from its bag alone"),
    "figures": (
        "dockhil.commands.figures",
        "the paper's Figs. 7, 9, 10 and 11-12 recomputed, and the 6-DOF docking, as PNGs",
    ),
    "report": ("dockhil.commands.report", "error against run time, stiff and extreme cases, lean scenes"),
    "sweep": ("dockhil.commands.sweep", "run a scene over a campaign of parameters into a Parquet table"),
    "benchmark": ("dockhil.commands.benchmark", "delay compensation methods against the ideal contact (compensation)"),
    "calibrate": (
        "dockhil.commands.calibrate",
        "identify the real loop's delay, lag, stiffness and F/T bias and noise",
    ),
}


class Parser(argparse.ArgumentParser):
    """argparse, but a refused command line is one line (no usage block) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {one_line(message)}{self._case_hint(message)}; see '{self.prog} --help'\n")

    def _case_hint(self, message: str) -> str:
        """An ambiguous abbreviation that is, in another case, an option of its own (--k for --K)."""
        if not message.startswith("ambiguous option: "):
            return ""
        given = message[len("ambiguous option: ") :].split(" ", 1)[0].split("=", 1)[0]
        same = [o for o in self._option_string_actions if o != given and o.lower() == given.lower()]
        return f"; did you mean {same[0]}? (options are case-sensitive)" if same else ""


class _Version(argparse.Action):
    """`dockhil --version`: the version and which arithmetic runs, compiled or pure Python (worked
    out only when asked: it loads the compiled modules)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(
            option_strings,
            dest,
            nargs=0,
            help="show the version, and whether the compiled arithmetic or pure Python runs",
        )

    def __call__(self, parser, namespace, values, option_string=None):
        from dockhil import __version__
        from dockhil.compiled import which_arithmetic

        print(f"dockhil {__version__} ({which_arithmetic()})")
        parser.exit()


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = Parser(
        prog="dockhil",
        description="Hardware-in-the-loop docking simulation (passive + virtual compliance contact).",
        epilog="Run 'dockhil COMMAND --help' for the options of one command.",
    )
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == only:
            importlib.import_module(module).add_arguments(p)
    return parser


def parse(argv: list[str]) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and the parsed command line; ROS 2 style `name:=value` may stand anywhere."""
    # Find the subcommand first so that only its module is imported.
    only = next((a for a in argv if not a.startswith("-")), None)
    if only is not None and only not in COMMANDS:
        only = None
    parser = build_parser(only)
    args, unknown = parser.parse_known_args(argv)
    if unknown and hasattr(args, "overrides") and all(":=" in u and not u.startswith("-") for u in unknown):
        args.overrides = list(args.overrides or []) + unknown
    elif unknown:
        slip = next((u for u in unknown if "=" in u and ":=" not in u and not u.startswith("-")), None)
        hint = f"; a launch argument is name:=value: did you mean {slip.replace('=', ':=', 1)}?" if slip else ""
        parser.error(f"unrecognized arguments: {' '.join(unknown)}{hint}")
    return parser, args


def main(argv: list[str] | None = None) -> int:
    parser, args = parse(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        return 0
    module = importlib.import_module(COMMANDS[args.command][0])
    from dockhil import log

    say = log.Log(f"dockhil {args.command}:")
    try:
        log.setup(getattr(args, "log_level", None), getattr(args, "log_file", None))
        return int(module.run(args) or 0)
    except DockhilError as exc:
        say.error(str(exc))
        return 2
    except RecursionError:  # input nested deeper than any check foresaw: still one line
        say.error("the input is nested too deeply to process (Python's recursion limit); give a flatter one")
        return 2
    except MemoryError:
        say.error("out of memory processing the input; give a smaller one")
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `dockhil graph FILE | head`: the reader left, nothing to report
        sys.stderr.close()
        return 0
    except Exception as exc:  # a bug, not the user's input: still one line, naming where it happened
        if os.environ.get("DOCKHIL_TRACEBACK"):
            raise
        where = traceback.extract_tb(exc.__traceback__)[-1]
        print(
            f"dockhil {args.command}: internal error: {type(exc).__name__}: {one_line(str(exc))} "
            f"(at {os.path.basename(where.filename)}:{where.lineno}); please report it with the command line "
            f"(DOCKHIL_TRACEBACK=1 shows the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
