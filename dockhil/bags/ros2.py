"""rosbag2 bags from dockhil bags, for the tools of a ROS 2 lab (`ros2 bag info/play`, rosbags,
Foxglove, PlotJuggler).

A rosbag2 bag is a directory DIR holding `DIR_0.mcap` and `metadata.yaml`, as rosbag2 writes them:

- the MCAP file has profile "ros2", one schema per ROS type (encoding "ros2msg": the type's `.msg`
  text, then each type it uses after a line of 80 "=" and a line "MSG: pkg/Type";
  `cdr.schema_text`), one channel per ROS topic (message encoding "cdr", metadata
  offered_qos_profiles and topic_type_hash) and a metadata record "rosbag2" repeating
  metadata.yaml;
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

The ROS 2 message definitions, their schemas and type hashes, and the CDR encoder are
dockhil.bags.cdr.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import textwrap
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import msgspec

from dockhil.bags.cdr import PACKAGE, definitions, schema_text, serialize, type_hash
from dockhil.bags.format import BagError
from dockhil.bags.reader import BagReader

if TYPE_CHECKING:
    from dockhil.log import Log
    from dockhil.msgs import Header, Message

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


def ros_header(header: Header) -> dict:
    """A dockhil Header as a std_msgs/Header value."""
    if not header.stamp < MAX_STAMP_S:
        raise ValueError(f"stamp {header.stamp} s does not fit builtin_interfaces/Time (int32 seconds)")
    sec, nanosec = divmod(round(header.stamp * 1e9), 10**9)
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": header.frame}


def ros_value(message: Message, names: tuple[str, ...] | None) -> dict:
    """The value of a ROS message from a dockhil message: its header and the fields `names` (None:
    every field, each under its lowercased name)."""
    value = {
        name.lower(): msgspec.to_builtins(getattr(message, name))
        for name in (names if names is not None else message.__struct_fields__)
        if name != "header"
    }
    value["header"] = ros_header(message.header)  # type: ignore[attr-defined]  # every message type has one
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
        for planned in plan.values():
            for ros_topic, ros_type, _ in planned:
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
            routes = plan.get(topic)
            if routes is None:
                continue
            try:
                message = decode(data, TYPES[type_name])
                encoded = [
                    (ros_topic, serialize(ros_type, ros_value(message, names))) for ros_topic, ros_type, names in routes
                ]
            except (DecodeError, ValueError, RecursionError):
                unconvertible += 1
                continue
            for ros_topic, cdr in encoded:
                writer.add_message(
                    channels[ros_topic],
                    log_ns,
                    cdr,
                    publish_ns,
                    sequence=message.header.seq & 0xFFFFFFFF,  # type: ignore[attr-defined]  # every message type has a header
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


def tell(result: Ros2Result, dst: str, say: Log) -> str:
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


def record_then_convert(dst: str, record: Callable[[str], int], say: Log, *, overwrite: bool = False) -> int:
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
