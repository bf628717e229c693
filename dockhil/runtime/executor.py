"""Run a node over the transport, in sim time (lock-step) or wall time (fixed rate).

Sim time: every message carries its tick. A node computes tick k once it
holds, for each connected input, the message of tick k - lag (lag 0 for
feedthrough inputs, 1 for the others, more for a declared delay; None
before tick 0). An output a node leaves empty at a tick is sent as an
explicit "no message" frame, so lock-step never waits for it. No hop adds a
hidden delay, and the result does not depend on arrival order, so a graph
run as processes and the same graph composed in one process give
bit-identical outputs.

Wall time: a fixed-rate loop on the runtime's clock; each input holds its
latest value (None until the first message arrives), for at most its
maximum age after it arrived: past it the node stops with one line naming
node, input and age (its close() holds a robot). Outputs a node leaves out
are not sent.

Both clocks: every output is checked before it leaves the node. A NaN or
Inf in a physical field (a diverging loop) stops the producing node with one
line, the same in a multi-process and a composed run.
"""

from __future__ import annotations

import functools
import gc
import json
import math
import os
import signal
import time
from dataclasses import dataclass, field
from typing import Any

import msgspec

from dockhil.errors import DockhilError
from dockhil.log import node_line
from dockhil.node import NodeContext, Tick
from dockhil.msgs.codec import DecodeError, decode, decode_header, encode

TIMING = "\x1edockhil-timing "
DEFERRED = 16  # sim time: frames an output holds at most while its node computes on without waiting  # a node process's line with its wall-time loop figures (JSON), read by the launcher


@dataclass
class PortWire:
    topic: str
    endpoint: str
    type: str  # wire type name, e.g. dockhil/WrenchStamped
    lag: int = 0  # inputs: ticks between the message read and the tick computed
    subscribers: int = 0  # outputs: how many subscriptions to await in sim time
    unlimited_age: bool = False  # inputs: no maximum age (a publisher the launcher respawns may pause)
    max_age: float | None = None  # inputs: the launch file's maximum age [s], over the node's own
    burst: int = 1  # outputs, sim time: ticks whose messages go out together (readers' slack: launcher.burst)


@dataclass
class RunSpec:
    """Everything a node process needs; the launcher writes it as JSON."""

    name: str
    type_name: str
    params: dict[str, Any]
    dt: float
    clock: str = "sim"  # "sim" | "wall"
    n_ticks: int | None = None  # ticks 0..n_ticks-1; None = until stopped
    inputs: dict[str, PortWire] = field(default_factory=dict)
    outputs: dict[str, PortWire] = field(default_factory=dict)
    start_timeout: float = 20.0
    realtime: bool = False  # wall time: ask the OS for real-time (SCHED_FIFO) scheduling
    wait_for_go: bool = False  # wall time: after READY, start the loop on SIGUSR1 (all nodes at once)
    key_file: str = ""  # the graph's CURVE key file (mode 0600); needed by a node with inputs or outputs
    run_id: str = ""  # the graph's run id: names the owner of the devices this node claims


class Stop:
    """A flag set by SIGINT/SIGTERM; loops check it between waits."""

    def __init__(self) -> None:
        self.requested = False

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:
        self.requested = True


class StaleInput(DockhilError):
    """A wall-time input's latest message is older than its maximum age."""


def checked_payload(name: str, port: str, topic: str, k: int, msg) -> bytes:
    """`msg` encoded, after checking it decodes as a valid message: a NaN or Inf in a physical field
    (a loop that diverged) stops the node that produced it, not its readers, with one line. (Decoding
    is the reader's own check, and faster than a screen of the fields' types written in Python.)"""
    payload = encode(msg)
    try:
        decode(payload, type(msg))
    except DecodeError as exc:
        raise DockhilError(f"node {name!r} produced an invalid message at tick {k} on output {port!r} "
                           f"({topic}): {exc}; stopping the graph") from None
    return payload


def check_message(name: str, port: str, topic: str, k: int, msg) -> None:
    """What checked_payload checks, for a message that is not sent (composed runs): the numbers'
    screen first (several times faster than encoding and decoding; the message is handed on as
    the object it is); on a failure, the same check and line as a node process gives."""
    if not bounds_check(type(msg))(msg):
        checked_payload(name, port, topic, k, msg)


