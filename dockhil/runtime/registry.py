"""The registry of running graphs: each launcher describes its graph in a JSON file here (nodes,
topics, its key file) for the observers (`dockhil topic`, `node list`, `run`, `bag record`,
`bag play`), which read it without importing the launcher."""

from __future__ import annotations

import json
import os
from pathlib import Path

from dockhil.errors import LaunchError
from dockhil.runtime.transport import GraphKeys, private_dir, runtime_dir

KEY_FILE = "graph.keys"  # a graph's CURVE keys, in its run directory


def registry_dir() -> Path:
    return private_dir(runtime_dir() / "graphs", "registry directory")


def graph_keys(info: dict) -> GraphKeys:
    """The CURVE keys of a registered graph, for an observer (`topic echo`, a recorder)."""
    path = info.get("keys")
    if not path:
        raise LaunchError(f"graph {info.get('run_id')} names no key file; it was started by an older dockhil: "
                          f"restart it")
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
