"""rosbag2 export: a dockhil bag as a rosbag2 bag (`bag export --ros2`, `--bag-format ros2`), read
back by two independent readers, the `rosbags` library and `mcap-ros2-support`, message for message
and field for field. (The `ros2` CLI is not installed here: rosbags reads rosbag2's metadata.yaml
and MCAP storage as `ros2 bag` does.)"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from collections import defaultdict
from importlib.resources import files
from pathlib import Path

import msgspec
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from dockhil import cli
from dockhil.bags import cdr, ros2
from dockhil.bags.reader import BagReader
from dockhil.bags.tools import info
from dockhil.bags.writer import BagWriter
from dockhil.msgs import (
    TYPES,
    BodyState,
    BodyWrenches,
    Energy,
    EStop,
    Header,
    ImpedanceParams,
    NodeStatus,
    Pose,
    Quaternion,
    RobotCommand,
    RobotCycle,
    RobotCycles,
    RobotState,
    SatelliteState,
    Twist,
    Vector3,
    Wrench,
    WrenchStamped,
    type_name,
)
from dockhil.msgs.codec import encode
from tests.conftest import Lines, dockhil_cmd, registered

ROOT = Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------- readers


def typestore():
    """ROS 2 Jazzy's standard types and the dockhil_msgs types from the shipped .msg files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    found = {}
    folder = files("dockhil.msgs").joinpath("ros2", "dockhil_msgs", "msg")
    for entry in folder.iterdir():
        if entry.name.endswith(".msg"):
            found.update(get_types_from_msg(entry.read_text(), f"dockhil_msgs/msg/{entry.name[:-4]}"))
    store.register(found)
    return store


def plain(value):
    """A decoded ROS message (rosbags dataclass or mcap_ros2 object) as dicts and lists."""
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    names = getattr(value, "__dataclass_fields__", None) or getattr(value, "__slots__", None)
    if names is None or isinstance(value, (str, bytes)):
        return value
    return {n: plain(getattr(value, n)) for n in names if not n.startswith("_")}


def read_rosbags(directory: Path) -> list[tuple[str, str, int, dict, bytes]]:
    """(topic, type, time [ns], message, raw CDR) of every message, through rosbags' rosbag2 Reader."""
    store = typestore()
    out = []
    with Rosbag2Reader(directory) as reader:
        for connection, t, raw in reader.messages():
            msg = store.deserialize_cdr(raw, connection.msgtype)
            out.append((connection.topic, connection.msgtype, t, plain(msg), bytes(raw)))
    return out


def read_mcap_ros2(directory: Path) -> list[tuple[str, str, int, int, int, dict]]:
    """(topic, schema name, log time, publish time, sequence, message) through mcap_ros2's decoder,
    which knows only the schemas in the file."""
    (mcap_file,) = directory.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        return [
            (ch.topic, schema.name, m.log_time, m.publish_time, m.sequence, plain(dec))
            for schema, ch, m, dec in reader.iter_decoded_messages(log_time_order=False)
        ]


# --------------------------------------------------------------------------- the expected mapping


def header_of(ros: dict) -> dict:
    stamp = ros["header"]["stamp"]
    assert 0 <= stamp["nanosec"] < 10**9
    return {"stamp_ns": stamp["sec"] * 10**9 + stamp["nanosec"], "frame": ros["header"]["frame_id"]}


def as_dockhil(ros_type: str, ros: dict) -> dict:
    """The fields of the dockhil message a ROS message carries, in dockhil's names."""
    body = {k: v for k, v in ros.items() if k != "header"}
    if ros_type.startswith("dockhil_msgs/"):
        dockhil_cls = TYPES["dockhil/" + ros_type.rsplit("/", 1)[1]] if "Robot" not in ros_type else None
        if dockhil_cls is not None:  # ROS 2 field names are lowercase: map back to dockhil's
            names = {n.lower(): n for n in dockhil_cls.__struct_fields__}
            body = {names[k]: v for k, v in body.items()}
    return body


# dockhil topic type -> suffixes of its ROS topics
SPLIT = {"dockhil/RobotCommand": ("/pose", "/twist", "/enable"), "dockhil/RobotState": ("/pose", "/twist", "/status")}


