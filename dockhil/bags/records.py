"""An MCAP file record by record, across damage: the recovery behind dockhil.bags.reader.

`RecordScanner` hands out each valid record after the header. A damaged record or chunk
(checksum, zeros, a bad opcode or length) is skipped: it scans forward for the next valid record
(a chunk whose framing is consistent and whose CRC checks, or a record whose fields are consistent
and that is followed by another record) and notes the stretch it skipped in the pass's `lost`.
"""

from __future__ import annotations

import io
import re
import struct
import zlib
from collections.abc import Container, Iterator
from typing import TYPE_CHECKING, Any, BinaryIO

from dockhil.bags.format import MAGIC, MESSAGE_HEAD, RECORD_HEAD, BagError, LostRegion

if TYPE_CHECKING:
    from mcap.records import Channel, Schema

# MCAP opcodes (spec "Records"); 0x80-0xFF are reserved for user records.
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK, MESSAGE_INDEX, METADATA, DATA_END = (
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
KNOWN_OPCODES = frozenset(range(0x01, 0x10))
# Where a damaged stretch may end: an MCAP opcode, then a length below 2**40 (its top
# three bytes zero). Zero-width, so that overlapping candidates are all found.
_CANDIDATE = re.compile(rb"(?=[\x02-\x0f][\x00-\xff]{5}\x00\x00\x00)")
_COMPRESSIONS_READ = {b"zstd": "zstd", b"lz4": "lz4", b"": ""}
_MAX_CHUNK = 1 << 30  # uncompressed bytes; a larger size field is damage
_MAX_DEFINITION = 1 << 24  # a schema or channel found while scanning damaged bytes
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length


class FilePass:
    """What one pass over the file found; the reader takes it over when the pass ends."""

    def __init__(self) -> None:
        self.chunks = 0
        self.lost: list[LostRegion] = []
        self.orphaned = 0  # messages whose channel definition was lost
        self.bare = False  # a message outside any chunk was read: the file is not chunked
        self.top_ns: int | None = None  # largest log time read so far
        self.finished = False  # the file ends with a footer and the magic bytes
        self.waiting: list[int] = []  # regions (index in lost) whose before_ns is the next chunk's first log time


class RecordScanner:
    """The records of the MCAP file `file` (its `size` bytes, read by one reader). `channels`: the
    ids of the channels the reader knows so far, which tell a bare message found while scanning
    damaged bytes from one of a damaged chunk's own records."""

    def __init__(self, file: BinaryIO, path: str, size: int, channels: Container[int]):
        self.file = file
        self.path = path
        self.size = size
        self.channels = channels
        self.data_start = len(MAGIC)  # where the records after the header begin (read_start)

    def read_start(self) -> tuple[str, str]:
        """(profile, library) of the MCAP header; BagError, in one line, if the file is not an MCAP
        bag or no record of it can be read."""
        f, size = self.file, self.size
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
        if opcode != HEADER:
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
            self.data_start = len(MAGIC) + 9 + length
            return profile, library
        # A damaged header: what follows may be whole. Read on if a valid record comes
        # (the header is then a lost region like any other), else say what is wrong.
        self.data_start = len(MAGIC)
        if self.resync(len(MAGIC) + 1, FilePass()) >= size:
            raise BagError(f"{self.path}: {problem}")
        return "", ""

    def records(self, run: FilePass) -> Iterator[tuple[int, int, Any]]:
        """(offset, opcode, content) of each valid record after the header; damaged
        stretches are skipped and noted in `run`. Content: for a chunk its
        decompressed records and their index (see `_chunk`), for a message,
        schema or channel its body, else None. Once all are read, `run.finished`
        says whether the file ends as a finished bag does."""
        size = self.size
        pos = self.data_start
        finished = False
        while pos < size:
            found = self._record_at(pos, run, resync=False)
            if found is None:
                resume = self.resync(pos + 1, run)
                self._lose(run, pos, resume)
                pos = resume
                continue
            opcode, length, content = found
            yield pos, opcode, content
            pos += 9 + length
            if opcode == FOOTER:
                self.file.seek(pos)
                finished = self.file.read(len(MAGIC)) == MAGIC
                break
        run.finished = finished

    def _lose(self, run: FilePass, start: int, end: int) -> None:
        run.waiting.append(len(run.lost))
        run.lost.append(LostRegion(start, end - start, run.top_ns, None, end >= self.size))

    def _record_at(self, pos: int, run: FilePass, resync: bool) -> tuple[int, int, Any] | None:
        """(opcode, body length, content) of a valid record at `pos`, else None.

        `resync`: `pos` was found by scanning damaged bytes, so more is asked of
        the record: a known MCAP opcode (not a user one), and unless it is a
        chunk with a CRC, the record after it must start plausibly too.
        """
        f, size = self.file, self.size
        f.seek(pos)
        head = f.read(9)
        if len(head) < 9:
            return None
        opcode, length = RECORD_HEAD.unpack(head)
        if length > size - pos - 9 or opcode == HEADER:
            return None
        if not (opcode in KNOWN_OPCODES or (opcode >= 0x80 and not resync)):
            return None
        content: bytes | tuple[bytes, list[Any]] | None = None
        checked = False  # True: a CRC vouches for the record
        try:
            if opcode == CHUNK:
                content, checked = self._chunk(pos, length)
            elif opcode in (MESSAGE, SCHEMA, CHANNEL):
                if resync and length > _MAX_DEFINITION and opcode != MESSAGE:
                    return None
                content = body = f.read(length)
                if opcode == MESSAGE:
                    if length < MESSAGE_HEAD.size:
                        return None
                    # Unless the file is known to be unchunked, a bare message found by
                    # scanning is one of a damaged (uncompressed) chunk's own records.
                    known = MESSAGE_HEAD.unpack_from(body)[0] in self.channels
                    if resync and (run.chunks or not run.bare or not known):
                        return None
                else:
                    parse_definition(opcode, body)
            elif opcode == MESSAGE_INDEX:
                if length < 6:
                    return None
                (n,) = struct.unpack("<I", f.read(6)[2:])
                if 6 + n != length or n % 16:
                    return None
            elif opcode == DATA_END and length != 4 or opcode == FOOTER and length != 20:
                return None
        except Exception:  # struct, UTF-8, zstandard and lz4 errors alike: the record is damaged
            return None
        if resync and not checked and not self._followed_plausibly(pos + 9 + length, opcode):
            return None
        return opcode, length, content

    def _followed_plausibly(self, pos: int, opcode: int) -> bool:
        f, size = self.file, self.size
        f.seek(pos)
        if opcode == FOOTER:
            return f.read(len(MAGIC)) == MAGIC
        head = f.read(9)
        if len(head) < 9:  # the end of the file, or a cut record head
            return True
        next_opcode, length = RECORD_HEAD.unpack(head)
        return next_opcode in KNOWN_OPCODES and next_opcode != HEADER and length <= size - pos - 9

    def resync(self, start: int, run: FilePass) -> int:
        """Offset of the first valid record at or after `start`, or the file size."""
        f, size = self.file, self.size
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
        f = self.file
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
            if op == MESSAGE:
                if n < MESSAGE_HEAD.size:
                    raise ValueError("a message record is too short")
                index.append((op, a, b))
            elif op == SCHEMA or op == CHANNEL:
                index.append((op, parse_definition(op, records[a:b]), 0))
            i = b
        return (records, index), crc != 0

    def metadata(self) -> list[tuple[str, dict[str, str]]]:
        """(name, str -> str) of each metadata record, in file order. Reads record heads only
        (chunks are stepped over, not decompressed); a damaged stretch is skipped as in a full pass."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Metadata

        f, size = self.file, self.size
        found: list[tuple[str, dict[str, str]]] = []
        pos = self.data_start
        run = FilePass()
        while pos + 9 <= size:
            f.seek(pos)
            opcode, length = RECORD_HEAD.unpack(f.read(9))
            if opcode == FOOTER or opcode == DATA_END:
                break
            if opcode == HEADER or not (opcode in KNOWN_OPCODES or opcode >= 0x80) or length > size - pos - 9:
                pos = self.resync(pos + 1, run)
                continue
            if opcode == METADATA:
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

    def summary_definitions(self) -> Iterator[Any]:
        """The schemas and channels a finished bag repeats in its summary section (none if it has none)."""
        f, size = self.file, self.size
        footer_at = size - len(MAGIC) - 9 - 20
        if footer_at < self.data_start:
            return
        f.seek(footer_at)
        tail = f.read(9 + 20 + len(MAGIC))
        opcode, length, summary_start = struct.unpack_from("<BQQ", tail, 0)
        if opcode != FOOTER or length != 20 or tail[29:] != MAGIC or not self.data_start <= summary_start < footer_at:
            return
        pos = summary_start
        while pos < footer_at:
            f.seek(pos)
            opcode, length = RECORD_HEAD.unpack(f.read(9))
            if length > footer_at - pos - 9:
                return
            if opcode == SCHEMA or opcode == CHANNEL:
                yield parse_definition(opcode, f.read(length))
            pos += 9 + length


def parse_definition(opcode: int, body: bytes) -> Schema | Channel:
    """A schema or channel record, parsed; ValueError unless its fields fill the body exactly."""
    from mcap.data_stream import ReadDataStream
    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Schema

    stream = ReadDataStream(io.BytesIO(body))
    try:
        record = (Schema if opcode == SCHEMA else Channel).read(stream)
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
