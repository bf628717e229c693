"""A component container: several nodes of a graph in one process.

Nodes that name the same `container:` in a launch file step in one process,
in the graph's same-tick order, handing messages to each other as objects
(as a composed run does); what they read from the rest of the graph and what
the rest reads from them goes over the transport. To the runtime a container
is one node: its inputs are its members' inputs from outside, its outputs
its members' outputs, named "member.port". Sim-time results are the same,
bit for bit, as with every node in its own process.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, cast

from dockhil.errors import NODE_RAISES
from dockhil.node import Input, Node, NodeContext, Output, Tick

if TYPE_CHECKING:
    from dockhil.runtime.composed import Schedule


def _members(params: dict) -> list[dict]:
    return params["members"]


class Container(Node):
    """Runs its member nodes in one process (members: what the launcher resolved for each)."""

    @classmethod
    def resolve_params(cls, node_name: str, given: dict[str, Any]) -> dict[str, Any]:
        return dict(given)  # made by the launcher from a checked graph

    @classmethod
    def ports(cls, params: dict[str, Any]) -> tuple[dict[str, Input], dict[str, Output]]:
        from dockhil import node_types

        inputs, outputs = {}, {}
        for m in _members(params):
            node_cls = node_types.load(m["type"])
            ins, outs = node_cls.ports(m["params"])
            for port, (topic, _lag) in m["external"].items():
                decl = ins[port]
                # A free-running member (an emulated device) goes on from its last input, as on its own.
                age = math.inf if node_cls.free_running and decl.max_age is None else decl.max_age
                inputs[f"{m['name']}.{port}"] = Input(
                    decl.type, topic, decl.feedthrough, decl.required, decl.help, decl.delay, age
                )
            for port, topic in m["outputs"].items():
                outputs[f"{m['name']}.{port}"] = Output(outs[port].type, topic, outs[port].help)
        return inputs, outputs

    def __init__(self, ctx: NodeContext, **params: Any):
        from dockhil import node_types
        from dockhil.runtime.composed import ComposedGraph
        from dockhil.scene.graph import Graph, GraphNode, PortRef

        self.ctx = ctx
        self.p = SimpleNamespace(**params)
        gnodes, publishers = {}, {}
        self.boxes: dict[tuple[str, str], list] = {}
        self.reads: list[tuple[str, list]] = []  # (container input, its member's box)
        for m in _members(params):
            cls = node_types.load(m["type"])
            ins, outs = cls.ports(m["params"])
            inputs = {
                port: PortRef(m["name"], port, topic, ins[port].type, lag)
                for port, (topic, lag) in {**m["internal"], **m["external"]}.items()
            }
            outputs = {port: PortRef(m["name"], port, topic, outs[port].type) for port, topic in m["outputs"].items()}
            gnodes[m["name"]] = GraphNode(m["name"], m["type"], cls, m["params"], inputs, outputs)
            publishers.update({ref.topic: ref for ref in outputs.values()})
            for port in m["external"]:
                box = self.boxes[(m["name"], port)] = [None]
                self.reads.append((f"{m['name']}.{port}", box))
        graph = SimpleNamespace(
            scene=SimpleNamespace(dt=ctx.dt),
            nodes=gnodes,
            order=[m["name"] for m in _members(params)],
            publishers=publishers,
        )
        self.sent: dict[str, Any] = {}
        self.out_port = {topic: f"{ref.node}.{ref.port}" for topic, ref in publishers.items()}
        self.members = ComposedGraph(
            cast("Graph", graph),  # the parts of a Graph a composed run reads
            sim_time=ctx.sim_time,
            clock=ctx.clock,
            boxes=self.boxes,
            log=lambda name, msg: ctx.log(f"[{name}] {msg}"),
            taps=[self._sent],
        )
        self._schedule: Schedule | None = None

    def _sent(self, topic: str, msg: Any) -> None:
        self.sent[self.out_port[topic]] = msg

    def setup(self) -> None:
        self.members.setup()

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        if self._schedule is None:
            self._schedule = self.members.schedule(wall=not self.ctx.sim_time)
        for port, box in self.reads:
            box[0] = inputs[port]
        self.sent = {}
        try:
            self.members.step_tick(self._schedule, tick, wall=not self.ctx.sim_time)
        except NODE_RAISES as exc:
            from dockhil.runtime.composed import node_failure

            raise node_failure(exc, tick.index)  # noqa: B904 - names the member that failed, chained
        return self.sent

    def close(self) -> None:
        self.members.close()
