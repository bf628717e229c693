"""Reading a bag front to back: finished, unfinished or damaged (see BagReader; the format is
described in dockhil.bags.writer)."""

from __future__ import annotations

import io
import os
import re
import struct
import zlib
from dataclasses import dataclass
from typing import Any, Iterable, Iterator

import msgspec

from dockhil.bags.format import (
    MAGIC,
    MESSAGE_HEAD,
    READ_ENCODINGS,
    RECORD_HEAD,
    U64_MAX,
    BagError,
    BagMessage,
    LostRegion,
    loss_line,
)
from dockhil.files import os_reason

# MCAP opcodes (spec "Records"); 0x80-0xFF are reserved for user records.
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _METADATA, _DATA_END = (
    0x01,
    0x02,
    0x03,
    0x04,
    0x05,
    0x06,
    0x07,
    0x0C,
    0x0F,
)
_KNOWN_OPCODES = frozenset(range(0x01, 0x10))
# Where a damaged stretch may end: an MCAP opcode, then a length below 2**40 (its top
# three bytes zero). Zero-width, so that overlapping candidates are all found.
_CANDIDATE = re.compile(rb"(?=[\x02-\x0f][\x00-\xff]{5}\x00\x00\x00)")
_COMPRESSIONS_READ = {b"zstd": "zstd", b"lz4": "lz4", b"": ""}
_MAX_CHUNK = 1 << 30  # uncompressed bytes; a larger size field is damage
_MAX_DEFINITION = 1 << 24  # a schema or channel found while scanning damaged bytes
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length


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


