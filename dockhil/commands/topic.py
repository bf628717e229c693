"""`dockhil topic list | info TOPIC | echo TOPIC | hz TOPIC`: look at the topics of running graphs.

When several graphs run, `--graph ID` (the run id `dockhil node list` shows) picks one; info, echo
and hz refuse to guess between graphs that publish the same topic. Echo and hz stop, with one line
and exit 0, when their graph ends.

Info, echo and hz are observers (`dockhil.runtime.transport`): one whose output is not read (a pager
left open) never slows the graph; it loses its own messages, and says at the end how many.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

from dockhil.argtypes import nonnegative, seconds
from dockhil.errors import DockhilError
from dockhil.log import Log

if TYPE_CHECKING:
    import msgspec

    from dockhil.runtime.keys import GraphKeys
    from dockhil.runtime.transport import Subscriber

# How often echo and hz look whether their graph still runs [s].
ALIVE_CHECK_S = 0.5
OUTPUT_QUEUE = 1000  # lines waiting for stdout at most; beyond, an unread output drops them
HZ_WINDOW = 10_000  # hz's statistics are over this many messages by default, as ros2 topic hz's


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    ls = sub.add_parser("list", help="topics of every running graph, with type and publisher")
    info = sub.add_parser("info", help="a topic's type, publisher, subscribers, endpoint and rate")
    info.add_argument("topic")
    info.add_argument(
        "--window",
        type=nonnegative,
        default=1.0,
        metavar="S",
        help="measure the rate over S seconds (default 1; 0: do not measure)",
    )
    info.add_argument("--json", action="store_true", help="one JSON object")
    echo = sub.add_parser("echo", help="print messages of a topic as JSON lines")
    echo.add_argument("topic")
    echo.add_argument("--count", "-n", type=int, metavar="N", help="stop after N messages")
    echo.add_argument(
        "--field",
        metavar="PATH",
        help="print only this field: dotted, list indices as numbers (wrench.force.x, bodies.0.mass)",
    )
    echo.add_argument(
        "--wait", action="store_true", help="wait for a graph to publish the topic rather than fail (Ctrl-C ends it)"
    )
    hz = sub.add_parser("hz", help="measure the rate of a topic, with min/max/std dev of its period")
    hz.add_argument("topic")
    hz.add_argument(
        "--window",
        type=_positive_int,
        default=HZ_WINDOW,
        metavar="N",
        help=f"statistics over the last N messages (default {HZ_WINDOW})",
    )
    hz.add_argument("--every", type=seconds, default=1.0, metavar="S", help="report every S seconds (default 1)")
    hz.add_argument("--count", "-n", type=int, metavar="N", help="stop after N reports")
    for q in (ls, info, echo, hz):
        q.add_argument(
            "--graph",
            metavar="ID",
            help="the run id of the graph to look at (see 'dockhil node list'); needed when several run",
        )


def _positive_int(text: str) -> int:
    import argparse

    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 2:
        raise argparse.ArgumentTypeError(f"{text!r} is not a window of messages (a whole number >= 2)")
    return value


class NotYet(DockhilError):
    """The graph or topic looked for is not there yet: `echo --wait` waits for it."""


def _describe(info: dict) -> str:
    return f"{info['run_id']} ({info['file']})"


def select_graphs(graph_id: str | None) -> list[dict]:
    """The running graphs, or only the one with run id `graph_id`; DockhilError (one line) if it does not run."""
    from dockhil.runtime.registry import running_graphs

    graphs = running_graphs()
    if graph_id is None:
        return graphs
    chosen = [info for info in graphs if info["run_id"] == graph_id]
    if not chosen:
        running = ", ".join(_describe(i) for i in graphs) or "none"
        raise NotYet(f"--graph {graph_id}: no such running graph; running: {running} (see 'dockhil node list')")
    return chosen


def choose_graph(topic: str, graph_id: str | None) -> dict:
    """The registry entry of the running graph whose `topic` to read; DockhilError (one line) if none or ambiguous."""
    graphs = select_graphs(graph_id)
    if not graphs:
        raise NotYet("no running graph found; start one with 'dockhil launch FILE'")
    publishing = [info for info in graphs if topic in info["topics"]]
    if len(publishing) > 1:
        raise DockhilError(
            f"topic {topic} is published by {len(publishing)} running graphs: "
            f"{', '.join(_describe(i) for i in publishing)}; choose one with --graph ID"
        )
    if not publishing:
        known = sorted({t for info in graphs for t in info["topics"]})
        where = f"graph {graph_id}" if graph_id is not None else "any running graph"
        raise NotYet(f"topic {topic} is not published by {where}; topics: {', '.join(known)}")
    return publishing[0]


def graph_alive(info: dict) -> bool:
    """Whether the graph's launcher still runs (it removes its registry entry when it ends)."""
    from dockhil.runtime.registry import registry_dir

    try:
        os.kill(info["pid"], 0)
    except OSError:
        return False
    return (registry_dir() / f"{info['run_id']}.json").exists()