_MAX_FLOAT = 1.7976931348623157e308
_SCREENS: dict[type, Any] = {}


class _Unscreened(Exception):
    """A number the screen does not judge (multiple_of): every message of that type gets the full check."""


def bounds_check(cls: type):
    """A function true when a message of type `cls` holds what its decoding would accept: every
    number finite and within its type's bounds, and every value of its field's own type (a float,
    a str, a bool, an int, the declared struct, a tuple), as a node process's encoding and decoding
    would check it. A screen, not the verdict: it may say False for a good message (a sum of finite
    values that overflows, an int where a float goes, a numpy float), and callers then run the full
    check. Compiled (dockhil/runtime/_screen.c) where built, else `python_screen`."""
    check = _SCREENS.get(cls)
    if check is None:
        from dockhil.compiled import twin

        compiled = twin("dockhil.runtime._screen")
        try:
            spec = _screen_spec(cls)
        except _Unscreened:  # a type neither screen judges: every message of it gets the full check
            check = _never
        else:  # the same judgement in C (dockhil/runtime/_screen.c), several times faster, or its Python twin
            check = functools.partial(compiled.screen, spec) if compiled else _python_screen(cls.__name__, spec)
        _SCREENS[cls] = check
    return check


def python_screen(cls: type):
    """`bounds_check`'s screen of `cls` as a generated Python function (the compiled one's twin)."""
    try:
        return _python_screen(cls.__name__, _screen_spec(cls))
    except _Unscreened:
        return _never


def _never(m) -> bool:
    return False


def _screen_spec(cls: type) -> tuple:
    """(cls, fields): what a screen judges of a message type, read once from its type; each field
    (member, kind, ...), member its descriptor in cls (the C screen reads the slot through it),
    kind 0 float and 1 int (with ge, gt, le, lt: a float or None each), 2 bool, 3 str, 4 struct (its
    spec), 5 tuple and 6 list (an item's field, member None). _Unscreened for a type no screen
    judges (a multiple_of, a constrained str, a type msgs do not use)."""
    import msgspec.inspect as mi

    def struct(t) -> tuple:
        return (t.cls, tuple(field(f.type, _member(t.cls, f.name)) for f in t.fields))

    def field(t, member) -> tuple:
        if isinstance(t, mi.Metadata):
            t = t.type
        kind = _LEAF_KINDS.get(type(t).__name__)
        if kind in (0, 1):
            if t.multiple_of is not None:
                raise _Unscreened
            return (member, kind, *(None if b is None else float(b) for b in (t.ge, t.gt, t.le, t.lt)))
        if kind == 3 and (t.min_length or t.max_length is not None or t.pattern):
            raise _Unscreened
        if kind is not None:
            return (member, kind)
        if isinstance(t, mi.StructType):
            return (member, 4, struct(t))
        if isinstance(t, (mi.ListType, mi.VarTupleType)):
            return (member, 5 if isinstance(t, mi.VarTupleType) else 6, field(t.item_type, None))
        raise _Unscreened

    return struct(mi.type_info(cls))


def _member(cls: type, name: str):
    for klass in cls.__mro__:
        if name in vars(klass):
            return vars(klass)[name]
    raise _Unscreened


# A leaf's kind in a screen's spec, and the Python type its value has where its decoding would
# accept it without conversion (the kind indexes _LEAF_TYPES).
_LEAF_KINDS = {"FloatType": 0, "IntType": 1, "BoolType": 2, "StrType": 3}
_LEAF_TYPES = (float, int, bool, str)


def _python_screen(name: str, spec: tuple):
    """A screen's spec written out as a Python function. The floats are added up as they are read
    (each struct read once): a NaN or Inf anywhere makes the sum non-finite; the types are compared
    a struct's fields at a time."""
    lines: list[str] = []
    scope: dict[str, Any] = {}
    _screen_lines((None, 4, spec), "m", lines, "        ", scope)
    src = ("def check(m):\n    s = 0.0\n    try:\n" + "".join(f"{line}\n" for line in lines)
           + "    except Exception:\n        return False\n    return s - s == 0\n")
    exec(compile(src, f"<screen of {name}>", "exec"), scope)  # noqa: S102 - built from the type
    return scope["check"]


