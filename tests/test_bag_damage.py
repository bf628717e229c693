"""Damaged bags: every intact message is kept, and one line says what was lost.

Each test damages a bag itself (a bad CRC, 4 KiB of zeros, a bad opcode, a
corrupted chunk length, a torn last chunk followed by zeros) and checks
exactly which messages survive: those of every chunk but the damaged one,
known from the flushes that closed each chunk while the bag was written, and
the chunk's bytes from the index of the intact file (read by the reference
MCAP reader, not by dockhil).
"""

from __future__ import annotations

import csv
import random
import struct
from pathlib import Path

import pytest

from dockhil import cli
from dockhil.bags.format import format_size
from dockhil.bags.reader import BagReader
from dockhil.bags.tools import info
from dockhil.bags.writer import BagWriter
from dockhil.msgs import Header, Vector3, Wrench, WrenchStamped
from dockhil.msgs.codec import encode

PER_CHUNK = 150
N_CHUNKS = 6
T0 = 1_000_000_000  # ns: the first log time, 1 s
STEP = 1_000_000  # ns between messages


class Written:
    """A finished bag of N_CHUNKS chunks, and what each chunk holds."""

    def __init__(self, path: Path):
        self.path = path
        self.chunk_of: dict[int, int] = {}  # seq -> chunk number (0-based, in file order)
        self.time_of: dict[int, int] = {}  # seq -> log time [ns]
        self.topic_of: dict[int, str] = {}
        rng = random.Random(7)
        seq = 0
        with BagWriter(path, chunk_size=1 << 30, chunk_seconds=3600) as bag:
            bag.add_topic("/ft/wrench", "dockhil/WrenchStamped")
            bag.add_topic("/impedance/wrench", "dockhil/WrenchStamped")
            for chunk in range(N_CHUNKS):
                for _ in range(PER_CHUNK):
                    topic = "/impedance/wrench" if seq % 5 == 4 else "/ft/wrench"
                    # Noisy values: zstd cannot shrink them much, so a chunk is larger than 4 KiB of zeros.
                    force = Vector3(x=rng.gauss(0, 5), y=rng.gauss(0, 5), z=rng.gauss(0, 5))
                    msg = WrenchStamped(header=Header(stamp=seq * 1e-3, tick=seq, seq=seq), wrench=Wrench(force=force))
                    t = T0 + seq * STEP
                    bag.write(topic, t, t, encode(msg))
                    self.chunk_of[seq], self.time_of[seq], self.topic_of[seq] = chunk, t, topic
                    seq += 1
                bag.flush()
        self.data = path.read_bytes()
        self.chunks = _chunk_spans(path)  # [(offset, length)] in file order
        assert len(self.chunks) == N_CHUNKS

    def seqs_outside(self, *damaged: int) -> list[int]:
        return [s for s, c in self.chunk_of.items() if c not in damaged]

    def after_ns(self, chunk: int) -> int | None:
        """Largest log time of the chunks before `chunk`."""
        times = [self.time_of[s] for s, c in self.chunk_of.items() if c < chunk]
        return max(times) if times else None

    def before_ns(self, chunk: int) -> int | None:
        """Smallest log time of the chunks after `chunk`."""
        times = [self.time_of[s] for s, c in self.chunk_of.items() if c > chunk]
        return min(times) if times else None


def _chunk_spans(path: Path) -> list[tuple[int, int]]:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        indexes = make_reader(fh).get_summary().chunk_indexes
    return sorted((c.chunk_start_offset, c.chunk_length) for c in indexes)


@pytest.fixture
def bag(tmp_path) -> Written:
    return Written(tmp_path / "intact.mcap")


def _seqs(path: Path) -> list[int]:
    with BagReader(path) as reader:
        return [m.decode().header.seq for m in reader]


