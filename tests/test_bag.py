"""Bags: write -> info -> export -> read back, recovery after SIGKILL, interop, bad files."""

from __future__ import annotations

import csv
import errno
import io
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import msgspec
import pytest

from dockhil import cli
from dockhil.bags.format import BagError
from dockhil.bags.reader import BagReader
from dockhil.bags.tools import flatten, info
from dockhil.bags.writer import BagWriter
from dockhil.msgs import (
    BodyState,
    Header,
    Pose,
    SatelliteState,
    Twist,
    Vector3,
    Wrench,
    WrenchStamped,
    type_name,
)
from dockhil.msgs.codec import encode, schema
from tests.support.bagfiles import write_msgpack_bag

ROOT = Path(__file__).resolve().parent.parent
MS = 1_000_000  # ns


def wrench(k: int) -> WrenchStamped:
    return WrenchStamped(
        header=Header(stamp=k * 1e-3, tick=k, seq=k, frame="chaser"),
        wrench=Wrench(force=Vector3(x=-0.1 * k, y=k / 3, z=1e-9 * k), torque=Vector3(z=(-1) ** k * 0.25)),
    )


def state(k: int) -> SatelliteState:
    # One body for the first messages, then two: the CSV must grow columns.
    bodies = [
        BodyState(
            name="chaser", mass=120.0, pose=Pose(position=Vector3(x=0.01 * k)), twist=Twist(linear=Vector3(x=0.02))
        )
    ]
    if k >= 5:
        bodies.append(BodyState(name="target", mass=300.0, pose=Pose(position=Vector3(x=1.0 - 0.001 * k))))
    return SatelliteState(
        header=Header(stamp=k * 1e-2, tick=10 * k, seq=k), bodies=tuple(bodies), in_contact=k % 2 == 0
    )


