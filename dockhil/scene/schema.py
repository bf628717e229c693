"""The launch file's schema: typed, bounded fields, checked by msgspec.

A file is checked against `LaunchFile` after `$(arg ...)` / `$(var ...)`
substitution, so `rate: $(arg rate)` is bounded like `rate: 500`. A refusal names the file,
the line and the field path (`nodes[2].respawn_delay`), says what was
expected and what was given. `dockhil graph --schema` prints the JSON Schema.
"""

from __future__ import annotations

import difflib
import math
import re
import types
from typing import Annotated, Any, Literal, Union, cast, get_args, get_origin

import msgspec
from msgspec import Meta, Struct, field

# Physical bounds of a scene. A sim-time step below 1 us or a run longer than about
# 11 days is no docking experiment; the bounds keep every derived count finite.
MIN_RATE, MAX_RATE = 1e-3, 1e6  # [Hz]
MAX_DURATION = 1e6  # [s]
MAX_RESPAWN_DELAY = 600.0  # [s]
MAX_NODES = 1000  # nodes in one scene, includes counted
MAX_INCLUDES = 100  # launch files read for one scene
MAX_CHOICES = 1000
MAX_TEXT = 65536  # characters of one string after $(arg ...) substitution
MAX_SUBSTITUTED = 1 << 22  # characters built by substitution for one scene, includes counted
MAX_LETS = 1000  # `let` variables in one file
MAX_AGE = 600.0  # [s] the longest maximum age a launch file may give a wall-time input

UNIONS = (Union, types.UnionType)  # typing.Union[...] and X | Y

Scalar = bool | int | float | str
# A list of numbers (an F/T bias per axis): an argument's default, given as [a, b, ...] or a,b,...
Numbers = Annotated[list[float], Meta(max_length=MAX_CHOICES)]
Condition = bool | int | str | None
Rate = Annotated[
    float,
    Meta(
        ge=MIN_RATE,
        le=MAX_RATE,
        description=(f"steps per second [Hz], {MIN_RATE:g} to {MAX_RATE:g}; the sim-time step is 1/rate"),
    ),
]
Duration = Annotated[
    float,
    Meta(
        gt=0.0,
        le=MAX_DURATION,
        description=(f"run length [s], > 0 and at most {MAX_DURATION:g}; default for --duration"),
    ),
]
RespawnDelay = Annotated[
    float, Meta(ge=0.0, le=MAX_RESPAWN_DELAY, description=f"wait before a respawn [s], 0 to {MAX_RESPAWN_DELAY:g}")
]
NODE_NAME = r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$"
NodeName = Annotated[
    str,
    Meta(pattern=NODE_NAME, max_length=64, description="a node name; letters, digits, _ . - and at most 64 characters"),
]
NodeType = Annotated[
    str,
    Meta(
        pattern=r"^[A-Za-z_][A-Za-z0-9_.]*(:[A-Za-z_][A-Za-z0-9_]*)?$",
        max_length=200,
        description="a node type; a registered name (see `dockhil node types`) or package.module:Class",
    ),
]
NAMESPACE = r"^/?[A-Za-z_][A-Za-z0-9_]*$"
Namespace = Annotated[
    str,
    Meta(
        pattern=NAMESPACE,
        max_length=32,
        description="a namespace; one word of letters, digits and _ (a leading / is allowed), at most 32 characters",
    ),
]
VAR_NAME = r"^[A-Za-z_][A-Za-z0-9_]*$"
VarName = Annotated[
    str,
    Meta(
        pattern=VAR_NAME, max_length=64, description="a variable name; letters, digits and _, not starting with a digit"
    ),
]
MaxAge = Annotated[
    float,
    Meta(
        gt=0.0,
        le=MAX_AGE,
        description=(f"maximum age of the input's latest message in wall time [s], > 0 and at most {MAX_AGE:g}"),
    ),
]
Host = Annotated[
    str,
    Meta(
        pattern=r"^[A-Za-z0-9_.\-]*$",
        max_length=253,
        description="a host name or address; letters, digits, . - _ (empty: this host)",
    ),
]


class ArgDecl(Struct, forbid_unknown_fields=True):
    """A launch argument, set on the command line as name:=value."""

    default: Scalar | Numbers
    help: str = ""
    choices: Annotated[list[Scalar], Meta(min_length=1, max_length=MAX_CHOICES)] | None = None
    type: Literal["float", "int", "bool", "str", "list"] | None = None


