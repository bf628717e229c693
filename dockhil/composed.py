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

from dockhil.executor import LoopTiming, Stop, _bounds_check, _sleep_until, check_outputs, checked_payload
from dockhil.graph import Graph
from dockhil.log import node_line
from dockhil.node import NodeContext, Tick

Tap = Callable[[str, Any], None]  # (topic, message)


class ComposedGraph:
    def __init__(self, graph: Graph, *, sim_time: bool = True, log=None, taps: list[Tap] | None = None,
                 clock: Callable[[], float] = time.monotonic, boxes: dict[tuple[str, str], list] | None = None):
        """boxes: (node, port) -> a one-element list holding that input's message of the current
        tick, filled by the caller (a container, with what arrived from outside)."""
        self.clock = clock  # wall time: the runtime's clock, handed to every node
        self.graph = graph
        self.dt = graph.scene.dt
        self.taps = taps or []
        self.log = log or node_line  # (name, line): the line on stderr, under the node's name
        self.nodes = {}
        # The longest lag any reader needs of each topic: how much history to keep.
        depth: dict[str, int] = {}
        for gn in graph.nodes.values():
            for ref in gn.inputs.values():
                depth[ref.topic] = max(depth.get(ref.topic, 0), ref.lag)
        self.history = {topic: deque([None] * (depth.get(topic, 0) + 1), maxlen=depth.get(topic, 0) + 1)
                        for topic in graph.publishers}
        self.timing: LoopTiming | None = None  # wall time: the one loop's figures, for validity
        self._schedules: dict[bool, list] = {}  # step(): the schedule, resolved once per clock
        self.plan = []  # (name, node, [(port, history, lag)], [(port, topic, history)], declared outputs)
        for name in graph.order:
            gn = graph.nodes[name]
            ctx = NodeContext(name, self.dt, sim_time, lambda m, n=name: self.log(n, m), clock)
            node = gn.cls(ctx, **gn.params)
            self.nodes[name] = node
            _, outs = gn.cls.ports(gn.params)
            ins = [(port, boxes[(name, port)], 0) if boxes and (name, port) in boxes
                   else (port, self.history.get(ref.topic), ref.lag) for port, ref in gn.inputs.items()]
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

    def _publisher(self, name: str, declared: dict, outs_map, wall: bool):
        """The one function a node's outputs go through each tick: what check_outputs and
        check_message check (the same lines), with the types, topics and histories looked up once."""
        taps = self.taps
        ports = {}
        for port, out in declared.items():
            hist = next((h for p, _, h in outs_map if p == port), None)
            topic = next((t for p, t, _ in outs_map if p == port), out.topic)
            ports[port] = (out.type, _bounds_check(out.type), topic, hist)

        def publish(k: int, outs: dict, check_types: bool) -> None:
            for port, msg in outs.items():
                entry = ports.get(port)
                if entry is None or msg is None:
                    if entry is None:
                        check_outputs(name, declared, k, {port: msg}, sim=not wall)  # its line
                    continue
                cls, bounds, topic, hist = entry
                if check_types and (type(msg) is not cls or (not wall and msg.header.tick != k)):
                    check_outputs(name, declared, k, {port: msg}, sim=not wall)  # its line
                if not bounds(msg):
                    checked_payload(name, port, topic, k, msg)  # as a node process does before it sends
                if hist is not None:
                    hist[-1] = msg
                    for tap in taps:
                        tap(topic, msg)

        return publish

    def schedule(self, wall: bool) -> list:
        """The schedule, resolved once: each node's step, how it reads its inputs, where its outputs go."""
        return [(node.step, tuple((port, hist, -1 - lag) for port, hist, lag in ins),
                 self._publisher(name, declared, outs_map, wall))
                for name, node, ins, outs_map, declared in self.plan]

    def step_tick(self, schedule: list, tick: Tick, wall: bool) -> dict[str, dict]:
        """One tick of every node (a container's step; `run` inlines the same for speed); returns
        each node's outputs by node name."""
        k = tick.index
        for hist in self.history.values():
            hist.append(hist[-1] if wall else None)
        check_types = k == 0 or not wall
        done = {}
        for (step, reads, publish), plan in zip(schedule, self.plan):
            outs = step(tick, {port: (None if hist is None else hist[at]) for port, hist, at in reads})
            publish(k, outs, check_types)
            done[plan[0]] = outs
        return done

    def step(self, tick: Tick, wall: bool = False) -> dict[str, dict]:
        """One tick of every node, in order; returns each node's outputs by node name.
        (dockhil.testing steps a single node this way, with the test's inputs.)"""
        schedule = self._schedules.get(wall)
        if schedule is None:
            schedule = self._schedules[wall] = self.schedule(wall)
        return self.step_tick(schedule, tick, wall)

    def run(self, n_ticks: int | None, *, wall: bool = False, stop: Stop | None = None,
            progress: Callable[[int], None] | None = None) -> int:
        """Step ticks 0..n_ticks-1 (None: until stopped). Returns ticks done.

        Each topic's history holds its last lag+1 messages, newest last; a
        reader with lag L at tick k reads history[-1-L] once this tick's
        message has been appended (or before it, for L >= 1)."""
        stop = stop or Stop()
        dt = self.dt
        clock = self.clock
        histories = list(self.history.values())
        schedule = self.schedule(wall)
        timing = self.timing = LoopTiming([], period=dt, max_age=self.graph.wall_max_ages()) if wall else None
        end = n_ticks if n_ticks is not None else -1
        t0 = clock()
        k = 0
        while k != end and not stop.requested:
            if wall:
                timing.started(clock() - (t0 + k * dt))
                tick = Tick(k, clock() - t0, dt, stamp=time.time())
                for hist in histories:  # a slot for this tick, holding the latest value
                    hist.append(hist[-1])
            else:
                tick = Tick(k, k * dt, dt)
                for hist in histories:  # a slot for this tick; stays None if nothing is sent
                    hist.append(None)
            check_types = k == 0 or not wall
            for step, reads, publish in schedule:
                inputs = {port: (None if hist is None else hist[at]) for port, hist, at in reads}
                publish(k, step(tick, inputs), check_types)
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
