"""`dockhil bag`: inspect, export, record and replay MCAP bags.

`info`, `export` and `convert` read and write files only. `record` and `play` talk to a running
graph; they live in `dockhil.bags.live` and `dockhil.bags.play`, imported only when they run.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from types import ModuleType

from dockhil import log


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = "Run 'dockhil bag SUBCOMMAND --help' for the options of one subcommand."
    sub = parser.add_subparsers(dest="bag_command", metavar="SUBCOMMAND", required=True)

    p = sub.add_parser(
        "info",
        help="the run (scene, args, version, start, validity), topics, types, counts, times and rates of a bag",
        description="Show what a bag holds: the run it recorded (its scene, launch arguments, dockhil "
        "version, start time and validity; 'did not finish' when the recorder stopped before the run "
        "ended), and its topics. Works on unfinished bags too (a recorder that was "
        "killed): they are read up to their last complete chunk and marked as recovered. "
        "A damaged chunk or record is skipped; the line 'lost:' says how many bytes and which "
        "log times, and every other message is read.",
    )
    p.add_argument("path", metavar="PATH", help="MCAP bag file")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")

    p = sub.add_parser(
        "export",
        help="write one topic as CSV, the whole bag as a rosbag2 bag for ROS 2 tools, or a copy for Foxglove's 3D panel",
        description="--csv: one CSV row per message of a topic: log_time_ns, then every field, "
        "nested fields flattened to dotted names (header.stamp, wrench.force.x, "
        "bodies.0.pose.position.x). --ros2: every topic as a rosbag2 bag (a folder DIR holding "
        "DIR_0.mcap and metadata.yaml; cdr messages of standard ROS 2 types where they exist, "
        "dockhil_msgs otherwise) for ros2 bag, rosbags, Foxglove and PlotJuggler; "
        "docs/commands.md lists the topics and types. --foxglove: a copy of the bag with /tf "
        "(foxglove.FrameTransforms) and /scene (foxglove.SceneUpdate) added, which Foxglove's 3D panel "
        "draws (layout: 'dockhil foxglove layout').",
    )
    p.add_argument("path", metavar="PATH", help="MCAP bag file")
    p.add_argument("--topic", "-t", metavar="T", help="topic to export as CSV, e.g. /ft/wrench")
    out = p.add_mutually_exclusive_group(required=True)
    out.add_argument("--csv", metavar="OUT", help="CSV file to write ('-' for standard output)")
    out.add_argument("--ros2", metavar="DIR", help="rosbag2 bag (a folder) to create from every topic")
    out.add_argument("--foxglove", metavar="OUT", help="MCAP bag to create: the bag with /tf and /scene added")
    p.add_argument(
        "--scene",
        nargs="+",
        metavar=("FILE", "name:=value"),
        help="--foxglove: the launch file (and arguments) the bag was recorded from, for where the "
        "interfaces are mounted (default: the shipped scenes' mounting)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace OUT, or DIR if it is a rosbag2 bag, if it exists (default: refuse)",
    )

    p = sub.add_parser(
        "convert",
        help="rewrite a bag recorded with msgpack channels as a json bag (Foxglove, PlotJuggler)",
        description="Rewrite a bag whose channels are msgpack (as dockhil recorded them before) "
        "with json channels and self-contained JSON Schemas, which viewers open. Topics, types, "
        "log and publish times stay; a damaged or unfinished bag is converted as far as it reads.",
    )
    p.add_argument("path", metavar="IN", help="MCAP bag to read")
    p.add_argument("out", metavar="OUT", help="MCAP bag to create")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists (default: refuse)")

    p = sub.add_parser(
        "record",
        help="record topics of a running graph to a new bag",
        description="Record topics of a graph that is already running, until Ctrl-C. "
        "Chunks are small, so a recorder that is killed loses at most its last chunk.",
    )
    p.add_argument("path", metavar="PATH", help="MCAP bag file to create (a folder with --bag-format ros2)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="topics to record (default: all)")
    p.add_argument("--overwrite", action="store_true", help="replace PATH if it exists (default: refuse)")
    add_bag_format(p, "PATH")
    log.add_arguments(p)

    p = sub.add_parser(
        "play",
        help="re-publish a bag on the bus, in wall time or driving sim time",
        description="Re-publish the messages of a bag on their topics. In wall time they keep "
        "their recorded spacing, scaled by --rate; with --sim-time the bag drives the ticks "
        "and a recorded run is reproduced exactly.",
    )
    p.add_argument("path", metavar="PATH", help="MCAP bag file")
    p.add_argument(
        "--rate",
        type=_positive_float,
        default=1.0,
        metavar="R",
        help="playback speed factor in wall time (default 1.0; 10 plays 60 s in 6 s)",
    )
    p.add_argument("--loop", action="store_true", help="start again from the beginning at the end")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="topics to play (default: all)")
    p.add_argument(
        "--start",
        type=_non_negative_float,
        default=0.0,
        metavar="S",
        help="skip the first S seconds of the bag (default 0)",
    )
    p.add_argument(
        "--sim-time", action="store_true", help="drive sim-time ticks from the bag's stamps instead of the wall clock"
    )
    p.add_argument(
        "--subscribers",
        type=_non_negative_int,
        metavar="N",
        help="wait until each topic has N subscribers before playing (default 1 with --sim-time, 0 in wall time)",
    )
    log.add_arguments(p)


def add_bag_format(p: argparse.ArgumentParser, path: str) -> None:
    """--bag-format, of `bag record` and `launch`."""
    p.add_argument(
        "--bag-format",
        choices=("mcap", "ros2"),
        default="mcap",
        help=f"mcap: a dockhil bag (default); ros2: a rosbag2 bag, {path} a folder (recorded as "
        f"{path}.recording.mcap, converted when recording ends, as 'bag export --ros2' does)",
    )


def run(args: argparse.Namespace) -> int:
    return {"info": _info, "export": _export, "convert": _convert, "record": _record, "play": _play}[args.bag_command](
        args
    )


def _info(args: argparse.Namespace) -> int:
    from dockhil.bags.tools import info

    found = info(args.path)
    if args.json:
        print(json.dumps(found, indent=2))
    else:
        print(format_info(found))
    return 0


def format_info(found: dict) -> str:
    """The table `dockhil bag info` prints."""
    from dockhil.bags.format import format_size
    from dockhil.bags.runinfo import info_lines

    if found["recovered"]:
        state = "unfinished, recovered (the recorder stopped without closing the bag)"
    else:
        state = "finished"
    lines = [
        f"path:      {found['path']}",
        f"size:      {format_size(found['size_bytes'])}",
        f"state:     {state}",
    ]
    if found["lost"] or found["orphaned"]:
        lines.append(f"lost:      {found['loss'].removeprefix(found['path'] + ': ')}")
    lines += [
        f"messages:  {found['messages']} in {found['chunks']} chunks",
        f"start:     {_time(found['start'])}",
        f"end:       {_time(found['end'])}",
        f"duration:  {found['duration_s']:.3f} s",
    ]
    lines += info_lines(found.get("run"))
    encodings = sorted({t["encoding"] for t in found["topics"]})
    if encodings:
        line = f"encoding:  {', '.join(encodings)}"
        if "msgpack" in encodings:
            line += " (recorded before json channels; 'dockhil bag convert' rewrites it for viewers)"
        lines.append(line)
    lines.append("topics:")
    rows = [("topic", "type", "count", "rate [Hz]")] + [
        (t["topic"], t["type"] or "?", str(t["count"]), f"{t['rate_hz']:.1f}") for t in found["topics"]
    ]
    if len(rows) == 1:
        lines.append("  (none)")
    else:
        widths = [max(len(r[i]) for r in rows) for i in range(4)]
        for r in rows:
            lines.append(f"  {r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:>{widths[2]}}  {r[3]:>{widths[3]}}")
    return "\n".join(lines)


def _time(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    text = f"{seconds:.6f} s"
    # Wall-time bags carry Unix time; sim-time bags start near 0.
    if seconds > 1e9:
        stamp = datetime.datetime.fromtimestamp(seconds, datetime.UTC)
        text += f" ({stamp:%Y-%m-%d %H:%M:%S.%f} UTC)"
    return text


def _export(args: argparse.Namespace) -> int:
    from dockhil.errors import DockhilError

    if args.scene is not None and args.foxglove is None:
        raise DockhilError("--scene is for --foxglove")
    if args.foxglove is not None:
        return _export_foxglove(args)
    if args.ros2 is not None:
        if args.topic is not None:
            raise DockhilError("--topic is for --csv; --ros2 exports every topic")
        from dockhil.bags.ros2 import export, tell

        print(tell(export(args.path, args.ros2, overwrite=args.overwrite), args.ros2, log.Log("dockhil bag export:")))
        return 0
    if args.topic is None:
        raise DockhilError("--csv needs --topic T: the topic to export (see 'dockhil bag info PATH')")
    from dockhil.bags.tools import export_csv

    out = sys.stdout if args.csv == "-" else args.csv
    result = export_csv(args.path, args.topic, out, overwrite=args.overwrite)
    if result.loss:
        log.Log("dockhil bag export:").warning(result.loss)
    notes = []
    if result.unvalidated:
        notes.append(f"{result.unvalidated} messages fail validation (e.g. NaN) and are exported as recorded")
    if result.skipped:
        notes.append(f"{result.skipped} messages are not msgpack (or nest too deeply) and were skipped")
    for note in notes:
        log.Log("dockhil bag export:").info(f"note: {note}")
    if args.csv != "-":
        print(f"{result.rows} rows of {args.topic} written to {args.csv}")
    return 0


def _export_foxglove(args: argparse.Namespace) -> int:
    from dockhil.bags.foxglove_scene import export, geometry_of
    from dockhil.errors import DockhilError

    if args.topic is not None:
        raise DockhilError("--topic is for --csv; --foxglove copies every topic")
    geometry = None
    if args.scene is not None:
        from dockhil.scene import launchfile
        from dockhil.scene.graph import build

        file, *overrides = args.scene
        geometry = geometry_of(build(launchfile.load(file, launchfile.parse_overrides(overrides))))
    result = export(args.path, args.foxglove, geometry=geometry, overwrite=args.overwrite)
    if result.loss:
        log.Log("dockhil bag export:").warning(result.loss)
    print(f"{result.messages} messages and {result.derived} /tf and /scene messages written to {args.foxglove}")
    return 0


def _convert(args: argparse.Namespace) -> int:
    from dockhil.bags.tools import convert

    result = convert(args.path, args.out, overwrite=args.overwrite)
    if result.loss:
        log.Log("dockhil bag convert:").warning(result.loss)
    if result.unencodable:
        log.Log("dockhil bag convert:").info(
            f"note: {result.unencodable} messages are not msgpack and were not converted"
        )
    print(f"{result.messages} messages written to {args.out} (json)")
    return 0


def _record(args: argparse.Namespace) -> int:
    if args.bag_format == "ros2":
        from dockhil.bags.ros2 import record_then_convert

        def record(path: str) -> int:
            return _live().record(argparse.Namespace(**{**vars(args), "path": path}))

        return record_then_convert(args.path, record, log.Log("dockhil bag record:"), overwrite=args.overwrite)
    return _live().record(args)


def _play(args: argparse.Namespace) -> int:
    return _live("play").play(args)


def _live(name: str = "live") -> ModuleType:
    import importlib

    from dockhil.errors import DockhilError

    module = f"dockhil.bags.{name}"
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name != module:
            raise
        raise DockhilError(f"recording and playback need the dockhil runtime ({module}), not found") from None


def _positive_float(text: str) -> float:
    value = _float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def _non_negative_float(text: str) -> float:
    value = _float(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value
