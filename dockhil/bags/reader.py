"""MCAP bags: record the messages of topics, read them back, even unfinished or damaged.

A bag is an MCAP file (https://mcap.dev) that standard MCAP tools and viewers
(Foxglove, PlotJuggler) open:

- one schema per message type: name "dockhil/WrenchStamped" etc., encoding
  "jsonschema", data a self-contained JSON Schema of the msgspec Struct
  (top-level "type": "object", every $ref inlined: `channel_schema`);
- one channel per topic, message encoding "json";
- each message is its wire msgpack transcoded to JSON (msgspec, field for
  field; a non-finite float, which JSON cannot hold, becomes null). Bytes
  that are not msgpack cannot be JSON: they are counted
  (`BagWriter.messages_unencodable`), not written.

The bus stays msgpack, and `BagReader` hands back msgpack wire bytes whatever
the bag holds, so replay sends what was recorded. Bags recorded before (channels
encoded "msgpack") are read as they are; `dockhil bag convert` rewrites one.

Times: log and publish times are integer nanoseconds since the Unix epoch
(1970-01-01T00:00:00Z), as MCAP expects. A wall-time run logs the receive time
(time.time_ns()). A sim-time run logs the message's sim time: sim time t [s]
is t * 1e9 ns after the epoch, so a sim-time bag starts at 1970-01-01
00:00:00 in a viewer and the same run recorded twice gives the same bag.

Chunks are small (64 KiB or 0.5 s, whichever comes first) and each is handed
to the OS as soon as it is complete. A recorder killed with SIGKILL therefore
leaves a file without footer or summary whose complete chunks `BagReader`
reads back; only the chunk being filled at the moment of the kill is lost.

    with BagWriter("run.mcap") as bag:
        bag.add_topic("/ft/wrench", "dockhil/WrenchStamped")
        bag.write("/ft/wrench", log_time_ns, publish_time_ns, wire_bytes)

    for topic, type_name, log_time_ns, data in BagReader("run.mcap"):
        ...
    info("run.mcap")  # topics, counts, start/end, duration, rates, recovered, lost

A damaged bag (a bad CRC, zeros over a chunk, a bad opcode or length, a
chunk torn by a power cut) is read all the same: the reader skips the
damaged record or chunk, resumes at the next valid one and keeps every
intact message; `info` lists the regions skipped with the log times around
them and `loss_line` says it in one line.

Every failure a user can cause (unwritable path, full disk, a file that is
not a bag) raises `BagError` with one line that says what and where.
"""

from __future__ import annotations

import csv
import io
import json
import operator
import os
import re
import struct
import time
import zlib
from dataclasses import dataclass
from typing import IO, Any, Iterable, Iterator, NamedTuple

import msgspec

from dockhil.errors import DockhilError
from dockhil.files import complete_or_nothing, os_reason

MAGIC = b"\x89MCAP0\r\n"
MESSAGE_ENCODING = "json"  # what BagWriter records
READ_ENCODINGS = ("json", "msgpack")  # what BagReader decodes; msgpack: bags recorded before json
SCHEMA_ENCODING = "jsonschema"
COMPRESSIONS = ("zstd", "lz4", "none")

# MCAP opcodes (spec "Records"); 0x80-0xFF are reserved for user records.
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _DATA_END = (
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x0F
)
_KNOWN_OPCODES = frozenset(range(0x01, 0x10))
# Where a damaged stretch may end: an MCAP opcode, then a length below 2**40 (its top
# three bytes zero). Zero-width, so that overlapping candidates are all found.
_CANDIDATE = re.compile(rb"(?=[\x02-\x0f][\x00-\xff]{5}\x00\x00\x00)")
_COMPRESSIONS_READ = {b"zstd": "zstd", b"lz4": "lz4", b"": ""}
_MAX_CHUNK = 1 << 30  # uncompressed bytes; a larger size field is damage
_MAX_DEFINITION = 1 << 24  # a schema or channel found while scanning damaged bytes
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, body length
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_U64 = 2**64 - 1
# Size of a message record in a chunk besides its data: opcode, length, _MESSAGE_HEAD.
_MESSAGE_OVERHEAD = 9 + _MESSAGE_HEAD.size


class BagError(DockhilError):
    """A bag cannot be written or read: the message names the file and the reason."""


