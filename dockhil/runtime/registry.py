"""The registry of running graphs: each launcher describes its graph in a JSON file here (nodes,
topics, its key file) for the observers (`dockhil topic`, `node list`, `run`, `bag record`,
`bag play`), which read it without importing the launcher."""

from __future__ import annotations

import json
import math
import os
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from dockhil.errors import DockhilError, LaunchError
from dockhil.runtime.rundir import private_dir, runtime_dir
from dockhil.runtime.transport import GraphKeys

if TYPE_CHECKING:
    from collections.abc import Iterable

    from dockhil.scene.graph import Graph

KEY_FILE = "graph.keys"  # a graph's CURVE keys, in its run directory
COMPOSED = "composed"  # the process of a graph run --composed, as its entry names it


def registry_dir() -> Path:
    return private_dir(runtime_dir() / "graphs", "registry directory")


def new_run_id() -> str:
    """A run's id: when it started, and six hex digits so two started in the same second differ."""
    return time.strftime("%Y%m%d-%H%M%S-") + uuid.uuid4().hex[:6]


def write_entry(info: dict) -> Path:
    """Write (or rewrite, whole) a graph's entry; its path. Readers never see half of one."""
    path = registry_dir() / f"{info['run_id']}.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(info, indent=1))
    tmp.replace(path)
    return path


def register_composed(graph: Graph, clock: str) -> Path | None:
    """The entry of a graph run --composed in this process, for `node list` and `node info`: its
    nodes, all in one process (this one). No topics: its nodes hand messages to each other here,
    with no socket an observer could read. None if it cannot be written: the run needs no entry."""
    pid = os.getpid()
    try:
        return write_entry(
            {
                "run_id": new_run_id(),
                "pid": pid,
                "file": graph.scene.path,
                "clock": clock,
                "keys": "",
                "nodes": {COMPOSED: {"type": "composed", "pid": pid, "members": list(graph.order)}},
                "topics": {},
                "graph_nodes": describe_nodes(graph, {COMPOSED: list(graph.order)}),
                "unconnected": {},
            }
        )
    except (DockhilError, OSError):
        return None


def graph_keys(info: dict) -> GraphKeys:
    """The CURVE keys of a registered graph, for an observer (`topic echo`, a recorder)."""
    path = info.get("keys")
    if not path:
        raise LaunchError(
            f"graph {info.get('run_id')} names no key file; it was started by an older dockhil: restart it"
        )
    return GraphKeys.read(path)


def running_graphs() -> list[dict]:
    """Descriptions of graphs whose launcher is still alive."""
    out = []
    for f in sorted(registry_dir().glob("*.json")):
        try:
            info = json.loads(f.read_text())
            os.kill(info["pid"], 0)
        except (OSError, ValueError, KeyError):
            continue
        out.append(info)
    return out


def describe_nodes(graph: Graph, units: dict[str, list[str]]) -> dict[str, dict]:
    """Each node of a built graph as `dockhil node info` shows it: its type, host, process (its own,
    or the container it shares), parameters as resolved, and its ports with topic, message type,
    lag and maximum age (wall time; None: no limit)."""
    from dockhil import msgs

    process = {m: u for u, members in units.items() for m in members}
    dt = graph.scene.dt
    out = {}
    for name, gn in graph.nodes.items():
        declared, _ = gn.cls.ports(gn.params)
        inputs = {}
        for port, ref in gn.inputs.items():
            decl = declared.get(port)
            max_age = ref.max_age if ref.max_age is not None else decl.age_limit(dt) if decl else None
            pub = graph.publishers.get(ref.topic)
            if pub is not None and graph.nodes[pub.node].respawn:  # the launcher lifts the limit there
                max_age = math.inf
            inputs[port] = {
                "topic": ref.topic,
                "type": msgs.type_name(ref.type),
                "lag": ref.lag,
                "delay": decl.delay if decl else 0.0,
                "required": ref.required,
                "max_age": None if max_age is None or math.isinf(max_age) else float(max_age),
            }
        out[name] = {
            "type": gn.type_name,
            "host": gn.host or "localhost",
            "process": process.get(name, name),
            "params": json.loads(json.dumps(gn.params, default=str)),  # as JSON holds them
            "inputs": inputs,
            "outputs": {
                port: {"topic": ref.topic, "type": msgs.type_name(ref.type)} for port, ref in gn.outputs.items()
            },
        }
    return out


class Subscriber(Protocol):
    """A helper process that reads topics (plan.ExtraProcess, a recorder), as the registry names it."""

    name: str
    topics: list[str]


def describe_subscribers(graph: Graph, extra: Iterable[Subscriber] = ()) -> dict[str, list[str]]:
    """Topic -> what reads it: `node.port` for each input, and each helper process (a recorder) by name."""
    out = {topic: [f"{ref.node}.{ref.port}" for ref in refs] for topic, refs in graph.subscribers.items()}
    for proc in extra:
        for topic in proc.topics:
            out.setdefault(topic, []).append(proc.name)
    return out