def expected_of(msg) -> dict:
    """A dockhil message as the test compares it: every field, the header's stamp in ns and frame
    (a std_msgs/Header has no tick and no seq)."""
    value = plain(msgspec.to_builtins(msg))  # tuples as lists
    value.pop("type")
    value.pop("header")
    return {"header": {"stamp_ns": round(msg.header.stamp * 1e9), "frame": msg.header.frame}, **value}


def assert_same_messages(src: Path, rosbags_messages, mcap_messages) -> int:
    """Every message of the dockhil bag `src` equals what both readers give back; returns the count."""
    by_rosbags = defaultdict(list)  # (ROS topic, time) -> messages
    for topic, ros_type, t, msg, _ in rosbags_messages:
        by_rosbags[topic, t].append((ros_type, msg))
    by_mcap = defaultdict(list)
    for topic, ros_type, log_ns, publish_ns, sequence, msg in mcap_messages:
        by_mcap[topic, log_ns].append((ros_type, msg, publish_ns, sequence))
    used = 0
    with BagReader(src) as reader:
        publish = {(m[0], m[2]): m[3] for m in reader.messages_with_publish_time()}
        for topic, log_ns, msg in reader.decoded():
            suffixes = SPLIT.get(type_name(type(msg)), ("",))
            for source, index in ((by_rosbags, None), (by_mcap, 2)):
                parts = [source[topic + s, log_ns].pop(0) for s in suffixes]
                headers = [header_of(p[1]) for p in parts]
                assert all(h == headers[0] for h in headers), (topic, headers)
                got = {"header": headers[0]}
                for ros_type, ros, *_ in parts:
                    got.update(as_dockhil(ros_type, ros))
                assert got == expected_of(msg), (topic, log_ns)
                if index is not None:  # publish time and the publisher's seq in the MCAP message
                    assert all(p[2] == publish[topic, log_ns] and p[3] == msg.header.seq for p in parts)
            used += len(suffixes)
    assert not any(by_rosbags.values()) and not any(by_mcap.values())  # nothing more in the export
    assert used == len(rosbags_messages) == len(mcap_messages)
    return used


# --------------------------------------------------------------------------- a run of hil.yaml


