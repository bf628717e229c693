"""Run a whole graph in one process with in-process delivery and the same schedule.

Nodes step in the graph's feedthrough order: at tick k a node reads tick k
of its feedthrough inputs and tick k-1 of the others, exactly as the
multi-process lock-step does, so the trajectories are bit-identical.
Messages pass as objects (float64 survives msgpack exactly, so skipping the
codec changes no bit); taps see every message for recording.
"""

from __future__ import annotations

import time
from typing import Any, Callable

from dockhil.executor import Stop, _sleep_until, check_outputs
from dockhil.graph import Graph
from dockhil.node import NodeContext, Tick

Tap = Callable[[str, Any], None]  # (topic, message)


class ComposedGraph:
    def __init__(self, graph: Graph, *, sim_time: bool = True, log=None, taps: list[Tap] | None = None):
        self.graph = graph
        self.dt = graph.scene.dt
        self.taps = taps or []
        self.log = log or (lambda name, msg: print(f"[{name}] {msg}", flush=True))
        self.nodes = {}
        self.plan = []  # (name, node, [(port, topic, previous?)], [(port, topic)], declared outputs)
        for name in graph.order:
            gn = graph.nodes[name]
            ctx = NodeContext(name, self.dt, sim_time, lambda m, n=name: self.log(n, m))
            node = gn.cls(ctx, **gn.params)
            self.nodes[name] = node
            _, outs = gn.cls.ports(gn.params)
            ins = [(port, ref.topic if ref.topic in graph.publishers else None, not ref.feedthrough)
                   for port, ref in gn.inputs.items()]
            self.plan.append((name, node, ins, [(p, r.topic) for p, r in gn.outputs.items()], outs))

    def setup(self) -> None:
        for node in self.nodes.values():
            node.setup()

    def close(self) -> None:
        first = None
        for node in self.nodes.values():
            try:
                node.close()
            except Exception as exc:  # close every node even if one fails
                first = first or exc
        if first:
            raise first

    def run(self, n_ticks: int | None, *, wall: bool = False, stop: Stop | None = None,
            progress: Callable[[int], None] | None = None) -> int:
        """Step ticks 0..n_ticks-1 (None: until stopped). Returns ticks done."""
        now: dict[str, Any] = {}  # topic -> message of the current tick
        prev: dict[str, Any] = {}  # topic -> message of the previous tick
        stop = stop or Stop()
        dt = self.dt
        t0 = time.monotonic()
        k = 0
        while (n_ticks is None or k < n_ticks) and not stop.requested:
            tick = Tick(k, (time.monotonic() - t0) if wall else k * dt, dt)
            for name, node, ins, outs_map, declared in self.plan:
                inputs = {port: (None if topic is None else (prev if previous else now).get(topic))
                          for port, topic, previous in ins}
                outs = node.step(tick, inputs)
                check_outputs(name, declared, k, outs, sim=not wall)
                for port, topic in outs_map:
                    msg = outs.get(port)
                    if msg is not None:
                        now[topic] = msg
                        for tap in self.taps:
                            tap(topic, msg)
            prev, now = now, ({} if not wall else dict(now))
            k += 1
            if progress is not None:
                progress(k)
            if wall:
                _sleep_until(t0 + k * dt)
        return k
