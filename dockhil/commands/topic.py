"""`dockhil topic list | echo TOPIC | hz TOPIC`: look at the topics of running graphs.

When several graphs run, `--graph ID` (the run id `dockhil node list` shows) picks one; echo and
hz refuse to guess between graphs that publish the same topic. They stop, with one line and
exit 0, when their graph ends.

Echo and hz are observers (`dockhil.runtime.transport`): one whose output is not read (a pager left
open) never slows the graph; it loses its own messages, and says at the end how many.
"""

from __future__ import annotations

import os
import time

from dockhil.errors import DockhilError
from dockhil.log import Log

# How often echo and hz look whether their graph still runs [s].
ALIVE_CHECK_S = 0.5
OUTPUT_QUEUE = 1000  # lines waiting for stdout at most; beyond, an unread output drops them


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    ls = sub.add_parser("list", help="topics of every running graph, with type and publisher")
    echo = sub.add_parser("echo", help="print messages of a topic as JSON lines")
    echo.add_argument("topic")
    echo.add_argument("--count", "-n", type=int, metavar="N", help="stop after N messages")
    hz = sub.add_parser("hz", help="measure the rate of a topic")
    hz.add_argument("topic")
    hz.add_argument("--window", type=float, default=1.0, metavar="S", help="report every S seconds (default 1)")
    hz.add_argument("--count", "-n", type=int, metavar="N", help="stop after N reports")
    for q in (ls, echo, hz):
        q.add_argument("--graph", metavar="ID",
                       help="the run id of the graph to look at (see 'dockhil node list'); needed when several run")


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
        raise DockhilError(f"--graph {graph_id}: no such running graph; running: {running} (see 'dockhil node list')")
    return chosen


def choose_graph(topic: str, graph_id: str | None) -> dict:
    """The registry entry of the running graph whose `topic` to read; DockhilError (one line) if none or ambiguous."""
    graphs = select_graphs(graph_id)
    if not graphs:
        raise DockhilError("no running graph found; start one with 'dockhil launch FILE'")
    publishing = [info for info in graphs if topic in info["topics"]]
    if len(publishing) > 1:
        raise DockhilError(f"topic {topic} is published by {len(publishing)} running graphs: "
                           f"{', '.join(_describe(i) for i in publishing)}; choose one with --graph ID")
    if not publishing:
        known = sorted({t for info in graphs for t in info["topics"]})
        where = f"graph {graph_id}" if graph_id is not None else "any running graph"
        raise DockhilError(f"topic {topic} is not published by {where}; topics: {', '.join(known)}")
    return publishing[0]


def graph_alive(info: dict) -> bool:
    """Whether the graph's launcher still runs (it removes its registry entry when it ends)."""
    from dockhil.runtime.registry import registry_dir

    try:
        os.kill(info["pid"], 0)
    except OSError:
        return False
    return (registry_dir() / f"{info['run_id']}.json").exists()


def _subscribe(endpoint: str, keys):
    from dockhil.runtime.transport import Subscriber
    import zmq

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


def run(args) -> int:
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
    info = choose_graph(args.topic, args.graph)
    t = info["topics"][args.topic]
    from dockhil import msgs

    cls = msgs.type_by_name(t["type"])
    sub = _subscribe(t["endpoint"], graph_keys(info))
    out = _Output()
    try:  # closed: a command run inside another Python program (a test) leaves no socket behind
        return _read(args, sub, cls, _Watch(info), out)
    finally:
        sub.close()
        unprinted = out.close()
        lost = sub.lost + (unprinted if args.action == "echo" else 0)  # hz's lines are reports, not messages
        if lost:
            Log("[topic]").warning(f"{args.topic}: {lost} message(s) lost by this {args.action}, which did not keep "
                                   f"up (its output was not read in time); the graph's own deliveries are unaffected")


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
                        data = data[os.write(self._fd, data):]
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


def _read(args, sub, cls, watch, out) -> int:
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
                    out.put(msgspec.json.encode(decode(frames[1], cls)).decode())
                    n += 1
                except DecodeError as exc:
                    Log("[topic]").warning(f"bad message: {exc}")
            if watch.ended():
                return 0
        return 0
    reports = 0
    count = 0
    t0 = time.monotonic()
    while args.count is None or reports < args.count:
        frames = sub.recv(0.1)
        if out.left:
            return 0
        if frames is not None and len(frames) == 2:
            count += 1
        if watch.ended():
            return 0
        now = time.monotonic()
        if now - t0 >= args.window:
            out.put(f"{args.topic}: {count / (now - t0):.1f} Hz over {now - t0:.2f} s")
            reports += 1
            count = 0
            t0 = now
    return 0
