"""`dockhil node list`: the nodes of running graphs; `dockhil node types`: the node types\ninstalled (built in, or added by another package through the `dockhil.nodes` entry points)."""

from __future__ import annotations

import os

from dockhil.errors import LaunchError
from dockhil.log import Log


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    ls = sub.add_parser("list", help="nodes of every running graph (first its run id), with type, pid and state")
    ls.add_argument("--graph", metavar="ID", help="only the graph with this run id")
    types = sub.add_parser("types", help="node types this installation knows, with their ports and parameters")
    types.add_argument("name", nargs="?", help="show one type in full")


def _alive(pid) -> bool:
    try:
        os.kill(pid, 0)
        return True
    except (OSError, TypeError):
        return False


def run(args) -> int:
    if args.action == "types":
        return _types(args.name)
    from dockhil.commands.topic import select_graphs

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


def _types(name: str | None) -> int:
    from dockhil import msgs
    from dockhil import nodes

    extra = nodes.plugins()
    names = [name] if name else [*sorted(nodes.REGISTRY), *sorted(extra)]
    refused = 0
    for type_name in names:
        origin = f"  [from {extra[type_name][1]}]" if type_name in extra else ""
        if name is None and origin:  # one broken package does not hide the other types
            try:
                cls = nodes.load(type_name)
            except LaunchError as exc:
                Log("dockhil node types:").error(str(exc))
                refused += 1
                continue
        else:
            cls = nodes.load(type_name)
        alias = f"  [{nodes.ONE_DOF[type_name]} with dof: 6]" if type_name in nodes.ONE_DOF else ""
        print(f"{type_name}: {cls.describe()}{origin}{alias}")
        if not name:
            continue
        for port, i in cls.inputs.items():
            ft = f" (delayed {i.delay:g} s)" if i.delay else "" if i.feedthrough else " (previous tick)"
            opt = "" if i.required else " (optional)"
            print(f"  in  {port}: {i.topic} {msgs.type_name(i.type)}{ft}{opt}  {i.help}")
        for port, o in cls.outputs.items():
            print(f"  out {port}: {o.topic} {msgs.type_name(o.type)}  {o.help}")
        dof = nodes.dof_param(type_name)  # picks the class, so it is the registry's, not the class's
        for pname, p in {**({"dof": dof} if dof else {}), **cls.params}.items():
            unit = f" [{p.unit}]" if p.unit else ""
            print(f"  param {pname}: {p.type.__name__}{unit} = {p.default!r}  {p.help}")
    return 1 if refused else 0
