"""bag_source: recorded topics from a bag as node outputs, a stand-in for any source.

One output per recorded topic (port name = topic name), of the recorded type,
so a launch file can swap a driver for the bag with an `if:` condition:

    args:
      ft: {default: sim, choices: [sim, bag]}
      bag: {default: "", help: "bag to replay with ft:=bag"}
    nodes:
      - {name: ft, node: ft_emulator, if: $(arg ft) == sim}
      - name: ft
        node: bag_source
        params: {path: $(arg bag), topics: [/ft/wrench]}
        if: $(arg ft) == bag

Sim time: step k emits, on every topic, the message recorded at tick k (of
tick k + start/dt with `start`), decoded and passed on unchanged, so a
recorded run's inputs replayed into the rest of the graph reproduce its
outputs bit for bit. Where the recorded run sent nothing on a topic (an
empty tick), nothing is sent; a tick past the end of the bag is an error
that says at which tick the bag ends. With `start` > 0 the headers are
renumbered to the current tick. Wall time: each step emits the newest message of each topic
whose log time (relative to the bag's first message, plus `start`) has come.
"""

from __future__ import annotations

import os
from collections import deque
from typing import Any

import msgspec

from dockhil import msgs
from dockhil.bags.format import BagError, BagMessage
from dockhil.bags.reader import BagReader
from dockhil.errors import DockhilError, ParamError
from dockhil.msgs.codec import decode_header
from dockhil.node import Node, Output, Param, Tick
from dockhil.scene.schema import MAX_DURATION

_summaries: dict[tuple, dict] = {}


