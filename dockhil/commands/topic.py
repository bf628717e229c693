"""`dockhil topic list | echo TOPIC | hz TOPIC`: look at the topics of running graphs."""

from __future__ import annotations

import sys
import time

from dockhil.errors import DockhilError


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="topics of every running graph, with type and publisher")
    echo = sub.add_parser("echo", help="print messages of a topic as JSON lines")
    echo.add_argument("topic")
    echo.add_argument("--count", "-n", type=int, metavar="N", help="stop after N messages")
    hz = sub.add_parser("hz", help="measure the rate of a topic")
    hz.add_argument("topic")
    hz.add_argument("--window", type=float, default=1.0, metavar="S", help="report every S seconds (default 1)")
    hz.add_argument("--count", "-n", type=int, metavar="N", help="stop after N reports")


def find_topic(topic: str):
    """(endpoint, type name, the graph's keys) of a topic in a running graph."""
    from dockhil.launcher import graph_keys, running_graphs

    graphs = running_graphs()
    for info in graphs:
        if topic in info["topics"]:
            t = info["topics"][topic]
            return t["endpoint"], t["type"], graph_keys(info)
    if not graphs:
        raise DockhilError("no running graph found; start one with 'dockhil launch FILE'")
    known = sorted({t for info in graphs for t in info["topics"]})
    raise DockhilError(f"topic {topic} is not published by any running graph; topics: {', '.join(known)}")


def _subscribe(endpoint: str, keys):
    from dockhil.transport import Subscriber
    import zmq

    sub = Subscriber(zmq.Context.instance(), observer=True)
    sub.connect(endpoint, keys=keys)
    return sub


def run(args) -> int:
    from dockhil.launcher import running_graphs

    if args.action == "list":
        graphs = running_graphs()
        if not graphs:
            print("no running graph", file=sys.stderr)
            return 0
        for info in graphs:
            for topic, t in sorted(info["topics"].items()):
                print(f"{topic}  {t['type']}  from {t['publisher']}  ({info['run_id']})")
        return 0
    endpoint, type_name, keys = find_topic(args.topic)
    import msgspec

    import msgs
    from msgs.codec import DecodeError, decode

    cls = msgs.type_by_name(type_name)
    sub = _subscribe(endpoint, keys)
    if args.action == "echo":
        n = 0
        while args.count is None or n < args.count:
            frames = sub.recv(1.0)
            if frames is None or len(frames) != 2:  # time-out, or a sim-time tick with no message
                continue
            try:
                msg = decode(frames[1], cls)
            except DecodeError as exc:
                print(f"# bad message: {exc}", file=sys.stderr)
                continue
            print(msgspec.json.encode(msg).decode(), flush=True)
            n += 1
        return 0
    reports = 0
    count = 0
    t0 = time.monotonic()
    while args.count is None or reports < args.count:
        frames = sub.recv(0.1)
        if frames is not None and len(frames) == 2:
            count += 1
        now = time.monotonic()
        if now - t0 >= args.window:
            print(f"{args.topic}: {count / (now - t0):.1f} Hz over {now - t0:.2f} s", flush=True)
            reports += 1
            count = 0
            t0 = now
    return 0
