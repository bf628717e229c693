"""ROS 2 messages without ROS 2: the message definitions dockhil exports (`.msg` texts), the
schema text and type hash rosbag2 gives each, and their CDR encoding.

Definitions: the standard types used (`STANDARD_DEFINITIONS`, as in ROS 2's common_interfaces) and
every dockhil_msgs type, whose `.msg` files ship in dockhil.msgs (ros2/dockhil_msgs/msg/).

The CDR encoder needs only the standard library: little-endian plain CDR (XCDR1) behind the
encapsulation header 00 01 00 00, each primitive aligned to its size counted from the end of that
header, a string as uint32 length (with the NUL) + bytes + NUL, a sequence as uint32 count +
elements.
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
import struct
from collections.abc import Callable
from typing import Any, NamedTuple

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
