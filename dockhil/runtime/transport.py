"""ZeroMQ transport: one bound publisher socket per topic, one subscriber socket per node.

On the wire each message is one ZeroMQ frame: the topic, a NUL byte, then
the msgpack payload; in sim time a tick with no message is the topic, byte
0x01 and the tick as 8 bytes little-endian. (One frame, not a [topic,
payload] envelope: each ZeroMQ message sent costs a wake-up of its I/O thread.)
Topic names never hold those two bytes, so the first one ends the topic, and
SUB prefix filtering on the topic still works. Receivers see [topic,
payload] or [topic, b"", tick]. In sim time a publisher may send several
ticks at once, a burst (Publisher.flush): one ZeroMQ message of several such
frames, each frame one message, read one by one. Publishers are XPUB sockets so
that they see subscriptions arrive: in sim time a publisher waits until every
subscriber the launcher expects has joined before it sends tick 0, so the
slow-joiner effect of PUB/SUB never loses a message.

Only the graph's own processes take part: every socket speaks CURVE with
keys the launcher makes per graph (GraphKeys, handed over in a key file of
mode 0600, never on a command line). A subscriber connects only to a
publisher that proves it holds the graph's server secret key, so a process
that binds a topic's ipc path or tcp port in its place is never heard; a
publisher accepts only subscribers holding the graph's client key (checked
by a ZAP handler), so a stranger receives nothing. The ipc sockets and key
files live in a private runtime directory (0700, owner checked).

High-water marks bound every queue (HWM messages per subscriber). Sim time:
a full queue blocks the publisher (XPUB_NODROP), so a slow subscriber slows
the graph and lock-step loses nothing. Wall time: a message that a full
queue cannot take is dropped and counted (`Publisher.dropped`); the node
logs it and the run is judged on it.

Observers (`topic echo` and `hz`, `bag record` from outside, the Foxglove
bridge, the launcher's progress probe) are not the graph's: each publisher
binds a second socket for them, at `observer_endpoint(endpoint)`, that never
waits and never refuses. XPUB_NODROP judges all of a socket's pipes at once (one
full queue refuses the message to every subscriber), so an observer on the
graph's socket that stops reading (a pager left open) would stop the graph's
deliveries too; on its own socket, a full queue (OBSERVER_HWM) drops that
observer's messages alone. Its frames carry the publisher's count of messages
(topic, 0x02, the count as 8 bytes little-endian, the payload), from which the
observer counts what it lost (`Subscriber.lost`) and says so.

Trailing readers (sim time: the launch's recorder) are the graph's, and lose
nothing, but no tick waits for them: they read at
`trailing_endpoint(endpoint)`, a third socket, on which a publisher sends
their frames TRAIL_BURST at a time. On the graph's socket each of the
recorder's messages went out when the lock-step readers needed it, and woke
the publisher's I/O thread, the recorder's I/O thread and its reader once
more per message: a 1 kHz hil.yaml tick took twice the context switches of
one without the recorder. Its high-water mark is HWM // TRAIL_BURST bursts,
so it bounds as many frames as the graph's socket.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import zmq

from dockhil.errors import DockhilError
from dockhil.runtime.keys import GraphKeys, allow_clients, release_clients
from dockhil.runtime.rundir import new_run_dir, private_dir, runtime_dir  # noqa: F401 - importers find them here too

HWM = 20_000  # messages queued per subscriber, each way: bounded memory; far above any lock-step lead
OBSERVER_HWM = 1_000  # per observer, each way: one that stops reading loses messages, it does not hoard them
MESSAGE = b"\x00"
EMPTY_TICK = b"\x01"
OBSERVER_LINGER_MS = 500
LOOK_EVERY_S = 0.05  # wall time: how often a publisher looks whether an observer listens
OBSERVED = b"\x02"  # an observer's frame: the topic, this byte, the publisher's message count, the payload
OBSERVER_SUFFIX = "+observers"  # an ipc observer endpoint's path: a topic's name never holds "+"
TRAILING_SUFFIX = "+trailing"  # likewise, a trailing reader's endpoint
TRAIL_BURST = 64  # frames a trailing reader gets in one ZeroMQ message: ~0.2 wake-ups a tick for hil.yaml's 5 topics


def separator(frame: bytes) -> tuple[int, bool]:
    """(where the topic ends, whether a message follows) for one wire frame; -1 if it holds neither
    separator. The first of the two bytes ends the topic: an 0x01 is looked for only before the
    first NUL (the topic is short, a payload is not)."""
    a = frame.find(MESSAGE)
    b = frame.find(EMPTY_TICK, 0, a) if a >= 0 else frame.find(EMPTY_TICK)
    return (b, False) if b >= 0 else (a, a >= 0)


def split(frames: list[bytes]) -> list[bytes]:
    """One wire frame -> [topic, payload] or [topic, b"", tick]; anything else is passed on as it
    came, for the receiver to count as malformed."""
    if len(frames) != 1:
        return frames
    frame = frames[0]
    i, message = separator(frame)
    if i < 0:
        return frames
    if message:
        return [frame[:i], frame[i + 1 :]]
    return [frame[:i], b"", frame[i + 1 :]]


def _beside(endpoint: str, suffix: str, offset: int) -> str:
    if endpoint.startswith("tcp://"):
        base, port = endpoint.rsplit(":", 1)
        return endpoint if port in ("0", "*") else f"{base}:{int(port) + offset}"
    return endpoint + suffix


def observer_endpoint(endpoint: str) -> str:
    """Where a publisher bound at `endpoint` serves observers: the ipc path with OBSERVER_SUFFIX, or
    over tcp the next port (the launcher picks the three together); a random port stays random."""
    return _beside(endpoint, OBSERVER_SUFFIX, 1)


def trailing_endpoint(endpoint: str) -> str:
    """Where a sim-time publisher bound at `endpoint` serves trailing readers: the ipc path with
    TRAILING_SUFFIX, or over tcp the port after the observers'; a random port stays random."""
    return _beside(endpoint, TRAILING_SUFFIX, 2)


