"""rosbag2 bags from dockhil bags, for the tools of a ROS 2 lab (`ros2 bag info/play`, rosbags,
Foxglove, PlotJuggler).

A rosbag2 bag is a directory DIR holding `DIR_0.mcap` and `metadata.yaml`, as rosbag2 writes them:

- the MCAP file has profile "ros2", one schema per ROS type (encoding "ros2msg": the type's `.msg`
  text, then each type it uses after a line of 80 "=" and a line "MSG: pkg/Type"; `schema_text`), one channel per
  ROS topic (message encoding "cdr", metadata offered_qos_profiles and topic_type_hash) and a
  metadata record "rosbag2" repeating metadata.yaml;
- metadata.yaml is rosbag2's bag information, version 8: the newest layout that Humble's rosbag2
  still reads (version 9 writes the QoS profiles as a list, which Humble cannot parse), and that
  Iron's and Jazzy's read as well.

Messages take the standard ROS 2 types where one exists (`ROS_TOPICS`): a wrench is a
geometry_msgs/msg/WrenchStamped; a robot command or state is split into a PoseStamped topic
(TOPIC/pose), a TwistStamped topic (TOPIC/twist) and the rest (TOPIC/enable, TOPIC/status). What
has no standard type is a dockhil_msgs type, whose `.msg` files ship in dockhil.msgs
(ros2/dockhil_msgs/msg/). The header becomes a std_msgs/Header: `stamp` [s, float] becomes a
builtin_interfaces/Time (sec, nanosec: the stamp rounded to the nanosecond), `frame` the frame_id.
A std_msgs/Header has no tick and no seq: header.seq goes to the MCAP message's sequence number,
the tick stays in the dockhil bag (a sim-time run's tick is its stamp times the rate).

Times: a message's rosbag2 time (MCAP log and publish time) is its log time in the dockhil bag, in
ns since the Unix epoch (sim time t [s] is t * 1e9 ns after it).

The CDR encoder below needs only the standard library: little-endian plain CDR (XCDR1) behind the
encapsulation header 00 01 00 00, each primitive aligned to its size counted from the end of that
header, a string as uint32 length (with the NUL) + bytes + NUL, a sequence as uint32 count +
elements.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import shutil
import struct
import tempfile
import textwrap
from collections.abc import Callable
from typing import Any, NamedTuple

import msgspec

from dockhil.bags.format import BagError
from dockhil.bags.reader import BagReader

# ------------------------------------------------------------------ message definitions

# The standard types used, as in ROS 2's common_interfaces (comments left out).
STANDARD_DEFINITIONS = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/msg/Twist": "Vector3 linear\nVector3 angular\n",
    "geometry_msgs/msg/Wrench": "Vector3 force\nVector3 torque\n",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose\n",
    "geometry_msgs/msg/TwistStamped": "std_msgs/Header header\nTwist twist\n",
    "geometry_msgs/msg/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
}
PACKAGE = "dockhil_msgs"

# name -> (struct format, size); byte and char are uint8 in ROS 2.
_PRIMITIVES = {
    "bool": ("?", 1),
    "byte": ("B", 1),
    "char": ("B", 1),
    "int8": ("b", 1),
    "uint8": ("B", 1),
    "int16": ("h", 2),
    "uint16": ("H", 2),
    "int32": ("i", 4),
    "uint32": ("I", 4),
    "int64": ("q", 8),
    "uint64": ("Q", 8),
    "float32": ("f", 4),
    "float64": ("d", 8),
}
# Type ids of the type description (REP 2011), for the RIHS01 type hash; + 144 for a sequence.
_TYPE_IDS = {
    "int8": 2,
    "uint8": 3,
    "int16": 4,
    "uint16": 5,
    "int32": 6,
    "uint32": 7,
    "int64": 8,
    "uint64": 9,
    "float32": 10,
    "float64": 11,
    "char": 13,
    "bool": 15,
    "byte": 16,
    "string": 17,
}
_NESTED_ID, _SEQUENCE_ID = 1, 144
_FIELD = re.compile(r"^([A-Za-z][A-Za-z0-9_/]*)(\[\])?\s+([a-z][a-z0-9_]*)(\s+\S.*)?$")


class Field(NamedTuple):
    name: str
    type: str  # a primitive, "string", or a full type name "pkg/msg/Type"
    sequence: bool


def _message_dir():
    from importlib.resources import files

    return files("dockhil.msgs").joinpath("ros2", PACKAGE, "msg")


@functools.cache
def definitions() -> dict[str, str]:
    """Full type name -> `.msg` text: the standard types used and every shipped dockhil_msgs type."""
    found = dict(STANDARD_DEFINITIONS)
    for entry in sorted(_message_dir().iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".msg"):
            found[f"{PACKAGE}/msg/{entry.name[:-4]}"] = entry.read_text(encoding="utf-8")
    return found


@functools.cache
def fields(type_name: str) -> tuple[Field, ...]:
    """The fields of a type, parsed from its `.msg` text (constants, which are not serialized, left
    out). Only what the shipped files use is understood: primitives, strings, nested types and
    unbounded sequences of them."""
    package = type_name.split("/")[0]
    out = []
    for line in definitions()[type_name].splitlines():
        line = line.split("#", 1)[0].strip()
        if not line or "=" in line:
            continue  # a blank line or a constant (TYPE NAME=VALUE)
        match = _FIELD.match(line)
        if match is None:
            raise ValueError(f"{type_name}: cannot read field {line!r}")
        kind, sequence, name = match.group(1), bool(match.group(2)), match.group(3)
        if kind not in _PRIMITIVES and kind != "string":
            pkg, _, short = kind.rpartition("/")
            kind = f"{pkg or package}/msg/{short}"
            if kind not in definitions():
                raise ValueError(f"{type_name}: field {name} has unknown type {match.group(1)}")
        out.append(Field(name, kind, sequence))
    return tuple(out)


def _dependencies(type_name: str) -> list[str]:
    """The types `type_name` uses, each once, depth first in field order."""
    found: list[str] = []

    def visit(name: str) -> None:
        for field in fields(name):
            if "/" in field.type and field.type not in found:
                found.append(field.type)
                visit(field.type)

    visit(type_name)
    return found


def schema_text(type_name: str) -> str:
    """The concatenated `ros2msg` definition of a channel's schema, as rosbag2 builds it: the type's
    text, then for each type it uses (by name, sorted, depth first, each once) a new line, a line of
    80 "=", "MSG: pkg/Type" and that type's text."""
    seen: set[str] = set()

    def text(name: str) -> str:
        out = definitions()[name]
        for dep in sorted({f.type for f in fields(name) if "/" in f.type}):
            pkg, _, short = dep.split("/")
            if f"{pkg}/{short}" not in seen:
                seen.add(f"{pkg}/{short}")
                out += f"\n{'=' * 80}\nMSG: {pkg}/{short}\n{text(dep)}"
        return out

    return text(type_name)