def _subscribe(endpoint: str, keys: GraphKeys) -> Subscriber:
    import zmq

    from dockhil.runtime.transport import Subscriber

    sub = Subscriber(zmq.Context.instance(), observer=True)
    sub.connect(endpoint, keys=keys)
    return sub


class _Watch:
    """Says, at most every ALIVE_CHECK_S, whether the graph has ended."""

    def __init__(self, info: dict):
        self.info = info
        self.next = time.monotonic() + ALIVE_CHECK_S

    def ended(self) -> bool:
        now = time.monotonic()
        if now < self.next:
            return False
        self.next = now + ALIVE_CHECK_S
        if graph_alive(self.info):
            return False
        Log("[topic]").info(f"graph {self.info['run_id']} ended")
        return True


def run(args: argparse.Namespace) -> int:
    from dockhil.runtime.registry import graph_keys

    if args.action == "list":
        graphs = select_graphs(args.graph)
        if not graphs:
            Log("").info("no running graph")
            return 0
        for info in graphs:
            for topic, t in sorted(info["topics"].items()):
                print(f"{topic}  {t['type']}  from {t['publisher']}  ({info['run_id']})")
        return 0
    try:  # Ctrl-C ends an observer as its graph's end does: what it read is out, exit 0
        info = (
            _wait_for(args.topic, args.graph) if getattr(args, "wait", False) else choose_graph(args.topic, args.graph)
        )
        t = info["topics"][args.topic]
        from dockhil import msgs

        cls = msgs.type_by_name(t["type"])
        pick = field_reader(cls, args.field) if getattr(args, "field", None) else None
        if args.action == "info":
            return _info(args, info, t, graph_keys(info))
        sub = _subscribe(t["endpoint"], graph_keys(info))
        out = _Output()
        try:  # closed: a command run inside another Python program (a test) leaves no socket behind
            return _read(args, sub, cls, _Watch(info), out, pick)
        finally:
            sub.close()
            unprinted = out.close()
            lost = sub.lost + (unprinted if args.action == "echo" else 0)  # hz's lines are reports, not messages
            if lost:
                Log("[topic]").warning(
                    f"{args.topic}: {lost} message(s) lost by this {args.action}, which did not "
                    f"keep up (its output was not read in time); the graph's own deliveries "
                    f"are unaffected"
                )
    except KeyboardInterrupt:
        return 0


def _wait_for(topic: str, graph_id: str | None) -> dict:
    """The graph publishing `topic`, once one does (a launch started later); said once while waiting."""
    said = False
    while True:
        try:
            return choose_graph(topic, graph_id)
        except NotYet as exc:
            if not said:
                Log("[topic]").info(f"waiting for {topic}: {exc}")
                said = True
        time.sleep(ALIVE_CHECK_S)