class RemapDecl(Struct, forbid_unknown_fields=True):
    """One remap in the ROS 2 form: `{from: port or topic, to: topic}`."""

    from_: str = field(name="from")
    to: str


class ParamDecl(Struct, forbid_unknown_fields=True):
    """One parameter in the ROS 2 form: `{name: ..., value: ...}`."""

    name: Annotated[str, Meta(min_length=1, max_length=200)]
    value: Any


class LetDecl(Struct, forbid_unknown_fields=True):
    """A variable defined from arguments and earlier variables: `{name: ..., value: ...}`."""

    name: VarName
    value: Scalar


class NodeDecl(Struct, forbid_unknown_fields=True):
    """One node of the scene."""

    name: NodeName
    node: NodeType
    params: dict[str, Any] | list[ParamDecl] | None = None
    param: dict[str, Any] | list[ParamDecl] | None = None  # the ROS 2 spelling; either form in either
    remap: dict[str, str] | list[RemapDecl] | None = None
    max_age: dict[str, MaxAge] | None = None
    if_: Condition = field(default=None, name="if")
    unless: Condition = None
    respawn: bool = False
    respawn_delay: RespawnDelay = 1.0
    host: Host = ""
    container: Annotated[
        str,
        Meta(
            max_length=64,
            description="run in one process with the nodes naming the same container (in-process delivery)",
        ),
    ] = ""
    isolated: Annotated[bool, Meta(description="never contained: a hardware driver pinned to its own process")] = False


class IncludeDecl(Struct, forbid_unknown_fields=True):
    """Another launch file whose nodes join this scene."""

    file: Annotated[str, Meta(min_length=1, description="path relative to this file")]
    args: dict[str, Scalar] | None = None
    if_: Condition = field(default=None, name="if")
    unless: Condition = None


Lets = Annotated[list[LetDecl], Meta(max_length=MAX_LETS, description=f"at most {MAX_LETS} variables")] | None


class GroupDecl(Struct, forbid_unknown_fields=True):
    """Nodes under one namespace and one condition."""

    nodes: list[NodeDecl]
    namespace: Namespace | None = None
    if_: Condition = field(default=None, name="if")
    unless: Condition = None


class LaunchFile(Struct, forbid_unknown_fields=True):
    """A dockhil launch file (YAML)."""

    description: str = ""
    rate: Rate = 1000.0
    duration: Duration | None = None
    args: dict[str, ArgDecl | Scalar | Numbers] | None = None
    let: Lets = None
    nodes: list[NodeDecl] | None = None
    group: list[GroupDecl] | None = None
    include: list[IncludeDecl] | None = None


def json_schema() -> dict:
    return msgspec.json.schema(LaunchFile)


class SchemaError(Exception):
    """A value does not fit the schema: `path` (keys and indices) and a one-line reason."""

    def __init__(self, path: list, reason: str):
        super().__init__(reason)
        self.path = path
        self.reason = reason


def convert(data: Any, kind: Any, prefix: tuple = ()) -> Any:
    """`data` as `kind`, or SchemaError naming the path (after `prefix`) and what was given."""
    try:
        return msgspec.convert(data, kind)
    except msgspec.ValidationError as exc:
        path, reason = _explain(str(exc), data, kind)
        raise SchemaError([*prefix, *path], reason) from None


_AT = re.compile(r"^(?P<msg>.*?)(?: - at (?P<key>`key` in )?`(?P<path>[^`]*)`)?$", re.S)
_STEP = re.compile(r"\.([^.\[]+)|\[(\d+|\.\.\.)\]")