class _Pass:
    """What one pass over the file found; handed to the reader when the pass ends."""

    def __init__(self) -> None:
        self.chunks = 0
        self.lost: list[LostRegion] = []
        self.orphaned = 0  # messages whose channel definition was lost
        self.bare = False  # a message outside any chunk was read: the file is not chunked
        self.top_ns: int | None = None  # largest log time read so far
        self.waiting: list[int] = []  # regions (index in lost) whose before_ns is the next chunk's first log time


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
        try:
            self.profile, self.library = self._read_start()
        except BaseException:
            self._file.close()
            raise

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "BagReader":
        return self

    def __exit__(self, *exc_info) -> None:
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

    def decoded(self, topics: Iterable[str] | None = None, **bounds) -> Iterator[tuple[str, int, Any]]:
        """(topic, log_time_ns, msgs Struct) for each message; BagError if one does not decode."""
        from dockhil.msgs.codec import DecodeError

        checked: set[str] = set()
        for message in self.messages(topics, **bounds):
            if message.topic not in checked:
                self._check_encoding(message.topic)
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
        topics = []
        for channel_id, channel in self._channels.items():
            count, first, last = counts.get(channel_id, (0, None, None))
            span = (last - first) / 1e9 if count else 0.0
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
            "duration_s": (end - start) if firsts else 0.0,
            "topics": topics,
        }
        found["loss"] = loss_line(found)
        return found

    def metadata(self) -> list[tuple[str, dict[str, str]]]:
        """(name, str -> str) of each metadata record, in file order. Reads record heads only
        (chunks are stepped over, not decompressed); a damaged stretch is skipped as in a full pass."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Metadata

        f, size = self._file, self.size_bytes
        found: list[tuple[str, dict[str, str]]] = []
        pos = self._data_start
        run = _Pass()
        while pos + 9 <= size:
            f.seek(pos)
            opcode, length = RECORD_HEAD.unpack(f.read(9))
            if opcode == _FOOTER or opcode == _DATA_END:
                break
            if opcode == _HEADER or not (opcode in _KNOWN_OPCODES or opcode >= 0x80) or length > size - pos - 9:
                pos = self._resync(pos + 1, run)
                continue
            if opcode == _METADATA:
                body = f.read(length)
                try:
                    stream = ReadDataStream(io.BytesIO(body))
                    record = Metadata.read(stream)
                    if stream.count == len(body):
                        found.append((record.name, dict(record.metadata)))
                except Exception:  # a damaged record: as if it were not there
                    pass
            pos += 9 + length
        return found

    def _check_encoding(self, topic: str) -> None:
        for channel in self._channels.values():
            if channel.topic == topic and channel.encoding not in READ_ENCODINGS:
                raise BagError(
                    f"{self.path}: topic {topic} is encoded as {channel.encoding!r}; "
                    f"dockhil reads {' or '.join(READ_ENCODINGS)}"
                )

    # The file, record by record. -----------------------------------------

    def _read_start(self) -> tuple[str, str]:
        f, size = self._file, self.size_bytes
        if size == 0:
            raise BagError(f"{self.path}: empty file (0 bytes), not an MCAP bag")
        head = f.read(16)
        if not head.startswith(MAGIC[: len(head)]):
            what = _guess_format(head)
            raise BagError(f"{self.path}: not an MCAP bag ({what})")
        if size < len(MAGIC) + 9:
            raise BagError(f"{self.path}: truncated: {size} bytes end inside the MCAP header; nothing was recorded")
        f.seek(len(MAGIC))
        opcode, length = RECORD_HEAD.unpack(f.read(9))
        problem = None
        if opcode != _HEADER:
            problem = f"corrupt: the first record is opcode 0x{opcode:02x}, not the MCAP header"
        elif length > size - len(MAGIC) - 9:
            problem = f"truncated: {size} bytes end inside the MCAP header; nothing was recorded"
        else:
            try:
                body = f.read(length)
                (n,) = struct.unpack_from("<I", body, 0)
                profile = body[4 : 4 + n].decode()
                (m,) = struct.unpack_from("<I", body, 4 + n)
                library = body[8 + n : 8 + n + m].decode()
            except (struct.error, UnicodeDecodeError):
                problem = "corrupt MCAP header"
        if problem is None:
            self._data_start = len(MAGIC) + 9 + length
            return profile, library
        # A damaged header: what follows may be whole. Read on if a valid record comes
        # (the header is then a lost region like any other), else say what is wrong.
        self._data_start = len(MAGIC)
        if self._resync(len(MAGIC) + 1, _Pass()) >= size:
            raise BagError(f"{self.path}: {problem}")
        return "", ""

    def _records(self, run: _Pass) -> Iterator[tuple[int, int, Any]]:
        """(offset, opcode, content) of each valid record after the header; damaged
        stretches are skipped and noted in `run`. Content: for a chunk its
        decompressed records and their index (see `_chunk`), for a message,
        schema or channel its body, else None. Hands `run` to the reader when done."""
        size = self.size_bytes
        pos = self._data_start
        finished = False
        while pos < size:
            found = self._record_at(pos, run, resync=False)
            if found is None:
                resume = self._resync(pos + 1, run)
                self._lose(run, pos, resume)
                pos = resume
                continue
            opcode, length, content = found
            yield pos, opcode, content
            pos += 9 + length
            if opcode == _FOOTER:
                self._file.seek(pos)
                finished = self._file.read(len(MAGIC)) == MAGIC
                break
        self.recovered = not finished
        self.lost = run.lost
        self.skipped_bytes = sum(r.length for r in run.lost)
        self.orphaned = run.orphaned
        self.chunks = run.chunks

    def _lose(self, run: _Pass, start: int, end: int) -> None:
        run.waiting.append(len(run.lost))
        run.lost.append(LostRegion(start, end - start, run.top_ns, None, end >= self.size_bytes))

    def _record_at(self, pos: int, run: _Pass, resync: bool) -> tuple[int, int, Any] | None:
        """(opcode, body length, content) of a valid record at `pos`, else None.

        `resync`: `pos` was found by scanning damaged bytes, so more is asked of
        the record: a known MCAP opcode (not a user one), and unless it is a
        chunk with a CRC, the record after it must start plausibly too.
        """
        f, size = self._file, self.size_bytes
        f.seek(pos)
        head = f.read(9)
        if len(head) < 9:
            return None
        opcode, length = RECORD_HEAD.unpack(head)
        if length > size - pos - 9 or opcode == _HEADER:
            return None
        if not (opcode in _KNOWN_OPCODES or (opcode >= 0x80 and not resync)):
            return None
        content = None
        checked = False  # True: a CRC vouches for the record
        try:
            if opcode == _CHUNK:
                content, checked = self._chunk(pos, length)
            elif opcode in (_MESSAGE, _SCHEMA, _CHANNEL):
                if resync and length > _MAX_DEFINITION and opcode != _MESSAGE:
                    return None
                content = f.read(length)
                if opcode == _MESSAGE:
                    if length < MESSAGE_HEAD.size:
                        return None
                    # Unless the file is known to be unchunked, a bare message found by
                    # scanning is one of a damaged (uncompressed) chunk's own records.
                    known = MESSAGE_HEAD.unpack_from(content)[0] in self._channels
                    if resync and (run.chunks or not run.bare or not known):
                        return None
                else:
                    _parse_definition(opcode, content)
            elif opcode == _MESSAGE_INDEX:
                if length < 6:
                    return None
                (n,) = struct.unpack("<I", f.read(6)[2:])
                if 6 + n != length or n % 16:
                    return None
            elif opcode == _DATA_END and length != 4 or opcode == _FOOTER and length != 20:
                return None
        except Exception:  # struct, UTF-8, zstandard and lz4 errors alike: the record is damaged
            return None
        if resync and not checked and not self._followed_plausibly(pos + 9 + length, opcode):
            return None
        return opcode, length, content

    def _followed_plausibly(self, pos: int, opcode: int) -> bool:
        f, size = self._file, self.size_bytes
        f.seek(pos)
        if opcode == _FOOTER:
            return f.read(len(MAGIC)) == MAGIC
        head = f.read(9)
        if len(head) < 9:  # the end of the file, or a cut record head
            return True
        next_opcode, length = RECORD_HEAD.unpack(head)
        return next_opcode in _KNOWN_OPCODES and next_opcode != _HEADER and length <= size - pos - 9

    def _resync(self, start: int, run: _Pass) -> int:
        """Offset of the first valid record at or after `start`, or the file size."""
        f, size = self._file, self.size_bytes
        window = 1 << 20
        at = start
        while at < size:
            f.seek(at)
            block = f.read(window + 8)
            for match in _CANDIDATE.finditer(block, 0, window + 8):
                if match.start() >= window:
                    break  # the next window looks at it again, with all its bytes
                if self._record_at(at + match.start(), run, resync=True) is not None:
                    return at + match.start()
            at += window
        return size

    def _chunk(self, pos: int, length: int) -> tuple[tuple[bytes, list], bool]:
        """(records, index) of the chunk record at `pos` and whether a CRC vouches for it.

        index: (opcode, start, end) of each message record in `records`, and
        (opcode, parsed record, 0) of each schema and channel. Raises unless the
        chunk's framing, compression, size and CRC all agree.
        """
        f = self._file
        f.seek(pos + 9)
        body = f.read(min(length, _CHUNK_HEAD.size + 8 + 4))
        start, end, size, crc, name_length = _CHUNK_HEAD.unpack_from(body, 0)
        compression = _COMPRESSIONS_READ.get(body[_CHUNK_HEAD.size : _CHUNK_HEAD.size + name_length])
        offset = _CHUNK_HEAD.size + name_length
        if compression is None or start > end or size > _MAX_CHUNK:
            raise ValueError("implausible chunk header")
        (data_length,) = struct.unpack_from("<Q", body, offset)
        if offset + 8 + data_length != length:
            raise ValueError("chunk framing does not add up to its record length")
        f.seek(pos + 9 + offset + 8)
        data = f.read(data_length)
        if compression == "zstd":
            import zstandard

            records = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == "lz4":
            import lz4.frame

            records = lz4.frame.decompress(data)
        else:
            records = data
        if len(records) != size:
            raise ValueError("chunk size mismatch")
        if crc != 0 and zlib.crc32(records) != crc:
            raise ValueError("chunk checksum mismatch")
        index: list[tuple[int, Any, int]] = []
        unpack_head = RECORD_HEAD.unpack_from
        i = 0
        while i < size:
            op, n = unpack_head(records, i)
            a, b = i + 9, i + 9 + n
            if b > size:
                raise ValueError("a record runs past the chunk end")
            if op == _MESSAGE:
                if n < MESSAGE_HEAD.size:
                    raise ValueError("a message record is too short")
                index.append((op, a, b))
            elif op == _SCHEMA or op == _CHANNEL:
                index.append((op, _parse_definition(op, records[a:b]), 0))
            i = b
        return (records, index), crc != 0

    def _raw_messages(self, with_data: bool) -> Iterator[tuple[int, int, int, bytes | None]]:
        """(channel id, log time, publish time, data as stored) in file order; registers
        schemas and channels on the way."""
        unpack_head = MESSAGE_HEAD.unpack_from
        channels = self._channels
        run = _Pass()
        for _pos, opcode, content in self._records(run):
            if opcode == _CHUNK:
                run.chunks += 1
                records, index = content
                if run.waiting:
                    self._close_waiting(run, [unpack_head(records, a)[2] for op, a, _ in index if op == _MESSAGE])
                top = run.top_ns if run.top_ns is not None else -1
                for op, a, b in index:
                    if op != _MESSAGE:
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
            elif opcode == _MESSAGE:  # unchunked files from other writers
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
            elif opcode == _SCHEMA or opcode == _CHANNEL:
                self._define(_parse_definition(opcode, content))

    @staticmethod
    def _close_waiting(run: _Pass, log_times: list[int]) -> None:
        if log_times:
            first = min(log_times)
            for i in run.waiting:
                run.lost[i] = run.lost[i]._replace(before_ns=first)
            run.waiting = []

    def _define(self, record) -> None:
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
                for record in self._summary_definitions():
                    self._define(record)
            except Exception:  # a damaged summary: the channel stays unknown
                pass
        return channel_id in self._channels

    def _summary_definitions(self) -> Iterator[Any]:
        f, size = self._file, self.size_bytes
        footer_at = size - len(MAGIC) - 9 - 20
        if footer_at < self._data_start:
            return
        f.seek(footer_at)
        tail = f.read(9 + 20 + len(MAGIC))
        opcode, length, summary_start = struct.unpack_from("<BQQ", tail, 0)
        if opcode != _FOOTER or length != 20 or tail[29:] != MAGIC or not self._data_start <= summary_start < footer_at:
            return
        pos = summary_start
        while pos < footer_at:
            f.seek(pos)
            opcode, length = RECORD_HEAD.unpack(f.read(9))
            if length > footer_at - pos - 9:
                return
            if opcode == _SCHEMA or opcode == _CHANNEL:
                yield _parse_definition(opcode, f.read(length))
            pos += 9 + length


def _parse_definition(opcode: int, body: bytes):
    """A schema or channel record, parsed; ValueError unless its fields fill the body exactly."""
    from mcap.data_stream import ReadDataStream
    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Schema

    stream = ReadDataStream(io.BytesIO(body))
    try:
        record = (Schema if opcode == _SCHEMA else Channel).read(stream)
    except EndOfFile:
        raise ValueError("a schema or channel record is cut short") from None
    if stream.count != len(body):
        raise ValueError("a schema or channel record has bytes to spare")
    return record


def _guess_format(head: bytes) -> str:
    if head.startswith(b"#ROSBAG"):
        return "it is a ROS 1 bag"
    if head.startswith(b"SQLite format 3"):
        return "it is an SQLite database, e.g. a ROS 2 .db3 bag"
    return "it does not start with the MCAP magic bytes"