def field_reader(cls: type, path: str) -> Callable[[Any], Any]:
    """A function from a message of type `cls` to its field at `path` (dotted, list indices as
    numbers); DockhilError (one line, naming the fields there are) if the type has no such field."""
    import types
    import typing

    import msgspec

    steps: list[str | int] = []
    t: object = cls
    for part in path.split("."):
        where = "the message" if not steps else ".".join(map(str, steps))
        if typing.get_origin(t) is typing.Annotated:  # a constrained field: the type under the constraint
            t = typing.get_args(t)[0]
        held = [a for a in typing.get_args(t) if a is not type(None)]
        if typing.get_origin(t) in (typing.Union, types.UnionType) and len(held) == 1:
            t = held[0]  # an optional field: what it holds when set
        args = typing.get_args(t)
        if isinstance(t, type) and issubclass(t, msgspec.Struct):
            fields = {f.name: f.type for f in msgspec.structs.fields(t)}
            if part not in fields:
                raise DockhilError(
                    f"--field {path}: {where} ({t.__name__}) has no field {part!r}; fields: {', '.join(fields)}"
                )
            t = fields[part]
            steps.append(part)
        elif typing.get_origin(t) in (list, tuple):
            if not part.isdigit():
                raise DockhilError(f"--field {path}: {where} is a list; index it by number (0, 1, ...), not {part!r}")
            index = int(part)
            if Ellipsis in args or typing.get_origin(t) is list:
                t = args[0] if args else object
            elif index < len(args):
                t = args[index]
            else:
                raise DockhilError(f"--field {path}: {where} has {len(args)} items; index {index} is beyond")
            steps.append(index)
        else:
            name = getattr(t, "__name__", str(t))
            raise DockhilError(f"--field {path}: {where} is a value ({name}) with no fields; no {part!r} in it")

    def read(msg):
        value = msg
        for i, step in enumerate(steps):
            if isinstance(step, int):
                if step >= len(value):
                    where = ".".join(map(str, steps[:i])) or "the message"
                    raise DockhilError(
                        f"--field {path}: {where} has {len(value)} item(s) in this message; index {step} is beyond"
                    )
                value = value[step]
            else:
                value = getattr(value, step)
        return value

    return read


def period_stats(arrivals: Iterable[float]) -> dict | None:
    """Rate and period statistics of messages that arrived at `arrivals` [s, ascending], as ros2
    topic hz gives them: the mean rate, the shortest and longest period, the standard deviation of
    the periods (over all of them, not a sample's), and how many periods; None under two arrivals."""
    import math

    times = list(arrivals)
    if len(times) < 2:
        return None
    periods = [b - a for a, b in zip(times, times[1:])]
    n = len(periods)
    mean = (times[-1] - times[0]) / n
    std = math.sqrt(sum((p - mean) ** 2 for p in periods) / n)
    return {
        "rate": 1.0 / mean if mean > 0 else math.inf,
        "min": min(periods),
        "max": max(periods),
        "std": std,
        "window": n,
    }


def format_stats(stats: dict, lost: int = 0) -> str:
    line = (
        f"average rate: {stats['rate']:.1f} / min: {stats['min']:.3f}s max: {stats['max']:.3f}s "
        f"std dev: {stats['std']:.5f}s window: {stats['window']}"
    )
    return line + (f" / lost: {lost}" if lost else "")


def _info(args: argparse.Namespace, info: dict, t: dict, keys: GraphKeys) -> int:
    import json

    endpoint = t["endpoint"]
    nodes = info.get("nodes", {})
    described = info.get("graph_nodes", {})
    publisher = t["publisher"]
    process = described.get(publisher, {}).get("process", publisher)
    out = {
        "topic": args.topic,
        "type": t["type"],
        "graph": info["run_id"],
        "file": info["file"],
        "publisher": publisher,
        "process": process,
        "pid": nodes.get(process, {}).get("pid"),
        "subscribers": t.get("subscribers"),
        "endpoint": endpoint,
        "kind": endpoint.split("://", 1)[0],
        "rate_hz": None,
        "window_s": args.window,
        "messages": None,
    }
    if args.window > 0:
        sub = _subscribe(endpoint, keys)
        arrivals = []
        try:
            end = time.monotonic() + args.window
            while (left := end - time.monotonic()) > 0:
                frames = sub.recv(min(left, 0.1))
                if frames is not None and len(frames) == 2:
                    arrivals.append(time.monotonic())
        finally:
            sub.close()
        stats = period_stats(arrivals)
        out["messages"] = len(arrivals)
        out["rate_hz"] = stats["rate"] if stats else 0.0
    if args.json:
        print(json.dumps(out))
        return 0
    subs = out["subscribers"]
    readers = (
        "none"
        if subs == []
        else ", ".join(subs)
        if subs
        else "not registered (the graph was started by an older dockhil)"
    )
    pid = f", pid {out['pid']}" if out["pid"] else ""
    via = f" (process {process}{pid})" if process != publisher or pid else ""
    print(f"Topic: {args.topic}")
    print(f"Type: {out['type']}")
    print(f"Graph: {info['run_id']} ({info['file']})")
    print(f"Publisher: {publisher}{via}")
    print(f"Subscribers: {readers}")
    print(f"Endpoint: {out['kind']} ({endpoint})")
    if args.window > 0:
        print(f"Rate: {out['rate_hz']:.1f} Hz ({out['messages']} messages over {args.window:g} s)")
    return 0