def _explain(text: str, data: Any, kind: Any) -> tuple[list, str]:
    m = cast(re.Match[str], _AT.match(text))  # every text matches: all but `msg` is optional
    msg, where, key_error = m.group("msg"), m.group("path") or "$", bool(m.group("key"))
    path, declared = _resolve([k or i for k, i in _STEP.findall(where[1:])], data, kind)
    kind_there = _inner(declared, _value_at(data, path))
    unknown = re.match(r"Object contains unknown field `(.*)`$", msg)
    if unknown:
        name = unknown.group(1)
        allowed = [f.encode_name for f in msgspec.structs.fields(kind_there)] if _is_struct(kind_there) else []
        near = difflib.get_close_matches(name, allowed, n=1)
        hint = f"did you mean {near[0]!r}? " if near else ""
        return [*path, name], f"unknown key {name!r}; {hint}allowed: {', '.join(allowed)}"
    if key_error:
        if msg.startswith("Expected `str`, got") or msg == "Expected `str`":
            return path, "keys must be text (YAML reads on/off/yes/no as booleans and digits as numbers: quote them)"
        return path, f"a key is refused: {msg}"
    missing = re.match(r"Object missing required field `(.*)`$", msg)
    if missing:
        return path, f"`{missing.group(1)}` is required"
    msg = re.sub(r", got `[^`]*`$", "", msg).replace("Expected", "expected", 1)
    msg = re.sub(r"`([^`]*)`", lambda m: _words(m.group(1)), msg)
    about = _description(declared)
    got = _show(_value_at(data, path))
    if "matching regex" in msg:  # the description says it in words: `host` must be a host name or address
        head, _, tail = about.partition("; ")
        return path, f"`{path[-1] if path else 'value'}` must be {head}, got {got}" + (f" ({tail})" if tail else "")
    return path, f"{msg}, got {got}" + (f" ({about})" if about else "")


_WORDS = {
    "float": "a number",
    "int": "an integer",
    "str": "text",
    "bool": "true or false",
    "array": "a list",
    "object": "a mapping",
}


def _words(types: str) -> str:
    """msgspec's `bool | int | null` in words: true or false or an integer."""
    names = [_WORDS.get(t.strip(), t.strip()) for t in types.split("|") if t.strip() != "null"]
    return " or ".join(names)


def _resolve(steps: list, data: Any, kind: Any) -> tuple[list, Any]:
    """msgspec's path as keys and indices, with each unnamed dict key (`[...]`) found again: the
    first key whose value does not fit. Also the type expected at the end of the path."""
    path: list = []
    for step in steps:
        kind = _inner(kind, data)
        if _is_struct(kind):
            f = next((f for f in msgspec.structs.fields(kind) if f.encode_name == step), None)
            kind = f.type if f else Any
        elif get_origin(kind) is dict:
            kind = get_args(kind)[1]
            if step == "..." and isinstance(data, dict):
                step = next((k for k, v in data.items() if not _fits(v, kind)), step)
        elif get_origin(kind) is list:
            kind = get_args(kind)[0]
            step = int(step)
        path.append(step)
        data = _value_at(data, [step])
    return path, kind


def _inner(kind: Any, data: Any = None) -> Any:
    """Through Annotated and Optional to the one Struct, dict or list alternative of a Union (the
    one of the data's shape when there are both: `remap` is a mapping or a list)."""
    while True:
        if get_origin(kind) is Annotated:
            kind = get_args(kind)[0]
        elif get_origin(kind) in UNIONS:
            options = [k for k in get_args(kind) if k is not type(None)]
            shaped = [k for k in options if _is_struct(k) or get_origin(k) in (dict, list)]
            if len(shaped) > 1:
                want = list if isinstance(data, list) else dict if isinstance(data, dict) else None
                shaped = [k for k in shaped if (get_origin(k) or dict) is want] or shaped
            kind = shaped[0] if len(shaped) == 1 else options[0] if len(options) == 1 else Any
        else:
            return kind


def _description(kind: Any) -> str:
    """The Meta description declared for a field, through Optional."""
    if get_origin(kind) is Annotated:
        return next((m.description for m in get_args(kind)[1:] if isinstance(m, Meta) and m.description), "")
    if get_origin(kind) in UNIONS:
        return next((d for d in map(_description, get_args(kind)) if d), "")
    return ""


def _is_struct(kind: Any) -> bool:
    return isinstance(kind, type) and issubclass(kind, Struct)


def _fits(value: Any, kind: Any) -> bool:
    try:
        msgspec.convert(value, kind)
        return True
    except msgspec.ValidationError:
        return False


def _show(value: Any) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _value_at(data: Any, path: list) -> Any:
    for step in path:
        try:
            data = data[step]
        except (KeyError, IndexError, TypeError):
            return None
    return data
