"""`dockhil graph FILE`: what a launch file would start, how it connects, what it leaves out, and
whether `dockhil launch` would refuse its step (the same scene check, same one line, exit 2)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from dockhil import msgs

if TYPE_CHECKING:
    from dockhil.scene.graph import Graph


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", nargs="?", help="launch file (YAML)")
    p.add_argument("overrides", nargs="*", metavar="name:=value", help="launch arguments")
    p.add_argument("--dot", action="store_true", help="print Graphviz DOT instead of text")
    p.add_argument("--schema", action="store_true", help="print the JSON Schema of launch files and exit")


def run(args: argparse.Namespace) -> int:
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    if args.schema:
        import json

        from dockhil.scene.schema import json_schema

        print(json.dumps(json_schema(), indent=1))
        return 0
    from dockhil.analysis.scenecheck import scene_check

    scene = launchfile.load(args.file, launchfile.parse_overrides(args.overrides))
    graph = build(scene)
    warnings = scene_check(graph)["warnings"]  # refused: one line, exit 2, as `dockhil launch` would
    print(to_dot(graph) if args.dot else to_text(graph))
    from dockhil.log import Log

    for line in warnings:
        Log("[graph]").warning(line)
    return 0


def to_text(graph: Graph) -> str:
    scene = graph.scene
    lines = [
        f"{scene.path}: {scene.description}".rstrip(": "),
        f"rate {scene.rate:g} Hz (step {scene.dt:g} s)"
        + (f", duration {scene.duration:g} s" if scene.duration else ""),
    ]
    if scene.args:
        lines.append("args:")
        for name, spec in scene.args.items():
            value = scene.values[name]
            mark = "" if value == spec.default else f" (default {spec.default!r})"
            lines.append(f"  {name} = {value!r}{mark}  {spec.help}")
    if scene.lets:
        lines.append("let:")
        lines.extend(f"  {name} = {value!r}" for name, value in scene.lets.items())
    lines.append(f"nodes ({len(graph.nodes)}, in step order):")
    declared = declared_types(graph)
    for name in graph.order:
        gn = graph.nodes[name]
        where = f" (on {gn.host})" if gn.host else ""
        lines.append(f"  {name} [{declared[name]}]{where} {gn.cls.describe()}")
        for port, ref in gn.inputs.items():
            src = graph.publishers.get(ref.topic)
            frm = f"<- {src.node}.{src.port}" if src else "(unconnected, optional)"
            ft = "" if ref.lag == 0 else ", previous tick" if ref.lag == 1 else f", {ref.lag} ticks earlier"
            age = "" if ref.max_age is None else f", max_age {ref.max_age:g} s"
            lines.append(f"    in  {port}: {ref.topic} {msgs.type_name(ref.type)} {frm}{ft}{age}")
        for port, ref in gn.outputs.items():
            subs = ", ".join(f"{s.node}.{s.port}" for s in graph.subscribers.get(ref.topic, [])) or "no subscriber"
            lines.append(f"    out {port}: {ref.topic} {msgs.type_name(ref.type)} -> {subs}")
        changed = {k: v for k, v in gn.params.items() if v != gn.cls.params[k].default}
        if changed:
            lines.append("    params: " + ", ".join(f"{k}={v!r}" for k, v in changed.items()))
    from dockhil.runtime.plan import processes

    units = processes(graph)
    lines.append(f"processes ({len(units)}):")
    lines += [
        f"  {name}: {', '.join(members)}" if members != [name] else f"  {name}" for name, members in units.items()
    ]
    if scene.skipped:
        lines.append("left out by conditions:")
        for s in scene.skipped:
            lines.append(f"  {s.name} ({s.reason})")
    return "\n".join(lines)


def declared_types(graph: Graph) -> dict[str, str]:
    """Each node's type as its launch file writes it, with the dof it gives: `satellite_dynamics,
    dof 6`, not the registered satellite_dynamics6 that runs (a name the file does not show)."""
    out = {}
    for spec in graph.scene.nodes:
        dof = spec.params.get("dof")
        out[spec.name] = spec.type if dof is None else f"{spec.type}, dof {dof}"
    return out


def _q(text: str) -> str:
    """A DOT string's inside: quotes and backslashes escaped (an include's file name is free text)."""
    return text.replace("\\", "\\\\").replace('"', '\\"')


def to_dot(graph: Graph) -> str:
    out = ["digraph dockhil {", "  rankdir=LR;", "  node [shape=box];"]
    declared = declared_types(graph)
    for name in graph.order:
        out.append(f'  "{name}" [label="{name}\\n{_q(declared[name])}"];')
    for topic, subs in graph.subscribers.items():
        pub = graph.publishers[topic]
        for s in subs:
            style = "" if s.feedthrough else ", style=dashed"
            out.append(f'  "{pub.node}" -> "{s.node}" [label="{topic}"{style}];')
    # A node left out may share its name with one that runs (`robot` of either kind): its own id,
    # so it never restyles the running one.
    for i, left in enumerate(graph.scene.skipped):
        out.append(f'  "left out {i}" [style=dotted, label="{_q(left.name)}\\n(left out)"];')
    out.append("}")
    return "\n".join(out)