@pytest.fixture(scope="module")
def hil_run(tmp_path_factory):
    """A 0.5 s composed run of hil.yaml recorded as a dockhil bag, exported with the CLI."""
    d = tmp_path_factory.mktemp("hil")
    bag = d / "hil.mcap"
    run = subprocess.run(
        dockhil_cmd("launch", "hil.yaml", "--composed", "--duration", "0.5", "--bag", bag, "--quiet"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    out = d / "hil_ros2"
    export = subprocess.run(
        dockhil_cmd("bag", "export", "--ros2", out, bag),
        cwd=d,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert export.returncode == 0 and export.stderr == "", export.stderr
    return bag, out, export.stdout


def test_a_hil_run_exported_reads_back_equal_with_rosbags_and_mcap_ros2(hil_run):
    bag, out, stdout = hil_run
    assert sorted(p.name for p in out.iterdir()) == ["hil_ros2_0.mcap", "metadata.yaml"]
    rosbags_messages = read_rosbags(out)
    n = assert_same_messages(bag, rosbags_messages, read_mcap_ros2(out))
    dockhil_count = info(bag)["messages"]
    assert stdout == (
        f"{dockhil_count} messages written to {out} as {n} ROS 2 messages on 13 topics (rosbag2: mcap, cdr)\n"
    )
    # The encoder's bytes are the bytes rosbags' own CDR serializer makes of the same message.
    store = typestore()
    for topic, ros_type, _, _, raw in rosbags_messages[:: max(1, n // 500)]:
        assert bytes(store.serialize_cdr(store.deserialize_cdr(raw, ros_type), ros_type)) == raw, topic


def test_the_topics_take_standard_types_and_split_the_robot_messages(hil_run):
    _, out, _ = hil_run
    with Rosbag2Reader(out) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
    assert topics == {
        "/ft/wrench": "geometry_msgs/msg/WrenchStamped",
        "/robot/command/pose": "geometry_msgs/msg/PoseStamped",
        "/robot/command/twist": "geometry_msgs/msg/TwistStamped",
        "/robot/command/enable": "dockhil_msgs/msg/RobotEnable",
        "/robot/command/delayed/pose": "geometry_msgs/msg/PoseStamped",
        "/robot/command/delayed/twist": "geometry_msgs/msg/TwistStamped",
        "/robot/command/delayed/enable": "dockhil_msgs/msg/RobotEnable",
        "/robot/state/pose": "geometry_msgs/msg/PoseStamped",
        "/robot/state/twist": "geometry_msgs/msg/TwistStamped",
        "/robot/state/status": "dockhil_msgs/msg/RobotStatus",
        "/satellite/state": "dockhil_msgs/msg/SatelliteState",
        "/impedance/wrench": "dockhil_msgs/msg/BodyWrenches",
        "/energy": "dockhil_msgs/msg/Energy",
    }


def test_the_bag_carries_its_own_schemas_for_viewers(hil_run):
    """A viewer knows no dockhil_msgs: rosbags' AnyReader with no types of its own reads every
    message from the ros2msg schemas in the file, as Foxglove and PlotJuggler do."""
    _, out, _ = hil_run
    store = get_typestore(Stores.EMPTY)
    with AnyReader([out], default_typestore=store) as reader:
        n = sum(1 for c, _, raw in reader.messages() if reader.deserialize(raw, c.msgtype) is not None)
    with open(next(out.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    sat = next(s for s in summary.schemas.values() if s.name == "dockhil_msgs/msg/SatelliteState").data.decode()
    assert sat.startswith((files("dockhil.msgs") / "ros2/dockhil_msgs/msg/SatelliteState.msg").read_text())
    assert f"\n{'=' * 80}\nMSG: dockhil_msgs/BodyState\n" in sat and "\nMSG: geometry_msgs/Pose\n" in sat
    assert n == yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["message_count"]


def test_metadata_yaml_is_rosbag2s_with_counts_duration_and_topics(hil_run):
    bag, out, _ = hil_run
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    with BagReader(bag) as reader:
        times = [m.log_time_ns for m in reader]
    ros = read_rosbags(out)
    counts = defaultdict(int)
    for topic, *_ in ros:
        counts[topic] += 1
    assert meta["version"] == 8 and meta["storage_identifier"] == "mcap"
    assert meta["starting_time"] == {"nanoseconds_since_epoch": min(times)}
    assert meta["duration"] == {"nanoseconds": max(times) - min(times)} == {"nanoseconds": 500_000_000}
    assert meta["message_count"] == len(ros)
    assert meta["relative_file_paths"] == ["hil_ros2_0.mcap"]
    assert meta["files"] == [
        {
            "path": "hil_ros2_0.mcap",
            "starting_time": meta["starting_time"],
            "duration": meta["duration"],
            "message_count": len(ros),
        }
    ]
    assert meta["compression_format"] == "" and meta["compression_mode"] == ""
    assert meta["custom_data"] is None
    store = typestore()
    topics = {}
    for entry in meta["topics_with_message_count"]:
        m = entry["topic_metadata"]
        topics[m["name"]] = entry["message_count"]
        assert m["serialization_format"] == "cdr"
        assert m["type_description_hash"] == store.hash_rihs01(m["type"])  # REP 2011, computed by rosbags
        (qos,) = yaml.safe_load(m["offered_qos_profiles"])
        assert qos["reliability"] == 1 and qos["durability"] == 2 and qos["history"] == 1 and qos["depth"] == 10
    assert topics == counts
    # The MCAP file repeats it, as rosbag2 writes it, in its "rosbag2" metadata record.
    with open(out / "hil_ros2_0.mcap", "rb") as f:
        (record,) = [r for r in make_reader(f).iter_metadata() if r.name == "rosbag2"]
    assert yaml.safe_load(record.metadata["serialized_metadata"]) == meta


# --------------------------------------------------------------------------- every type, every field


def header(k: int, frame: str = "probe") -> Header:
    # A wall-time stamp: nanoseconds that are not a whole number of ticks.
    return Header(stamp=1_733_300_000.0 + k * 0.001234567, tick=k, seq=1000 + k, frame=frame)


def vec(k: float) -> Vector3:
    return Vector3(x=k + 0.1, y=-k / 3, z=1e-9 * k)


def pose(k: float) -> Pose:
    return Pose(position=vec(k), orientation=Quaternion(x=0.1 * k, y=-0.2, z=0.3, w=0.9))


def twist(k: float) -> Twist:
    return Twist(linear=vec(k + 1), angular=vec(-k))


def every_type(k: int) -> dict[str, object]:
    bodies = tuple(
        BodyState(name=f"body {i} é", mass=10.0 * (i + 1), pose=pose(k + i), twist=twist(i)) for i in range(k % 3)
    )  # 0, 1 or 2 bodies: a sequence of any length
    return {
        "/ft/wrench": WrenchStamped(header=header(k, "ft_sensor"), wrench=Wrench(force=vec(k), torque=vec(2 * k))),
        "/satellite/state": SatelliteState(header=header(k, "world"), bodies=bodies, in_contact=k % 2 == 1),
        "/impedance/wrench": BodyWrenches(header=header(k), wrenches=tuple(Wrench(force=vec(i)) for i in range(k % 4))),
        "/robot/command": RobotCommand(header=header(k, "target"), pose=pose(k), twist=twist(k), enable=k % 2 == 0),
        "/robot/state": RobotState(header=header(k, "target"), pose=pose(-k), twist=twist(k), status="ok" * (k % 3)),
        "/robot/cycles": RobotCycles(
            header=header(k, "target"),
            cycles=tuple(
                RobotCycle(
                    sent=1_733_300_000.0 + i * 0.001,
                    read=1_733_300_000.0004 + i * 0.001,
                    setpoint=pose(k + i),
                    written=i % 2 == 0,
                    actual=pose(-i),
                    device_cycle=65535 - i,
                    taken=i == 1,
                )
                for i in range(k % 3)
            ),
        ),
        "/impedance/params": ImpedanceParams(header=header(k), k1=2001.5 + k, b1=40.03, k2=2.6e6, b2=5e4, method="fit"),
        "/status": NodeStatus(
            header=header(k), node="dynamics", state="running", ticks=2**63 + k, dropped=k, message="line\twith tab"
        ),
        "/estop": EStop(header=header(k), active=k == 3, reason="" if k != 3 else "force 250 N > 200 N"),
        "/energy": Energy(
            header=header(k),
            **{name: 0.5 * k + i for i, name in enumerate(Energy.__struct_fields__) if name.endswith("_J")},
            damping_Ns_m=12.0 * k,
            at_max_damping=k == 2,
            port_loaded=k > 1,
        ),
    }


def test_every_dockhil_type_has_a_ros_type_and_every_field_comes_back(tmp_path, capsys):
    src = tmp_path / "all.mcap"
    with BagWriter(src) as bag:
        for k in range(6):
            for topic, msg in every_type(k).items():
                bag.add_topic(topic, type_name(type(msg)))
                t = round(msg.header.stamp * 1e9)
                bag.write(topic, t, t + 5, encode(msg))
    assert {type_name(type(m)) for m in every_type(0).values()} == set(TYPES)
    out = tmp_path / "all_ros2"
    assert cli.main(["bag", "export", "--ros2", str(out), str(src)]) == 0
    capsys.readouterr()
    assert assert_same_messages(src, read_rosbags(out), read_mcap_ros2(out)) == 6 * (len(TYPES) + 4)


# --------------------------------------------------------------------------- the CDR encoder


def test_cdr_aligns_after_the_encapsulation_header_and_counts_the_nul():
    value = {"header": {"stamp": {"sec": 7, "nanosec": 5}, "frame_id": "ab"}, "active": True, "reason": ""}
    data = cdr.serialize("dockhil_msgs/msg/EStop", value)
    assert data == (
        b"\x00\x01\x00\x00"
        + struct.pack("<iI", 7, 5)
        + struct.pack("<I", 3)
        + b"ab\x00"
        + b"\x01"
        + struct.pack("<I", 1)
        + b"\x00"
    )  # the bool lands on 4-aligned 11: no pad
    value = {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
        "k1": 1.0,
        "b1": 2.0,
        "k2": 3.0,
        "b2": 4.0,
        "method": "x",
    }
    data = cdr.serialize("dockhil_msgs/msg/ImpedanceParams", value)
    # 8 bytes of time, 4 + 1 of frame_id, then k1 8-aligned at 16 (3 bytes of padding)
    assert data[4:17] == bytes(8) + struct.pack("<I", 1) + b"\x00" and data[17:20] == bytes(3)
    assert struct.unpack_from("<4d", data, 4 + 16) == (1.0, 2.0, 3.0, 4.0)
    with pytest.raises(ValueError, match="NodeStatus"):
        cdr.serialize(
            "dockhil_msgs/msg/NodeStatus",
            {**value, "node": "", "state": "", "ticks": 2**64, "dropped": 0, "message": ""},
        )


finite = st.floats(allow_nan=False, allow_infinity=False)
text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=20)


@given(
    st.lists(st.tuples(text, finite, st.lists(finite, min_size=13, max_size=13)), max_size=4),
    st.booleans(),
    st.integers(0, 2**31 - 1),
    st.integers(0, 10**9 - 1),
    text,
)
def test_cdr_equals_rosbags_serializer_for_any_satellite_state(bodies, contact, sec, nanosec, frame):
    store = _STORE
    value = {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame},
        "in_contact": contact,
        "bodies": [
            {
                "name": name,
                "mass": mass,
                "pose": {"position": dict(zip("xyz", v[0:3])), "orientation": dict(zip("xyzw", v[3:7]))},
                "twist": {"linear": dict(zip("xyz", v[7:10])), "angular": dict(zip("xyz", v[10:13]))},
            }
            for name, mass, v in bodies
        ],
    }
    data = cdr.serialize("dockhil_msgs/msg/SatelliteState", value)
    msg = store.deserialize_cdr(data, "dockhil_msgs/msg/SatelliteState")
    assert plain(msg) == value
    assert bytes(store.serialize_cdr(msg, "dockhil_msgs/msg/SatelliteState")) == data


_STORE = typestore()


def test_every_type_hash_and_definition_agrees_with_rosbags():
    store = _STORE
    for name in cdr.definitions():
        assert cdr.type_hash(name) == store.hash_rihs01(name), name
        assert [f.name for f in cdr.fields(name)] == [f[0] for f in store.fielddefs[name][1]], name


def test_the_export_needs_none_of_the_test_libraries(tmp_path, hil_run):
    bag, _, _ = hil_run
    code = (
        "import sys; from dockhil.bags.ros2 import export; export(sys.argv[1], sys.argv[2]); "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('rosbags', 'mcap_ros2', 'yaml', 'numpy')]; "
        "assert not bad, bad"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(bag), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert run.returncode == 0, run.stderr


# --------------------------------------------------------------------------- bad input


def run_cli(capsys, *args):
    code = cli.main([*map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line(code, err, *words):
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, (word, err)


def test_bad_input_is_one_line_and_leaves_what_exists(tmp_path, capsys, hil_run):
    bag, _, _ = hil_run
    code, _, err = run_cli(capsys, "bag", "export", "--ros2", tmp_path / "x", tmp_path / "missing.mcap")
    assert_one_line(code, err, "missing.mcap", "no such file")
    not_a_bag = tmp_path / "notes.txt"
    not_a_bag.write_text("hello\n")
    code, _, err = run_cli(capsys, "bag", "export", "--ros2", tmp_path / "x", not_a_bag)
    assert_one_line(code, err, "not an MCAP bag")
    assert not (tmp_path / "x").exists() and os.listdir(tmp_path) == ["notes.txt"]  # nothing left behind

    out = tmp_path / "out"
    assert run_cli(capsys, "bag", "export", "--ros2", out, bag)[0] == 0
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    code, _, err = run_cli(capsys, "bag", "export", "--ros2", out, bag)
    assert_one_line(code, err, str(out), "already exists", "--overwrite")
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    code, _, _ = run_cli(capsys, "bag", "export", "--ros2", out, bag, "--overwrite")  # a rosbag2 bag: replaced
    assert code == 0 and sorted(p.name for p in out.iterdir()) == ["metadata.yaml", "out_0.mcap"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("keep")
    code, _, err = run_cli(capsys, "bag", "export", "--ros2", mine, bag, "--overwrite")
    assert_one_line(code, err, "not a rosbag2 bag", "not replaced")
    assert os.listdir(mine) == ["thesis.tex"]
    code, _, err = run_cli(capsys, "bag", "export", "--ros2", tmp_path / "no" / "dir", bag)
    assert_one_line(code, err, "does not exist")
    code, _, err = run_cli(capsys, "bag", "export", "--ros2", tmp_path / "y", bag, "--topic", "/ft/wrench")
    assert_one_line(code, err, "--topic is for --csv")
    assert sorted(os.listdir(tmp_path)) == ["mine", "notes.txt", "out"]  # no half-written folder


def test_a_damaged_bag_says_its_loss_in_one_line_and_exports_the_rest(tmp_path, capsys, hil_run):
    bag, _, _ = hil_run
    data = bytearray(bag.read_bytes())
    with open(bag, "rb") as f:
        chunks = sorted((c.chunk_start_offset, c.chunk_length) for c in make_reader(f).get_summary().chunk_indexes)
    start, length = chunks[len(chunks) // 2]
    data[start + 100 : start + length - 100] = bytes(length - 200)  # zeros over most of a middle chunk
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    found = info(damaged)
    assert found["lost"] and 0 < found["messages"] < info(bag)["messages"]
    out = tmp_path / "damaged_ros2"
    code, stdout, err = run_cli(capsys, "bag", "export", "--ros2", out, damaged)
    assert code == 0
    assert err == f"dockhil bag export: warning: {found['loss']}\n"
    assert stdout.startswith(f"{found['messages']} messages written to {out}")
    assert_same_messages(damaged, read_rosbags(out), read_mcap_ros2(out))


def test_a_message_that_does_not_decode_is_counted_not_exported(tmp_path, capsys):
    src = tmp_path / "nan.mcap"
    good = WrenchStamped(header=Header(stamp=0.001, frame="probe"))
    with BagWriter(src) as bag:
        bag.add_topic("/ft/wrench", type_name(WrenchStamped))
        bag.write("/ft/wrench", 1_000_000, 1_000_000, encode(good))
        nan = encode(msgspec.structs.replace(good, header=Header(stamp=0.002)))
        bag.write(
            "/ft/wrench",
            2_000_000,
            2_000_000,
            nan.replace(b"\xcb" + struct.pack(">d", 0.002), b"\xcb" + struct.pack(">d", float("nan"))),
        )
    code, out, err = run_cli(capsys, "bag", "export", "--ros2", tmp_path / "out", src)
    assert code == 0 and out.startswith("1 messages written")
    assert err == (
        "dockhil bag export: note: 1 messages do not decode as their type (e.g. a recorded NaN) "
        "or do not fit their ROS 2 type, and were not exported\n"
    )


# --------------------------------------------------------------------------- recording as rosbag2


def test_launch_with_bag_format_ros2_writes_the_same_bag_as_export(tmp_path):
    args = ("launch", "hil.yaml", "--composed", "--duration", "0.1", "--quiet")
    direct = subprocess.run(
        dockhil_cmd(*args, "--bag", tmp_path / "run", "--bag-format", "ros2"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert direct.returncode == 0, direct.stderr
    assert "messages written to" in direct.stderr.splitlines()[-1]
    assert sorted(os.listdir(tmp_path)) == ["run"]  # the recording is gone once converted
    recorded = subprocess.run(
        dockhil_cmd(*args, "--bag", tmp_path / "run.mcap"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert recorded.returncode == 0, recorded.stderr
    ros2.export(tmp_path / "run.mcap", tmp_path / "exported")
    a, b = read_mcap_ros2(tmp_path / "run"), read_mcap_ros2(tmp_path / "exported")
    assert len(a) > 600 and a == b  # sim time: the same run, the same messages and times
    meta = [
        yaml.safe_load((tmp_path / d / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        for d in ("run", "exported")
    ]
    assert meta[0]["topics_with_message_count"] == meta[1]["topics_with_message_count"]

    refused = subprocess.run(
        dockhil_cmd(*args, "--bag", tmp_path / "run", "--bag-format", "ros2"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert refused.returncode == 2 and "already exists" in refused.stderr and refused.stderr.count("\n") == 1
    refused = subprocess.run(
        dockhil_cmd(*args, "--bag-format", "ros2"), cwd=ROOT, capture_output=True, text=True, timeout=300, check=False
    )
    assert refused.returncode == 2 and "--bag-format ros2 needs --bag DIR" in refused.stderr


class _Say:
    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(("info", text))

    def warning(self, text):
        self.lines.append(("warning", text))

    def error(self, text):
        self.lines.append(("error", text))


def test_a_recording_that_cannot_be_converted_is_kept_and_fails_the_run(tmp_path, monkeypatch):
    dst = tmp_path / "lab"

    def record(path):
        with BagWriter(path) as bag:
            bag.add_topic("/ft/wrench", type_name(WrenchStamped))
            bag.write("/ft/wrench", 0, 0, encode(WrenchStamped(header=Header())))
        return 0

    say = _Say()
    assert ros2.record_then_convert(str(dst), record, say) == 0
    assert sorted(os.listdir(tmp_path)) == ["lab"] and say.lines[-1][0] == "info"

    def failing_export(*_, **__):
        raise ros2.BagError("cannot write lab2: No space left on device (ENOSPC)")

    monkeypatch.setattr(ros2, "export", failing_export)
    say = _Say()
    assert ros2.record_then_convert(str(tmp_path / "lab2"), record, say) == 1
    assert (tmp_path / "lab2.recording.mcap").exists()
    ((level, line),) = say.lines
    assert level == "error" and "ENOSPC" in line and "dockhil bag export --ros2" in line
    # The recording left behind is refused as a place to record to, and named.
    with pytest.raises(ros2.BagError, match="lab2.recording.mcap exists"):
        ros2.record_then_convert(str(tmp_path / "lab2"), record, say)


def test_bag_record_with_bag_format_ros2_and_no_graph_leaves_nothing(tmp_path, capsys):
    code, _, err = run_cli(capsys, "bag", "record", tmp_path / "lab", "--bag-format", "ros2", "--topics", "/nope")
    assert code != 0 and err.count("\n") == 1 and "Traceback" not in err, err
    assert os.listdir(tmp_path) == []


def test_bag_record_with_bag_format_ros2_records_a_played_run_as_its_export(tmp_path, hil_run):
    """`bag play --sim-time` of the hil bag, recorded by `bag record DIR --bag-format ros2`: the
    rosbag2 bag holds what exporting the hil bag gives (sim time: the same messages and times)."""
    bag, exported, _ = hil_run
    out = tmp_path / "lab"
    play = subprocess.Popen(
        dockhil_cmd("bag", "play", bag, "--sim-time"), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    rec = None
    try:
        registered(play.pid)
        rec = subprocess.Popen(
            dockhil_cmd("bag", "record", out, "--bag-format", "ros2"),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        _, play_err = play.communicate(timeout=120)
        rec_err = Lines(rec, rec.stderr).rest(timeout=120)
    finally:
        for proc in (play, rec):
            if proc is not None and proc.poll() is None:
                proc.kill()
    assert play.returncode == 0, play_err
    assert rec.returncode == 0 and "Traceback" not in rec_err, rec_err
    assert f"messages written to {out} as " in rec_err.splitlines()[-1]
    assert sorted(os.listdir(tmp_path)) == ["lab"]
    assert sorted(read_mcap_ros2(out), key=repr) == sorted(read_mcap_ros2(exported), key=repr)