def _damage(bag: Written, how: str, chunk: int) -> bytes:
    """The intact bytes with `chunk` damaged `how`."""
    data = bytearray(bag.data)
    start, length = bag.chunks[chunk]
    if how == "crc":  # the CRC field of the chunk header: opcode, length, start, end, size, then the CRC
        crc_at = start + 9 + 24
        data[crc_at : crc_at + 4] = struct.pack("<I", struct.unpack_from("<I", data, crc_at)[0] ^ 0x5A5A5A5A)
    elif how == "flipped_byte":  # one bit of the compressed records
        data[start + length // 2] ^= 0x10
    elif how == "zeros_4k":
        assert length > 4096 + 200, "the test needs chunks larger than the zeros"
        data[start + 100 : start + 100 + 4096] = bytes(4096)
    elif how == "bad_opcode":
        data[start] = 0x42
    elif how.startswith("length"):
        (old,) = struct.unpack_from("<Q", data, start + 1)
        new = {"length_huge": 1 << 39, "length_longer": old + 1000, "length_shorter": old - 100}[how]
        data[start + 1 : start + 9] = struct.pack("<Q", new)
    else:
        raise AssertionError(how)
    return bytes(data)


HOWS = ["crc", "flipped_byte", "zeros_4k", "bad_opcode", "length_huge", "length_longer", "length_shorter"]


@pytest.mark.parametrize("how", HOWS)
@pytest.mark.parametrize("chunk", [2, N_CHUNKS - 1])
def test_a_damaged_chunk_loses_only_its_own_messages(bag, tmp_path, how, chunk):
    path = tmp_path / f"{how}.mcap"
    path.write_bytes(_damage(bag, how, chunk))

    assert _seqs(path) == bag.seqs_outside(chunk)
    found = info(path)
    start, length = bag.chunks[chunk]
    after, before = bag.after_ns(chunk), bag.before_ns(chunk)
    # The chunk's message indexes follow it intact: reading resumes right after the chunk.
    assert found["lost"] == [
        {
            "offset": start,
            "bytes": length,
            "after": after / 1e9,
            "before": None if before is None else before / 1e9,
            "at_end": False,
        }
    ]
    assert found["skipped_bytes"] == length
    assert found["recovered"] is False  # the footer is there: finished, though damaged
    assert found["messages"] == len(bag.seqs_outside(chunk))
    line = found["loss"]
    assert "\n" not in line and line.startswith(f"{path}: ")
    assert f"{format_size(length)} unreadable, skipped in 1 place: bytes {start}-{start + length}" in line
    if before is None:  # the last chunk: nothing after it but the summary
        assert f"(after log time {after / 1e9:.6f} s)" in line
    else:
        assert f"(log time {after / 1e9:.6f} s to {before / 1e9:.6f} s)" in line
    assert line.endswith("every other message was read")


def test_torn_last_chunk_followed_by_zeros_is_read_up_to_it(bag, tmp_path):
    """A power cut: the last chunk is half on disk, the file was extended with zeros, no footer."""
    start, length = bag.chunks[-1]
    path = tmp_path / "torn.mcap"
    path.write_bytes(bag.data[: start + length // 2] + bytes(64 * 1024))
    size = path.stat().st_size

    assert _seqs(path) == bag.seqs_outside(N_CHUNKS - 1)
    found = info(path)
    after = bag.after_ns(N_CHUNKS - 1)
    assert found["recovered"] is True
    assert found["lost"] == [
        {"offset": start, "bytes": size - start, "after": after / 1e9, "before": None, "at_end": True}
    ]
    assert found["loss"] == (
        f"{path}: {format_size(size - start)} unreadable, skipped in 1 place: bytes {start}-{size} "
        f"(the end, after log time {after / 1e9:.6f} s); the bag is unfinished (the recorder stopped "
        "without closing it); every other message was read"
    )


def test_two_damaged_chunks_are_two_regions(bag, tmp_path):
    data = bytearray(_damage(bag, "crc", 1))
    start, _ = bag.chunks[3]
    data[start] = 0x00  # a zero where the opcode was, zeros are not the end here
    path = tmp_path / "two.mcap"
    path.write_bytes(bytes(data))
    assert _seqs(path) == bag.seqs_outside(1, 3)
    found = info(path)
    assert [(r["offset"], r["bytes"]) for r in found["lost"]] == [bag.chunks[1], bag.chunks[3]]
    assert [r["after"] for r in found["lost"]] == [bag.after_ns(1) / 1e9, bag.after_ns(3) / 1e9]
    assert [r["before"] for r in found["lost"]] == [bag.before_ns(1) / 1e9, bag.before_ns(3) / 1e9]
    assert "in 2 places" in found["loss"]


def test_adjacent_damaged_chunks_share_the_time_range_around_them(bag, tmp_path):
    """Chunk 2 and its message indexes and chunk 3 all zeroed: one stretch, times 1..4."""
    start2, _ = bag.chunks[2]
    start3, length3 = bag.chunks[3]
    data = bytearray(bag.data)
    data[start2 : start3 + length3] = bytes(start3 + length3 - start2)
    path = tmp_path / "adjacent.mcap"
    path.write_bytes(bytes(data))
    assert _seqs(path) == bag.seqs_outside(2, 3)
    (region,) = info(path)["lost"]
    assert (region["offset"], region["bytes"]) == (start2, start3 + length3 - start2)
    assert (region["after"], region["before"]) == (bag.after_ns(2) / 1e9, bag.before_ns(3) / 1e9)


def test_first_chunk_damaged_channels_come_from_the_summary(bag, tmp_path):
    """The first chunk defines the channels. A finished bag repeats them in its summary."""
    path = tmp_path / "first.mcap"
    path.write_bytes(_damage(bag, "crc", 0))
    with BagReader(path) as reader:
        got = [(m.topic, m.decode().header.seq) for m in reader]
    assert got == [(bag.topic_of[s], s) for s in bag.seqs_outside(0)]
    found = info(path)
    assert found["orphaned"] == 0 and [(r["offset"], r["bytes"]) for r in found["lost"]] == [bag.chunks[0]]
    assert found["lost"][0]["after"] is None
    assert f"(before log time {bag.before_ns(0) / 1e9:.6f} s)" in found["loss"]

    # Unfinished as well: the definitions are lost with the chunk; the messages that need them are counted.
    end_of_chunks = bag.chunks[-1][0] + bag.chunks[-1][1]
    cut = tmp_path / "first-unfinished.mcap"
    cut.write_bytes(_damage(bag, "crc", 0)[:end_of_chunks])
    found = info(cut)
    assert found["messages"] == 0 and found["orphaned"] == len(bag.seqs_outside(0))
    assert f"{len(bag.seqs_outside(0))} messages skipped: their channel was defined in a damaged chunk" in found["loss"]


def test_header_then_garbage_is_an_empty_bag_that_says_so(tmp_path, capsys):
    path = tmp_path / "junk.mcap"
    path.write_bytes(b"\x89MCAP0\r\n\x01" + (8).to_bytes(8, "little") + bytes(8) + b"\x42junk")
    found = info(path)
    assert found["messages"] == 0 and found["recovered"] is True
    assert found["lost"] == [{"offset": 25, "bytes": 5, "after": None, "before": None, "at_end": True}]
    code = cli.main(["bag", "info", str(path)])
    out, err = capsys.readouterr()
    assert code == 0 and err == ""
    assert "lost:      5 B unreadable, skipped in 1 place: bytes 25-30 (the end, no message before it)" in out


# --------------------------------------------------------------------------- the commands


def test_info_export_and_play_report_the_loss_in_one_line_and_go_on(bag, tmp_path, capsys):
    chunk = 2
    path = tmp_path / "damaged.mcap"
    path.write_bytes(_damage(bag, "zeros_4k", chunk))
    expected_line = info(path)["loss"]

    code = cli.main(["bag", "info", str(path)])
    out, err = capsys.readouterr()
    assert code == 0 and err == ""
    lost_lines = [line for line in out.splitlines() if line.startswith("lost:")]
    assert lost_lines == ["lost:      " + expected_line.removeprefix(f"{path}: ")]
    assert "state:     finished" in out

    out_csv = tmp_path / "ft.csv"
    code = cli.main(["bag", "export", str(path), "--topic", "/ft/wrench", "--csv", str(out_csv)])
    out, err = capsys.readouterr()
    assert code == 0
    assert err == f"dockhil bag export: warning: {expected_line}\n"
    rows = list(csv.DictReader(open(out_csv, newline="")))
    expected = [s for s in bag.seqs_outside(chunk) if bag.topic_of[s] == "/ft/wrench"]
    assert [int(r["header.seq"]) for r in rows] == expected

    # play: no subscriber is waited for in wall time; a high rate plays the 0.9 s bag at once.
    code = cli.main(["bag", "play", str(path), "--rate", "1000"])
    out, err = capsys.readouterr()
    assert code == 0
    warnings = [line for line in err.splitlines() if "unreadable" in line]
    assert len(warnings) == 1 and expected_line in warnings[0]
    assert f"played {len(bag.seqs_outside(chunk))} messages" in err


def test_export_of_a_deeply_nested_message_is_one_line(tmp_path, capsys):
    from tests.support.bagfiles import write_msgpack_bag

    good = encode(WrenchStamped(header=Header(seq=1)))
    deep_arrays = b"\x91" * 20_000 + b"\x01"  # 20,000 nested arrays
    deep_maps = b"\x81\xa1a" * 500 + b"\x01"  # 500 nested maps: decodes, flattens deep
    # A bag recorded before json channels holds the wire bytes as they came.
    path = tmp_path / "nested.mcap"
    write_msgpack_bag(
        path,
        {"/ft/wrench": "dockhil/WrenchStamped"},
        [("/ft/wrench", k, k, d) for k, d in enumerate([good, deep_arrays, deep_maps], 1)],
    )
    out_csv = tmp_path / "nested.csv"
    code = cli.main(["bag", "export", str(path), "--topic", "/ft/wrench", "--csv", str(out_csv)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "Traceback" not in err and "RecursionError" not in err
    assert err == (
        "dockhil bag export: note: 1 messages fail validation (e.g. NaN) and are exported as recorded\n"
        "dockhil bag export: note: 1 messages are not msgpack (or nest too deeply) and were skipped\n"
    )
    rows = list(csv.DictReader(open(out_csv, newline="")))
    assert [r["log_time_ns"] for r in rows] == ["1", "3"]
    assert rows[1][".".join(["a"] * 500)] == "1"

    # Reading it typed gives one line too.
    from dockhil.bags.format import BagError

    with BagReader(path) as reader, pytest.raises(BagError) as caught:
        list(reader.decoded())
    assert "\n" not in str(caught.value) and "log time 2 ns" in str(caught.value)

    # Recording it as json: too deep to transcode, counted and left out; the others are kept.
    with BagWriter(tmp_path / "nested.json.mcap") as writer:
        writer.add_topic("/ft/wrench", "dockhil/WrenchStamped")
        for k, data in enumerate([good, deep_arrays, deep_maps], 1):
            writer.write("/ft/wrench", k, k, data)
    assert (writer.messages_written, writer.messages_unencodable) == (2, 1)
    with BagReader(tmp_path / "nested.json.mcap") as reader:
        assert [m.data for m in reader] == [good, deep_maps]


def test_bag_source_replays_around_a_damaged_chunk_and_warns_once(bag, tmp_path):
    from dockhil.node import NodeContext, Tick
    from dockhil.nodes.bag_source import BagSource

    chunk = 2
    path = tmp_path / "damaged.mcap"
    path.write_bytes(_damage(bag, "crc", chunk))
    logged: list[str] = []
    node = BagSource(NodeContext("ft", 1e-3, sim_time=True, log=logged.append), path=str(path), topics=["/ft/wrench"])
    node.setup()
    sent = []
    for k in range(N_CHUNKS * PER_CHUNK):
        msg = node.step(Tick(k, k * 1e-3, 1e-3), {})["/ft/wrench"]
        if msg is not None:
            sent.append(msg.header.seq)
    node.close()
    # Ticks of the damaged chunk have no message, as ticks where the recorded run sent nothing.
    assert sent == [s for s in bag.seqs_outside(chunk) if bag.topic_of[s] == "/ft/wrench"]
    assert logged == [f"warning: {info(path)['loss']}"]


def test_a_damaged_header_is_a_lost_region_when_chunks_follow(bag, tmp_path):
    data = bytearray(bag.data)
    data[8] = 0x42  # the header record's opcode, right after the magic
    path = tmp_path / "header.mcap"
    path.write_bytes(bytes(data))
    assert _seqs(path) == bag.seqs_outside()
    found = info(path)
    first_chunk = bag.chunks[0][0]
    assert found["lost"] == [
        {"offset": 8, "bytes": first_chunk - 8, "after": None, "before": T0 / 1e9, "at_end": False}
    ]


def test_random_damage_never_costs_an_intact_chunk(bag, tmp_path):
    """Flipped bits, zeros, random bytes and torn ends at random places (a fixed seed):
    reading never fails, and every chunk the damage does not touch is read in full."""
    rng = random.Random(2024)
    size = len(bag.data)
    path = tmp_path / "random.mcap"
    for case in range(120):
        data = bytearray(bag.data)
        kind = case % 4
        a = rng.randrange(8, size)
        if kind == 0:  # a few flipped bits within 64 bytes
            b = min(size, a + 64)
            for _ in range(rng.randint(1, 4)):
                data[rng.randrange(a, b)] ^= 1 << rng.randrange(8)
        elif kind == 1:  # a run of zeros
            b = min(size, a + rng.randint(1, 6000))
            data[a:b] = bytes(b - a)
        elif kind == 2:  # a run of random bytes
            b = min(size, a + rng.randint(1, 3000))
            data[a:b] = rng.randbytes(b - a)
        else:  # torn at `a`, then zeros (a power cut)
            b = size + 4096
            data = data[:a] + bytearray(4096 + size - a)
        path.write_bytes(bytes(data))

        touched = {c for c, (start, length) in enumerate(bag.chunks) if start < b and a < start + length}
        found = info(path)  # never raises
        got = _seqs(path)
        assert got == sorted(set(got)), case  # in order, none twice
        must = bag.seqs_outside(*touched)
        assert set(must) <= set(got), (case, kind, a, b, touched)
        assert set(got) <= set(bag.chunk_of), case
        # Whatever was lost lies in the regions reported, and they cover no intact chunk.
        lost_chunks = {bag.chunk_of[s] for s in set(bag.chunk_of) - set(got)}
        for c in lost_chunks:
            start, length = bag.chunks[c]
            assert any(r["offset"] <= start + length and start < r["offset"] + r["bytes"] for r in found["lost"]), case
        for r in found["lost"]:
            for c, (start, length) in enumerate(bag.chunks):
                if c not in touched:
                    assert not (r["offset"] <= start and start + length <= r["offset"] + r["bytes"]), case
