"""Reading a bag front to back: finished, unfinished or damaged (see BagReader; the format is
described in dockhil.bags.writer)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, overload

import msgspec

from dockhil.bags.format import (
    MESSAGE_HEAD,
    READ_ENCODINGS,
    U64_MAX,
    BagError,
    BagMessage,
    LostRegion,
    loss_line,
)
from dockhil.bags.records import CHANNEL, CHUNK, MESSAGE, SCHEMA, FilePass, RecordScanner, parse_definition
from dockhil.files import os_reason

if TYPE_CHECKING:
    from mcap.records import Channel, Schema


@dataclass
class _Channel:
    topic: str
    type_name: str
    encoding: str
    to_wire: Any = None  # json bytes -> msgpack bytes, for a json channel


def _json_to_wire() -> Any:
    from_json = msgspec.json.Decoder().decode
    to_msgpack = msgspec.msgpack.Encoder().encode

    def to_wire(data: bytes) -> bytes:
        try:
            return to_msgpack(from_json(data))
        except (msgspec.DecodeError, RecursionError):
            return data  # not JSON: handed on as it is, and fails to decode later with one line

    return to_wire


class BagReader:
    """Reads a bag front to back: finished, unfinished or damaged.

    A finished bag ends with a footer. An unfinished one (the recorder was
    killed, its disk filled up, the power went) ends wherever writing stopped.
    A damaged record or chunk (checksum, zeros, a bad opcode or length) is
    skipped: the reader scans forward for the next valid record (a chunk whose
    framing is consistent and whose CRC checks, or a record whose fields are
    consistent and that is followed by another record) and reads on from there.
    Every intact message is read; the messages of a damaged chunk are lost.

    After a full pass: `recovered` (no footer: unfinished), `lost` (the
    regions skipped, with the log times around them), `skipped_bytes` (their
    total), `orphaned` (messages on a channel whose definition was in a
    damaged chunk of an unfinished bag: skipped) and `chunks`.

    Messages come in file order, which is the order the recorder wrote them.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        try:
            self._file = open(self.path, "rb")
        except FileNotFoundError:
            raise BagError(f"{self.path}: no such file") from None
        except IsADirectoryError:
            raise BagError(f"{self.path}: is a directory, not an MCAP bag") from None
        except OSError as exc:
            raise BagError(f"{self.path}: cannot open: {os_reason(exc)}") from None
        # One snapshot of the size: a bag still being recorded reads as unfinished up to here.
        self.size_bytes = os.fstat(self._file.fileno()).st_size
        self._channels: dict[int, _Channel] = {}
        self._schema_names: dict[int, str] = {}
        self._summary_read = False
        self.recovered: bool | None = None  # known after a full pass
        self.lost: list[LostRegion] = []
        self.skipped_bytes = 0
        self.orphaned = 0
        self.chunks = 0
        self._scanner = RecordScanner(self._file, self.path, self.size_bytes, self._channels)
        try:
            self.profile, self.library = self._scanner.read_start()
        except BaseException:
            self._file.close()
            raise

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[BagMessage]:
        return self.messages()

    @property
    def topics(self) -> dict[str, str]:
        """topic -> type name, from the channels seen so far (all of them after a full pass)."""
        return {c.topic: c.type_name for c in self._channels.values()}

    def messages(
        self,
        topics: Iterable[str] | None = None,
        *,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[BagMessage]:
        """Messages on `topics` (all if None) with start_ns <= log time <= end_ns."""
        wanted = None if topics is None else set(topics)
        selected: dict[int, bool] = {}
        channels = self._channels
        lo = 0 if start_ns is None else start_ns
        hi = U64_MAX if end_ns is None else end_ns
        for channel_id, log_time, _, data in self._raw_messages(with_data=True):
            keep = selected.get(channel_id)
            if keep is None:
                keep = selected[channel_id] = wanted is None or channels[channel_id].topic in wanted
            if keep and lo <= log_time <= hi:
                channel = channels[channel_id]
                if channel.to_wire is not None:
                    data = channel.to_wire(data)
                yield BagMessage(channel.topic, channel.type_name, log_time, data)

    def messages_with_publish_time(self) -> Iterator[tuple[str, str, int, int, bytes]]:
        """(topic, type name, log time, publish time, wire bytes) of every message."""
        channels = self._channels
        for channel_id, log_time, publish_time, data in self._raw_messages(with_data=True):
            channel = channels[channel_id]
            if channel.to_wire is not None:
                data = channel.to_wire(data)
            yield channel.topic, channel.type_name, log_time, publish_time, data

    def decoded(self, topics: Iterable[str] | None = None, **bounds: int | None) -> Iterator[tuple[str, int, Any]]:
        """(topic, log_time_ns, msgs Struct) for each message; BagError if one does not decode."""
        from dockhil.msgs.codec import DecodeError

        checked: set[str] = set()
        for message in self.messages(topics, **bounds):
            if message.topic not in checked:
                self.check_encoding(message.topic)
                checked.add(message.topic)
            try:
                yield message.topic, message.log_time_ns, message.decode()
            except (DecodeError, KeyError) as exc:
                raise BagError(
                    f"{self.path}: message on {message.topic} at log time {message.log_time_ns} ns: {exc}"
                ) from None
            except RecursionError:
                raise BagError(
                    f"{self.path}: message on {message.topic} at log time {message.log_time_ns} ns "
                    "nests too deeply to decode"
                ) from None

    def summary(self) -> dict:
        """One pass over the file: what `info` reports (see there)."""
        counts: dict[int, list[int]] = {}  # channel id -> [count, first, last]
        for channel_id, log_time, _, _ in self._raw_messages(with_data=False):
            entry = counts.get(channel_id)
            if entry is None:
                counts[channel_id] = [1, log_time, log_time]
            else:
                entry[0] += 1
                if log_time < entry[1]:
                    entry[1] = log_time
                if log_time > entry[2]:
                    entry[2] = log_time
        topics: list[dict[str, Any]] = []
        for channel_id, channel in self._channels.items():
            count, first, last = counts.get(channel_id, (0, None, None))
            span = (last - first) / 1e9 if first is not None and last is not None else 0.0  # count > 0
            topics.append(
                {
                    "topic": channel.topic,
                    "type": channel.type_name,
                    "encoding": channel.encoding,
                    "count": count,
                    "first": None if first is None else first / 1e9,
                    "last": None if last is None else last / 1e9,
                    # Over the topic's own span: a topic that starts late is not diluted.
                    "rate_hz": (count - 1) / span if count > 1 and span > 0 else 0.0,
                }
            )
        topics.sort(key=lambda t: t["topic"])
        firsts = [v[1] for v in counts.values()]
        lasts = [v[2] for v in counts.values()]
        start = min(firsts) / 1e9 if firsts else None
        end = max(lasts) / 1e9 if lasts else None
        found = {
            "path": self.path,
            "size_bytes": self.size_bytes,
            "recovered": bool(self.recovered),
            "skipped_bytes": self.skipped_bytes,
            "lost": [
                {
                    "offset": r.offset,
                    "bytes": r.length,
                    "after": None if r.after_ns is None else r.after_ns / 1e9,
                    "before": None if r.before_ns is None else r.before_ns / 1e9,
                    "at_end": r.at_end,
                }
                for r in self.lost
            ],
            "orphaned": self.orphaned,
            "library": self.library,
            "messages": sum(v[0] for v in counts.values()),
            "chunks": self.chunks,
            "start": start,
            "end": end,
            "duration_s": (end - start) if start is not None and end is not None else 0.0,  # firsts
            "topics": topics,
        }
        found["loss"] = loss_line(found)
        return found

    def metadata(self) -> list[tuple[str, dict[str, str]]]:
        """(name, str -> str) of each metadata record, in file order. Reads record heads only
        (chunks are stepped over, not decompressed); a damaged stretch is skipped as in a full pass."""
        return self._scanner.metadata()

    def check_encoding(self, topic: str) -> None:
        """BagError, in one line, if `topic` is stored in an encoding dockhil does not read."""
        for channel in self._channels.values():
            if channel.topic == topic and channel.encoding not in READ_ENCODINGS:
                raise BagError(
                    f"{self.path}: topic {topic} is encoded as {channel.encoding!r}; "
                    f"dockhil reads {' or '.join(READ_ENCODINGS)}"
                )

    # The file, record by record (dockhil.bags.records). ---------------------

    def _records(self, run: FilePass) -> Iterator[tuple[int, int, Any]]:
        """The file's records (`RecordScanner.records`); once all are read, what the pass found."""
        yield from self._scanner.records(run)
        self.recovered = not run.finished
        self.lost = run.lost
        self.skipped_bytes = sum(r.length for r in run.lost)
        self.orphaned = run.orphaned
        self.chunks = run.chunks

    @overload
    def _raw_messages(self, with_data: Literal[True]) -> Iterator[tuple[int, int, int, bytes]]: ...
    @overload
    def _raw_messages(self, with_data: Literal[False]) -> Iterator[tuple[int, int, int, None]]: ...
    def _raw_messages(self, with_data: bool) -> Iterator[tuple[int, int, int, bytes | None]]:
        """(channel id, log time, publish time, data as stored) in file order; registers
        schemas and channels on the way."""
        unpack_head = MESSAGE_HEAD.unpack_from
        channels = self._channels
        run = FilePass()
        for _pos, opcode, content in self._records(run):
            if opcode == CHUNK:
                run.chunks += 1
                records, index = content
                if run.waiting:
                    self._close_waiting(run, [unpack_head(records, a)[2] for op, a, _ in index if op == MESSAGE])
                top = run.top_ns if run.top_ns is not None else -1
                for op, a, b in index:
                    if op != MESSAGE:
                        self._define(a)
                        continue
                    channel_id, _, log_time, publish_time = unpack_head(records, a)
                    if log_time > top:
                        top = log_time
                    if channel_id not in channels and not self._recover_channel(channel_id):
                        run.orphaned += 1
                        continue
                    yield channel_id, log_time, publish_time, records[a + 22 : b] if with_data else None
                if top >= 0:
                    run.top_ns = top
            elif opcode == MESSAGE:  # unchunked files from other writers
                channel_id, _, log_time, publish_time = unpack_head(content, 0)
                run.bare = True
                if run.waiting:
                    self._close_waiting(run, [log_time])
                if run.top_ns is None or log_time > run.top_ns:
                    run.top_ns = log_time
                if channel_id not in channels and not self._recover_channel(channel_id):
                    run.orphaned += 1
                    continue
                yield channel_id, log_time, publish_time, content[22:] if with_data else None
            elif opcode == SCHEMA or opcode == CHANNEL:
                self._define(parse_definition(opcode, content))

    @staticmethod
    def _close_waiting(run: FilePass, log_times: list[int]) -> None:
        if log_times:
            first = min(log_times)
            for i in run.waiting:
                run.lost[i] = run.lost[i]._replace(before_ns=first)
            run.waiting = []

    def _define(self, record: Schema | Channel) -> None:
        from mcap.records import Schema

        if isinstance(record, Schema):
            if record.id != 0:
                self._schema_names[record.id] = record.name
        else:
            self._channels[record.id] = _Channel(
                record.topic,
                self._schema_names.get(record.schema_id, ""),
                record.message_encoding,
                _json_to_wire() if record.message_encoding == "json" else None,
            )

    def _recover_channel(self, channel_id: int) -> bool:
        """A channel defined in a damaged chunk: a finished bag repeats every
        definition in its summary section. True if the channel is known now."""
        if not self._summary_read:
            self._summary_read = True
            try:
                for record in self._scanner.summary_definitions():
                    self._define(record)
            except Exception:  # a damaged summary: the channel stays unknown
                pass
        return channel_id in self._channels
