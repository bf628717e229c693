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

import json
import operator
import os
import time
from typing import IO, Any, cast

import msgspec

from dockhil.bags.format import COMPRESSIONS, MESSAGE_ENCODING, MESSAGE_HEAD, SCHEMA_ENCODING, U64_MAX, BagError
from dockhil.files import os_reason

# Size of a message record in a chunk besides its data: opcode, length, MESSAGE_HEAD.
_MESSAGE_OVERHEAD = 9 + MESSAGE_HEAD.size


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
            self._file: IO[bytes] = cast(IO[bytes], path)
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

    def add_topic(self, topic: str, type_name: str, schema: dict | None = None) -> None:
        """Declare a topic and its message type (a key of msgs.TYPES, or another type with its JSON
        `schema`, such as Foxglove's well-known types); adding it again is a no-op."""
        from dockhil.msgs import TYPES

        if not isinstance(topic, str) or not topic:
            raise BagError(f"bag {self.path}: a topic must be a non-empty string, got {topic!r}")
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != type_name:
                raise BagError(f"bag {self.path}: topic {topic} is already recorded as {known[1]}, not {type_name}")
            return
        cls = TYPES.get(type_name)
        if cls is None and schema is None:
            raise BagError(
                f"bag {self.path}: topic {topic} has unknown message type {type_name!r}; "
                f"known: {', '.join(sorted(TYPES))}"
            )
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            data = json.dumps(
                channel_schema(cast(type, cls)) if schema is None else schema, separators=(",", ":")
            ).encode()
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
        if not (0 <= log_time_ns <= U64_MAX and 0 <= publish_time_ns <= U64_MAX):
            raise BagError(
                f"bag {self.path}: topic {topic}: times must be integer ns in [0, 2**64), got {log_time_ns!r}"
            )
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

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write an MCAP metadata record (name, str -> str) between chunks, on disk at once: what the
        run was (dockhil.bags.runinfo) survives a kill of the recorder like the chunks before it."""
        if self._failed is not None:
            raise self._failed
        if self._closed:
            raise BagError(f"bag {self.path} is closed")
        self.flush()
        try:
            self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})
            self._file.flush()
        except OSError as exc:
            raise self._stop(exc, "writing") from None

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

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
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
            name = ref[len("#/$defs/") :]
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


def _open_for_writing(path: str, overwrite: bool) -> IO[bytes]:
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