# --------------------------------------------------------------------------- writing


class BagWriter:
    """Writes an MCAP bag: call `add_topic` once per topic, then `write` the wire bytes.

    `chunk_size` [bytes] and `chunk_seconds` [s, wall clock] bound a chunk, and so
    what a crash of the recording process can lose. `flush()` closes the chunk
    being filled now (a logger with a quiet topic may call it on a timer).
    An existing file is refused unless `overwrite` is true.

    Any OSError while writing (full disk, removed device) raises BagError once
    and leaves the writer stopped: later `write` calls raise the same error and
    `close()` only releases the file. What reached the disk before stays
    readable by `BagReader` as an unfinished bag.
    """

    def __init__(
        self,
        path: str | os.PathLike | IO[bytes],
        *,
        chunk_size: int = 64 * 1024,
        chunk_seconds: float = 0.5,
        compression: str = "zstd",
        overwrite: bool = False,
    ):
        from mcap.writer import CompressionType, Writer

        from dockhil import __version__

        if compression not in COMPRESSIONS:
            raise BagError(f"unknown bag compression {compression!r}; choose one of {', '.join(COMPRESSIONS)}")
        if not chunk_size > 0 or not chunk_seconds > 0:
            raise BagError(f"chunk_size and chunk_seconds must be > 0, got {chunk_size!r} and {chunk_seconds!r}")
        if hasattr(path, "write"):
            self.path = str(getattr(path, "name", "<stream>"))
            self._file = path
            self._owns_file = False
        else:
            self.path = os.fspath(path)
            self._file = _open_for_writing(self.path, overwrite)
            self._owns_file = True
        self._chunk_size = int(chunk_size)
        self._chunk_seconds = float(chunk_seconds)
        self._chunk_opened: float | None = None  # monotonic time of the first message of the open chunk
        self._pending = 0  # bytes in the open chunk
        self._channels: dict[str, tuple[int, str]] = {}  # topic -> (channel id, type name)
        self._schemas: dict[str, int] = {}  # type name -> schema id
        self._sequence: dict[int, int] = {}
        self._from_wire = msgspec.msgpack.Decoder().decode
        self._to_json = msgspec.json.Encoder().encode
        self._failed: BagError | None = None
        self._closed = False
        self.messages_written = 0
        self.messages_flushed = 0  # in complete chunks handed to the OS: they survive a kill
        self.messages_unencodable = 0  # not msgpack (or no JSON for them): not written
        self._writer = Writer(
            self._file,
            # Chunks are closed here, by bytes and by time, so that each one is
            # flushed to the OS; the library's own size limit is never reached.
            chunk_size=2**62,
            compression={
                "zstd": CompressionType.ZSTD,
                "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE,
            }[compression],
        )
        try:
            self._writer.start(profile="", library=f"dockhil {__version__}")
            # The header on disk at once: a bag killed before its first chunk is still a bag.
            self._file.flush()
        except OSError as exc:
            self._release()
            raise BagError(f"cannot start bag {self.path}: {os_reason(exc)}") from None

    @property
    def topics(self) -> dict[str, str]:
        """topic -> type name of the topics added so far."""
        return {topic: type_name for topic, (_, type_name) in self._channels.items()}

    def add_topic(self, topic: str, type_name: str) -> None:
        """Declare a topic and its message type (a key of msgs.TYPES); adding it again is a no-op."""
        from dockhil.msgs import TYPES

        if not isinstance(topic, str) or not topic:
            raise BagError(f"bag {self.path}: a topic must be a non-empty string, got {topic!r}")
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != type_name:
                raise BagError(f"bag {self.path}: topic {topic} is already recorded as {known[1]}, not {type_name}")
            return
        cls = TYPES.get(type_name)
        if cls is None:
            raise BagError(
                f"bag {self.path}: topic {topic} has unknown message type {type_name!r}; "
                f"known: {', '.join(sorted(TYPES))}"
            )
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            data = json.dumps(channel_schema(cls), separators=(",", ":")).encode()
            schema_id = self._writer.register_schema(name=type_name, encoding=SCHEMA_ENCODING, data=data)
            self._schemas[type_name] = schema_id
            self._pending += len(data)
        channel_id = self._writer.register_channel(topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id)
        self._channels[topic] = (channel_id, type_name)
        self._sequence[channel_id] = 0

    def write(self, topic: str, log_time_ns: int, publish_time_ns: int, data: bytes) -> None:
        """Append one message given as its wire (msgpack) bytes, times in integer ns.

        Bytes that are not msgpack, or hold what JSON cannot (msgpack extension
        types), are counted in `messages_unencodable` and not written."""
        if self._failed is not None:
            raise self._failed
        if self._closed:
            raise BagError(f"bag {self.path} is closed")
        known = self._channels.get(topic)
        if known is None:
            raise BagError(f"bag {self.path}: topic {topic} was not added; call add_topic(topic, type) first")
        # Checked before the library sees them: a bad value mid-record would corrupt the chunk.
        try:
            log_time_ns = operator.index(log_time_ns)
            publish_time_ns = operator.index(publish_time_ns)
        except TypeError:
            log_time_ns = -1
        if not (0 <= log_time_ns <= _U64 and 0 <= publish_time_ns <= _U64):
            raise BagError(f"bag {self.path}: topic {topic}: times must be integer ns in [0, 2**64), got {log_time_ns!r}")
        try:
            data = self._to_json(self._from_wire(data))
        except (msgspec.DecodeError, msgspec.EncodeError, TypeError, ValueError, RecursionError):
            self.messages_unencodable += 1
            return
        channel_id = known[0]
        sequence = self._sequence[channel_id]
        self._sequence[channel_id] = (sequence + 1) & 0xFFFFFFFF
        self._writer.add_message(channel_id, log_time_ns, data, publish_time_ns, sequence)
        self.messages_written += 1
        if self._chunk_opened is None:
            self._chunk_opened = time.monotonic()
        self._pending += _MESSAGE_OVERHEAD + len(data)
        if self._pending >= self._chunk_size or time.monotonic() - self._chunk_opened >= self._chunk_seconds:
            self.flush()

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS (not fsync: it survives a crash
        of this process, not a power cut)."""
        if self._failed is not None:
            raise self._failed
        if self._closed:
            return
        try:
            self._writer.flush()
        except OSError as exc:
            raise self._stop(exc, "writing") from None
        self._pending = 0
        self._chunk_opened = None
        self.messages_flushed = self.messages_written

    def close(self) -> None:
        """Write the last chunk, the summary and the footer; then fsync and close."""
        if self._closed:
            return
        self._closed = True
        if self._failed is not None:
            self._release()
            return
        try:
            self._writer.finish()
            self._file.flush()
            if self._owns_file:
                os.fsync(self._file.fileno())
                self._file.close()
        except OSError as exc:
            error = self._stop(exc, "finishing")
            self._release()
            raise error from None
        self.messages_flushed = self.messages_written

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def _stop(self, exc: OSError, doing: str) -> BagError:
        self._failed = BagError(
            f"bag {self.path}: {doing} failed: {os_reason(exc)}; recording stopped, "
            f"{self.messages_flushed} of {self.messages_written} messages are on disk"
        )
        return self._failed

    def _release(self) -> None:
        # The writer has failed: closing may retry a write that fails again.
        if self._owns_file:
            try:
                self._file.close()
            except OSError:
                pass


def channel_schema(cls: type) -> dict:
    """The JSON Schema of a message type, self-contained for a bag's channel.

    msgspec gives {"$ref": "#/$defs/X", "$defs": {...}}; viewers want the
    message's own object at the top ("type": "object"), so every $ref is
    inlined. A type that contains itself keeps $ref to "#/$defs/..." for the
    inner occurrences, with the $defs they need.
    """
    from dockhil.msgs.codec import schema

    found = schema(cls)
    defs = found.get("$defs", {})
    kept: dict[str, bool] = {}  # definitions referred to from inside themselves

    def inline(node: Any, path: tuple[str, ...]) -> Any:
        if isinstance(node, list):
            return [inline(item, path) for item in node]
        if not isinstance(node, dict):
            return node
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            name = ref[len("#/$defs/"):]
            siblings = {k: inline(v, path) for k, v in node.items() if k not in ("$ref", "$defs")}
            if name in path:  # recursion: leave a reference
                kept[name] = True
                return node
            return {**inline(defs[name], path + (name,)), **siblings}
        return {key: inline(value, path) for key, value in node.items() if key != "$defs"}

    out = inline(found, ())
    if kept:
        done: dict[str, Any] = {}
        while len(done) < len(kept):  # inlining a kept definition may keep another
            for name in [n for n in kept if n not in done]:
                done[name] = inline(defs[name], (name,))
        out["$defs"] = done
    return out


def _open_for_writing(path: str, overwrite: bool):
    try:
        return open(path, "wb" if overwrite else "xb")
    except FileExistsError:
        if os.path.isdir(path):
            raise BagError(f"cannot create bag {path}: it is a directory") from None
        raise BagError(f"bag {path} already exists; choose another name or allow overwriting it") from None
    except IsADirectoryError:
        raise BagError(f"cannot create bag {path}: it is a directory") from None
    except OSError as exc:
        raise BagError(f"cannot create bag {path}: {os_reason(exc)}") from None


# --------------------------------------------------------------------------- reading


class BagMessage(NamedTuple):
    """One recorded message: its topic, type name, log time [ns] and wire bytes."""

    topic: str
    type_name: str
    log_time_ns: int
    data: bytes

    def decode(self):
        """The message as its msgs Struct (typed, validated); DecodeError if it is not one."""
        from dockhil.msgs import type_by_name
        from dockhil.msgs.codec import decode

        return decode(self.data, type_by_name(self.type_name))


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


class LostRegion(NamedTuple):
    """Bytes of a bag that could not be read: a damaged record or chunk, or a cut end."""

    offset: int  # first byte skipped
    length: int  # bytes skipped
    after_ns: int | None  # largest log time read before it (None: no message before)
    before_ns: int | None  # smallest log time of the first chunk read after it (None: no message after)
    at_end: bool  # nothing readable follows: the recorder stopped while writing, or a power cut


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
        hi = _U64 if end_ns is None else end_ns
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
        opcode, length = _RECORD_HEAD.unpack(f.read(9))
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
        opcode, length = _RECORD_HEAD.unpack(head)
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
                    if length < _MESSAGE_HEAD.size:
                        return None
                    # Unless the file is known to be unchunked, a bare message found by
                    # scanning is one of a damaged (uncompressed) chunk's own records.
                    known = _MESSAGE_HEAD.unpack_from(content)[0] in self._channels
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
        next_opcode, length = _RECORD_HEAD.unpack(head)
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
        unpack_head = _RECORD_HEAD.unpack_from
        i = 0
        while i < size:
            op, n = unpack_head(records, i)
            a, b = i + 9, i + 9 + n
            if b > size:
                raise ValueError("a record runs past the chunk end")
            if op == _MESSAGE:
                if n < _MESSAGE_HEAD.size:
                    raise ValueError("a message record is too short")
                index.append((op, a, b))
            elif op == _SCHEMA or op == _CHANNEL:
                index.append((op, _parse_definition(op, records[a:b]), 0))
            i = b
        return (records, index), crc != 0

    def _raw_messages(self, with_data: bool) -> Iterator[tuple[int, int, int, bytes | None]]:
        """(channel id, log time, publish time, data as stored) in file order; registers
        schemas and channels on the way."""
        unpack_head = _MESSAGE_HEAD.unpack_from
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
            opcode, length = _RECORD_HEAD.unpack(f.read(9))
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


def loss_line(found: dict) -> str | None:
    """What `info` found unreadable or unfinished, in one line; None for an intact, finished bag."""
    lost, orphaned = found["lost"], found["orphaned"]
    parts = []
    if lost:
        total = sum(r["bytes"] for r in lost)
        where = "; ".join(_describe_region(r) for r in lost[:3])
        if len(lost) > 3:
            where += f"; and {len(lost) - 3} more"
        places = "1 place" if len(lost) == 1 else f"{len(lost)} places"
        parts.append(f"{format_size(total)} unreadable, skipped in {places}: {where}")
    if orphaned:
        parts.append(f"{orphaned} messages skipped: their channel was defined in a damaged chunk")
    if found["recovered"]:
        parts.append("the bag is unfinished (the recorder stopped without closing it)")
    if not parts:
        return None
    if lost or orphaned:
        parts.append("every other message was read")
    return f"{found['path']}: " + "; ".join(parts)


def _describe_region(region: dict) -> str:
    end = region["offset"] + region["bytes"]
    after, before = region["after"], region["before"]
    if region["at_end"]:
        when = "the end" + (f", after log time {after:.6f} s" if after is not None else ", no message before it")
    elif after is not None and before is not None:
        when = f"log time {after:.6f} s to {before:.6f} s"
    elif before is not None:
        when = f"before log time {before:.6f} s"
    elif after is not None:
        when = f"after log time {after:.6f} s"
    else:
        when = "no message before or after it"
    return f"bytes {region['offset']}-{end} ({when})"


def format_size(n: float) -> str:
    """1536 -> '1.5 KiB'."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


