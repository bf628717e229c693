"""`dockhil run NODE [param:=value ...]`: one node alone, wired to a running graph.

Its inputs connect to the topics of the running graph; its outputs bind
fresh endpoints (registered, so `dockhil topic echo` finds them). It runs in
wall time at --rate until Ctrl-C or --duration.
"""

from __future__ import annotations

import argparse
import math
import os

from dockhil import log
from dockhil.argtypes import hertz, max_age_setting, node_name, seconds
from dockhil.errors import DockhilError, suggest


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("node", help="node type (see 'dockhil node types') or module:Class")
    p.add_argument("overrides", nargs="*", metavar="param:=value", help="node parameters (anywhere on the line)")
    p.add_argument("--name", type=node_name, help="node name (default: the type name)")
    p.add_argument(
        "-r",
        "--remap",
        action="append",
        default=[],
        metavar="FROM:=TO",
        help="remap a port or topic to a topic (repeatable)",
    )
    p.add_argument("--rate", type=hertz, default=100.0, metavar="HZ", help="loop rate (default 100)")
    p.add_argument("--duration", type=seconds, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--max-age",
        type=max_age_setting,
        action="append",
        default=[],
        metavar="NAME.INPUT=SECONDS",
        help="how old an input's latest message may be (> 0, at most 600 s, or inf for no limit; "
        "NAME: --name or the type's; repeatable)",
    )
    log.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    import json
    import uuid

    from dockhil import msgs, node_types
    from dockhil.runtime.executor import PortWire, RunSpec
    from dockhil.runtime.process import run_node
    from dockhil.runtime.registry import KEY_FILE, graph_keys, registry_dir, running_graphs
    from dockhil.runtime.transport import GraphKeys, ipc_endpoint, new_run_dir
    from dockhil.scene import boundedyaml
    from dockhil.scene.launchfile import parse_overrides

    name = args.name or args.node.rsplit(":", 1)[-1]
    params = {k: boundedyaml.load(v, f"parameter {k}:={v}")[0] for k, v in parse_overrides(args.overrides).items()}
    type_name, cls, params = node_types.resolve(args.node, name, params)  # dof:=6 picks the 6-DOF type
    remap = parse_overrides(args.remap)
    ins, outs = cls.ports(params)
    ages = {}
    for node, port, age in args.max_age:
        where = f"--max-age {node}.{port}"
        if node != name:
            raise DockhilError(f"{where}: the node run here is {name!r}; give --max-age {name}.{port}=SECONDS")
        if port not in ins:
            raise DockhilError(
                f"{where}: node {name!r} ({type_name}) has no input {port!r}; {suggest(port, ins, 'inputs')}"
            )
        ages[port] = age

    def topic_of(port: str, default: str) -> str:
        return remap.get(port, remap.get(default, default))

    published: dict[str, dict] = {}
    for info in running_graphs():
        for topic, t in info["topics"].items():
            published.setdefault(topic, dict(t, graph=info))
    inputs = {}
    for port, i in ins.items():
        topic = topic_of(port, i.topic)
        t = published.get(topic)
        if t is None:
            if i.required:
                raise DockhilError(
                    f"node {name!r} input {port!r} needs {topic}, which no running graph publishes; "
                    f"start the graph first or remap with -r {port}:=TOPIC"
                )
            continue
        if t["type"] != msgs.type_name(i.type):
            raise DockhilError(f"topic {topic} carries {t['type']}, but {name}.{port} expects {msgs.type_name(i.type)}")
        age = ages.get(port)
        inputs[port] = PortWire(
            topic,
            t["endpoint"],
            t["type"],
            i.lag_ticks(1.0 / args.rate),
            unlimited_age=age == math.inf,
            max_age=None if age == math.inf else age,
        )
    for port, o in outs.items():
        _refuse_unheard(name, port, topic_of(port, o.topic))
    # One key file: the graph's keys when wired to one, which this node's own outputs then share.
    graphs = {published[w.topic]["graph"]["run_id"]: published[w.topic]["graph"] for w in inputs.values()}
    if len(graphs) > 1:
        raise DockhilError(
            f"node {name!r} inputs come from {len(graphs)} running graphs "
            f"({', '.join(sorted(graphs))}); a node joins one graph"
        )
    keys = graph_keys(next(iter(graphs.values()))) if graphs else GraphKeys.make()
    run_id = f"run-{name}-{uuid.uuid4().hex[:6]}"
    run_dir = new_run_dir(run_id)
    key_file = keys.write(run_dir / KEY_FILE)
    outputs = {
        port: PortWire(topic_of(port, o.topic), ipc_endpoint(run_dir, topic_of(port, o.topic)), msgs.type_name(o.type))
        for port, o in outs.items()
    }
    n_ticks = None if args.duration is None else int(round(args.duration * args.rate))
    spec = RunSpec(
        name,
        type_name,
        params,
        1.0 / args.rate,
        "wall",
        n_ticks,
        inputs,
        outputs,
        key_file=str(key_file),
        run_id=run_id,
    )
    reg = registry_dir() / f"{run_id}.json"
    reg.write_text(
        json.dumps(
            {
                "run_id": run_id,
                "pid": os.getpid(),
                "file": f"dockhil run {args.node}",
                "clock": "wall",
                "keys": str(key_file),
                "nodes": {name: {"type": type_name, "pid": os.getpid()}},
                "topics": {
                    w.topic: {"type": w.type, "endpoint": w.endpoint, "publisher": name} for w in outputs.values()
                },
            }
        )
    )
    try:
        return run_node(spec)
    finally:
        reg.unlink(missing_ok=True)
        for f in run_dir.iterdir():
            f.unlink(missing_ok=True)
        run_dir.rmdir()


def _refuse_unheard(name: str, port: str, topic: str) -> None:
    """An output of a node run alone is a new topic. A running graph's subscribers connect only to the
    publishers the launch wired them to: a second publisher of one of its topics, or of a topic one of
    its inputs was left without (the robot driver's /estop), would not be heard, however urgent."""
    from dockhil.runtime.registry import running_graphs

    for info in running_graphs():
        t = info.get("topics", {}).get(topic)
        if t is not None:
            raise DockhilError(
                f"topic {topic} is published by graph {info['run_id']} (node {t['publisher']!r}); "
                f"{name}.{port} would be a second publisher its subscribers never hear: remap it "
                f"with -r {port}:=/TOPIC"
            )
        readers = info.get("unconnected", {}).get(topic)
        if readers:
            raise DockhilError(
                f"graph {info['run_id']} left input {readers[0]} ({topic}) unconnected at launch, so it "
                f"would not hear {name}.{port}; publish {topic} from a node of the launch file"
            )