def type_hash(type_name: str) -> str:
    """The type's RIHS01 hash (REP 2011): sha256 of its type description as JSON."""

    def describe(name: str) -> dict:
        out = []
        for field in fields(name):
            nested = "/" in field.type
            type_id = (_NESTED_ID if nested else _TYPE_IDS[field.type]) + (_SEQUENCE_ID if field.sequence else 0)
            out.append(
                {
                    "name": field.name,
                    "type": {
                        "type_id": type_id,
                        "capacity": 0,
                        "string_capacity": 0,
                        "nested_type_name": field.type if nested else "",
                    },
                }
            )
        return {"type_name": name, "fields": out}

    description = {
        "type_description": describe(type_name),
        "referenced_type_descriptions": [describe(dep) for dep in sorted(_dependencies(type_name))],
    }
    return "RIHS01_" + hashlib.sha256(json.dumps(description).encode()).hexdigest()


# ------------------------------------------------------------------ CDR

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian; options 0
_COUNT = struct.Struct("<I")
_Encode = Callable[[bytearray, Any], None]


def serialize(type_name: str, value: dict) -> bytes:
    """`value` (a dict of the type's fields, nested dicts and lists) as CDR bytes; ValueError naming
    the type if a field is missing or does not fit its type."""
    buf = bytearray(_ENCAPSULATION)
    try:
        _encoder(type_name)(buf, value)
    except (struct.error, KeyError, TypeError, UnicodeEncodeError, OverflowError) as exc:
        raise ValueError(f"{type_name}: {type(exc).__name__}: {exc}") from None
    return bytes(buf)


