"""Run a whole graph in one process with in-process delivery and the same schedule.

Nodes step in the graph's same-tick order: at tick k a node reads, for each
input, the message of tick k - lag, exactly as the multi-process lock-step
does, so the trajectories are bit-identical. Messages pass as objects
(float64 survives msgpack exactly, so skipping the codec changes no bit);
taps see every message for recording.
"""

from __future__ import annotations

import functools
import time
from collections import deque
from collections.abc import Callable
from typing import Any, cast

import msgspec

from dockhil.errors import NODE_RAISES, DockhilError, failure_line
from dockhil.log import node_line
from dockhil.node import NodeContext, Tick
from dockhil.runtime.executor import Stop, check_outputs
from dockhil.runtime.looptime import LoopTiming, loop_spin, sleep_until
from dockhil.runtime.screen import bounds_check, checked_payload
from dockhil.scene.graph import Graph

Tap = Callable[[str, Any], None]  # (topic, message)
# A whole tick, written out (tick_function): (tick, k, check_types) -> each node's outputs, with collect.
Schedule = Callable[[Tick, int, bool], dict[str, dict] | None]


class ComposedGraph:
    def __init__(
        self,
        graph: Graph,
        *,
        sim_time: bool = True,
        log: Callable[[str, str], object] | None = None,
        taps: list[Tap] | None = None,
        clock: Callable[[], float] = time.monotonic,
        boxes: dict[tuple[str, str], list] | None = None,
    ):
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
        self.history = {
            topic: deque([None] * (depth.get(topic, 0) + 1), maxlen=depth.get(topic, 0) + 1)
            for topic in graph.publishers
        }
        self.timing: LoopTiming | None = None  # wall time: the one loop's figures, for validity
        self._schedules: dict[bool, Callable] = {}  # step(): the tick function, made once per clock
        self.plan = []  # (name, node, [(port, history, lag)], [(port, topic, history)], declared outputs)
        for name in graph.order:
            gn = graph.nodes[name]
            ctx = NodeContext(name, self.dt, sim_time, lambda m, n=name: self.log(n, m), clock)
            node = gn.cls(ctx, **gn.params)
            self.nodes[name] = node
            _, outs = gn.cls.ports(gn.params)
            ins = [
                (port, boxes[(name, port)], 0)
                if boxes and (name, port) in boxes
                else (port, self.history.get(ref.topic), ref.lag)
                for port, ref in gn.inputs.items()
            ]
            outs_map = [(p, r.topic, self.history[r.topic]) for p, r in gn.outputs.items()]
            self.plan.append((name, node, ins, outs_map, outs))

    def setup(self, name_failures: bool = True) -> None:
        """Each node's setup. A node's own exception becomes one line naming the node, as a node
        process says it (name_failures=False, for tests of a node, keeps the exception itself)."""
        for name, node in self.nodes.items():
            try:
                node.setup()
            except NODE_RAISES as exc:
                if not name_failures or isinstance(exc, DockhilError):
                    raise
                raise DockhilError(failure_line(name, "setup", exc)) from exc

    def close(self) -> None:
        """Every node's close, even after one failed; then the first failure, as one line naming
        its node (a driver holds the robot in close: its failure fails the run). Drivers close
        before the emulators standing in for their devices, as on a real bench the device outlives them."""
        first = None
        for name, node in sorted(self.nodes.items(), key=lambda item: type(item[1]).free_running):
            try:
                node.close()
            except NODE_RAISES as exc:  # close every node even if one fails (a driver holds the robot there)
                if first is None and isinstance(exc, DockhilError):
                    first = exc
                elif first is None:
                    first = DockhilError(failure_line(name, "close", exc))
                    first.__cause__ = exc
        if first:
            raise first

    def schedule(self, wall: bool, collect: bool = False) -> Schedule:
        """The whole tick as one function, resolved once (see `tick_function`)."""
        return tick_function(self.plan, list(self.history.values()), self.taps, wall, collect)

    def step_tick(self, schedule: Schedule, tick: Tick, wall: bool) -> dict[str, dict] | None:
        """One tick of every node (a container's step, and `step`); with a
        schedule made with collect=True, returns each node's outputs by node name."""
        k = tick.index
        return schedule(tick, k, k == 0 or not wall)

    def step(self, tick: Tick, wall: bool = False) -> dict[str, dict]:
        """One tick of every node, in order; returns each node's outputs by node name.
        (dockhil.testing steps a single node this way, with the test's inputs.)"""
        schedule = self._schedules.get(wall)
        if schedule is None:
            schedule = self._schedules[wall] = self.schedule(wall, collect=True)
        return cast("dict[str, dict]", self.step_tick(schedule, tick, wall))  # a collecting schedule's

    def run(
        self,
        n_ticks: int | None,
        *,
        wall: bool = False,
        stop: Stop | None = None,
        progress: Callable[[int], None] | None = None,
    ) -> int:
        """Step ticks 0..n_ticks-1 (None: until stopped). Returns ticks done.

        Each topic's history holds its last lag+1 messages, newest last; a
        reader with lag L at tick k reads history[-1-L] once this tick's
        message has been appended (or before it, for L >= 1)."""
        stop = stop or Stop()
        dt = self.dt
        clock = self.clock
        schedule = self.schedule(wall)
        timing = self.timing = LoopTiming([], period=dt, max_age=self.graph.wall_max_ages()) if wall else None
        end = n_ticks if n_ticks is not None else -1
        spin = loop_spin()
        t0 = clock()
        k = 0
        while k != end and not stop.requested:
            if wall:
                timing.started(clock() - (t0 + k * dt))  # type: ignore[union-attr]  # wall: timing is set
                tick = Tick(k, clock() - t0, dt, stamp=time.time())
            else:
                tick = Tick(k, k * dt, dt)
            try:
                schedule(tick, k, k == 0 or not wall)
            except NODE_RAISES as exc:
                raise node_failure(exc, k)  # noqa: B904 - node_failure chains it
            k += 1
            if progress is not None:
                progress(k)
            if wall:
                over = clock() - (t0 + k * dt)
                if over > 0:
                    timing.missed(over if k > 1 else 0.0)  # type: ignore[union-attr]  # wall: timing is set; tick 0 keeps no schedule
                sleep_until(t0 + k * dt, clock, spin)
        if wall:
            timing.ticks, timing.elapsed = k, clock() - t0  # type: ignore[union-attr]  # wall: timing is set
        return k