def _screen_lines(field: tuple, var: str, lines: list[str], indent: str, scope: dict) -> None:
    """Statements that return False when a value under `var` is out of its bounds or not of its
    field's type, and add its floats to the sum s."""
    leaves: dict[type, list[str]] = {}
    _screen_field(field, var, lines, indent, scope, leaves)
    for kind, names in leaves.items():  # builtins: float, int, bool, str
        lines.append(f"{indent}if not ({' is '.join(f'type({n})' for n in names)} is {kind.__name__}): return False")
    if leaves.get(float):
        lines.append(f"{indent}s += {' + '.join(leaves[float])}")


def _screen_field(field: tuple, var: str, lines: list[str], indent: str, scope: dict, leaves: dict) -> None:
    kind = field[1]
    if kind < 4:
        conds = [f"{var} {op} {bound!r}" for op, bound in zip((">=", ">", "<=", "<"), field[2:])
                 if bound is not None and abs(bound) != _MAX_FLOAT]
        if conds:  # a NaN fails a bound too
            lines.append(f"{indent}if not ({' and '.join(conds)}): return False")
        leaves.setdefault(_LEAF_TYPES[kind], []).append(var)
    elif kind == 4:
        cls, fields = field[2]
        if "." in var or var.startswith("_i"):  # a nested struct (or a tuple's item): its type checked
            cls_name = f"_T{len(scope)}"
            scope[cls_name] = cls
            if "." in var:  # read once into a local, not once per field below it
                local = f"_s{len(scope)}"
                scope[local] = None
                lines.append(f"{indent}{local} = {var}")
                var = local
            lines.append(f"{indent}if type({var}) is not {cls_name}: return False")
        for f in fields:
            _screen_field(f, f"{var}.{f[0].__name__}", lines, indent, scope, leaves)
    else:  # a tuple or a list of items
        item = f"_i{len(scope)}"
        scope[item] = None
        body: list[str] = []
        _screen_lines(field[2], item, body, indent + "    ", scope)
        lines.append(f"{indent}if type({var}) is not {'tuple' if kind == 5 else 'list'}: return False")
        if body:
            lines.append(f"{indent}for {item} in {var}:")
            lines.extend(body)


def check_outputs(name: str, declared: dict, k: int, outs: dict, sim: bool) -> None:
    """Refuse outputs a node did not declare, of the wrong type, or stamped with another tick."""
    if not isinstance(outs, dict):
        raise DockhilError(f"node {name!r} returned {type(outs).__name__} from step at tick {k}; step returns "
                           f"a dict of its outputs (port -> message), {{}} for none")
    for port, msg in outs.items():
        if port not in declared:
            raise DockhilError(f"node {name!r} returned undeclared output {port!r} at tick {k}")
        if msg is None:
            continue
        if type(msg) is not declared[port].type:
            raise DockhilError(
                f"node {name!r} output {port!r} at tick {k}: expected {declared[port].type.__name__}, "
                f"got {type(msg).__name__}"
            )
        if sim and msg.header.tick != k:
            raise DockhilError(
                f"node {name!r} output {port!r} at tick {k} carries header.tick {msg.header.tick}; "
                f"build headers with tick.header()"
            )


def read_spec_keys(spec: RunSpec):
    """The graph's keys, which every endpoint needs; a node without endpoints needs none."""
    from dockhil.runtime.transport import GraphKeys

    if not spec.inputs and not spec.outputs:
        return None
    if not spec.key_file:
        raise DockhilError(f"node {spec.name!r}: its spec names no key file for its endpoints; "
                           f"start it with 'dockhil launch' or give --keys FILE")
    return GraphKeys.read(spec.key_file)