def _guess_format(head: bytes) -> str:
    if head.startswith(b"#ROSBAG"):
        return "it is a ROS 1 bag"
    if head.startswith(b"SQLite format 3"):
        return "it is an SQLite database, e.g. a ROS 2 .db3 bag"
    return "it does not start with the MCAP magic bytes"


def info(path: str | os.PathLike) -> dict:
    """What a bag holds, read in one pass (finished, unfinished or damaged bag).

    Keys: path, size_bytes, recovered (True: no footer, the recorder stopped
    without closing), skipped_bytes (all bytes that could not be read),
    lost: a list of {offset, bytes, after, before [s]: the largest log time
    read before the region and the smallest of the first chunk after it (None:
    no message there), at_end (nothing readable follows)}, orphaned (messages
    skipped: their channel was defined in a damaged chunk), loss (one line on
    all of it, None for an intact, finished bag), library, messages, chunks,
    start and end [s] (log times of the first and last message, None if
    empty), duration_s, and topics: a list of {topic, type, encoding, count,
    first, last [s], rate_hz (mean over the topic's span)}.
    """
    with BagReader(path) as reader:
        return reader.summary()


# --------------------------------------------------------------------------- export


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested Struct/dict/list -> {"header.stamp": .., "bodies.0.pose.position.x": ..}.

    Iterative, not recursive: a recorded message may nest as deeply as msgpack allows.
    """
    out: dict[str, Any] = {}
    stack = [(prefix, value)]
    while stack:
        prefix, value = stack.pop()
        if isinstance(value, msgspec.Struct):
            items = [(name, getattr(value, name)) for name in value.__struct_fields__]
        elif isinstance(value, dict):
            items = list(value.items())
        elif isinstance(value, (list, tuple)):
            items = list(enumerate(value))
        else:
            out[prefix or "value"] = value
            continue
        # Pushed in reverse so that fields come out in their order.
        stack.extend((f"{prefix}.{key}" if prefix else str(key), item) for key, item in reversed(items))
    return out


class ExportResult(NamedTuple):
    rows: int
    unvalidated: int  # msgpack that failed typed validation (e.g. NaN): exported as recorded
    skipped: int  # not msgpack at all, or nested too deeply to decode: no row
    recovered: bool
    loss: str | None  # the one line on what was unreadable or unfinished (see loss_line)


def export_csv(path: str | os.PathLike, topic: str, out: str | os.PathLike | IO[str], *,
               overwrite: bool = False) -> ExportResult:
    """Write one CSV row per message on `topic`: log_time_ns, then the flattened fields.

    A file `out` appears only when complete (written aside, then renamed); an
    existing one is refused unless `overwrite`, and the bag itself always.
    Messages that fail typed validation (a recorded NaN, say) are exported as
    recorded; bytes that are not msgpack at all are skipped and counted.
    """
    if not hasattr(out, "write"):
        dst = os.fspath(out)
        if os.path.exists(dst) and os.path.exists(path) and os.path.samefile(dst, path):
            raise BagError(f"cannot write {dst}: it is the bag it reads; give the CSV another name")
        if os.path.isdir(dst):
            raise BagError(f"cannot write {dst}: it is a directory")
        if os.path.exists(dst) and not overwrite:
            raise BagError(f"{dst} already exists; choose another name or pass --overwrite to replace it")
    with BagReader(path) as reader:
        found = reader.summary()
        entry = next((t for t in found["topics"] if t["topic"] == topic), None)
        if entry is None:
            have = ", ".join(t["topic"] for t in found["topics"]) or "none"
            raise BagError(f"{reader.path}: no topic {topic}; topics in the bag: {have}")
        reader._check_encoding(topic)
        if hasattr(out, "write"):
            result = _write_csv(reader, topic, out)
        else:
            with complete_or_nothing(os.fspath(out), BagError) as part, open(part, "w", newline="") as fh:
                result = _write_csv(reader, topic, fh)
        return ExportResult(*result, bool(reader.recovered), found["loss"])


def _write_csv(reader: BagReader, topic: str, fh: IO[str]) -> tuple[int, int, int]:
    from dockhil.msgs import TYPES
    from dockhil.msgs.codec import DecodeError, decode

    type_name = reader.topics[topic]
    cls = TYPES.get(type_name)
    untyped = msgspec.msgpack.Decoder()
    # A tagged Struct carries its type name in the map; a typed row has no such column.
    tag_field = getattr(getattr(cls, "__struct_config__", None), "tag_field", None)
    counts = {"unvalidated": 0, "skipped": 0}

    def rows() -> Iterator[dict[str, Any]]:
        for message in reader.messages([topic]):
            value = None
            if cls is not None:
                try:
                    value = decode(message.data, cls)
                except (DecodeError, RecursionError):
                    pass
            if value is None:
                try:
                    value = untyped.decode(message.data)
                except (msgspec.DecodeError, RecursionError):
                    counts["skipped"] += 1
                    continue
                if cls is not None:
                    counts["unvalidated"] += 1
                if tag_field is not None and isinstance(value, dict):
                    value.pop(tag_field, None)
            row = {"log_time_ns": message.log_time_ns}
            row.update(flatten(value))
            yield row

    # One pass when every row has the columns of the first (fixed-shape
    # messages); a second pass with the union when lists change length.
    columns: list[str] | None = None
    known: set[str] = set()
    reshaped = False
    written = 0
    writer = csv.writer(fh)
    for row in rows():
        if columns is None:
            columns = list(row)
            known = set(columns)
            writer.writerow(columns)
        if not reshaped and row.keys() <= known:
            writer.writerow([row.get(c, "") for c in columns])
            written += 1
            continue
        reshaped = True
        for key in row:
            if key not in known:
                known.add(key)
                columns.append(key)
    if reshaped:
        if not fh.seekable():
            raise BagError(f"{reader.path}: messages on {topic} change shape; export to a file, not a stream")
        fh.seek(0)
        fh.truncate()
        counts = {"unvalidated": 0, "skipped": 0}
        writer.writerow(columns)
        written = 0
        for row in rows():
            writer.writerow([row.get(c, "") for c in columns])
            written += 1
    if columns is None:
        writer.writerow(["log_time_ns"])
    return written, counts["unvalidated"], counts["skipped"]


class ConvertResult(NamedTuple):
    messages: int  # written to the new bag
    unencodable: int  # not msgpack in the old bag: no JSON for them, not written
    loss: str | None  # what of the old bag was unreadable or unfinished (see loss_line)


def convert(src: str | os.PathLike, dst: str | os.PathLike, *, overwrite: bool = False) -> ConvertResult:
    """Rewrite the bag `src` (msgpack channels, as recorded before json) as a json bag `dst`.

    Topics, types, log and publish times and the order stay; what `src` holds
    in damaged chunks stays lost. `dst` appears only when complete.
    """
    src, dst = os.fspath(src), os.fspath(dst)
    if os.path.isdir(dst):
        raise BagError(f"cannot create bag {dst}: it is a directory")
    if os.path.exists(dst) and not overwrite:
        raise BagError(f"bag {dst} already exists; choose another name or allow overwriting it")
    with BagReader(src) as reader:
        found = reader.summary()
        with complete_or_nothing(dst, BagError) as part, BagWriter(part, overwrite=True) as out:
            for topic, type_name in reader.topics.items():
                try:
                    out.add_topic(topic, type_name)
                except BagError as exc:
                    raise BagError(f"{src}: cannot convert: {str(exc).split(': ', 1)[1]}") from None
                reader._check_encoding(topic)
            for topic, _, log_ns, publish_ns, data in reader.messages_with_publish_time():
                out.write(topic, log_ns, publish_ns, data)
    return ConvertResult(out.messages_written, out.messages_unencodable, found["loss"])


__all__ = [
    "BagError",
    "BagMessage",
    "BagReader",
    "BagWriter",
    "ConvertResult",
    "ExportResult",
    "LostRegion",
    "channel_schema",
    "convert",
    "export_csv",
    "flatten",
    "format_size",
    "info",
    "loss_line",
]
