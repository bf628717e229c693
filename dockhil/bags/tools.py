"""What `dockhil bag` does with a bag besides reading it: info (topics, counts, times, rates, what
was lost), a topic exported as CSV, and a bag rewritten in the current encoding."""

from __future__ import annotations

import csv
import os
from collections.abc import Iterator
from typing import IO, Any, NamedTuple, cast

import msgspec

from dockhil.bags.format import BagError
from dockhil.bags.reader import BagReader
from dockhil.bags.writer import BagWriter
from dockhil.files import complete_or_nothing


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
    first, last [s], rate_hz (mean over the topic's span)}; run: what the bag says of its run
    (dockhil.bags.runinfo: scene, args, version, start, validity), None for a bag of an older dockhil.
    """
    from dockhil.bags import runinfo

    with BagReader(path) as reader:
        found = reader.summary()
        found["run"] = runinfo.read(reader).as_json()
    return found


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested Struct/dict/list -> {"header.stamp": .., "bodies.0.pose.position.x": ..}.

    Iterative, not recursive: a recorded message may nest as deeply as msgpack allows.
    """
    out: dict[str, Any] = {}
    stack = [(prefix, value)]
    while stack:
        prefix, value = stack.pop()
        items: list[tuple[Any, Any]]
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


def export_csv(
    path: str | os.PathLike, topic: str, out: str | os.PathLike | IO[str], *, overwrite: bool = False
) -> ExportResult:
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
        reader.check_encoding(topic)
        if hasattr(out, "write"):
            result = _write_csv(reader, topic, cast(IO[str], out))  # it writes
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
    if reshaped and columns is not None:  # reshaped: a row was seen, so columns are set
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
                reader.check_encoding(topic)
            for topic, _, log_ns, publish_ns, data in reader.messages_with_publish_time():
                out.write(topic, log_ns, publish_ns, data)
    return ConvertResult(out.messages_written, out.messages_unencodable, found["loss"])
