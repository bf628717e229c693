"""`dockhil node list`: the nodes of running graphs; `dockhil node types`: the node types
installed (built in, or added by another package through the `dockhil.nodes` entry points)."""

from __future__ import annotations

import argparse
import os
from typing import Any

from dockhil.errors import DockhilError, LaunchError
from dockhil.log import Log


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    ls = sub.add_parser("list", help="nodes of every running graph (first its run id), with type, pid and state")
    ls.add_argument("--graph", metavar="ID", help="only the graph with this run id")
    info = sub.add_parser("info", help="a running node's type, ports, parameters (as resolved), process and host")
    info.add_argument("node")
    info.add_argument("--graph", metavar="ID", help="the run id of its graph; needed when several run it")
    info.add_argument("--json", action="store_true", help="one JSON object")
    types = sub.add_parser("types", help="node types this installation knows, with their ports and parameters")
    types.add_argument("name", nargs="?", help="show one type in full")


def _alive(pid: Any) -> bool:  # as a registry file gives it: not checked to be an int
    try:
        os.kill(pid, 0)
        return True
    except (OSError, TypeError):
        return False


def run(args: argparse.Namespace) -> int:
    if args.action == "types":
        return _types(args.name)
    from dockhil.commands.topic import select_graphs

    if args.action == "info":
        return _info(args.node, select_graphs(args.graph), args.json)
    graphs = select_graphs(args.graph)
    if not graphs:
        Log("").info("no running graph")
        return 0
    for info in graphs:
        print(f"{info['run_id']}  {info['file']}  ({info['clock']} time)")
        for name, n in info["nodes"].items():
            state = "running" if _alive(n["pid"]) else "exited"
            print(f"  {name}  {n['type']}  pid {n['pid']}  {state}")
    return 0


def _info(name: str, graphs: list[dict], as_json: bool) -> int:
    import json

    if not graphs:
        raise DockhilError("no running graph found; start one with 'dockhil launch FILE'")
    found = [g for g in graphs if name in g.get("graph_nodes", {})]
    if len(found) > 1:
        raise DockhilError(
            f"node {name} runs in {len(found)} graphs: {', '.join(g['run_id'] for g in found)}; "
            f"choose one with --graph ID"
        )
    if not found:
        known = sorted({n for g in graphs for n in g.get("graph_nodes", g["nodes"])})
        raise DockhilError(
            f"node {name} runs in no running graph{' chosen' if len(graphs) == 1 else ''}; "
            f"nodes: {', '.join(known)} (a graph started by an older dockhil does not describe them)"
        )
    g = found[0]
    n = g["graph_nodes"][name]
    proc = g["nodes"].get(n["process"], {})
    pid = proc.get("pid")
    out = {
        "node": name,
        "graph": g["run_id"],
        "file": g["file"],
        "clock": g["clock"],
        **n,
        "pid": pid,
        "state": "running" if _alive(pid) else "on another host" if pid is None else "exited",
    }
    if as_json:
        print(json.dumps(out))
        return 0
    shared = (
        f" (container, with {', '.join(m for m in proc.get('members', []) if m != name)})"
        if len(proc.get("members", [])) > 1
        else ""
    )
    print(f"Node: {name}")
    print(f"Type: {n['type']}")
    print(f"Graph: {g['run_id']} ({g['file']}, {g['clock']} time)")
    print(f"Process: {n['process']}{shared}, pid {pid if pid else '-'}, {out['state']}")
    print(f"Host: {n['host']}")
    print("Inputs:" + ("" if n["inputs"] else " none"))
    for port, i in n["inputs"].items():
        when = f"delayed {i['delay']:g} s" if i["delay"] else "feedthrough" if i["lag"] == 0 else "previous tick"
        age = "none" if i["max_age"] is None else f"{i['max_age']:g} s"
        opt = "" if i["required"] else ", optional"
        print(f"  {port}: {i['topic']}  {i['type']}  ({when}, {i['lag']} tick(s) back, max_age {age}{opt})")
    print("Outputs:" + ("" if n["outputs"] else " none"))
    for port, o in n["outputs"].items():
        print(f"  {port}: {o['topic']}  {o['type']}")
    print("Parameters:" + ("" if n["params"] else " none"))
    for pname, value in n["params"].items():
        print(f"  {pname}: {json.dumps(value)}")
    return 0


def _types(name: str | None) -> int:
    from dockhil import msgs, node_types

    extra = node_types.plugins()
    names = [name] if name else [*sorted(node_types.REGISTRY), *sorted(extra)]
    refused = 0
    for type_name in names:
        origin = f"  [from {extra[type_name][1]}]" if type_name in extra else ""
        if name is None and origin:  # one broken package does not hide the other types
            try:
                cls = node_types.load(type_name)
            except LaunchError as exc:
                Log("dockhil node types:").error(str(exc))
                refused += 1
                continue
        else:
            cls = node_types.load(type_name)
        alias = f"  [{node_types.ONE_DOF[type_name]} with dof: 6]" if type_name in node_types.ONE_DOF else ""
        print(f"{type_name}: {cls.describe()}{origin}{alias}")
        if not name:
            continue
        for port, i in cls.inputs.items():
            ft = f" (delayed {i.delay:g} s)" if i.delay else "" if i.feedthrough else " (previous tick)"
            opt = "" if i.required else " (optional)"
            print(f"  in  {port}: {i.topic} {msgs.type_name(i.type)}{ft}{opt}  {i.help}")
        for port, o in cls.outputs.items():
            print(f"  out {port}: {o.topic} {msgs.type_name(o.type)}  {o.help}")
        dof = node_types.dof_param(type_name)  # picks the class, so it is the registry's, not the class's
        for pname, p in {**({"dof": dof} if dof else {}), **cls.params}.items():
            unit = f" [{p.unit}]" if p.unit else ""
            print(f"  param {pname}: {p.type.__name__}{unit} = {p.default!r}  {p.help}")
    return 1 if refused else 0