def tick_function(plan: list, histories: list, taps: list[Tap], wall: bool, collect: bool) -> Schedule:
    """One tick of every node in `plan`, written out as one function and compiled once per run:
    `f(tick, k, check_types)`. Each topic's history gets this tick's slot (in wall time holding
    the latest value, in sim time None until a message is sent); each node's inputs are read
    from the histories, its step called, and each declared output checked as check_outputs and
    check_message check it (the same lines) and stored; with collect, f returns each node's
    outputs by node name. Written out rather than looped over, since the loop's own bookkeeping
    cost more than the checks it ran (bench/graph.py). `f.owners` maps each line of it to its
    node, for failed_node."""
    scope: dict[str, Any] = {
        "check_outputs": check_outputs,
        "checked_payload": checked_payload,
        "taps": taps,
        "replace": msgspec.structs.replace,
    }
    lines = ["def tick_function(tick, k, check_types):"]
    for i, hist in enumerate(histories):
        scope[f"topic{i}"] = hist
        lines.append(f"    topic{i}.append({f'topic{i}[-1]' if wall else 'None'})")
    if collect:
        lines.append("    done = {}")
    owners: dict[int, str] = {}  # line number -> the node whose step or outputs that line handles
    for i, (name, node, ins, outs_map, declared) in enumerate(plan):
        first = len(lines) + 1
        scope[f"step{i}"], scope[f"declared{i}"], scope[f"names{i}"] = node.step, declared, frozenset(declared)
        reads = []
        for j, (port, hist, lag) in enumerate(ins):
            if hist is None:  # no publisher of that topic in this graph
                reads.append(f"{port!r}: None")
            else:
                scope[f"in{i}_{j}"] = hist
                reads.append(f"{port!r}: in{i}_{j}[{-1 - lag}]")
        lines += [
            f"    o = step{i}(tick, {{{', '.join(reads)}}})",
            f"    if type(o) is not dict or not o.keys() <= names{i}:",
            f"        check_outputs({name!r}, declared{i}, k, o, sim={not wall})  # its line",
        ]
        for j, (port, out) in enumerate(declared.items()):
            hist = next((h for p, _, h in outs_map if p == port), None)
            topic = next((t for p, t, _ in outs_map if p == port), out.topic)
            v = f"{i}_{j}"
            scope[f"type{v}"], scope[f"screen{v}"] = out.type, bounds_check(out.type)
            header = "" if wall else " or m.header.tick != k"
            lines += [
                f"    m = o.get({port!r})",
                "    if m is not None:",
                f"        if check_types and (type(m) is not type{v}{header}):",
                f"            check_outputs({name!r}, declared{i}, k, {{{port!r}: m}}, sim={not wall})",
            ]
            for field in _sequence_fields(out.type):  # a list a node built: a tuple, as a reader decodes it
                lines += [
                    f"        if type(m.{field}) is not tuple:",
                    f"            m = o[{port!r}] = replace(m, {field}=tuple(m.{field}))",
                ]
            lines += [
                f"        if not screen{v}(m):",
                f"            checked_payload({name!r}, {port!r}, {topic!r}, k, m)  # as a node process",
            ]
            if hist is not None:
                scope[f"out{v}"] = hist
                lines.append(f"        out{v}[-1] = m")
                lines += ["        for tap in taps:", f"            tap({topic!r}, m)"] if taps else []
        if collect:
            lines.append(f"    done[{name!r}] = o")
        owners.update(dict.fromkeys(range(first, len(lines) + 1), name))
    lines.append("    return done" if collect else "    return None")
    exec(compile("\n".join(lines) + "\n", TICK_SOURCE, "exec"), scope)  # noqa: S102 - built from the graph
    scope["tick_function"].owners = owners
    return scope["tick_function"]