class _Output:
    """Lines to stdout from a thread of their own, so that a reader that stops reading (a pager left
    open) blocks that thread only: the socket is still read, the graph's end still seen, and lines
    beyond OUTPUT_QUEUE waiting are dropped and counted (`dropped`), never queued without bound."""

    def __init__(self) -> None:
        import queue
        import sys
        import threading

        self.lines: queue.Queue = queue.Queue(OUTPUT_QUEUE)
        self.dropped = 0
        self.left = False  # the reader closed the pipe (`| head`): nothing more to print
        try:
            sys.stdout.flush()
            self._fd = sys.stdout.fileno()  # raw writes: no buffer that exit would have to flush
        except (AttributeError, OSError, ValueError):
            self._fd = None  # not a file (a test's capture): its write
        self._thread = threading.Thread(target=self._write, name="topic-output", daemon=True)
        self._thread.start()

    def put(self, line: str) -> None:
        import queue

        try:
            self.lines.put_nowait(line)
        except queue.Full:
            self.dropped += 1

    def _write(self) -> None:
        import sys

        while (line := self.lines.get()) is not None:
            try:
                if self._fd is None:
                    sys.stdout.write(line + "\n")
                    sys.stdout.flush()
                else:
                    data = (line + "\n").encode()
                    while data:
                        data = data[os.write(self._fd, data) :]
            except (BrokenPipeError, OSError):
                self.left = True
                return

    def close(self, patience_s: float = 1.0) -> int:
        """Let the lines waiting go out while they still move (stalled for patience_s: left behind);
        how many were dropped or left behind."""
        waiting = self.lines.qsize()
        while waiting and self._thread.is_alive():
            self._thread.join(patience_s)
            moved, waiting = waiting - self.lines.qsize(), self.lines.qsize()
            if not moved:
                break
        if self._thread.is_alive() and not waiting:
            self.lines.put(None)
            self._thread.join(patience_s)
        return self.dropped + (0 if self.left else self.lines.qsize())


def _read(
    args: argparse.Namespace,
    sub: Subscriber,
    cls: type[msgspec.Struct],
    watch: _Watch,
    out: _Output,
    pick: Callable[[Any], Any] | None = None,
) -> int:
    import collections

    import msgspec

    from dockhil.msgs.codec import DecodeError, decode

    if args.action == "echo":
        n = 0
        while args.count is None or n < args.count:
            frames = sub.recv(ALIVE_CHECK_S)
            if out.left:
                return 0
            if frames is not None and len(frames) == 2:  # not a time-out, nor a sim-time tick with no message
                try:
                    msg = decode(frames[1], cls)
                except DecodeError as exc:
                    Log("[topic]").warning(f"bad message: {exc}")
                else:
                    out.put(msgspec.json.encode(pick(msg) if pick else msg).decode())
                    n += 1
            if watch.ended():
                return 0
        return 0
    reports = 0
    arrivals: collections.deque = collections.deque(maxlen=args.window + 1)  # N periods
    new = 0
    next_report = time.monotonic() + args.every
    while args.count is None or reports < args.count:
        frames = sub.recv(0.1)
        if out.left:
            return 0
        if frames is not None and len(frames) == 2:
            arrivals.append(time.monotonic())
            new += 1
        if watch.ended():
            return 0
        now = time.monotonic()
        if now >= next_report:
            stats = period_stats(arrivals) if new else None
            idle = f"{args.topic}: no new messages" if not new else f"{args.topic}: one message so far"
            out.put(format_stats(stats, sub.lost) if stats else idle)
            reports += 1
            new = 0
            next_report = now + args.every
    return 0