class NodeExecutor:
    """Owns one node's sockets and loop. Used by node processes and `dockhil run`."""

    def __init__(self, spec: RunSpec, node_cls: type, stop: Stop, log=None, clock=time.monotonic):
        import zmq

        from dockhil.runtime.transport import Publisher, Subscriber, separator

        self.spec = spec
        self.stop = stop
        self.clock = clock
        self.log = log or (lambda m: node_line(spec.name, m))
        self.node = node_cls(NodeContext(spec.name, spec.dt, spec.clock == "sim", self.log, clock), **spec.params)
        ins, outs = node_cls.ports(vars(self.node.p))
        self.outputs = outs
        # Wall time: how long each input's latest message may be used after it arrived. A free-running
        # node stands for a device (an emulated sensor): like the physics it stands for, it goes on
        # from the last value unless it declares a limit; the drivers' watchdogs judge what it delivers.
        def limit(port: str, wire: PortWire) -> float:
            if wire.unlimited_age:
                return math.inf
            if wire.max_age is not None:
                return wire.max_age
            if node_cls.free_running and ins[port].max_age is None:
                return math.inf
            return ins[port].age_limit(spec.dt)

        self.max_age = {port: limit(port, wire) for port, wire in spec.inputs.items() if port in ins}
        self.unconnected = [port for port in ins if port not in spec.inputs]
        self.in_types = {port: ins[port].type for port in spec.inputs}
        self.ctx = zmq.Context.instance()
        keys = read_spec_keys(spec)
        self.sub = Subscriber(self.ctx)
        self._separator = separator
        # Topic -> [(port, the decoder of its type)], resolved once: the receive path looks up nothing else.
        self.routes: dict[bytes, list[tuple[str, Any]]] = {}
        for port, wire in spec.inputs.items():
            self.sub.connect(wire.endpoint, keys=keys)
            fast = msgspec.msgpack.Decoder(self.in_types[port]).decode  # errors: the codec's lines, below
            self.routes.setdefault(wire.topic.encode(), []).append((port, fast))
        # Sim time loses nothing: a finished node waits (up to 60 s) until its slowest subscriber has all.
        linger = 60.0 if spec.clock == "sim" else 1.0
        # Sim time sends in bursts: an output its readers take late (wire.burst > 1) every burst ticks;
        # any other when the node is about to wait for input (or DEFERRED frames are held), so a
        # node handed a burst passes one on. A node never waits holding a frame of the second kind.
        sim = spec.clock == "sim"
        self.pubs = {port: Publisher(self.ctx, wire.topic, wire.endpoint, linger, keys=keys, lossy=not sim,
                                     burst=(wire.burst if wire.burst > 1 else DEFERRED) if sim else 1)
                     for port, wire in spec.outputs.items()}
        self._deferred = [self.pubs[port] for port, wire in spec.outputs.items() if sim and wire.burst <= 1]
        self.dropped = 0
        self._drop_logged = 0.0
        self._drop_reasons: set[str] = set()
        self.ticks_done = 0

    # -- receiving ---------------------------------------------------------
    def _decode(self, frame: bytes) -> list[tuple[str, int | None, Any, bool]]:
        """[(port, tick, msg, ok)] for one received frame; ok=False for a bad message,
        (port, tick, None, True) for an empty tick."""
        i, message = self._separator(frame)
        if i < 0:
            joined = self.sub.joined(frame)  # an envelope of frames, as `bag play` sends
            if joined is not frame:
                return self._decode(joined)
        topic = frame[:i] if i >= 0 else frame
        routes = self.routes.get(topic)
        if routes is None:
            self._drop(topic.decode(errors="replace"), "message on a topic this node does not subscribe")
            return []
        if not message:
            if i < 0 or len(frame) - i != 9:
                self._drop(topic.decode(errors="replace"),
                           "malformed frame: expected the topic, a NUL byte, then msgpack")
                return []
            tick = int.from_bytes(frame[i + 1:], "little")
            return [(port, tick, None, True) for port, _ in routes]
        payload = frame[i + 1:]
        out = []
        for port, fast in routes:
            try:
                msg = fast(payload)
                out.append((port, msg.header.tick, msg, True))
            except (msgspec.ValidationError, msgspec.DecodeError, UnicodeDecodeError):
                try:  # the codec's own call, for its one line naming the field and the reason
                    decode(payload, self.in_types[port])
                except DecodeError as exc:
                    self._drop(topic.decode(), str(exc))
                header = decode_header(payload)
                tick = None if header is None else header.tick
                out.append((port, tick, None, False))
        return out

    def _drop(self, topic: str, reason: str) -> None:
        self.dropped += 1
        now = time.monotonic()
        # One line per bad message, at most ~10 a second, but every new kind of fault once.
        kind = reason.split(" - at ")[0][:60]
        if now - self._drop_logged > 0.1 or kind not in self._drop_reasons:
            self._drop_reasons.add(kind)
            self._drop_logged = now
            self.log(f"warning: dropped bad message on {topic}: {reason} ({self.dropped} dropped so far)")

    # -- running -------------------------------------------------------------
    def start(self) -> None:
        self.node.setup()
        # What start-up made (imports, devices) lives for the whole run: keep the collector from
        # walking it again on every full collection of the loop's garbage (measured: a quarter of
        # a ring's CPU per tick). No collection first: what little garbage the imports left is kept,
        # and a full collection of everything they made would cost each process 10-30 ms.
        gc.freeze()

    def wait_for_subscribers(self) -> None:
        for port, pub in self.pubs.items():
            pub.wait_subscribers(self.spec.outputs[port].subscribers, self.spec.start_timeout, lambda: self.stop.requested)

    def publish(self, k: int, outs: dict, sim: bool) -> None:
        for port, pub in self.pubs.items():
            msg = outs.get(port)
            if msg is not None:
                if not pub.send(checked_payload(self.spec.name, port, pub.topic, k, msg)):
                    self._lost_output(pub)
            elif sim:
                pub.send_empty(k)

    def _lost_output(self, pub) -> None:
        # Wall time: a subscriber's queue is full (it stopped reading); the message is dropped, not queued.
        if pub.dropped == 1 or pub.dropped % 1000 == 0:
            self.log(f"warning: output {pub.topic}: a subscriber is not keeping up; {pub.dropped} message(s) dropped "
                     f"(high-water mark reached)")

    @property
    def dropped_outputs(self) -> int:
        return sum(pub.dropped for pub in self.pubs.values())

    def run_sim(self) -> None:
        spec, node = self.spec, self.node
        self.wait_for_subscribers()
        self._buffers: dict[str, dict[int, Any]] = {port: {} for port in spec.inputs}
        self._held: dict[str, Any] = {port: None for port in spec.inputs}
        self._last_seen = {port: -1 for port in spec.inputs}
        # Looked up once, not per message: each input's buffer and lag, the loop's constants.
        needs = [(port, self._buffers[port], w.lag) for port, w in spec.inputs.items()]
        unconnected = {port: None for port in self.unconnected}
        step, dt, name, declared, stop, publish = node.step, spec.dt, spec.name, self.outputs, self.stop, self.publish
        end = -1 if spec.n_ticks is None else spec.n_ticks
        self._waited_since = time.monotonic()
        self._warned_at: int | None = None
        k = 0
        self.timing = LoopTiming([], period=spec.dt)  # sim time: only what was dropped is judged
        while k != end and not stop.requested:
            for port, buf, lag in needs:  # the first input whose message of this tick is not in yet
                if k >= lag and k - lag not in buf:
                    self._receive(k, port)
                    break
            else:
                if k == 0:  # the real-time factor counts from here, not from the start-up
                    self.timing.first_tick_at = time.time()
                inputs = {port: buf.pop(k - lag, None) for port, buf, lag in needs}
                if unconnected:
                    inputs.update(unconnected)
                outs = step(Tick(k, k * dt, dt), inputs)
                check_outputs(name, declared, k, outs, sim=True)
                publish(k, outs, sim=True)
                k += 1
                self.ticks_done = k
                self._waited_since = time.monotonic()
        self.timing.last_tick_at = time.time()
        for pub in self.pubs.values():  # the last, incomplete bursts
            pub.flush()
        # Stay subscribed until every input's last tick is in: a publisher waits for its subscribers
        # before tick 0, and a node that needs no input for its ticks (a long delay) must not leave first.
        while spec.n_ticks is not None and not self.stop.requested:
            behind = [p for p, seen in self._last_seen.items() if seen < spec.n_ticks - 1]
            if not behind:
                break
            self._receive(k, behind[0], keep=False)
        self.timing.ticks = k
        self.timing.dropped_in = self.dropped

    def _receive(self, k: int, waiting_for: str, keep: bool = True) -> None:
        """Take one message off the socket (or time out after 0.2 s), file it by tick; before
        waiting, send what the deferred outputs hold."""
        frames = self.sub.recv_frame_nowait()
        if frames is None:
            for pub in self._deferred:
                pub.flush()
            frames = self.sub.recv_frame(0.2)
        if frames is None:
            if time.monotonic() - self._waited_since > 10 and self._warned_at != k:
                self._warned_at = k
                self.log(f"warning: tick {k}: still waiting for {self.spec.inputs[waiting_for].topic} after 10 s")
            return
        for port, tick, msg, ok in self._decode(frames):
            if tick is None:
                continue
            self._last_seen[port] = max(self._last_seen[port], tick)
            if not ok:  # bad message for a known tick: hold the last good value
                msg = self._held[port]
            elif msg is not None:
                self._held[port] = msg
            if keep:
                self._buffers[port][tick] = msg

    def run_wall(self, duration: float | None) -> dict:
        spec, node = self.spec, self.node
        # As in sim time: what is sent before a subscriber (a recorder) has joined would be lost.
        self.wait_for_subscribers()
        latest: dict[str, Any] = {port: None for port in spec.inputs}
        arrived: dict[str, float] = {}  # port -> when its latest message arrived (runtime clock)
        for port in self.unconnected:
            latest[port] = None
        self.timing = timing = LoopTiming(list(spec.inputs), period=spec.dt, max_age=self.max_age)
        clock = self.clock
        period = spec.dt
        t0 = clock()
        timing.first_tick_at = time.time()
        next_t = t0
        k = 0
        try:
            while not self.stop.requested:
                now = clock()
                if duration is not None and now - t0 >= duration:
                    break
                timing.started(now - next_t)
                while (frames := self.sub.recv_frame_nowait()) is not None:
                    for port, _tick, msg, ok in self._decode(frames):
                        if msg is not None:
                            latest[port] = msg
                            arrived[port] = now
                self._check_ages(arrived, now, timing)
                stamp = time.time()
                timing.inputs(stamp, latest)
                outs = node.step(Tick(k, now - t0, period, stamp=stamp), dict(latest))
                check_outputs(spec.name, self.outputs, k, outs, sim=False)
                self.publish(k, outs, sim=False)
                k += 1
                self.ticks_done = k
                next_t += period
                late = clock() - next_t
                if late > 0:
                    timing.missed(late if k > 1 else 0.0)  # the first tick has no schedule to keep
                    if late > period:  # fell far behind: skip, do not burst to catch up
                        next_t = clock() + period
                else:
                    sleep_until(next_t, clock)
        finally:
            timing.ticks = k
            timing.elapsed = clock() - t0
            timing.last_tick_at = timing.first_tick_at + timing.elapsed  # on the loop's own clock
            timing.dropped_in = self.dropped
            timing.dropped_out = self.dropped_outputs
        out = timing.report(spec.name)
        folder = os.environ.get("DOCKHIL_TIMING_DIR")
        if folder:  # benchmarks collect every node's figures
            with open(os.path.join(folder, f"{spec.name}.json"), "w") as f:
                json.dump(out, f)
        return out

    def _check_ages(self, arrived: dict[str, float], now: float, timing: "LoopTiming") -> None:
        for port, at in arrived.items():
            age = now - at
            timing.aged(port, age)
            limit = self.max_age.get(port, math.inf)
            if age > limit:
                topic = self.spec.inputs[port].topic
                raise StaleInput(f"node {self.spec.name!r}: input {port!r} ({topic}) is {age:.3f} s old > "
                                 f"max_age {limit:g} s (its publisher stalled or died); stopping")

    def close(self) -> None:
        try:
            self.node.close()
        finally:
            for pub in self.pubs.values():
                pub.close()
            self.sub.close()
            self.ctx.term()  # returns once queued messages are out (or linger has passed)


