"""A live view in Foxglove: every topic of a running graph served over the Foxglove WebSocket protocol.

`dockhil launch FILE --foxglove [PORT]` starts foxglove-sdk's WebSocket server
(127.0.0.1:8765 unless told otherwise) with one channel per topic, the same
channels a bag records: message encoding "json", schema encoding
"jsonschema", the message type's self-contained JSON Schema
(`dockhil.bags.writer.channel_schema`). Times are those of bags: in sim time the log
time is the message's sim time t * 1e9 ns after the Unix epoch, in wall time
the time the bridge received it.

Beside them, for Foxglove's 3D panel, a graph with /satellite/state gets /tf
(foxglove.FrameTransforms) and /scene (foxglove.SceneUpdate), computed from
/satellite/state, /ft/wrench and /robot/state by `dockhil.bags.foxglove_scene`
(as `dockhil bag export --foxglove` adds them to a bag); the bridge reads those
topics while a viewer subscribes to /tf or /scene.

The bridge observes; it never holds the graph back:

- multi-process: one observer subscriber (prefix subscriptions, which the
  sim-time start barrier does not wait for), subscribed only to the topics a
  viewer subscribes to, so a topic nobody looks at costs nothing. It empties
  its socket at each pass; when more came in than it can forward, it drops
  the oldest of the burst and counts them. It reads the publishers' observer
  sockets (`dockhil.runtime.transport`): if it falls behind anyway, its own queue
  drops its messages (counted too), never the graph's.
- composed: a tap that encodes a message only when a viewer wants its topic.
- a viewer too slow for the stream loses the oldest messages in the server's
  per-client queue (foxglove-sdk); the graph does not wait for it.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import msgspec

from dockhil.errors import DockhilError

if TYPE_CHECKING:
    from dockhil.bags.foxglove_scene import Geometry
    from dockhil.runtime.keys import GraphKeys
    from dockhil.runtime.transport import Subscriber
    from dockhil.scene.graph import Graph

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
BURST = 4096  # messages forwarded per pass at most; the older ones of a larger burst are dropped
STOP_WAIT_S = 1.0  # s: how long the end of a run waits for the viewers to take the close
DRAIN_MAX = 100_000  # frames taken from the socket in one pass, so that a pass ends


def _log(line: str) -> None:
    from dockhil.log import node_line

    node_line("foxglove", line)  # "[foxglove] warning: ...": under its own name, at its level


class FoxgloveBridge:
    """A Foxglove WebSocket server with one json channel per topic (topic -> wire type name).

    Serving starts at once; `observe` feeds it from a multi-process graph, `tap` from a composed one."""

    def __init__(
        self,
        topics: dict[str, str],
        *,
        sim: bool,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        log: Callable[[str], None] = _log,
        burst: int = BURST,
        geometry: Geometry | None = None,
    ):
        """geometry: where the interfaces are mounted (`foxglove_scene.Geometry`, default at the CoMs)."""
        try:
            import foxglove
        except ImportError:
            raise DockhilError("--foxglove needs the foxglove-sdk package: pip install 'dockhil[foxglove]'") from None
        from dockhil import msgs
        from dockhil.bags import foxglove_scene as fs
        from dockhil.bags.format import SCHEMA_ENCODING
        from dockhil.bags.writer import channel_schema

        self.sim = sim
        self.log = log
        self.burst = burst
        self.sent = 0  # messages handed to the server
        self.dropped = 0  # messages the bridge could not keep up with
        self.unencodable = 0  # not msgpack of a message with a header: not served
        self._from_wire = msgspec.msgpack.Decoder().decode
        self._to_json = msgspec.json.Encoder().encode
        self._context = foxglove.Context()  # channels of this bridge only, not the process-wide default
        schemas = {}
        for type_name in set(topics.values()):
            data = json.dumps(channel_schema(msgs.type_by_name(type_name)), separators=(",", ":")).encode()
            schemas[type_name] = foxglove.Schema(name=type_name, encoding=SCHEMA_ENCODING, data=data)
        self.channels = {
            topic: foxglove.Channel(topic, schema=schemas[type_name], message_encoding="json", context=self._context)
            for topic, type_name in sorted(topics.items())
        }
        self.types = {topic: msgs.type_by_name(type_name) for topic, type_name in topics.items()}
        # The 3D view's channels, fed from the bodies' states (none in a scene without them).
        self.derived: dict[str, Any] = {}
        self._feed = fs.SceneFeed(geometry or fs.AT_THE_COMS)
        if fs.STATE in topics:
            for topic, name in fs.DERIVED.items():
                data = json.dumps(fs.schema(name), separators=(",", ":")).encode()
                self.derived[topic] = foxglove.Channel(
                    topic,
                    schema=foxglove.Schema(name=name, encoding=SCHEMA_ENCODING, data=data),
                    message_encoding="json",
                    context=self._context,
                )
        # The server starts once every channel exists: a viewer that connects while channels are being
        # added can be told of one its session does not know, and its subscription is refused.
        try:
            self._server = foxglove.start_server(name="dockhil", host=host, port=port, context=self._context)
        except RuntimeError as exc:
            reason = str(exc).removeprefix("FoxgloveError: ")
            todo = (
                "choose a free port with --foxglove PORT"
                if "in use" in reason
                else "give --foxglove-host an address of this machine"
            )
            raise DockhilError(f"--foxglove: cannot serve on {host}:{port}: {reason}; {todo}") from None
        self.host, self.port = host, self._server.port
        self._sources = [topic for topic in fs.SOURCES if topic in topics]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: str | None = None
        log(
            f"[foxglove] live view of {len(self.channels)} topics{' and /tf, /scene' if self.derived else ''} on "
            f"ws://{host}:{self.port} (Foxglove: Open connection, Foxglove WebSocket; layout: "
            f"'dockhil foxglove layout > layout.json', then Import layout)"
        )

    # -- a multi-process graph ---------------------------------------------------
    def observe(self, endpoints: dict[str, str], keys: GraphKeys) -> None:
        """Serve the topics of a multi-process graph: topic -> endpoint, with the graph's CURVE keys.
        The nodes need not have bound yet: the subscriber connects when they do."""
        import zmq

        from dockhil.runtime.transport import Subscriber

        sub = Subscriber(zmq.Context.instance(), observer=True)
        # An observer subscribes to "/" (everything); this one only to the topics viewers want.
        sub.sock.setsockopt(zmq.UNSUBSCRIBE, b"/")
        for topic in self.channels:
            if topic in endpoints:
                sub.connect(endpoints[topic], keys=keys)
        self._thread = threading.Thread(target=self._run, args=(sub,), name="foxglove-bridge", daemon=True)
        self._thread.start()

    def _run(self, sub: Subscriber) -> None:
        import zmq

        from dockhil.runtime.transport import OBSERVED

        wanted: set[str] = set()
        try:
            while not self._stop.is_set():
                now = self._wanted()
                for topic in now - wanted:  # the topic's messages, not its empty sim-time ticks
                    sub.sock.setsockopt(zmq.SUBSCRIBE, topic.encode() + OBSERVED)
                for topic in wanted - now:
                    sub.sock.setsockopt(zmq.UNSUBSCRIBE, topic.encode() + OBSERVED)
                wanted = now
                frames = sub.recv(0.1)
                if frames is None:
                    continue
                burst = [frames]
                while len(burst) < DRAIN_MAX and (frames := sub.recv_nowait()) is not None:
                    burst.append(frames)
                self.serve(burst)
        except DockhilError as exc:  # a peer failed the graph's authentication: serve nothing more from it
            self.error = str(exc)
            self.log(f"[foxglove] warning: live view stopped: {exc}")
        finally:
            sub.close()
            self.dropped += sub.lost  # an observer: what it fell behind on never arrived

    def serve(self, burst: list[list[bytes]]) -> None:
        """Forward the messages ([topic, payload]) that came in since the last pass; of more than
        `self.burst`, the oldest are dropped and counted: the bridge catches up instead of lagging."""
        if len(burst) > self.burst:
            self.dropped += len(burst) - self.burst
            burst = burst[-self.burst :]
        for frames in burst:
            if len(frames) == 2:
                self._forward(frames[0].decode(errors="replace"), frames[1])

    def _wanted(self) -> set[str]:
        """The topics a viewer wants now: theirs, and the 3D view's sources while one wants /tf or /scene."""
        wanted = {topic for topic, channel in self.channels.items() if channel.has_sinks()}
        if self._deriving():
            wanted.update(self._sources)
        return wanted

    def _deriving(self) -> bool:
        return any(channel.has_sinks() for channel in self.derived.values())

    def _forward(self, topic: str, payload: bytes) -> None:
        channel = self.channels.get(topic)
        if channel is None:
            return
        try:
            message = self._from_wire(payload)
            log_ns = round(message["header"]["stamp"] * 1e9) if self.sim else time.time_ns()
            if not 0 <= log_ns < 2**64:
                raise ValueError(log_ns)
            data = self._to_json(message) if channel.has_sinks() else None
        except (msgspec.DecodeError, msgspec.EncodeError, TypeError, KeyError, ValueError, OverflowError):
            self.unencodable += 1
            return
        if data is not None:
            channel.log(data, log_time=log_ns)
            self.sent += 1
        if topic in self._sources and self._deriving():
            try:
                typed = msgspec.convert(message, self.types[topic])
            except msgspec.ValidationError:  # not of its type (a NaN): served as it came, not drawn
                return
            self._derive(topic, typed, log_ns)

    def _derive(self, topic: str, message: Any, log_ns: int) -> None:
        """The 3D view's messages at a satellite state, to the viewers that want them."""
        for derived_topic, value in self._feed.add(topic, message).items():
            channel = self.derived[derived_topic]
            if channel.has_sinks():
                channel.log(self._to_json(value), log_time=log_ns)
                self.sent += 1

    # -- a composed graph ----------------------------------------------------------
    def tap(self, topic: str, message: Any) -> None:
        """ComposedGraph tap: encode only what a viewer subscribed to."""
        channel = self.channels.get(topic)
        if channel is None:
            return
        derive = topic in self._sources and self._deriving()
        if not (derive or channel.has_sinks()):
            return
        log_ns = round(message.header.stamp * 1e9) if self.sim else time.time_ns()
        if channel.has_sinks():
            channel.log(self._to_json(message), log_time=log_ns)
            self.sent += 1
        if derive:
            self._derive(topic, message, log_ns)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        # The server's stop waits for each viewer to take its close, and one that stopped reading (a paused
        # or frozen app) takes 40 s to be given up: the run's end does not wait for that.
        stopping = threading.Thread(target=self._server.stop, name="foxglove-stop", daemon=True)
        stopping.start()
        stopping.join(timeout=STOP_WAIT_S)
        late = f"; a viewer that stopped reading was not waited for ({STOP_WAIT_S:g} s)" if stopping.is_alive() else ""
        lost = f"; dropped {self.dropped} it could not keep up with" if self.dropped else ""
        bad = f"; {self.unencodable} not encodable as JSON" if self.unencodable else ""
        self.log(f"[foxglove] served {self.sent} messages{lost}{bad}{late}")


def start(graph: Graph, *, clock: str, host: str, port: int) -> FoxgloveBridge:
    """A bridge serving every topic of `graph` (checked before any node starts: a busy port fails here)."""
    from dockhil import msgs
    from dockhil.bags.foxglove_scene import geometry_of

    topics = {topic: msgs.type_name(ref.type) for topic, ref in graph.publishers.items()}
    return FoxgloveBridge(topics, sim=clock == "sim", host=host, port=port, geometry=geometry_of(graph))
