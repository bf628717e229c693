"""`dockhil bag play`: a bag played onto topics, as a running graph would publish them.

Binds one publisher per recorded topic and registers them like `dockhil run`, so
`dockhil topic echo` and `dockhil bag record` find them. Wall time keeps the recorded spacing
scaled by --rate. Sim time publishes in tick order, as fast as the subscribers take the messages,
after waiting for them; ticks count from 0 at the first message played (--start and --loop
renumber the headers; otherwise the bytes are sent as recorded).
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import time
import uuid
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import msgspec

from dockhil import msgs
from dockhil.bags.format import BagError, BagMessage
from dockhil.bags.reader import BagReader
from dockhil.log import Log
from dockhil.msgs.codec import decode_header

if TYPE_CHECKING:
    from dockhil.runtime.executor import Stop
    from dockhil.runtime.transport import Publisher

_play_log = Log("dockhil bag play:").line


class _Player:
    """Publishers for the played topics, registered so that other commands find them."""

    def __init__(self, path: str, topics: dict[str, str], sim: bool):
        import zmq

        from dockhil.runtime.registry import KEY_FILE, registry_dir
        from dockhil.runtime.transport import GraphKeys, Publisher, ipc_endpoint, new_run_dir

        self.run_id = f"play-{uuid.uuid4().hex[:6]}"
        self.run_dir = new_run_dir(self.run_id)
        ctx: zmq.Context = zmq.Context.instance()
        self.pubs: dict[str, Any] = {}
        try:
            keys = GraphKeys.make()
            self.key_file = keys.write(self.run_dir / KEY_FILE)
            for topic in topics:
                pub = Publisher(ctx, topic, ipc_endpoint(self.run_dir, topic), keys=keys)
                if sim:
                    # Bounded queues that block instead of dropping: sends go as fast as subscribers take them.
                    pub.sock.setsockopt(zmq.SNDHWM, 1000)
                    pub.sock.setsockopt(zmq.XPUB_NODROP, 1)
                    pub.sock.setsockopt(zmq.SNDTIMEO, 200)
                    pub.sock.setsockopt(zmq.LINGER, 10_000)
                self.pubs[topic] = pub
        except BaseException:
            self.close()
            raise
        self.socks = dict(self.pubs)  # what is played goes to the observers too (Publisher.send_multipart)
        self.registry = registry_dir() / f"{self.run_id}.json"
        tmp = self.registry.with_suffix(".tmp")
        tmp.write_text(
            json.dumps(
                {
                    "run_id": self.run_id,
                    "pid": os.getpid(),
                    "file": f"dockhil bag play {path}",
                    "clock": "sim" if sim else "wall",
                    "keys": str(self.key_file),
                    "nodes": {"bag-play": {"type": "bag play", "pid": os.getpid()}},
                    "topics": {
                        t: {"type": topics[t], "endpoint": p.endpoint, "publisher": "bag-play"}
                        for t, p in self.pubs.items()
                    },
                },
                indent=1,
            )
        )
        tmp.replace(self.registry)

    def wait_subscribers(self, n: int, stop: Stop) -> bool:
        """Until every topic has `n` subscribers; False if stopped first."""
        if n <= 0:
            return True
        _play_log(f"waiting for {n} subscriber(s) on each of {len(self.pubs)} topics (Ctrl-C to give up)")
        hint_at: float | None = time.monotonic() + 5.0
        while True:
            short = [t for t, pub in self.pubs.items() if pub.subscribers < n]
            if not short:
                return True
            if stop.requested:
                return False
            if hint_at is not None and time.monotonic() > hint_at:
                hint_at = None
                _play_log(
                    f"still waiting for {short[0]}"
                    + (f" and {len(short) - 1} more" if len(short) > 1 else "")
                    + "; to play fewer topics give --topics, to wait for fewer subscribers --subscribers"
                )
            for topic in short:
                # A subscription is a frame starting with 1 (XPUB_VERBOSE). Unlike a graph's
                # publishers, a player counts observers (`topic echo`) too: they may be its audience.
                pub = self.pubs[topic]
                while pub.sock.poll(0) and pub.sock.recv()[:1] == b"\x01":
                    pub.subscribers += 1
                pub.subscribers += pub.look()
            time.sleep(0.01)

    def close(self) -> None:
        for pub in self.pubs.values():
            pub.close()
        if getattr(self, "registry", None) is not None:
            self.registry.unlink(missing_ok=True)
        for f in self.run_dir.iterdir():
            f.unlink(missing_ok=True)
        self.run_dir.rmdir()


def play(args: argparse.Namespace) -> int:
    """`dockhil bag play PATH [--rate R] [--loop] [--topics ...] [--start S] [--sim-time] [--subscribers N]`."""
    from dockhil.runtime.executor import Stop

    with BagReader(args.path) as reader:
        found = reader.summary()
    if found["loss"]:
        _play_log(f"warning: {found['loss']}")
    in_bag = {t["topic"]: t["type"] for t in found["topics"] if t["count"] > 0}
    if not in_bag:
        raise BagError(f"{args.path}: the bag holds no message; nothing to play")
    if args.topics:
        missing = [t for t in args.topics if t not in in_bag]
        if missing:
            raise BagError(f"{args.path}: no messages on {missing[0]}; topics in the bag: {', '.join(sorted(in_bag))}")
        topics = {t: in_bag[t] for t in args.topics}
    else:
        topics = in_bag
    # info() gives seconds; exact enough to skip S > 0 seconds, and no threshold at all for S = 0.
    first_s = min(t["first"] for t in found["topics"] if t["count"])
    last_s = max(t["last"] for t in found["topics"] if t["topic"] in topics and t["count"])
    if first_s + args.start > last_s:
        raise BagError(
            f"{args.path}: no message after --start {args.start:g} s; the bag lasts {found['duration_s']:.3f} s"
        )
    start_ns = None if args.start == 0 else int(round(first_s * 1e9)) + int(round(args.start * 1e9))
    sim = args.sim_time
    wait_for = getattr(args, "subscribers", None)
    wait_for = (1 if sim else 0) if wait_for is None else wait_for
    stop = Stop()
    stop.install()
    player = _Player(args.path, topics, sim)
    try:
        if not player.wait_subscribers(wait_for, stop):
            return 130
        started = time.perf_counter()
        passes = 0
        sent = 0
        state = _TickShift()
        while not stop.requested:
            with BagReader(args.path) as reader:
                stream = reader.messages(list(topics), start_ns=start_ns)
                if sim:
                    sent += _play_sim(_tick_order(stream), player.socks, state, stop)
                else:
                    sent += _play_wall(stream, player.socks, args.rate, stop)
            passes += 1
            if not args.loop or sent == 0:
                break
        elapsed = time.perf_counter() - started
    finally:
        player.close()
    how = "in tick order" if sim else f"at rate {args.rate:g}"
    loops = f" ({passes} passes)" if passes > 1 else ""
    _play_log(f"played {sent} messages on {len(topics)} topics {how} in {elapsed:.3f} s{loops}")
    return 130 if stop.requested else 0


def _play_wall(stream: Iterator[BagMessage], socks: dict[str, Publisher], rate: float, stop: Stop) -> int:
    sent = 0
    t0 = time.monotonic()
    origin = None
    scale = 1e-9 / rate
    sleep, monotonic = time.sleep, time.monotonic
    for topic, _type, log_ns, data in stream:
        if origin is None:
            origin = log_ns
        due = t0 + (log_ns - origin) * scale
        ahead = due - monotonic()
        while ahead > 0.001:  # batches the rest: sleeping per message would cost more than it spaces
            if stop.requested:
                return sent
            sleep(min(ahead, 0.1))
            ahead = due - monotonic()
        socks[topic].send_multipart((topic.encode(), data), copy=len(data) > 4096)
        sent += 1
        if stop.requested:
            break
    return sent


class _TickShift:
    """Renumbers ticks so that the played run starts at tick 0 and a loop continues counting."""

    def __init__(self) -> None:
        self.base_tick = 0  # tick the current pass starts at
        self.base_stamp = 0.0
        self.first: tuple[int, float] | None = None
        self.last: tuple[int, float] | None = None

    def end_pass(self) -> None:
        if self.first is None or self.last is None:
            return
        (t0, s0), (t1, s1) = self.first, self.last
        dt = (s1 - s0) / (t1 - t0) if t1 > t0 else 0.0
        self.base_tick += t1 - t0 + 1
        self.base_stamp += s1 - s0 + dt
        self.first = self.last = None


def _tick_order(stream: Iterator[BagMessage], window: int = 4096) -> Iterator[tuple[int, float, str, str, bytes]]:
    """(tick, stamp, topic, type, data) by tick. Within one tick, and for messages
    without a header, file order is kept. The window covers the skew between topics
    of a lock-step run (a few ticks), not arbitrary disorder."""
    heap: list = []
    n = 0
    last = (0, 0.0)
    for topic, type_name, _log_ns, data in stream:
        header = decode_header(data)
        key = (header.tick, header.stamp) if header is not None else last
        last = key
        heapq.heappush(heap, (key[0], n, key[1], topic, type_name, data))
        n += 1
        if len(heap) > window:
            tick, _, stamp, topic, type_name, data = heapq.heappop(heap)
            yield tick, stamp, topic, type_name, data
    while heap:
        tick, _, stamp, topic, type_name, data = heapq.heappop(heap)
        yield tick, stamp, topic, type_name, data


def _retick(data: bytes, type_name: str, tick: int, stamp: float) -> bytes | None:
    """The message with its header moved to `tick`/`stamp`; None if it does not decode."""
    from dockhil.msgs.codec import DecodeError, decode, encode

    try:
        msg = decode(data, msgs.type_by_name(type_name))
    except (DecodeError, KeyError):
        return None
    h = msg.header  # type: ignore[attr-defined]  # every message type has a header
    header = msgspec.structs.replace(h, tick=tick, seq=max(0, h.seq + tick - h.tick), stamp=max(0.0, stamp))
    return encode(msgspec.structs.replace(msg, header=header))


def _play_sim(
    ordered: Iterator[tuple[int, float, str, str, bytes]], socks: dict[str, Publisher], state: _TickShift, stop: Stop
) -> int:
    """Send in tick order. Before tick k starts, every topic is complete up to k-1: a
    topic with no message at a tick gets the transport's empty-tick frame, so that
    lock-step subscribers never wait for a tick that has no message."""
    import zmq

    def send(sock: Publisher, frames: tuple[bytes, ...]) -> bool:
        while True:
            try:
                sock.send_multipart(frames)
                return True
            except zmq.Again:  # the subscriber's queue is full: wait for it, or for Ctrl-C
                if stop.requested:
                    return False

    def complete_to(k: int) -> bool:
        for topic, sock in socks.items():
            for empty in range(done[topic] + 1, k + 1):
                if not send(sock, (topic.encode(), b"", empty.to_bytes(8, "little"))):
                    return False
            done[topic] = max(done[topic], k)
        return True

    done = {topic: state.base_tick - 1 for topic in socks}  # last tick sent per topic
    current = None
    sent = 0
    unplayable = 0
    for tick, stamp, topic, type_name, data in ordered:
        if state.first is None:
            state.first = (tick, stamp)
        state.last = (tick, stamp)
        shift = state.base_tick - state.first[0]
        played_tick = tick + shift
        if played_tick != current:
            if not complete_to(played_tick - 1):
                return sent
            current = played_tick
        if shift:
            moved = _retick(data, type_name, played_tick, stamp - state.first[1] + state.base_stamp)
            if moved is None:
                unplayable += 1
                continue
            data = moved
        if not send(socks[topic], (topic.encode(), data)):
            return sent
        done[topic] = max(done[topic], played_tick)
        sent += 1
        if stop.requested:
            return sent
    if current is not None:
        complete_to(current)
    state.end_pass()
    if unplayable:
        _play_log(f"note: {unplayable} messages could not be renumbered (not a valid message) and were not played")
    return sent
