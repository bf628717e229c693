"""The message screen: every output is checked before it leaves its node. A NaN or Inf in a
physical field (a diverging loop), a number out of its type's bounds or a value of the wrong type
stops the producing node with one line, the same in a multi-process and a composed run."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, cast

import msgspec

from dockhil.errors import DockhilError
from dockhil.msgs.codec import DecodeError, decode, encode


def checked_payload(name: str, port: str, topic: str, k: int, msg: msgspec.Struct) -> bytes:
    """`msg` encoded, after checking it decodes as a valid message: a NaN or Inf in a physical field
    (a loop that diverged) stops the node that produced it, not its readers, with one line. (Decoding
    is the reader's own check, and faster than a screen of the fields' types written in Python.)"""
    payload = encode(msg)
    try:
        decode(payload, type(msg))
    except DecodeError as exc:
        raise DockhilError(
            f"node {name!r} produced an invalid message at tick {k} on output {port!r} "
            f"({topic}): {exc}; stopping the graph"
        ) from None
    return payload


def check_message(name: str, port: str, topic: str, k: int, msg: msgspec.Struct) -> None:
    """What checked_payload checks, for a message that is not sent (composed runs): the numbers'
    screen first (several times faster than encoding and decoding; the message is handed on as
    the object it is); on a failure, the same check and line as a node process gives."""
    if not bounds_check(type(msg))(msg):
        checked_payload(name, port, topic, k, msg)


_MAX_FLOAT = 1.7976931348623157e308
Screen = Callable[[Any], bool]  # true when a message holds what its decoding would accept
_SCREENS: dict[type, Screen] = {}


class _Unscreened(Exception):
    """A number the screen does not judge (multiple_of): every message of that type gets the full check."""


def bounds_check(cls: type) -> Screen:
    """A function true when a message of type `cls` holds what its decoding would accept: every
    number finite and within its type's bounds, and every value of its field's own type (a float,
    a str, a bool, an int, the declared struct, a tuple), as a node process's encoding and decoding
    would check it. A screen, not the verdict: it may say False for a good message (a sum of finite
    values that overflows, an int where a float goes, a numpy float), and callers then run the full
    check. Compiled (dockhil/runtime/_screen.c) where built, else `python_screen`."""
    check = _SCREENS.get(cls)
    if check is None:
        from dockhil.compiled import twin

        compiled = twin("dockhil.runtime._screen")
        try:
            spec = _screen_spec(cls)
        except _Unscreened:  # a type neither screen judges: every message of it gets the full check
            check = _never
        else:  # the same judgement in C (dockhil/runtime/_screen.c), several times faster, or its Python twin
            check = functools.partial(compiled.screen, spec) if compiled else _python_screen(cls.__name__, spec)
        _SCREENS[cls] = check
    return check


def python_screen(cls: type) -> Screen:
    """`bounds_check`'s screen of `cls` as a generated Python function (the compiled one's twin)."""
    try:
        return _python_screen(cls.__name__, _screen_spec(cls))
    except _Unscreened:
        return _never


def _never(m: Any) -> bool:
    return False


def _screen_spec(cls: type) -> tuple:
    """(cls, fields): what a screen judges of a message type, read once from its type; each field
    (member, kind, ...), member its descriptor in cls (the C screen reads the slot through it),
    kind 0 float and 1 int (with ge, gt, le, lt: a float or None each), 2 bool, 3 str, 4 struct (its
    spec), 5 tuple and 6 list (an item's field, member None). _Unscreened for a type no screen
    judges (a multiple_of, a constrained str, a type msgs do not use)."""
    import msgspec.inspect as mi

    def struct(t: mi.StructType) -> tuple:
        return (t.cls, tuple(field(f.type, _member(t.cls, f.name)) for f in t.fields))

    def field(t: Any, member: Any) -> tuple:  # t: a msgspec.inspect type, told apart by its class name
        if isinstance(t, mi.Metadata):
            t = t.type
        kind = _LEAF_KINDS.get(type(t).__name__)
        if kind in (0, 1):
            if t.multiple_of is not None:
                raise _Unscreened
            return (member, kind, *(None if b is None else float(b) for b in (t.ge, t.gt, t.le, t.lt)))
        if kind == 3 and (t.min_length or t.max_length is not None or t.pattern):
            raise _Unscreened
        if kind is not None:
            return (member, kind)
        if isinstance(t, mi.StructType):
            return (member, 4, struct(t))
        if isinstance(t, (mi.ListType, mi.VarTupleType)):
            return (member, 5 if isinstance(t, mi.VarTupleType) else 6, field(t.item_type, None))
        raise _Unscreened

    return struct(cast(mi.StructType, mi.type_info(cls)))  # msgs are Structs


def _member(cls: type, name: str) -> Any:
    for klass in cls.__mro__:
        if name in vars(klass):
            return vars(klass)[name]
    raise _Unscreened


# A leaf's kind in a screen's spec, and the Python type its value has where its decoding would
# accept it without conversion (the kind indexes _LEAF_TYPES).
_LEAF_KINDS = {"FloatType": 0, "IntType": 1, "BoolType": 2, "StrType": 3}
_LEAF_TYPES = (float, int, bool, str)


def _python_screen(name: str, spec: tuple) -> Screen:
    """A screen's spec written out as a Python function. The floats are added up as they are read
    (each struct read once): a NaN or Inf anywhere makes the sum non-finite; the types are compared
    a struct's fields at a time."""
    lines: list[str] = []
    scope: dict[str, Any] = {}
    _screen_lines((None, 4, spec), "m", lines, "        ", scope)
    src = (
        "def check(m):\n    s = 0.0\n    try:\n"
        + "".join(f"{line}\n" for line in lines)
        + "    except Exception:\n        return False\n    return s - s == 0\n"
    )
    exec(compile(src, f"<screen of {name}>", "exec"), scope)  # noqa: S102 - built from the type
    return scope["check"]


def _screen_lines(field: tuple, var: str, lines: list[str], indent: str, scope: dict) -> None:
    """Statements that return False when a value under `var` is out of its bounds or not of its
    field's type, and add its floats to the sum s."""
    leaves: dict[type, list[str]] = {}
    _screen_field(field, var, lines, indent, scope, leaves)
    for kind, names in leaves.items():  # builtins: float, int, bool, str
        lines.append(f"{indent}if not ({' is '.join(f'type({n})' for n in names)} is {kind.__name__}): return False")
    if leaves.get(float):
        lines.append(f"{indent}s += {' + '.join(leaves[float])}")


def _screen_field(field: tuple, var: str, lines: list[str], indent: str, scope: dict, leaves: dict) -> None:
    kind = field[1]
    if kind < 4:
        conds = [
            f"{var} {op} {bound!r}"
            for op, bound in zip((">=", ">", "<=", "<"), field[2:])
            if bound is not None and abs(bound) != _MAX_FLOAT
        ]
        if conds:  # a NaN fails a bound too
            lines.append(f"{indent}if not ({' and '.join(conds)}): return False")
        leaves.setdefault(_LEAF_TYPES[kind], []).append(var)
    elif kind == 4:
        cls, fields = field[2]
        if "." in var or var.startswith("_i"):  # a nested struct (or a tuple's item): its type checked
            cls_name = f"_T{len(scope)}"
            scope[cls_name] = cls
            if "." in var:  # read once into a local, not once per field below it
                local = f"_s{len(scope)}"
                scope[local] = None
                lines.append(f"{indent}{local} = {var}")
                var = local
            lines.append(f"{indent}if type({var}) is not {cls_name}: return False")
        for f in fields:
            _screen_field(f, f"{var}.{f[0].__name__}", lines, indent, scope, leaves)
    else:  # a tuple or a list of items
        item = f"_i{len(scope)}"
        scope[item] = None
        body: list[str] = []
        _screen_lines(field[2], item, body, indent + "    ", scope)
        lines.append(f"{indent}if type({var}) is not {'tuple' if kind == 5 else 'list'}: return False")
        if body:
            lines.append(f"{indent}for {item} in {var}:")
            lines.extend(body)
