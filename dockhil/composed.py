"""Run a whole graph in one process with in-process delivery and the same schedule.

Nodes step in the graph's same-tick order: at tick k a node reads, for each
input, the message of tick k - lag, exactly as the multi-process lock-step
does, so the trajectories are bit-identical. Messages pass as objects
(float64 survives msgpack exactly, so skipping the codec changes no bit);
taps see every message for recording.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any, Callable

from dockhil.executor import LoopTiming, Stop, _sleep_until, check_message, check_outputs
from dockhil.graph import Graph
from dockhil.node import NodeContext, Tick

Tap = Callable[[str, Any], None]  # (topic, message)


class ComposedGraph:
    def __init__(self, graph: Graph, *, sim_time: bool = True, log=None, taps: list[Tap] | None = None,
                 clock: Callable[[], float] = time.monotonic):
        self.clock = clock  # wall time: the runtime's clock, handed to every node
        self.graph = graph
        self.dt = graph.scene.dt
        self.taps = taps or []
        self.log = log or (lambda name, msg: print(f"[{name}] {msg}", flush=True))
        self.nodes = {}
        # The longest lag any reader needs of each topic: how much history to keep.
        depth: dict[str, int] = {}
        for gn in graph.nodes.values():
            for ref in gn.inputs.values():
                depth[ref.topic] = max(depth.get(ref.topic, 0), ref.lag)
        self.history = {topic: deque([None] * (depth.get(topic, 0) + 1), maxlen=depth.get(topic, 0) + 1)
                        for topic in graph.publishers}
        self.timing: LoopTiming | None = None  # wall time: the one loop's figures, for validity
        self.plan = []  # (name, node, [(port, history, lag)], [(port, topic, history)], declared outputs)
        for name in graph.order:
            gn = graph.nodes[name]
            ctx = NodeContext(name, self.dt, sim_time, lambda m, n=name: self.log(n, m), clock)
            node = gn.cls(ctx, **gn.params)
            self.nodes[name] = node
            _, outs = gn.cls.ports(gn.params)
            ins = [(port, self.history.get(ref.topic), ref.lag) for port, ref in gn.inputs.items()]
            outs_map = [(p, r.topic, self.history[r.topic]) for p, r in gn.outputs.items()]
            self.plan.append((name, node, ins, outs_map, outs))

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

    def step(self, tick: Tick, wall: bool = False) -> dict[str, dict]:
        """One tick of every node, in order; returns each node's outputs by node name.
        (dockhil.testing steps a single node this way, with the test's inputs.)"""
        k = tick.index
        for hist in self.history.values():  # a slot for this tick; stays None if nothing is sent
            hist.append(hist[-1] if wall else None)
        done = {}
        for name, node, ins, outs_map, declared in self.plan:
            inputs = {port: (None if hist is None else hist[-1 - lag]) for port, hist, lag in ins}
            outs = node.step(tick, inputs)
            if k == 0 or not wall:
                check_outputs(name, declared, k, outs, sim=not wall)
            for port, topic, hist in outs_map:
                msg = outs.get(port)
                if msg is not None:
                    check_message(name, port, topic, k, msg)  # as a node process does before it sends
                    hist[-1] = msg
                    for tap in self.taps:
                        tap(topic, msg)
            done[name] = outs
        return done

    def run(self, n_ticks: int | None, *, wall: bool = False, stop: Stop | None = None,
            progress: Callable[[int], None] | None = None) -> int:
        """Step ticks 0..n_ticks-1 (None: until stopped). Returns ticks done.

        Each topic's history holds its last lag+1 messages, newest last; a
        reader with lag L at tick k reads history[-1-L] once this tick's
        message has been appended (or before it, for L >= 1)."""
        stop = stop or Stop()
        dt = self.dt
        clock = self.clock
        t0 = clock()
        timing = self.timing = LoopTiming([], period=dt, max_age=self.graph.wall_max_ages()) if wall else None
        k = 0
        while (n_ticks is None or k < n_ticks) and not stop.requested:
            if wall:
                timing.started(clock() - (t0 + k * dt))
            tick = Tick(k, (clock() - t0) if wall else k * dt, dt, stamp=time.time() if wall else None)
            self.step(tick, wall)
            k += 1
            if progress is not None:
                progress(k)
            if wall:
                over = clock() - (t0 + k * dt)
                if over > 0:
                    timing.missed(over if k > 1 else 0.0)  # the first tick has no schedule to keep
                _sleep_until(t0 + k * dt, clock)
        if wall:
            timing.ticks, timing.elapsed = k, clock() - t0
        return k