def _pad(buf: bytearray, size: int) -> None:
    # Alignment counts from the end of the encapsulation header.
    pad = -(len(buf) - 4) % size
    if pad:
        buf += bytes(pad)


@functools.cache
def _encoder(type_name: str) -> _Encode:
    steps = [_field_encoder(f) for f in fields(type_name)]

    def encode(buf: bytearray, value: Any) -> None:
        for step in steps:
            step(buf, value)

    return encode


def _string(buf: bytearray, text: str) -> None:
    data = text.encode("utf-8") + b"\x00"
    _pad(buf, 4)
    buf += _COUNT.pack(len(data))
    buf += data


def _field_encoder(field: Field) -> _Encode:
    name = field.name
    if field.type in _PRIMITIVES:
        fmt, size = _PRIMITIVES[field.type]
        if field.sequence:

            def encode(buf, value):
                items = value[name]
                _pad(buf, 4)
                buf += _COUNT.pack(len(items))
                if items:
                    _pad(buf, size)
                    buf += struct.pack(f"<{len(items)}{fmt}", *items)
        else:
            pack = struct.Struct("<" + fmt).pack

            def encode(buf, value):
                _pad(buf, size)
                buf += pack(value[name])

        return encode
    element = _string if field.type == "string" else _encoder(field.type)
    if field.sequence:

        def encode(buf, value):
            items = value[name]
            _pad(buf, 4)
            buf += _COUNT.pack(len(items))
            for item in items:
                element(buf, item)
    else:

        def encode(buf, value):
            element(buf, value[name])

    return encode


# ------------------------------------------------------------------ dockhil messages as ROS messages

POSE, TWIST = "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TwistStamped"

# dockhil type -> (suffix of the ROS topic, ROS type, the fields of its value besides the header).
# Other dockhil types map to dockhil_msgs types of the same name, field for field (lowercased).
ROS_TOPICS: dict[str, tuple[tuple[str, str, tuple[str, ...]], ...]] = {
    "dockhil/WrenchStamped": (("", "geometry_msgs/msg/WrenchStamped", ("wrench",)),),
    "dockhil/RobotCommand": (
        ("/pose", POSE, ("pose",)),
        ("/twist", TWIST, ("twist",)),
        ("/enable", f"{PACKAGE}/msg/RobotEnable", ("enable",)),
    ),
    "dockhil/RobotState": (
        ("/pose", POSE, ("pose",)),
        ("/twist", TWIST, ("twist",)),
        ("/status", f"{PACKAGE}/msg/RobotStatus", ("status",)),
    ),
}
MAX_STAMP_S = 2**31  # builtin_interfaces/Time has int32 seconds


def ros_topics(topic: str, type_name: str) -> tuple[tuple[str, str, tuple[str, ...] | None], ...]:
    """(ROS topic, ROS type, fields or None for all of them) for a dockhil topic of `type_name`;
    KeyError if the type has no ROS type."""
    mapped = ROS_TOPICS.get(type_name)
    if mapped is not None:
        return tuple((topic + suffix, ros_type, names) for suffix, ros_type, names in mapped)
    ros_type = f"{PACKAGE}/msg/{type_name.removeprefix('dockhil/')}"
    if not type_name.startswith("dockhil/") or ros_type not in definitions():
        raise KeyError(type_name)
    return ((topic, ros_type, None),)


def ros_header(header) -> dict:
    """A dockhil Header as a std_msgs/Header value."""
    if not header.stamp < MAX_STAMP_S:
        raise ValueError(f"stamp {header.stamp} s does not fit builtin_interfaces/Time (int32 seconds)")
    sec, nanosec = divmod(round(header.stamp * 1e9), 10**9)
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": header.frame}