def _summary(path: str) -> dict:
    """What the bag holds (one pass), cached: ports() is asked several times per run."""
    if not path:
        raise ParamError("node type bag_source needs parameter 'path': the bag to replay")
    try:
        st = os.stat(path)
        key = (os.path.abspath(path), st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    found = _summaries.get(key) if key else None
    if found is None:
        with BagReader(path) as reader:
            found = reader.summary()
        if key:
            _summaries[key] = found
    return found


def _selected(params: dict[str, Any]) -> dict[str, str]:
    """topic -> type name of the topics to replay."""
    found = _summary(params["path"])
    in_bag = {t["topic"]: t["type"] for t in found["topics"] if t["count"] > 0}
    wanted = params["topics"]
    if not all(isinstance(t, str) for t in wanted):
        raise ParamError(f"node type bag_source parameter 'topics': expected a list of topic names, got {wanted!r}")
    for topic in wanted:
        if topic not in in_bag:
            raise BagError(
                f"{params['path']}: no messages on {topic}; topics in the bag: {', '.join(sorted(in_bag)) or 'none'}"
            )
    selected = {t: in_bag[t] for t in (wanted or sorted(in_bag))}
    for topic, type_name in selected.items():
        if type_name not in msgs.TYPES:
            raise BagError(f"{params['path']}: topic {topic} has type {type_name!r}, not a dockhil message type")
    if not selected:
        raise BagError(f"{params['path']}: the bag holds no message to replay")
    return selected


class BagSource(Node):
    """Replays recorded topics from an MCAP bag: in sim time tick by tick, in wall time by time."""

    replays_recording = True

    params = {
        "path": Param(str, "", help="MCAP bag to replay"),
        "topics": Param(list, [], help="topics to replay (default: every topic in the bag)"),
        "start": Param(
            float,
            0.0,
            unit="s",
            ge=0.0,
            le=MAX_DURATION,
            help="skip the first S seconds of the bag (sim time: S/dt ticks)",
        ),
    }

    @classmethod
    def ports(cls, params):
        return {}, {
            topic: Output(msgs.TYPES[type_name], topic, help="as recorded")
            for topic, type_name in _selected(params).items()
        }

    def setup(self):
        self.types = {t: msgs.TYPES[n] for t, n in _selected(vars(self.p)).items()}
        self.found = _summary(self.p.path)
        if self.found["loss"]:  # damaged or unfinished: replay what is intact, and say so once
            self.log(f"warning: {self.found['loss']}")
        self.reader = BagReader(self.p.path)
        # Every topic is read, in sim time to know the run's last tick (topics may have empty ticks).
        self.stream = self.reader.messages(None if self.ctx.sim_time else list(self.types))
        self.last_tick_in_bag = -1
        self.queues: dict[str, deque] = {t: deque() for t in self.types}
        self.exhausted = False
        self.frontier_ns = 0  # log time of the last message read
        self.offset = int(round(self.p.start / self.ctx.dt))
        self.decoders = {t: msgspec.msgpack.Decoder(cls) for t, cls in self.types.items()}
        firsts = [t["first"] for t in self.found["topics"] if t["count"]]
        self.origin_ns = int(round(min(firsts) * 1e9))
        self.warned_stamp = False

    def _read_more(self) -> bool:
        """Queue the next message of the bag; False at its end."""
        if self.exhausted:
            return False
        message = next(self.stream, None)
        if message is None:
            self.exhausted = True
            return False
        queue = self.queues.get(message.topic)
        if self.ctx.sim_time:
            header = decode_header(message.data)
            if header is not None:
                self.last_tick_in_bag = max(self.last_tick_in_bag, header.tick)
        if queue is not None:
            queue.append(message)
        self.frontier_ns = message.log_time_ns
        return True

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        if self.ctx.sim_time:
            return {topic: self._at_tick(topic, tick) for topic in self.types}
        return self._by_time(tick)

    def _at_tick(self, topic: str, tick: Tick) -> Any:
        want = tick.index + self.offset
        queue = self.queues[topic]
        while True:
            while queue:
                message = queue[0]
                k = self._tick_of(topic, message)
                if k < want:
                    queue.popleft()
                    continue
                if k > want:
                    return None  # the recorded run sent nothing on this topic at this tick
                queue.popleft()
                return self._emit(topic, message, tick, want)
            if not self._read_more():
                if want <= self.last_tick_in_bag:
                    return None  # the topic went quiet before the end of the run
                raise DockhilError(
                    f"bag {self.p.path} has no tick {want}: it ends at tick {self.last_tick_in_bag}"
                    + (f" (start {self.p.start:g} s skips {self.offset} ticks)" if self.offset else "")
                    + "; shorten the run or record a longer bag"
                )

    def _tick_of(self, topic: str, message: BagMessage) -> int:
        header = decode_header(message.data)
        if header is None:
            raise DockhilError(
                f"bag {self.p.path}: a message on {topic} at log time {message.log_time_ns} ns has no readable header"
            )
        return header.tick

    def _decode(self, topic: str, message: BagMessage) -> Any:
        try:
            return self.decoders[topic].decode(message.data)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            raise DockhilError(
                f"bag {self.p.path}: message on {topic} at log time {message.log_time_ns} ns: {exc}"
            ) from None
        except RecursionError:
            raise DockhilError(
                f"bag {self.p.path}: message on {topic} at log time {message.log_time_ns} ns nests too deeply to decode"
            ) from None

    def _emit(self, topic: str, message: BagMessage, tick: Tick, recorded_tick: int) -> Any:
        msg = self._decode(topic, message)
        if self.offset:
            header = msgspec.structs.replace(msg.header, tick=tick.index, seq=tick.index, stamp=tick.t)
            return msgspec.structs.replace(msg, header=header)
        if not self.warned_stamp and abs(msg.header.stamp - tick.t) > 1e-9 * max(1.0, tick.t):
            self.warned_stamp = True
            self.log(
                f"note: {topic} tick {recorded_tick} was recorded at {msg.header.stamp:g} s, this scene's tick "
                f"{tick.index} is at {tick.t:g} s: was the bag recorded at another rate?"
            )
        return msg

    def _by_time(self, tick):
        due_ns = self.origin_ns + int(round((tick.t + self.p.start) * 1e9))
        # The file is in receive order: read up to the first message not yet due, no further.
        while self.frontier_ns <= due_ns and self._read_more():
            pass
        out = {}
        for topic, queue in self.queues.items():
            newest = None
            while queue and queue[0].log_time_ns <= due_ns:
                newest = queue.popleft()
            if newest is not None:
                out[topic] = self._decode(topic, newest)
        return out

    def close(self):
        reader = getattr(self, "reader", None)
        if reader is not None:
            reader.close()
