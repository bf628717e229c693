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
line, the same in a multi-process and a composed run (`screen`). The loop's
figures and its sleep to the next tick are `looptime`'s.
"""

from __future__ import annotations

import gc
import json
import math
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from types import FrameType
from typing import TYPE_CHECKING, Any

import msgspec

from dockhil.errors import DockhilError
from dockhil.log import node_line
from dockhil.msgs.codec import DecodeError, decode, decode_header
from dockhil.node import NodeContext, Tick
from dockhil.runtime import realtime
from dockhil.runtime.looptime import LoopTiming, loop_spin, sleep_until
from dockhil.runtime.screen import checked_payload

if TYPE_CHECKING:
    from dockhil.node import Node
    from dockhil.runtime.transport import GraphKeys, Publisher

TIMING = "\x1edockhil-timing "  # a node process's line with its wall-time loop figures (JSON), read by the launcher
STALE = "\x1edockhil-stale "  # ... with the input that stopped it as stale (JSON): the launcher says whose fault
DEFERRED = 16  # sim time: frames an output holds at most while its node computes on without waiting


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
    publisher: str = ""  # inputs: the node that publishes the topic (named when the input goes stale)


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


# A gap this long between two of a wall-time loop's own ticks is its own stall (stopped, starved of CPU):
# its inputs' ages count from its restart (NodeExecutor._check_ages).
OWN_STALL_S = 0.05
IDLE_DEVICE_PERIOD_S = 0.05  # the loop of an emulated device with no topics (its device thread does the work)
WALL_LINGER_S = 2.0  # wall time: how long a closing node's publishers still send what a slow reader has not taken


class Stop:
    """A flag set by SIGINT/SIGTERM; loops check it between waits."""

    def __init__(self) -> None:
        self.requested = False

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True


class StaleInput(DockhilError):
    """A wall-time input's latest message is older than its maximum age."""


def check_outputs(name: str, declared: dict, k: int, outs: dict, sim: bool) -> None:
    """Refuse outputs a node did not declare, of the wrong type, or stamped with another tick."""
    if not isinstance(outs, dict):
        raise DockhilError(
            f"node {name!r} returned {type(outs).__name__} from step at tick {k}; step returns "
            f"a dict of its outputs (port -> message), {{}} for none"
        )
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


def read_spec_keys(spec: RunSpec) -> GraphKeys | None:
    """The graph's keys, which every endpoint needs; a node without endpoints needs none."""
    from dockhil.runtime.transport import GraphKeys

    if not spec.inputs and not spec.outputs:
        return None
    if not spec.key_file:
        raise DockhilError(
            f"node {spec.name!r}: its spec names no key file for its endpoints; "
            f"start it with 'dockhil launch' or give --keys FILE"
        )
    return GraphKeys.read(spec.key_file)


def dump_report(report: dict) -> None:
    """A node's loop figures to DOCKHIL_TIMING_DIR/NAME.json, where set: benchmarks and tests collect
    every node's figures (the launcher reads them from the node's TIMING line)."""
    folder = os.environ.get("DOCKHIL_TIMING_DIR")
    if folder:
        with open(os.path.join(folder, f"{report['node']}.json"), "w") as f:
            json.dump(report, f)


