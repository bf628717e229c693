"""The MCAP records of dockhil's bags as both sides see them: the magic, the encodings, the record
heads, the error every failure raises, a recorded message, a region lost to damage and the one line
that says what was lost. The format itself is described in dockhil.bags.writer."""

from __future__ import annotations

import struct
from typing import NamedTuple

from dockhil.errors import DockhilError

MAGIC = b"\x89MCAP0\r\n"
MESSAGE_ENCODING = "json"  # what BagWriter records
READ_ENCODINGS = ("json", "msgpack")  # what BagReader decodes; msgpack: bags recorded before json
SCHEMA_ENCODING = "jsonschema"
COMPRESSIONS = ("zstd", "lz4", "none")
RECORD_HEAD = struct.Struct("<BQ")  # opcode, body length
MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
U64_MAX = 2**64 - 1  # the largest log or publish time [ns]


class BagError(DockhilError):
    """A bag cannot be written or read: the message names the file and the reason."""


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


class LostRegion(NamedTuple):
    """Bytes of a bag that could not be read: a damaged record or chunk, or a cut end."""

    offset: int  # first byte skipped
    length: int  # bytes skipped
    after_ns: int | None  # largest log time read before it (None: no message before)
    before_ns: int | None  # smallest log time of the first chunk read after it (None: no message after)
    at_end: bool  # nothing readable follows: the recorder stopped while writing, or a power cut


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