def ros_value(message, names: tuple[str, ...] | None) -> dict:
    """The value of a ROS message from a dockhil message: its header and the fields `names` (None:
    every field, each under its lowercased name)."""
    value = {
        name.lower(): msgspec.to_builtins(getattr(message, name))
        for name in (names if names is not None else message.__struct_fields__)
        if name != "header"
    }
    value["header"] = ros_header(message.header)
    return value


_TOPIC_NAME = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")


# ------------------------------------------------------------------ metadata.yaml

VERSION = 8
# ROS 2's default publisher QoS (keep last 10, reliable, volatile; default deadline, lifespan and
# liveliness), in version 8's form: a YAML text with the enums as numbers.
QOS_PROFILES = (
    "- history: 1\n  depth: 10\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 0\n    nsec: 0\n"
    "  lifespan:\n    sec: 0\n    nsec: 0\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n"
    "    nsec: 0\n  avoid_ros_namespace_conventions: false"
)


def metadata_yaml(file_name: str, start_ns: int, duration_ns: int, topics: list[tuple[str, str, int]]) -> str:
    """rosbag2's metadata.yaml for one MCAP file; topics: (name, type, message count). Written as
    rosbag2 writes it (names and types need no quoting: they are checked ROS names)."""
    count = sum(n for _, _, n in topics)
    qos = json.dumps(QOS_PROFILES)  # a double-quoted YAML string: JSON's escapes are YAML's
    lines = [
        "rosbag2_bagfile_information:",
        f"  version: {VERSION}",
        "  storage_identifier: mcap",
        "  duration:",
        f"    nanoseconds: {duration_ns}",
        "  starting_time:",
        f"    nanoseconds_since_epoch: {start_ns}",
        f"  message_count: {count}",
        "  topics_with_message_count:" + ("" if topics else " []"),
    ]
    for name, ros_type, n in topics:
        lines += [
            "    - topic_metadata:",
            f"        name: {name}",
            f"        type: {ros_type}",
            "        serialization_format: cdr",
            f"        offered_qos_profiles: {qos}",
            f"        type_description_hash: {type_hash(ros_type)}",
            f"      message_count: {n}",
        ]
    lines += [
        '  compression_format: ""',
        '  compression_mode: ""',
        "  relative_file_paths:",
        f"    - {file_name}",
        "  files:",
        f"    - path: {file_name}",
        "      starting_time:",
        f"        nanoseconds_since_epoch: {start_ns}",
        "      duration:",
        f"        nanoseconds: {duration_ns}",
        f"      message_count: {count}",
        "  custom_data: ~",
        '  ros_distro: ""',
    ]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ export


class Ros2Result(NamedTuple):
    messages: int  # ROS messages written
    topics: int  # ROS topics
    converted: int  # dockhil messages they came from
    unconvertible: int  # not written: they do not decode as their type (a recorded NaN) or do not fit the ROS type
    skipped_topics: list[str]  # "TOPIC: why" for each topic left out
    loss: str | None  # what of the dockhil bag was unreadable or unfinished (see dockhil.bags.format.loss_line)


def export(src: str | os.PathLike, dst: str | os.PathLike, *, overwrite: bool = False) -> Ros2Result:
    """Write the dockhil bag `src` as the rosbag2 bag (directory) `dst`.

    `dst` appears only complete: it is written aside in its parent folder, then moved into place.
    An existing `dst` is refused unless `overwrite`, and then replaced only if it is a rosbag2 bag
    (it holds metadata.yaml) or an empty folder. A damaged or unfinished bag is exported as far as
    it reads (`loss` says what was lost).
    """
    src, dst = os.fspath(src), os.path.normpath(os.fspath(dst))
    _check_destination(src, dst, overwrite)
    with BagReader(src) as reader:
        found = reader.summary()
        parent = os.path.dirname(os.path.abspath(dst))
        try:
            work = tempfile.mkdtemp(prefix=f".{os.path.basename(dst)}.", suffix=".part", dir=parent)
        except OSError as exc:
            raise BagError(f"cannot create {dst}: {_reason(exc)}") from None
        try:
            result = _write(reader, found, os.path.join(work, os.path.basename(dst)), src)
            _move_into_place(os.path.join(work, os.path.basename(dst)), dst)
        except OSError as exc:
            raise BagError(f"cannot write {dst}: {_reason(exc)}") from None
        finally:
            shutil.rmtree(work, ignore_errors=True)
    return result


