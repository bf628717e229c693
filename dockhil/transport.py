"""ZeroMQ transport: one bound publisher socket per topic, one subscriber socket per node.

On the wire each message is one ZeroMQ frame: the topic, a NUL byte, then
the msgpack payload; in sim time a tick with no message is the topic, byte
0x01 and the tick as 8 bytes little-endian. (One frame, not a [topic,
payload] envelope: each frame sent costs a wake-up of ZeroMQ's I/O thread.)
Topic names never hold those two bytes, so the first one ends the topic, and
SUB prefix filtering on the topic still works. Receivers see [topic,
payload] or [topic, b"", tick]. Publishers are XPUB sockets so
that they see subscriptions arrive: in sim time a publisher waits until every
subscriber the launcher expects has joined before it sends tick 0, so the
slow-joiner effect of PUB/SUB never loses a message.

High-water marks bound every queue (HWM messages per subscriber). Sim time:
a full queue blocks the publisher (XPUB_NODROP), so a slow subscriber slows
the graph and lock-step loses nothing. Wall time: a message that a full
queue cannot take is dropped and counted (`Publisher.dropped`); the node
logs it and the run is judged on it.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import zmq

from dockhil.errors import DockhilError


HWM = 20_000  # messages queued per subscriber, each way: bounded memory; far above any lock-step lead
MESSAGE = b"\x00"
EMPTY_TICK = b"\x01"


def split(frames: list[bytes]) -> list[bytes]:
    """One wire frame -> [topic, payload] or [topic, b"", tick]; anything else is passed on as it
    came, for the receiver to count as malformed."""
    if len(frames) != 1:
        return frames
    frame = frames[0]
    a, b = frame.find(MESSAGE), frame.find(EMPTY_TICK)
    i = a if b < 0 or 0 <= a < b else b
    if i < 0:
        return frames
    if frame[i:i + 1] == MESSAGE:
        return [frame[:i], frame[i + 1:]]
    return [frame[:i], b"", frame[i + 1:]]


def runtime_dir() -> Path:
    """Where ipc sockets and the registry of running graphs live."""
    base = os.environ.get("DOCKHIL_RUNTIME_DIR") or f"/tmp/dockhil-{os.getuid()}"
    path = Path(base)
    path.mkdir(parents=True, exist_ok=True)
    return path


def ipc_endpoint(run_dir: Path, topic: str) -> str:
    name = topic.strip("/").replace("/", ".") or "root"
    return f"ipc://{run_dir}/{name}"


class Publisher:
    def __init__(self, ctx: zmq.Context, topic: str, endpoint: str, linger_s: float = 2.0, lossy: bool = False):
        self.topic = topic
        self.topic_bytes = topic.encode()
        self._message_prefix = self.topic_bytes + MESSAGE
        self._empty_prefix = self.topic_bytes + EMPTY_TICK
        self.sock = ctx.socket(zmq.XPUB)
        self.sock.setsockopt(zmq.SNDHWM, HWM)
        self.sock.setsockopt(zmq.XPUB_NODROP, 1)  # a full queue refuses the message rather than lose it quietly
        self._send_flags = zmq.NOBLOCK if lossy else 0  # wall time drops (counted); sim time waits
        self.dropped = 0
        self.sock.setsockopt(zmq.XPUB_VERBOSE, 1)
        # On close, queued messages still go out for up to linger_s (a slow recorder in sim time).
        self.sock.setsockopt(zmq.LINGER, int(linger_s * 1000))
        try:
            if endpoint.startswith("tcp://") and endpoint.endswith(":0"):
                port = self.sock.bind_to_random_port(endpoint.rsplit(":", 1)[0])
                endpoint = endpoint.rsplit(":", 1)[0] + f":{port}"
            else:
                self.sock.bind(endpoint)
        except zmq.ZMQError as exc:
            raise DockhilError(f"topic {topic}: cannot bind {endpoint}: {exc}; is another graph using it?") from None
        self.endpoint = endpoint
        self.subscribers = 0

    def wait_subscribers(self, expected: int, timeout: float, should_stop=lambda: False) -> None:
        """Block until `expected` subscriptions have arrived (sim-time start barrier)."""
        deadline = time.monotonic() + timeout
        while self.subscribers < expected:
            if should_stop():
                return
            left = deadline - time.monotonic()
            if left <= 0:
                raise DockhilError(
                    f"topic {self.topic}: {self.subscribers} of {expected} subscribers joined within {timeout:.0f} s; "
                    f"a subscribing node did not start"
                )
            if self.sock.poll(min(left, 0.2) * 1000, zmq.POLLIN):
                # Graph members subscribe to everything (b""); observers (progress, `topic echo`)
                # subscribe to the prefix "/" and are not waited for.
                if self.sock.recv() == b"\x01":
                    self.subscribers += 1

    def send(self, payload: bytes) -> bool:
        """False if a subscriber's full queue refused it (wall time only; sim time waits for room)."""
        try:
            self.sock.send(self._message_prefix + payload, self._send_flags)
        except zmq.Again:
            self.dropped += 1
            return False
        return True

    def send_empty(self, tick: int) -> None:
        """Sim time: this topic has no message at this tick."""
        self.sock.send(self._empty_prefix + tick.to_bytes(8, "little"))

    def close(self) -> None:
        self.sock.close()


class Subscriber:
    """One SUB socket connected to the endpoints of all of a node's inputs.

    An observer (a progress display, `dockhil topic echo`) is not part of the
    graph: sim time does not wait for it, and it may miss the first messages."""

    def __init__(self, ctx: zmq.Context, observer: bool = False):
        self.sock = ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, HWM)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"/" if observer else b"")
        self._connected: set[str] = set()
        self._timeout_ms = -1

    def connect(self, endpoint: str) -> None:
        if endpoint not in self._connected:
            self.sock.connect(endpoint)
            self._connected.add(endpoint)

    def recv(self, timeout_s: float | None) -> list[bytes] | None:
        """The frames of one message, or None on time-out. timeout_s=None blocks."""
        # A receive time-out on the socket costs one call per message, where poll+recv costs two.
        ms = -1 if timeout_s is None else int(timeout_s * 1000)
        if ms != self._timeout_ms:
            self.sock.setsockopt(zmq.RCVTIMEO, ms)
            self._timeout_ms = ms
        try:
            return split(self.sock.recv_multipart())
        except zmq.Again:
            return None

    def recv_nowait(self) -> list[bytes] | None:
        try:
            return split(self.sock.recv_multipart(zmq.NOBLOCK))
        except zmq.Again:
            return None

    def close(self) -> None:
        self.sock.close()