TICK_SOURCE = "<composed tick>"


@functools.cache
def _sequence_fields(cls: type) -> tuple[str, ...]:
    """The top-level fields of a message type that hold a sequence (tuples in msgs): a reader in
    the same process must not be able to change them under another reader. Cached: inspecting a
    type costs milliseconds, and a run writes its tick anew."""
    import msgspec.inspect as mi

    info = cast(mi.StructType, mi.type_info(cls))  # msgs are Structs
    return tuple(f.name for f in info.fields if isinstance(f.type, (mi.VarTupleType, mi.ListType)))


def node_failure(exc: BaseException, k: int) -> BaseException:
    """`exc` as one line naming the node whose step (or outputs) raised it at tick k, as a node
    process says it; `exc` itself when it is a check's line already or not a node's."""
    failed = None if isinstance(exc, DockhilError) else failed_node(exc)
    if failed is None:
        return exc
    line = DockhilError(failure_line(failed, f"tick {k}", exc))
    line.__cause__ = exc
    return line


def failed_node(exc: BaseException) -> str | None:
    """The node whose step (or whose outputs) raised `exc` inside a written-out tick, read from the
    traceback's line in it (no bookkeeping on the tick's path); None if the tick did not raise it."""
    tb = exc.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code.co_filename == TICK_SOURCE:
            return tb.tb_frame.f_globals["tick_function"].owners.get(tb.tb_lineno)
        tb = tb.tb_next
    return None