def _reason(exc: OSError) -> str:
    from dockhil.files import os_reason

    return os_reason(exc)


def _check_destination(src: str, dst: str, overwrite: bool) -> None:
    if not os.path.lexists(dst):
        if not os.path.isdir(os.path.dirname(os.path.abspath(dst))):
            raise BagError(f"cannot create {dst}: folder {os.path.dirname(os.path.abspath(dst))} does not exist")
        return
    if not overwrite:
        raise BagError(f"{dst} already exists; choose another name or pass --overwrite to replace it")
    if not os.path.isdir(dst) or os.path.islink(dst):
        raise BagError(f"{dst} exists and is not a folder, so not a rosbag2 bag; not replaced: choose another name")
    if os.listdir(dst) and not os.path.isfile(os.path.join(dst, "metadata.yaml")):
        raise BagError(f"{dst} is a folder but not a rosbag2 bag (no metadata.yaml); not replaced: choose another name")
    if os.path.exists(src) and os.path.realpath(src).startswith(os.path.realpath(dst) + os.sep):
        raise BagError(f"{dst} holds the bag {src} it would be made from; choose another name")


def _move_into_place(made: str, dst: str) -> None:
    """Move the folder `made` to `dst`; a `dst` there (checked: a rosbag2 bag or an empty folder)
    goes into `made`'s folder first, which the caller removes."""
    if os.path.lexists(dst):
        os.rename(dst, os.path.join(os.path.dirname(made), "replaced"))
    os.rename(made, dst)