def ipc_endpoint(run_dir: Path, topic: str) -> str:
    name = topic.strip("/").replace("/", ".") or "root"
    return f"ipc://{run_dir}/{name}"


class Publisher:
    """A topic's XPUB socket, a CURVE server with the graph's keys (None: plain, for benchmarks only).
    trailing: also serve trailing readers (sim time), on a socket of their own."""

    def __init__(
        self,
        ctx: zmq.Context,
        topic: str,
        endpoint: str,
        linger_s: float = 2.0,
        *,
        keys: GraphKeys | None,
        lossy: bool = False,
        burst: int = 1,
        trailing: bool = False,
    ):
        self.topic = topic
        # Sim time, readers with slack (a declared delay): frames held and sent `burst` at a time, back
        # to back, so that every process down the line wakes once a burst rather than once a message.
        self.burst = burst
        self._held: list[bytes] = []
        self._held_observed: list[bytes] = []  # the observers' frames of the same messages
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
        # Observers' socket: no XPUB_NODROP, so a full queue drops that observer's message alone, and
        # a send never waits; on close, what they have not taken lingers a moment only.
        self.observers = ctx.socket(zmq.XPUB)
        self.observers.setsockopt(zmq.SNDHWM, OBSERVER_HWM)
        self.observers.setsockopt(zmq.LINGER, OBSERVER_LINGER_MS)
        # Every subscription and unsubscription reaches `look`: frames for observers are made only while one listens.
        self.observers.setsockopt(zmq.XPUB_VERBOSER, 1)
        self.watchers = 0  # observers' subscriptions in (see `look`)
        self._next_look = 0.0
        self.sent = 0  # messages offered to observers, counted in their frames
        self._observed_prefix = self.topic_bytes + OBSERVED
        # Trailing readers' socket: waits for room as the graph's does, with as many frames queued at most.
        self.trail = None
        self.trailing_readers = 0  # their subscriptions in (counted in `subscribers` too)
        self._held_trail: list[bytes] = []
        if trailing:
            self.trail = ctx.socket(zmq.XPUB)
            self.trail.setsockopt(zmq.SNDHWM, max(1, HWM // TRAIL_BURST))
            self.trail.setsockopt(zmq.XPUB_NODROP, 1)
            self.trail.setsockopt(zmq.LINGER, int(linger_s * 1000))
        self._ctx = ctx if keys is not None else None
        sockets = [self.sock, self.observers] + ([self.trail] if self.trail is not None else [])
        if keys is not None:
            allow_clients(ctx, keys)  # before bind: no handshake may happen without the check
            for sock in sockets:
                sock.curve_server = True
                sock.curve_secretkey = keys.server_secret
                sock.curve_publickey = keys.server_public
        self.endpoint = self._bind(self.sock, endpoint)
        self.observer_endpoint = self._bind(self.observers, observer_endpoint(endpoint))
        if self.trail is not None:
            self._bind(self.trail, trailing_endpoint(endpoint))
        self.subscribers = 0

    def _bind(self, sock: zmq.Socket, endpoint: str) -> str:
        try:
            if endpoint.startswith("tcp://") and endpoint.endswith(":0"):
                port = sock.bind_to_random_port(endpoint.rsplit(":", 1)[0])
                return endpoint.rsplit(":", 1)[0] + f":{port}"
            sock.bind(endpoint)
            return endpoint
        except zmq.ZMQError as exc:
            self.close()
            raise DockhilError(
                f"topic {self.topic}: cannot bind {endpoint}: {exc}; is another graph using it?"
            ) from None

    def wait_subscribers(self, expected: int, timeout: float, should_stop: Callable[[], bool] = lambda: False) -> None:
        """Block until `expected` subscriptions have arrived, the graph's and the trailing readers'
        (sim-time start barrier)."""
        deadline = time.monotonic() + timeout
        self.look()  # observers already there get the first tick too
        poller = zmq.Poller()
        for sock in (self.sock, self.trail):
            if sock is not None:
                poller.register(sock, zmq.POLLIN)
        while self.subscribers < expected:
            if should_stop():
                return
            left = deadline - time.monotonic()
            if left <= 0:
                raise DockhilError(
                    f"topic {self.topic}: {self.subscribers} of {expected} subscribers joined within {timeout:.0f} s; "
                    f"a subscribing node did not start"
                )
            for sock, _ in poller.poll(int(min(left, 0.2) * 1000)):  # as poll itself truncates a float
                # Graph members and trailing readers subscribe to everything (b""); observers (progress,
                # `topic echo`) subscribe to the prefix "/" on their own socket and are not waited for.
                if sock.recv() == b"\x01":
                    self.subscribers += 1
                    self.trailing_readers += sock is self.trail

    def send(self, payload: bytes) -> bool:
        """False if a subscriber's full queue refused it (wall time only; sim time waits for room)."""
        self._observe(payload)
        frame = self._message_prefix + payload
        if self.trailing_readers:
            self._trail(frame)
        if self.burst > 1:
            self._hold(frame)
            return True
        try:
            self.sock.send(frame, self._send_flags)
        except zmq.Again:
            self.dropped += 1
            return False
        return True

    @property
    def taken(self) -> int:
        """Messages the graph's socket took (queued for every subscriber): those sent, less those a full
        queue refused (wall time). A node reports it per topic as it exits, and the launch's recorder
        counts what of it never arrived (dockhil.bags.live)."""
        return self.sent - self.dropped

    def send_multipart(self, frames: Sequence[bytes], copy: bool = True) -> None:
        """Send an envelope of frames ([topic, payload] or [topic, b"", tick], as `bag play` sends)
        on the graph's socket as it is (zmq.Again if a full queue refused it), then to the observers."""
        self.sock.send_multipart(frames, copy=copy)
        if len(frames) == 2:
            self._observe(frames[1], hold=False)
        elif self.watchers > 0:
            self.observers.send(frames[0] + EMPTY_TICK + frames[2], zmq.NOBLOCK)

    def look(self) -> int:
        """Take in the observers' subscriptions and unsubscriptions; how many subscriptions came."""
        came = 0
        try:
            while True:
                joined = self.observers.recv(zmq.NOBLOCK)[:1] == b"\x01"
                came += joined
                self.watchers = self.watchers + 1 if joined else max(0, self.watchers - 1)
        except zmq.Again:
            return came

    def _observe(self, payload: bytes, hold: bool = True) -> None:
        """Offer a message to the observers (with a burst's, when it goes out); never waits. Whether
        one listens is looked at every LOOK_EVERY_S (as a message or a burst goes out): a new observer
        may miss the first messages, and none costs 0.2 us a message."""
        self.sent += 1
        if self.burst == 1:
            self._look_now_and_then()
        if self.watchers > 0:
            frame = self._observed_prefix + self.sent.to_bytes(8, "little") + payload
            if self.burst > 1 and hold:
                self._held_observed.append(frame)
            else:
                self.observers.send(frame, zmq.NOBLOCK)

    def send_empty(self, tick: int) -> None:
        """Sim time: this topic has no message at this tick."""
        frame = self._empty_prefix + tick.to_bytes(8, "little")
        if self.trailing_readers:
            self._trail(frame)
        if self.burst > 1:
            if self.watchers > 0:
                self._held_observed.append(frame)
            self._hold(frame)
        else:
            if self.watchers > 0:
                self.observers.send(frame, zmq.NOBLOCK)
            self.sock.send(frame)

    def _hold(self, frame: bytes) -> None:
        self._held.append(frame)
        if len(self._held) >= self.burst:
            self.flush()

    def _trail(self, frame: bytes) -> None:
        self._held_trail.append(frame)
        if len(self._held_trail) >= TRAIL_BURST:
            self.flush_trailing()

    def flush_trailing(self) -> None:
        """Send what the trailing readers' burst holds (sim time: waits for room), as one ZeroMQ
        message of its frames: they subscribe to every kind, so one run; the end of a run sends it
        whole."""
        if self._held_trail:  # only with trailing readers, on their socket
            assert self.trail is not None
            if len(self._held_trail) == 1:
                self.trail.send(self._held_trail[0])
            else:
                self.trail.send_multipart(self._held_trail)
            self._held_trail.clear()

    def flush(self) -> None:
        """Send the frames a burst holds (sim time, which waits for room rather than drop) as one
        ZeroMQ message of several frames, each frame still one message: ZeroMQ hands a message of
        many frames to its I/O thread, and to the reader, in one wake-up. Messages and empty ticks
        go in separate runs, as a reader may subscribe to only one kind (its prefix is matched
        against the first frame). The observers get theirs the same way, after, without waiting."""
        if self._held:
            self._send_runs(self.sock, self._held, 0)
        if self._held_observed:
            self._send_runs(self.observers, self._held_observed, zmq.NOBLOCK)
        self._look_now_and_then()

    def _look_now_and_then(self) -> None:
        """`look`, at most every LOOK_EVERY_S: a node flushes before each wait, once a tick in lock-step,
        and a look that finds nothing is a ZeroMQ receive, its system call and an exception."""
        if (now := time.monotonic()) >= self._next_look:
            self._next_look = now + LOOK_EVERY_S
            self.look()

    def _send_runs(self, sock: zmq.Socket, held: list[bytes], flags: int) -> None:
        n = len(self.topic_bytes)
        start = 0
        for i in range(1, len(held) + 1):
            if i == len(held) or held[i][n] != held[start][n]:
                if i - start == 1:
                    sock.send(held[start], flags)
                else:
                    sock.send_multipart(held[start:i], flags)
                start = i
        held.clear()

    def close(self) -> None:
        for sock, held in ((self.sock, self._held), (self.trail, self._held_trail)):
            try:  # a graph stopped early: what was computed still goes out, if there is room
                for frame in held:
                    sock.send(frame, zmq.NOBLOCK)  # type: ignore[union-attr]  # no trail socket: nothing held
            except zmq.ZMQError:
                pass
            held.clear()
        self._send_runs(self.observers, self._held_observed, zmq.NOBLOCK)
        self.sock.close()
        self.observers.close()
        if self.trail is not None:
            self.trail.close()
        if self._ctx is not None:
            release_clients(self._ctx)
            self._ctx = None


_HANDSHAKE_EVENTS = (
    zmq.EVENT_HANDSHAKE_SUCCEEDED
    | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
    | zmq.EVENT_HANDSHAKE_FAILED_AUTH
    | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
)
# A handshake cut short without detail may be a publisher closing mid-handshake: stop on the third in a row.
NO_DETAIL_FAILURES = 3
RECONNECT_MS = 10  # a subscriber's wait before it tries a refused endpoint again
PEER_CHECK_S = 0.1  # recv_nowait looks at handshake failures at most this often


def monitor_event(frames: list[bytes]) -> tuple[int, bytes]:
    """(event, endpoint) of one message of a ZeroMQ socket monitor: a frame of the 16-bit event
    and its 32-bit value, then the endpoint. (pyzmq's zmq.utils.monitor reads the same, but
    importing it loads asyncio: 0.05 s of CPU in every node process with inputs.)"""
    if len(frames) != 2 or len(frames[0]) != 6:
        raise DockhilError(f"unexpected socket monitor message {frames!r}")
    event, _value = struct.unpack("=hi", frames[0])
    return event, frames[1]


class Subscriber:
    """One SUB socket connected to the endpoints of all of a node's inputs.

    An observer (a progress display, `dockhil topic echo`) is not part of the
    graph: sim time does not wait for it, and it may miss the first messages.
    It reads the publishers' observer sockets, and counts in `lost` what they
    dropped because it fell behind.

    A trailing reader (sim time: the launch's recorder) is the graph's, loses
    nothing, and takes the publishers' messages in bursts from their trailing
    sockets.

    A peer that fails the CURVE handshake is not the graph's publisher (a
    process that took its ipc path or tcp port): receiving then raises
    DockhilError, so the node stops and says so instead of waiting in silence."""

    def __init__(self, ctx: zmq.Context, observer: bool = False, trailing: bool = False):
        if observer and trailing:
            raise ValueError("a subscriber is an observer or a trailing reader, not both")
        self.trailing = trailing
        self.sock = ctx.socket(zmq.SUB)
        # A trailing reader's messages are bursts: as many frames queued at most as a member's.
        self.sock.setsockopt(zmq.RCVHWM, OBSERVER_HWM if observer else HWM // TRAIL_BURST if trailing else HWM)
        self.observer = observer
        self.lost = 0  # an observer's: messages its publishers sent it that never arrived (it fell behind)
        self.lost_on: dict[bytes, int] = {}  # topic -> of these
        self._count: dict[bytes, int] = {}  # topic -> the publisher's count in the last frame read
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"/" if observer else b"")
        # A node's publishers bind while it starts, often after its readers connect: retry a refused
        # connect every 10 ms, not ZeroMQ's default 100 ms, which sim time waits out before tick 0.
        self.sock.setsockopt(zmq.RECONNECT_IVL, RECONNECT_MS)
        self._monitor = self.sock.get_monitor_socket(_HANDSHAKE_EVENTS)
        self._failures: dict[str, int] = {}
        self._next_check = 0.0
        self._connected: set[str] = set()
        self._timeout_ms = -1

    def connect(self, endpoint: str, *, keys: GraphKeys | None) -> None:
        """Connect to a publisher of the graph with these keys (None: plain, for benchmarks only).
        The keys are taken at connect time, so one socket may listen to several graphs."""
        if endpoint not in self._connected:
            if keys is not None:
                self.sock.curve_serverkey = keys.server_public
                self.sock.curve_publickey = keys.client_public
                self.sock.curve_secretkey = keys.client_secret
            if self.observer:
                self.sock.connect(observer_endpoint(endpoint))
            else:
                self.sock.connect(trailing_endpoint(endpoint) if self.trailing else endpoint)
            self._connected.add(endpoint)

    def recv(self, timeout_s: float | None) -> list[bytes] | None:
        """The frames of one message, or None on time-out. timeout_s=None blocks."""
        # A receive time-out on the socket costs one call per message, where poll+recv costs two.
        ms = -1 if timeout_s is None else int(timeout_s * 1000)
        if ms != self._timeout_ms:
            self.sock.setsockopt(zmq.RCVTIMEO, ms)
            self._timeout_ms = ms
        try:
            return self._message(self.sock.recv())
        except zmq.Again:
            self.check_peers()
            return None

    def recv_nowait(self) -> list[bytes] | None:
        try:
            return self._message(self.sock.recv(zmq.NOBLOCK))
        except zmq.Again:
            self._peers_now_and_then()
            return None

    def _message(self, frame: bytes) -> list[bytes]:
        """A frame read alone is one message (a burst's frames are read one by one); a frame with no
        separator opens an envelope of frames ([topic, payload] or [topic, b"", tick], as `bag play`
        sends), read whole."""
        if self.observer:
            return self._observed(frame)
        if separator(frame)[0] >= 0:
            return split([frame])
        return self._rest(frame)

    def _observed(self, frame: bytes) -> list[bytes]:
        """An observer's frame as [topic, payload] (or [topic, b"", tick]); a gap in the publisher's
        count is what this observer lost."""
        i = frame.find(OBSERVED)
        j = separator(frame)[0]
        if i < 0 or 0 <= j < i:
            return split([frame]) if j >= 0 else self._rest(frame)
        topic, count = frame[:i], int.from_bytes(frame[i + 1 : i + 9], "little")
        last = self._count.get(topic)
        if last is not None and count > last + 1:  # a smaller count: the publisher started again
            self.lost += count - last - 1
            self.lost_on[topic] = self.lost_on.get(topic, 0) + count - last - 1
        self._count[topic] = count
        return [topic, frame[i + 9 :]]

    def _rest(self, first: bytes) -> list[bytes]:
        parts = [first]
        while self.sock.getsockopt(zmq.RCVMORE):
            parts.append(self.sock.recv())
        return parts

    def joined(self, frame: bytes) -> bytes:
        """The one-frame form of a message whose first frame has no separator: an envelope of
        frames (`bag play` sends [topic, payload] and [topic, b"", tick]) joined; anything else as
        it came, for the reader to count as malformed."""
        parts = self._rest(frame)
        if len(parts) == 2:
            return parts[0] + MESSAGE + parts[1]
        if len(parts) == 3 and parts[1] == b"":
            return parts[0] + EMPTY_TICK + parts[2]
        return frame

    def recv_frame(self, timeout_s: float | None) -> bytes | None:
        """One frame (a node's hot path: see `separator`), or None on time-out; a frame without a
        separator is the first of an envelope: see `joined`. (recv_multipart asks the socket after
        every frame whether more follow: 1.5 us a message.)"""
        ms = -1 if timeout_s is None else int(timeout_s * 1000)
        if ms != self._timeout_ms:
            self.sock.setsockopt(zmq.RCVTIMEO, ms)
            self._timeout_ms = ms
        try:
            return self.sock.recv()
        except zmq.Again:
            self.check_peers()
            return None

    def recv_frame_nowait(self) -> bytes | None:
        try:
            return self.sock.recv(zmq.NOBLOCK)
        except zmq.Again:
            self._peers_now_and_then()
            return None

    def _peers_now_and_then(self) -> None:
        now = time.monotonic()
        if now >= self._next_check:
            self._next_check = now + PEER_CHECK_S
            self.check_peers()

    def check_peers(self) -> None:
        """DockhilError if a peer failed the handshake: it is not the graph's publisher."""
        while self._monitor.poll(0):
            event, where = monitor_event(self._monitor.recv_multipart())
            endpoint = where.decode(errors="replace")
            if event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                self._failures.pop(endpoint, None)
                continue
            n = self._failures[endpoint] = self._failures.get(endpoint, 0) + 1
            if event != zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL or n >= NO_DETAIL_FAILURES:
                raise DockhilError(
                    f"{endpoint}: the peer there failed the graph's authentication (CURVE handshake): it is not "
                    f"this graph's publisher; another process may have taken its address. Nothing from it was read"
                )

    def close(self) -> None:
        self.sock.disable_monitor()
        self._monitor.close(linger=0)
        self.sock.close()