class LoopTiming:
    """Wall-time loop statistics: how late each tick started against its schedule,
    missed deadlines, and how old each input's latest message was when used
    (by its stamp, and by the time since it arrived against its maximum age)."""

    def __init__(self, ports: list[str], period: float = 0.0, max_age: dict[str, float] | None = None):
        from array import array

        self.lateness = array("d")
        self.ages = {port: array("d") for port in ports}
        self.misses = 0
        self.ticks = 0
        self.period = period
        self.elapsed = 0.0
        self.max_age = dict(max_age or {})
        self.worst_age = {port: 0.0 for port in ports}  # since arrival [s]
        self.dropped_in = 0
        self.dropped_out = 0
        self.worst_overrun = 0.0
        # When the loop's first tick began and its last ended (time.time(), comparable across the
        # graph's processes): the run's real-time factor counts this span, not the start-up.
        self.first_tick_at: float | None = None
        self.last_tick_at: float | None = None

    def aged(self, port: str, age: float) -> None:
        if age > self.worst_age.get(port, 0.0):
            self.worst_age[port] = age

    def started(self, late_s: float) -> None:
        self.lateness.append(late_s)

    def inputs(self, now: float, latest: dict) -> None:
        for port, ages in self.ages.items():
            msg = latest.get(port)
            if msg is not None:
                ages.append(now - msg.header.stamp)

    def missed(self, late: float = 0.0) -> None:
        """A tick ended `late` seconds after its deadline (a long one re-bases the schedule, so the
        next start does not show it: keep the worst here)."""
        self.misses += 1
        self.worst_overrun = max(self.worst_overrun, late)

    def report(self, name: str) -> dict:
        def pct(values) -> dict:
            if not len(values):
                return {}
            us = sorted(abs(v) * 1e6 for v in values)
            return {"p50": percentile(us, 50), "p99": percentile(us, 99), "max": us[-1]}

        late = [abs(v) for v in self.lateness[1:]]  # the first tick has no schedule to keep
        worst = max(late, default=0.0)
        out = {"node": name, "ticks": self.ticks, "deadline_misses": self.misses,
               "jitter_us": pct(late), "worst_tick": late.index(worst) + 1 if late else None,
               "input_age_us": {port: pct(a) for port, a in self.ages.items()},
               # What validity is judged on (dockhil/runtime/validity.py):
               "period_s": self.period, "elapsed_s": self.elapsed, "covered_s": self.ticks * self.period,
               "worst_late_s": max(worst, self.worst_overrun),
               "max_age_s": {p: (None if math.isinf(a) else a) for p, a in self.max_age.items()},
               "worst_input_age_s": dict(self.worst_age),
               "dropped_in": self.dropped_in, "dropped_out": self.dropped_out,
               "first_tick_at_s": self.first_tick_at, "last_tick_at_s": self.last_tick_at}
        return out


def percentile(ordered: list[float], p: float) -> float:
    """numpy.percentile(values, p) (its default, linear method) of values sorted ascending, without
    numpy: a node that does not compute with numpy does not import it (0.1 s of CPU) to report."""
    at = p / 100 * (len(ordered) - 1)
    below = math.floor(at)
    a, b = ordered[below], ordered[min(below + 1, len(ordered) - 1)]
    t = at - below
    return b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t  # numpy's two-sided interpolation


SPIN_S = float(os.environ.get("DOCKHIL_SPIN_S", "0.0002"))


def sleep_until(deadline: float, clock=time.monotonic) -> None:
    # Sleep most of the way, then spin the last SPIN_S: time.sleep alone overshoots by ~60-150 us,
    # but every microsecond spun is CPU the other nodes on the machine do not get.
    if clock is not time.monotonic:  # a test's clock: its time moves when the test says, never by waiting
        if hasattr(clock, "sleep_until"):
            clock.sleep_until(deadline)
        return
    left = deadline - time.monotonic()
    if left > SPIN_S:
        time.sleep(left - SPIN_S)
    while time.monotonic() < deadline:
        pass