def write_run(path, n_wrench=500, n_state=50, **writer_options):
    """A 0.5 s run: a 1 kHz wrench and a 100 Hz state; returns what was written, in order."""
    written = []
    with BagWriter(path, **writer_options) as bag:
        bag.add_topic("/ft/wrench", type_name(WrenchStamped))
        bag.add_topic("/dynamics/state", type_name(SatelliteState))
        for k in range(n_wrench):
            t = 5_000 * MS + k * MS
            msg = wrench(k)
            bag.write("/ft/wrench", t, t + 7, encode(msg))
            written.append(("/ft/wrench", t, msg))
            if k % 10 == 0 and k // 10 < n_state:
                msg = state(k // 10)
                bag.write("/dynamics/state", t, t, encode(msg))
                written.append(("/dynamics/state", t, msg))
    return written


def run_cli(capsys, *args):
    code = cli.main(["bag", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, *words):
    assert code == 2
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert err.startswith("dockhil bag: error: ")
    assert "Traceback" not in err
    for word in words:
        assert word in err, (word, err)


# --------------------------------------------------------------------------- round trip


def test_round_trip_info_export_read_back(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    written = write_run(path, chunk_size=2048)

    found = info(path)
    assert found["recovered"] is False and found["skipped_bytes"] == 0
    assert found["messages"] == len(written) == 550
    assert found["chunks"] > 5  # small chunks
    assert found["start"] == pytest.approx(5.0) and found["end"] == pytest.approx(5.499)
    assert found["duration_s"] == pytest.approx(0.499)
    topics = {t["topic"]: t for t in found["topics"]}
    assert topics["/ft/wrench"]["type"] == "dockhil/WrenchStamped"
    assert topics["/ft/wrench"]["count"] == 500
    assert topics["/ft/wrench"]["rate_hz"] == pytest.approx(1000.0)
    assert topics["/dynamics/state"]["type"] == "dockhil/SatelliteState"
    assert topics["/dynamics/state"]["count"] == 50
    assert topics["/dynamics/state"]["rate_hz"] == pytest.approx(100.0)

    # Read back: same topics, times and bytes, in the order written; decode to equal Structs.
    with BagReader(path) as reader:
        back = list(reader)
        assert reader.recovered is False
    assert [(m.topic, m.log_time_ns) for m in back] == [(t, ns) for t, ns, _ in written]
    assert [m.data for m in back] == [encode(msg) for _, _, msg in written]
    assert [m.decode() for m in back] == [msg for _, _, msg in written]
    with BagReader(path) as reader:
        assert [(t, ns, msg) for t, ns, msg in reader.decoded(["/dynamics/state"])] == [
            w for w in written if w[0] == "/dynamics/state"
        ]
        assert len(list(reader.messages(start_ns=5_100 * MS, end_ns=5_199 * MS))) == 110
        # Two passes at once over one reader (play reading while info is asked) do not disturb each other.
        first, second = reader.messages(), reader.messages()
        pairs = list(zip(first, second))
        assert len(pairs) == len(written) and all(a == b for a, b in pairs)

    # CLI info: a table and the same facts as JSON.
    code, out, err = run_cli(capsys, "info", path)
    assert code == 0 and err == ""
    assert "finished" in out and "/ft/wrench" in out and "dockhil/WrenchStamped" in out and "1000.0" in out
    code, out, _ = run_cli(capsys, "info", path, "--json")
    assert code == 0 and json.loads(out) == json.loads(json.dumps(found))

    # CLI export: header row, one row per message, values read back equal.
    for topic in ("/ft/wrench", "/dynamics/state"):
        out_csv = tmp_path / (topic.strip("/").replace("/", "_") + ".csv")
        code, out, err = run_cli(capsys, "export", path, "--topic", topic, "--csv", out_csv)
        assert code == 0 and err == "", err
        with open(out_csv, newline="") as fh:
            rows = list(csv.DictReader(fh))
        expected = [(ns, msg) for t, ns, msg in written if t == topic]
        assert len(rows) == len(expected)
        for row, (ns, msg) in zip(rows, expected):
            assert int(row["log_time_ns"]) == ns
            for column, value in flatten(msg).items():
                assert _parse(row[column], value) == value, (column, row[column], value)
        assert not (tmp_path / (out_csv.name + ".part")).exists()

    with open(tmp_path / "dynamics_state.csv", newline="") as fh:
        header = next(csv.reader(fh))
        first = next(csv.DictReader(open(tmp_path / "dynamics_state.csv", newline="")))
    assert header[:3] == ["log_time_ns", "header.stamp", "header.tick"]
    assert "bodies.0.pose.position.x" in header and "bodies.1.pose.position.x" in header
    assert first["bodies.1.name"] == ""  # the first messages have one body


def _parse(text: str, like):
    if isinstance(like, bool):
        return {"True": True, "False": False}[text]
    return type(like)(text)


def test_flatten_names_nested_fields():
    flat = flatten(state(6))
    assert flat["header.stamp"] == 0.06
    assert flat["bodies.0.pose.position.x"] == pytest.approx(0.06)
    assert flat["bodies.1.name"] == "target"
    assert flat["bodies.0.pose.orientation.w"] == 1.0
    assert flatten({"a": [1, {"b": 2}]}) == {"a.0": 1, "a.1.b": 2}


@pytest.mark.parametrize("encoding", ["json", "msgpack"])
def test_export_keeps_a_recorded_nan_and_skips_non_msgpack(tmp_path, capsys, encoding):
    path = tmp_path / "nan.mcap"
    wire = [
        encode(wrench(1)),
        encode(WrenchStamped(header=Header(seq=2), wrench=Wrench(force=Vector3(x=math.nan)))),
        b"\xc1",  # never valid msgpack
    ]
    if encoding == "json":
        with BagWriter(path) as bag:
            bag.add_topic("/ft/wrench", "dockhil/WrenchStamped")
            for k, data in enumerate(wire, 1):
                bag.write("/ft/wrench", k, k, data)
        # JSON holds neither bytes that are not msgpack (counted, not written) nor NaN (null).
        assert (bag.messages_written, bag.messages_unencodable) == (2, 1)
    else:  # a bag recorded before json channels holds the wire bytes as they came
        write_msgpack_bag(
            path, {"/ft/wrench": "dockhil/WrenchStamped"}, [("/ft/wrench", k, k, d) for k, d in enumerate(wire, 1)]
        )
    out_csv = tmp_path / "w.csv"
    code, out, err = run_cli(capsys, "export", path, "--topic", "/ft/wrench", "--csv", out_csv)
    assert code == 0
    assert "1 messages fail validation" in err
    assert ("1 messages are not msgpack" in err) == (encoding == "msgpack")
    with open(out_csv, newline="") as fh:
        header = next(csv.reader(fh))
        fh.seek(0)
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 and rows[1]["header.seq"] == "2"
    if encoding == "json":
        assert rows[1]["wrench.force.x"] == ""  # null
    else:
        assert math.isnan(float(rows[1]["wrench.force.x"]))
    assert header == ["log_time_ns", *flatten(wrench(1))]  # the row exported as recorded has the same columns


# --------------------------------------------------------------------------- interop


def test_reference_mcap_reader_reads_json_that_validates_against_the_channel_schema(tmp_path):
    import jsonschema
    from mcap.reader import make_reader

    path = tmp_path / "run.mcap"
    written = write_run(path, n_wrench=200, n_state=20)
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.message_count == len(written)
        got = list(reader.iter_messages(log_time_order=False))
    assert len(got) == len(written)
    validators = {}
    for (schema_rec, channel, message), (topic, ns, msg) in zip(got, written):
        assert channel.topic == topic and channel.message_encoding == "json"
        assert schema_rec.name == type_name(type(msg)) and schema_rec.encoding == "jsonschema"
        assert message.log_time == ns
        assert message.publish_time == (ns + 7 if topic == "/ft/wrench" else ns)
        value = json.loads(message.data)
        assert value == msgspec.json.decode(msgspec.json.encode(msg))  # the message as JSON, sequences as arrays
        if schema_rec.name not in validators:
            found = json.loads(schema_rec.data)
            # What viewers need: the message's own object at the top, no $ref to follow.
            assert found["type"] == "object" and "$ref" not in json.dumps(found)
            jsonschema.Draft202012Validator.check_schema(found)
            validators[schema_rec.name] = jsonschema.Draft202012Validator(found)
        validators[schema_rec.name].validate(value)
    assert set(validators) == {"dockhil/WrenchStamped", "dockhil/SatelliteState"}
    # The validator is not a yes-man: a field of the wrong type or a NaN (null in JSON) is refused.
    bad = json.loads(got[0][2].data)
    bad["wrench"]["force"]["x"] = None
    assert not validators["dockhil/WrenchStamped"].is_valid(bad)
    bad["wrench"]["force"]["x"] = "1.0"
    assert not validators["dockhil/WrenchStamped"].is_valid(bad)


class Tree(msgspec.Struct):
    name: str
    children: list[Tree] = []


def test_every_message_type_has_a_self_contained_schema_its_messages_meet():
    import jsonschema

    from dockhil.bags.writer import channel_schema
    from dockhil.msgs import TYPES

    for name, cls in TYPES.items():
        found = channel_schema(cls)
        assert found["type"] == "object" and "$ref" not in json.dumps(found) and "$defs" not in found, name
        jsonschema.Draft202012Validator.check_schema(found)
        # Same meaning as msgspec's own schema: the default message is valid under both.
        # (as JSON, which is what a schema describes and what a viewer gets: sequences are arrays)
        default = msgspec.json.decode(
            msgspec.json.encode(cls(header=Header()) if "header" in cls.__struct_fields__ else cls())
        )
        jsonschema.validate(default, found)
        jsonschema.validate(default, schema(cls))

    # A type that contains itself keeps a reference for the inner occurrences only.
    found = channel_schema(Tree)
    assert found["type"] == "object" and found["properties"]["children"]["items"] == {"$ref": "#/$defs/Tree"}
    jsonschema.validate({"name": "a", "children": [{"name": "b", "children": []}]}, found)
    assert not jsonschema.Draft202012Validator(found).is_valid({"name": "a", "children": [{"children": []}]})


# --------------------------------------------------------------------------- unfinished bags

_KILLED_WRITER = textwrap.dedent(
    """
    import sys
    from dockhil.bags.writer import BagWriter
    from dockhil.msgs import Header, WrenchStamped
    from dockhil.msgs.codec import encode

    bag = BagWriter(sys.argv[1], chunk_size=2048, chunk_seconds=3600)
    bag.add_topic("/ft/wrench", "dockhil/WrenchStamped")
    flushed, k = 0, 0
    while True:
        bag.write("/ft/wrench", k * 1_000_000, k * 1_000_000, encode(WrenchStamped(header=Header(seq=k, tick=k))))
        k += 1
        if bag.messages_flushed != flushed:
            flushed = bag.messages_flushed
            print(flushed, flush=True)
    """
)


def test_sigkill_mid_run_loses_at_most_the_last_chunk(tmp_path, capsys):
    path = tmp_path / "killed.mcap"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    child = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(path)], stdout=subprocess.PIPE, text=True, env=env
    )
    line = "0"
    try:
        for line in child.stdout:
            if int(line) >= 3000:
                break
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
    finally:
        child.kill()
    # Every count the child printed was on disk when printed; drain what it printed before dying.
    printed = [int(line)] + [int(x) for x in child.stdout.read().split()]
    child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    last, per_chunk = printed[-1], printed[-1] - printed[-2] if len(printed) > 1 else None

    found = info(path)
    assert found["recovered"] is True
    n = found["messages"]
    assert n > 0
    # At most one chunk more than the last count printed: the kill can land between a flush and its print.
    assert n == last or (per_chunk and n == last + per_chunk), (n, printed[-3:])
    with BagReader(path) as reader:
        seqs = [m.decode().header.seq for m in reader]
    assert seqs == list(range(n))  # nothing missing, nothing doubled, in order

    out_csv = tmp_path / "killed.csv"
    code, out, err = run_cli(capsys, "export", path, "--topic", "/ft/wrench", "--csv", out_csv)
    assert code == 0 and "unfinished" in err
    rows = list(csv.DictReader(open(out_csv, newline="")))
    assert [int(r["header.seq"]) for r in rows] == list(range(n))
    code, out, _ = run_cli(capsys, "info", path)
    assert code == 0 and "recovered" in out


def test_cut_anywhere_reads_every_complete_chunk(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "full.mcap"
    per_chunk = 10
    with BagWriter(path, chunk_size=1 << 30, chunk_seconds=3600) as bag:
        bag.add_topic("/ft/wrench", "dockhil/WrenchStamped")
        for k in range(6 * per_chunk):
            bag.write("/ft/wrench", k, k, encode(wrench(k)))
            if k % per_chunk == per_chunk - 1:
                bag.flush()
    data = path.read_bytes()
    with open(path, "rb") as fh:
        indexes = make_reader(fh).get_summary().chunk_indexes
    chunk_ends = sorted(c.chunk_start_offset + c.chunk_length for c in indexes)
    data_start = min(c.chunk_start_offset for c in indexes)  # right after the MCAP header
    assert len(chunk_ends) == 6

    cut_path = tmp_path / "cut.mcap"
    cuts = set(range(chunk_ends[1] - 40, chunk_ends[4] + 60, 13))
    cuts |= {e + d for e in chunk_ends for d in (-1, 0, 1)} | {len(data) - 1, len(data) - 8, data_start, data_start + 5}
    for cut in sorted(cuts):
        cut_path.write_bytes(data[:cut])
        with BagReader(cut_path) as reader:
            seqs = [m.decode().header.seq for m in reader]
            assert reader.recovered is True
        complete = sum(end <= cut for end in chunk_ends)
        assert seqs == list(range(per_chunk * complete)), cut

    # Zeros after the last write (pre-allocated space, a power cut) are not corruption.
    cut_path.write_bytes(data[: chunk_ends[2]] + bytes(5000))
    assert info(cut_path)["messages"] == 3 * per_chunk


def test_bag_with_header_only_is_an_empty_unfinished_bag(tmp_path, capsys):
    path = tmp_path / "fresh.mcap"
    bag = BagWriter(path)
    bag.add_topic("/ft/wrench", "dockhil/WrenchStamped")
    bag.write("/ft/wrench", 1, 1, encode(wrench(1)))  # still in the open chunk
    found = info(path)
    assert found["recovered"] is True and found["messages"] == 0 and found["start"] is None
    code, out, _ = run_cli(capsys, "info", path)
    assert code == 0 and "(none)" in out
    bag.close()
    assert info(path)["messages"] == 1


# --------------------------------------------------------------------------- full disk, bad paths


class _FillingDisk(io.BytesIO):
    """A file on a disk that fills up after `room` bytes: the last write is partial."""

    def __init__(self, room: int):
        super().__init__()
        self.room = room

    def write(self, data) -> int:
        left = self.room - self.tell()
        if len(data) > left:
            super().write(bytes(data)[: max(left, 0)])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(data)


def test_full_disk_stops_recording_with_one_line_and_keeps_what_is_on_disk(tmp_path):
    disk = _FillingDisk(room=20_000)
    bag = BagWriter(disk, chunk_size=1024)
    bag.add_topic("/ft/wrench", "dockhil/WrenchStamped")
    with pytest.raises(BagError) as caught:
        for k in range(100_000):
            bag.write("/ft/wrench", k, k, encode(wrench(k)))
    text = str(caught.value)
    assert "\n" not in text and "No space left on device (ENOSPC)" in text and "recording stopped" in text
    kept = bag.messages_flushed
    assert 0 < kept < bag.messages_written
    assert f"{kept} of {bag.messages_written} messages are on disk" in text
    with pytest.raises(BagError, match="ENOSPC"):  # stays stopped
        bag.write("/ft/wrench", 1, 1, encode(wrench(1)))
    bag.close()  # releases, does not raise again

    path = tmp_path / "full.mcap"
    path.write_bytes(disk.getvalue())
    found = info(path)
    assert found["recovered"] is True and found["messages"] == kept


def test_disk_full_at_start_and_unwritable_paths(tmp_path):
    if os.path.exists("/dev/full"):
        with pytest.raises(BagError, match=r"cannot start bag /dev/full: No space left on device"):
            BagWriter("/dev/full", overwrite=True)
    a_file = tmp_path / "plain"
    a_file.write_text("x")
    for bad, words in [
        (tmp_path / "missing" / "run.mcap", "No such file or directory"),
        (a_file / "run.mcap", "Not a directory"),
        (tmp_path, "directory"),
        (a_file, "already exists"),
    ]:
        with pytest.raises(BagError) as caught:
            BagWriter(bad)
        assert words in str(caught.value) and "\n" not in str(caught.value)


def test_writer_refuses_what_would_make_a_bad_bag(tmp_path):
    with BagWriter(tmp_path / "w.mcap") as bag:
        with pytest.raises(BagError, match="unknown message type 'dockhil/Nope'"):
            bag.add_topic("/x", "dockhil/Nope")
        bag.add_topic("/x", "dockhil/EStop")
        bag.add_topic("/x", "dockhil/EStop")  # again: fine
        with pytest.raises(BagError, match="already recorded as dockhil/EStop"):
            bag.add_topic("/x", "dockhil/RobotState")
        with pytest.raises(BagError, match="not added"):
            bag.write("/y", 1, 1, b"\x80")
        for bad_time in (-1, 1.5, 2**64):
            with pytest.raises(BagError, match="integer ns"):
                bag.write("/x", bad_time, 1, b"\x80")
        bag.write("/x", 1, 1, b"\x80")
    assert info(tmp_path / "w.mcap")["messages"] == 1


BAD_FILES = {
    "text": (lambda p: p.write_text("time,force\n0,1\n"), "not an MCAP bag"),
    "ros1": (lambda p: p.write_bytes(b"#ROSBAG V2.0\n" + bytes(100)), "ROS 1 bag"),
    "empty": (lambda p: p.write_bytes(b""), "empty file"),
    "magic_only": (lambda p: p.write_bytes(b"\x89MCAP0\r\n"), "truncated"),
    "short_magic": (lambda p: p.write_bytes(b"\x89MCA"), "truncated"),
    "cut_header": (lambda p: p.write_bytes(b"\x89MCAP0\r\n\x01\x40\x00\x00\x00\x00\x00\x00\x00\x00\x00"), "truncated"),
    "directory": (lambda p: p.mkdir(), "is a directory"),
    "missing": (lambda p: None, "no such file"),
}


@pytest.mark.parametrize("kind", sorted(BAD_FILES))
def test_bad_files_get_one_line(kind, tmp_path, capsys):
    make, words = BAD_FILES[kind]
    path = tmp_path / f"{kind}.mcap"
    make(path)
    code, out, err = run_cli(capsys, "info", path)
    assert_one_line_error(code, err, str(path), words)
    out_csv = tmp_path / "out.csv"
    code, out, err = run_cli(capsys, "export", path, "--topic", "/ft/wrench", "--csv", out_csv)
    assert_one_line_error(code, err, str(path), words)
    assert not out_csv.exists() and not Path(f"{out_csv}.part").exists()


def test_export_errors_name_the_topic_or_the_output(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    write_run(path, n_wrench=20, n_state=2)
    code, _, err = run_cli(capsys, "export", path, "--topic", "/nope", "--csv", tmp_path / "x.csv")
    assert_one_line_error(code, err, "no topic /nope", "/ft/wrench")
    code, _, err = run_cli(capsys, "export", path, "--topic", "/ft/wrench", "--csv", tmp_path / "no" / "x.csv")
    assert_one_line_error(code, err, "cannot write", "No such file or directory")


def test_export_never_replaces_its_own_bag_nor_an_existing_file_unasked(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    write_run(path, n_wrench=20, n_state=2)
    bag_bytes = path.read_bytes()
    # --csv naming the bag it reads (by another spelling too) would replace the recording with a CSV
    for same in (path, tmp_path / "." / "run.mcap"):
        for extra in ((), ("--overwrite",)):
            code, _, err = run_cli(capsys, "export", path, "--topic", "/ft/wrench", "--csv", same, *extra)
            assert_one_line_error(code, err, "is the bag it reads")
    assert path.read_bytes() == bag_bytes
    # an existing file is refused unless --overwrite, as bag convert and bag record do
    existing = tmp_path / "notes.csv"
    existing.write_text("mine\n")
    code, _, err = run_cli(capsys, "export", path, "--topic", "/ft/wrench", "--csv", existing)
    assert_one_line_error(code, err, str(existing), "already exists", "--overwrite")
    assert existing.read_text() == "mine\n"
    code, out, err = run_cli(capsys, "export", path, "--topic", "/ft/wrench", "--csv", existing, "--overwrite")
    assert code == 0 and err == ""
    with open(existing, newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 20


def test_record_and_play_parse_their_options():
    parser = cli.build_parser("bag")
    args = parser.parse_args(
        ["bag", "play", "run.mcap", "--rate", "10", "--loop", "--topics", "/a", "/b", "--start", "2.5", "--sim-time"]
    )
    assert (args.bag_command, args.path, args.rate, args.loop, args.topics, args.start, args.sim_time) == (
        "play",
        "run.mcap",
        10.0,
        True,
        ["/a", "/b"],
        2.5,
        True,
    )
    args = parser.parse_args(["bag", "record", "run.mcap", "--topics", "/ft/wrench"])
    assert (args.bag_command, args.path, args.topics, args.overwrite) == ("record", "run.mcap", ["/ft/wrench"], False)
    for bad in (["--rate", "0"], ["--rate", "nan"], ["--start", "-1"]):
        with pytest.raises(SystemExit):
            parser.parse_args(["bag", "play", "run.mcap", *bad])


# --------------------------------------------------------------------------- bags recorded before json


def _old_run(path, n=300):
    """An old msgpack bag with the topics of write_run; returns (topic, log, publish, wire bytes)."""
    messages = []
    for k in range(n):
        t = 5_000 * MS + k * MS
        messages.append(("/ft/wrench", t, t + 7, encode(wrench(k))))
        if k % 10 == 0:
            messages.append(("/dynamics/state", t, t, encode(state(k // 10))))
    write_msgpack_bag(
        path, {"/ft/wrench": "dockhil/WrenchStamped", "/dynamics/state": "dockhil/SatelliteState"}, messages
    )
    return messages


def test_old_msgpack_bags_read_as_before_and_convert_to_json(tmp_path, capsys):
    import jsonschema
    import msgpack
    from mcap.reader import make_reader

    old = tmp_path / "old.mcap"
    messages = _old_run(old)
    with BagReader(old) as reader:
        assert [(m.topic, m.log_time_ns, m.data) for m in reader] == [(t, ns, d) for t, ns, _, d in messages]
    encodings = {t["topic"]: t["encoding"] for t in info(old)["topics"]}
    assert encodings == {"/ft/wrench": "msgpack", "/dynamics/state": "msgpack"}
    code, out, _ = run_cli(capsys, "info", old)
    assert code == 0 and "encoding:  msgpack (recorded before json channels; 'dockhil bag convert'" in out

    new = tmp_path / "new.mcap"
    code, out, err = run_cli(capsys, "convert", old, new)
    assert code == 0 and err == ""
    assert out == f"{len(messages)} messages written to {new} (json)\n"
    with open(new, "rb") as fh:
        got = list(make_reader(fh, validate_crcs=True).iter_messages(log_time_order=False))
    assert len(got) == len(messages)
    validators = {}  # one per schema record, its schema checked once (jsonschema.validate re-checks it every call)
    for (schema_rec, channel, message), (topic, log_ns, publish_ns, data) in zip(got, messages):
        assert (channel.topic, channel.message_encoding, message.log_time, message.publish_time) == (
            topic,
            "json",
            log_ns,
            publish_ns,
        )
        value = json.loads(message.data)
        assert value == msgpack.unpackb(data)
        if schema_rec.id not in validators:
            found = json.loads(schema_rec.data)
            jsonschema.validators.validator_for(found).check_schema(found)
            validators[schema_rec.id] = jsonschema.validators.validator_for(found)(found)
        validators[schema_rec.id].validate(value)
    code, out, _ = run_cli(capsys, "info", new)
    assert code == 0 and "encoding:  json\n" in out
    # Read back through dockhil: the wire bytes as they were recorded.
    with BagReader(new) as reader:
        assert [(m.topic, m.log_time_ns, m.data) for m in reader] == [(t, ns, d) for t, ns, _, d in messages]

    # An existing OUT is refused in one line, unless --overwrite.
    code, out, err = run_cli(capsys, "convert", old, new)
    assert_one_line_error(code, err, str(new), "already exists")
    code, out, err = run_cli(capsys, "convert", old, new, "--overwrite")
    assert code == 0


def test_convert_keeps_what_a_damaged_old_bag_holds_and_refuses_non_bags(tmp_path, capsys):
    from mcap.reader import make_reader

    old = tmp_path / "old.mcap"
    messages = _old_run(old, n=500)
    with open(old, "rb") as fh:
        chunks = sorted((c.chunk_start_offset, c.chunk_length) for c in make_reader(fh).get_summary().chunk_indexes)
    start, length = chunks[2]
    data = bytearray(old.read_bytes())
    data[start + length // 2] ^= 0x01
    old.write_bytes(bytes(data))
    # write_msgpack_bag closes a chunk after every 50 messages: chunk 2 held messages 100 to 149.
    survivors = [(t, ns, d) for k, (t, ns, _, d) in enumerate(messages) if not 100 <= k < 150]

    new = tmp_path / "new.mcap"
    code, out, err = run_cli(capsys, "convert", old, new)
    assert code == 0
    assert err.count("\n") == 1 and err.startswith("dockhil bag convert: warning: ")
    assert f"bytes {start}-{start + length}" in err
    with BagReader(new) as reader:
        assert [(m.topic, m.log_time_ns, m.data) for m in reader] == survivors
    assert info(new)["loss"] is None  # the new bag itself is whole

    text = tmp_path / "notes.txt"
    text.write_text("not a bag\n")
    out_bag = tmp_path / "out.mcap"
    code, out, err = run_cli(capsys, "convert", text, out_bag)
    assert_one_line_error(code, err, str(text), "not an MCAP bag")
    assert not out_bag.exists() and not Path(f"{out_bag}.part").exists()
