"""`dockhil launch FILE [name:=value ...]`: run a scene."""

from __future__ import annotations

import argparse

from dockhil import log
from dockhil.argtypes import max_age_setting, seconds
from dockhil.errors import LaunchError

EXIT_STATUS = """exit status:
  0  the run completed and its result is valid
  1  a node failed or a safety stop held the robot (the line above says which and why),
     the recorder lost messages, or the summary or the rosbag2 bag (--bag-format ros2)
     could not be written after the run
  2  bad input: launch file, arguments or parameters outside the range of docking
     hardware, an unwritable --summary (nothing ran)
  3  INVALID: the run completed but its result is not valid (a wall-time run fell
     behind real time, messages were lost, or the run left the physical range: its
     force, energy, distance or speed); the reasons are printed in one line and in
     the summary JSON ("valid": false, "invalid_reasons")
  128+N  stopped by signal N (130: Ctrl-C)"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    import argparse

    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = EXIT_STATUS
    p.add_argument("file", nargs="?", help="launch file (YAML), e.g. launch/hil.yaml")
    p.add_argument(
        "overrides",
        nargs="*",
        metavar="name:=value",
        help="launch arguments, ROS 2 style (see 'dockhil graph FILE' for the list)",
    )
    clock = p.add_mutually_exclusive_group()
    clock.add_argument(
        "--sim-time",
        dest="clock",
        action="store_const",
        const="sim",
        help="lock-step ticks, deterministic, as fast as possible (default)",
    )
    clock.add_argument(
        "--wall-time", dest="clock", action="store_const", const="wall", help="fixed rate in real time, for hardware"
    )
    p.set_defaults(clock="sim")
    p.add_argument(
        "--duration",
        type=seconds,
        metavar="S",
        help="simulated (or wall) seconds to run; default: the file's `duration`",
    )
    p.add_argument(
        "--max-age",
        type=max_age_setting,
        action="append",
        default=[],
        metavar="NODE.INPUT=SECONDS",
        help="wall time: how old an input's latest message may be, over the launch file's "
        "(> 0, at most 600 s, or inf for no limit; repeatable)",
    )
    p.add_argument(
        "--composed", action="store_true", help="run every node in this one process (same schedule, same results)"
    )
    p.add_argument(
        "--transport",
        choices=("ipc", "tcp"),
        default="ipc",
        help="ipc sockets on one host (default) or tcp on 127.0.0.1",
    )
    p.add_argument("--bag", metavar="PATH", help="record every topic to this MCAP bag")
    from dockhil.commands.bag import add_bag_format

    add_bag_format(p, "--bag PATH")
    p.add_argument("--summary", metavar="FILE.json", help="write the run summary (peak force, contact duration, ...)")
    p.add_argument("--quiet", action="store_true", help="print no progress and no summary table")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="wall time: run node loops with real-time (SCHED_FIFO) priority where the OS allows",
    )
    p.add_argument(
        "--foxglove",
        nargs="?",
        const=8765,
        type=_port,
        metavar="PORT",
        help="serve every topic live to Foxglove over WebSocket on PORT (default 8765); "
        "layout: dockhil foxglove layout > layout.json",
    )
    p.add_argument(
        "--foxglove-host",
        metavar="HOST",
        help="address the Foxglove server binds (default 127.0.0.1: this machine only)",
    )
    log.add_arguments(p)


def _port(text: str) -> int:
    import argparse

    if not text.isdigit() or not 1 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a port number (1-65535); "
            f"give --foxglove PORT, or put --foxglove after the launch arguments"
        )
    return int(text)


def run(args: argparse.Namespace) -> int:
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build, set_max_ages

    scene = launchfile.load(args.file, launchfile.parse_overrides(args.overrides))
    duration = args.duration if args.duration is not None else scene.duration  # both checked, > 0 and bounded
    if args.clock == "sim" and duration is None:
        raise LaunchError(f"{args.file}: sim time needs a run length: give --duration S or `duration:` in the file")
    if args.foxglove_host is not None and args.foxglove is None:
        raise LaunchError("--foxglove-host needs --foxglove [PORT]")
    if args.bag_format == "ros2" and args.bag is None:
        raise LaunchError("--bag-format ros2 needs --bag DIR: the rosbag2 bag (a folder) to write")
    graph = build(scene)
    set_max_ages(graph, args.max_age)
    if args.max_age and args.clock == "sim":
        log.Log("[launch]").warning("--max-age applies in wall time only (--wall-time); sim time is lock-step")
    from dockhil.session import run_scene

    def run_with(bag: str | None) -> int:
        return run_scene(
            graph,
            clock=args.clock,
            duration=duration,
            composed=args.composed,
            transport=args.transport,
            bag=bag,
            summary=args.summary,
            progress=not args.quiet,
            show_summary=not args.quiet,
            realtime=args.realtime,
            foxglove=None if args.foxglove is None else (args.foxglove_host or "127.0.0.1", args.foxglove),
        )

    if args.bag_format == "ros2":  # the recorder writes a dockhil bag, which becomes the rosbag2 bag at the end
        from dockhil.bags.ros2 import record_then_convert

        return record_then_convert(args.bag, run_with, log.Log("[launch]"))
    return run_with(args.bag)