class NodeExecutor:
    """Owns one node's sockets and loop. Used by node processes and `dockhil run`."""

    def __init__(
        self,
        spec: RunSpec,
        node_cls: type[Node],
        stop: Stop,
        log: Callable[[str], object] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
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
        self.ctx: zmq.Context = zmq.Context.instance()
        realtime.zmq_options(self.ctx)  # --realtime: its I/O threads too, set before its first socket
        keys = read_spec_keys(spec)
        self.sub = Subscriber(self.ctx)
        self._separator = separator
        # Topic -> [(port, the decoder of its type)], resolved once: the receive path looks up nothing else.
        self.routes: dict[bytes, list[tuple[str, Any]]] = {}
        for port, wire in spec.inputs.items():
            self.sub.connect(wire.endpoint, keys=keys)
            decoder: msgspec.msgpack.Decoder[Any] = msgspec.msgpack.Decoder(self.in_types[port])
            fast = decoder.decode  # errors: the codec's lines, below
            self.routes.setdefault(wire.topic.encode(), []).append((port, fast))
        # Sim time loses nothing: a finished node waits (up to 60 s) until its slowest subscriber has all.
        # Wall time: a recorder behind a busy machine's graph catches up once the graph stops; 2 s of it
        # (within the launcher's 3 s to stop a node), which the queues of a minute's run at 1 kHz need.
        linger = 60.0 if spec.clock == "sim" else WALL_LINGER_S
        # Sim time sends in bursts: an output its readers take late (wire.burst > 1) every burst ticks;
        # any other when the node is about to wait for input (or DEFERRED frames are held), so a
        # node handed a burst passes one on. A node never waits holding a frame of the second kind.
        sim = spec.clock == "sim"
        self.pubs = {
            port: Publisher(
                self.ctx,
                wire.topic,
                wire.endpoint,
                linger,
                keys=keys,
                lossy=not sim,
                burst=(wire.burst if wire.burst > 1 else DEFERRED) if sim else 1,
                trailing=sim,
            )
            for port, wire in spec.outputs.items()
        }
        self._deferred = [self.pubs[port] for port, wire in spec.outputs.items() if sim and wire.burst <= 1]
        if sim:  # the sockets above started the I/O threads
            realtime.lower_io_threads()
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
                self._drop(
                    topic.decode(errors="replace"), "malformed frame: expected the topic, a NUL byte, then msgpack"
                )
                return []
            tick: int | None = int.from_bytes(frame[i + 1 :], "little")
            return [(port, tick, None, True) for port, _ in routes]
        payload = frame[i + 1 :]
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
            pub.wait_subscribers(
                self.spec.outputs[port].subscribers, self.spec.start_timeout, lambda: self.stop.requested
            )

    def publish(self, k: int, outs: dict, sim: bool) -> None:
        for port, pub in self.pubs.items():
            msg = outs.get(port)
            if msg is not None:
                if not pub.send(checked_payload(self.spec.name, port, pub.topic, k, msg)):
                    self._lost_output(pub)
            elif sim:
                pub.send_empty(k)

    def _lost_output(self, pub: Publisher) -> None:
        # Wall time: a subscriber's queue is full (it stopped reading); the message is dropped, not queued.
        if pub.dropped == 1 or pub.dropped % 1000 == 0:
            self.log(
                f"warning: output {pub.topic}: a subscriber is not keeping up; {pub.dropped} message(s) dropped "
                f"(high-water mark reached)"
            )

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
                    self.timing.first_tick()
                inputs = {port: buf.pop(k - lag, None) for port, buf, lag in needs}
                if unconnected:
                    inputs.update(unconnected)
                outs = step(Tick(k, k * dt, dt), inputs)
                check_outputs(name, declared, k, outs, sim=True)
                publish(k, outs, sim=True)
                k += 1
                self.ticks_done = k
                self._waited_since = time.monotonic()
        self.timing.last_tick()
        for pub in self.pubs.values():  # the last, incomplete bursts
            pub.flush()
            pub.flush_trailing()
        # Stay subscribed until every input's last tick is in: a publisher waits for its subscribers
        # before tick 0, and a node that needs no input for its ticks (a long delay) must not leave first.
        while spec.n_ticks is not None and not self.stop.requested:
            behind = [p for p, seen in self._last_seen.items() if seen < spec.n_ticks - 1]
            if not behind:
                break
            self._receive(k, behind[0], keep=False)
        self.timing.ticks = k
        self.timing.dropped_in = self.dropped
        dump_report(self.timing.report(spec.name))

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
        clock = self.clock
        period = spec.dt
        if type(node).free_running and not spec.inputs and not spec.outputs:
            # An emulated device whose own thread is the device: its loop has nothing to read or hand on, and
            # ticking it at the graph's rate only takes the interpreter from the device's thread.
            period = max(period, IDLE_DEVICE_PERIOD_S)
        self.timing = timing = LoopTiming(list(spec.inputs), period=period, max_age=self.max_age)
        timing.device = getattr(node, "device_figures", None)  # a driver's account of its device (validity)
        spin = loop_spin()
        timing.first_tick()  # before the schedule starts: its reading of /proc is not the first tick's time
        t0 = clock()
        next_t = resumed = before = t0
        k = 0
        try:
            while not self.stop.requested:
                now = clock()
                if duration is not None and now - t0 >= duration:
                    break
                if now - before > OWN_STALL_S:  # this loop did not run (stopped, starved): its inputs' ages restart
                    resumed = now
                before = now
                timing.started(now - next_t)
                while (frames := self.sub.recv_frame_nowait()) is not None:
                    for port, _tick, msg, _ok in self._decode(frames):
                        if msg is not None:
                            latest[port] = msg
                            arrived[port] = now
                end = None if duration is None else t0 + duration
                if self._check_ages(arrived, now, timing, end, resumed):
                    break  # an input's publisher was stopped with the graph at the run's end
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
                    sleep_until(next_t, clock, spin)
        finally:
            timing.ticks = k
            timing.elapsed = clock() - t0
            assert timing.first_tick_at is not None  # set by first_tick, before the loop
            timing.last_tick(timing.first_tick_at + timing.elapsed)  # on the loop's own clock
            timing.dropped_in = self.dropped
            timing.dropped_out = self.dropped_outputs
            timing.published = {pub.topic: pub.taken for pub in self.pubs.values()}
        out = timing.report(spec.name)
        dump_report(out)
        return out

    def _check_ages(
        self, arrived: dict[str, float], now: float, timing: LoopTiming, end: float | None, resumed: float = 0.0
    ) -> bool:
        """Raises StaleInput for an input older than its max_age, counted from no earlier than `resumed`
        (this loop's own restart after a stall: what arrived meanwhile may still be on its way through
        the process's I/O thread, and the stall is the loop's, not the publisher's); True (the run is
        over) when that input's publisher ran to within two max_ages of the run's `end`: the graph
        stopped it there, and this loop, started a little after it, is still ticking."""
        for port, at in arrived.items():
            age = now - at
            timing.aged(port, age)
            limit = self.max_age.get(port, math.inf)
            if now - max(at, resumed) > limit:
                if end is not None and at >= end - 2 * limit:
                    return True
                wire = self.spec.inputs[port]
                source = f"{wire.topic} from node {wire.publisher!r}" if wire.publisher else wire.topic
                # The launcher, which sees the publisher's process, says whether it died or is late.
                late = age - self.spec.dt  # its next message was due one period after the last
                stale = {"port": port, "topic": wire.topic, "publisher": wire.publisher, "late": late}
                print(STALE + json.dumps(stale), flush=True)
                raise StaleInput(
                    f"node {self.spec.name!r}: input {port!r} ({source}) is {age:.3f} s old > max_age {limit:g} s; "
                    f"stopping"
                )
        return False

    def close(self) -> None:
        try:
            self.node.close()
        finally:
            for pub in self.pubs.values():
                pub.close()
            self.sub.close()
            self.ctx.term()  # returns once queued messages are out (or linger has passed)