def _write(reader: BagReader, found: dict, directory: str, src: str) -> Ros2Result:
    from mcap.writer import CompressionType, Writer

    from dockhil import __version__
    from dockhil.msgs import TYPES
    from dockhil.msgs.codec import DecodeError, decode

    plan: dict[str, list[tuple[str, str, tuple[str, ...] | None]]] = {}  # dockhil topic -> ROS topics
    skipped: list[str] = []
    owner: dict[str, str] = {}  # ROS topic -> the dockhil topic it comes from
    for entry in found["topics"]:
        topic, type_name = entry["topic"], entry["type"]
        if not _TOPIC_NAME.match(topic):
            skipped.append(f"{topic}: not a valid ROS 2 topic name (letters, digits and _ between /)")
            continue
        try:
            targets = ros_topics(topic, type_name)
        except KeyError:
            skipped.append(f"{topic}: type {type_name or '?'} has no ROS 2 type here")
            continue
        for ros_topic, _, _ in targets:
            if ros_topic in owner:
                raise BagError(
                    f"{src}: topics {owner[ros_topic]} and {topic} would both be the ROS 2 topic "
                    f"{ros_topic}; rename one before exporting"
                )
            owner[ros_topic] = topic
        plan[topic] = list(targets)

    name = os.path.basename(directory)
    file_name = f"{name}_0.mcap"
    os.mkdir(directory)
    counts: dict[str, int] = {}
    channels: dict[str, int] = {}
    converted = unconvertible = 0
    start = end = None
    with open(os.path.join(directory, file_name), "xb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library=f"dockhil {__version__}")
        schemas: dict[str, int] = {}
        for targets in plan.values():
            for ros_topic, ros_type, _ in targets:
                if ros_type not in schemas:
                    schemas[ros_type] = writer.register_schema(ros_type, "ros2msg", schema_text(ros_type).encode())
                channels[ros_topic] = writer.register_channel(
                    ros_topic,
                    "cdr",
                    schemas[ros_type],
                    {"offered_qos_profiles": QOS_PROFILES, "topic_type_hash": type_hash(ros_type)},
                )
                counts[ros_topic] = 0
        for topic, type_name, log_ns, publish_ns, data in reader.messages_with_publish_time():
            targets = plan.get(topic)
            if targets is None:
                continue
            try:
                message = decode(data, TYPES[type_name])
                encoded = [
                    (ros_topic, serialize(ros_type, ros_value(message, names)))
                    for ros_topic, ros_type, names in targets
                ]
            except (DecodeError, ValueError, RecursionError):
                unconvertible += 1
                continue
            for ros_topic, cdr in encoded:
                writer.add_message(
                    channels[ros_topic], log_ns, cdr, publish_ns, sequence=message.header.seq & 0xFFFFFFFF
                )
                counts[ros_topic] += 1
            converted += 1
            start = log_ns if start is None or log_ns < start else start
            end = log_ns if end is None or log_ns > end else end
        start = start or 0
        duration = (end - start) if end is not None else 0
        topics = [(t, ros_type, counts[t]) for targets in plan.values() for t, ros_type, _ in targets]
        text = metadata_yaml(file_name, start, duration, topics)
        writer.add_metadata("rosbag2", {"serialized_metadata": textwrap.dedent(text.split("\n", 1)[1])})
        writer.finish()
        f.flush()
        os.fsync(f.fileno())
    with open(os.path.join(directory, "metadata.yaml"), "x", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    return Ros2Result(sum(counts.values()), len(counts), converted, unconvertible, skipped, found["loss"])


def tell(result: Ros2Result, dst: str, say) -> str:
    """What an export lost or left out, to `say` (a dockhil.log.Log); returns the line saying what
    it wrote."""
    if result.loss:
        say.warning(result.loss)
    for line in result.skipped_topics:
        say.info(f"note: {line}; not exported")
    if result.unconvertible:
        say.info(
            f"note: {result.unconvertible} messages do not decode as their type (e.g. a recorded NaN) "
            f"or do not fit their ROS 2 type, and were not exported"
        )
    return (
        f"{result.converted} messages written to {dst} as {result.messages} ROS 2 messages on "
        f"{result.topics} topics (rosbag2: mcap, cdr)"
    )


# ------------------------------------------------------------------ recording as rosbag2


def recording_path(dst: str, *, overwrite: bool = False) -> str:
    """The dockhil bag to record before it becomes the rosbag2 bag `dst`: `dst`.recording.mcap,
    beside it. Refuses (one line) a `dst` that export would refuse, and a recording left there."""
    dst = os.path.normpath(dst)
    _check_destination("", dst, overwrite)
    path = f"{dst}.recording.mcap"
    if os.path.lexists(path):
        raise BagError(
            f"{path} exists (a recording for {dst} that was not converted?): convert it with "
            f"'dockhil bag export --ros2 {dst} {path}', or remove it"
        )
    return path


def record_then_convert(dst: str, record: Callable[[str], int], say, *, overwrite: bool = False) -> int:
    """`record(path)` records a dockhil bag at `path` and returns an exit code; the bag then becomes
    the rosbag2 bag `dst` and is removed. The dockhil bag is recorded first, and converted after,
    so that one recorder (crash-safe, lossless, read back by the run's summary) serves both formats.
    Returns record's code, or 1 if it was 0 and the conversion failed (the recording is kept)."""
    path = recording_path(dst, overwrite=overwrite)
    try:
        code = record(path)
    except BaseException:
        _remove_if_empty(path)
        raise
    if not os.path.exists(path):
        return code
    try:
        result = export(path, dst, overwrite=overwrite)
    except BagError as exc:
        say.error(f"{exc}; the recording stays at {path} ('dockhil bag export --ros2 {dst} {path}' converts it)")
        return code or 1
    os.remove(path)
    say.info(tell(result, dst, say))
    return code


def _remove_if_empty(path: str) -> None:
    """A recording that holds no message goes (a run refused or failed before its first tick)."""
    try:
        with BagReader(path) as reader:
            empty = reader.summary()["messages"] == 0
        if empty:
            os.remove(path)
    except (BagError, OSError):
        pass
