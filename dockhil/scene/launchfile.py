"""Launch files: YAML scenes with arguments, conditions and includes.

    description: one line shown by `dockhil graph`
    rate: 1000                 # Hz; the sim-time step is 1/rate
    duration: 3.0              # s; default for --duration
    args:
      delay: {default: 0.032, help: "robot response delay [s]"}
      ft: {default: sim, choices: [sim, can], help: "F/T sensor implementation"}
    let:
      - {name: slow, value: $(var delay)}        # a variable made from args (ROS 2 `let`)
    nodes:
      - name: dynamics
        node: satellite_dynamics          # registered type, or module:Class
        params: {m1: $(arg m1)}                # or param: [{name: m1, value: ...}]
        remap: {command: /robot/command_raw}   # port name or topic -> topic; or [{from, to}]
        max_age: {state: 0.05}                  # wall time: an input's maximum age [s]
        host: lab-pc-2                          # run on another machine (tcp)
        if: $(arg ft) == sim                   # or `unless:`
        respawn: false                          # wall time only
    group:
      - namespace: left                         # nodes `left.NAME`, default topics under /left
        if: $(var ft) == sim
        nodes: [...]
    include:
      - file: other.yaml                        # relative to this file
        args: {delay: $(arg delay)}

`$(arg NAME)` and `$(var NAME)` are the same: an argument or a `let`
variable. Standing alone it keeps the value's type; inside a longer
string it is replaced by its text. `$(var multicast_group)` is built in: an
IPv4 multicast group drawn each time the scene is read, one for all its
files. A condition is true/false, or `A == B` / `A != B` compared as text
after substitution.

The file is read with bounds (dockhil.scene.boundedyaml), its arguments are
substituted, and the result is checked against the schema in
dockhil.scene.schema: every refusal is one line with file, line and field.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from dockhil.errors import LaunchError, suggest
from dockhil.scene import boundedyaml
from dockhil.scene.files import SHIPPED_SCENES, find_shipped, unopenable  # noqa: F401 - part of this API
from dockhil.scene.loopfile import loop_args
from dockhil.scene.schema import (
    MAX_INCLUDES,
    MAX_NODES,
    MAX_SUBSTITUTED,
    MAX_TEXT,
    ArgDecl,
    LaunchFile,
    Lets,
    NodeDecl,
    Numbers,
    Scalar,
    SchemaError,
    convert,
)

_ARG = re.compile(r"\$\((?:arg|var) ([A-Za-z_][A-Za-z0-9_]*)\)")
_ARG_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_TYPES = {"float": float, "int": int, "bool": bool, "str": str, "list": list}


@dataclass
class ArgSpec:
    name: str
    default: Any
    type: type
    help: str = ""
    choices: tuple | None = None

    def parse(self, text: str, where: str) -> Any:
        """Convert command-line text (name:=text) to this argument's type."""
        try:
            if self.type is bool:
                low = text.strip().lower()
                if low not in ("true", "false", "1", "0"):
                    raise ValueError
                value: Any = low in ("true", "1")
            elif self.type is list:  # [a, b, ...] or a,b,...; empty: []
                items = text.strip().removeprefix("[").removesuffix("]").strip()
                value = [float(x) for x in items.split(",")] if items else []
            else:
                value = self.type(text)
        except ValueError:
            raise LaunchError(
                f"{where}: arg {self.name!r} expects {self._type_name()}, got {text!r} ({self.help or 'no help'})"
            ) from None
        return self.check(value, where)

    def _type_name(self) -> str:
        return "a list of numbers" if self.type is list else self.type.__name__

    def check(self, value: Any, where: str) -> Any:
        value = self.typed(value, where)
        if self.choices is not None and value not in self.choices:
            raise LaunchError(
                f"{where}: arg {self.name!r} must be one of {', '.join(map(str, self.choices))}, got {value!r}"
            )
        return value

    def typed(self, value: Any, where: str) -> Any:
        """`value` as this argument's type (an int is a float where a float is wanted), finite."""
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            try:
                value = float(value)
            except OverflowError:
                raise LaunchError(
                    f"{where}: arg {self.name!r}: an integer of {len(str(abs(value)))} digits is too large for a float"
                ) from None
        if self.type is list and isinstance(value, list):
            return [self._number(x, f"{where}: arg {self.name!r}[{i}]") for i, x in enumerate(value)]
        if not isinstance(value, self.type) or (self.type is not bool and isinstance(value, bool)):
            hint = " (YAML reads on/off/yes/no as booleans: quote them)" if isinstance(value, bool) else ""
            raise LaunchError(
                f"{where}: arg {self.name!r} expects {self._type_name()}, got {type(value).__name__} {value!r}{hint}"
            )
        if self.type is float and isinstance(value, float) and not math.isfinite(value):
            raise LaunchError(f"{where}: arg {self.name!r} is {value!r}; give a finite number")
        return value

    @staticmethod
    def _number(value: Any, where: str) -> float:
        """One number of a list argument, as a finite float."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise LaunchError(f"{where} is {type(value).__name__} {value!r}; give a number")
        try:
            number = float(value)
        except OverflowError:
            number = math.inf
        if not math.isfinite(number):
            raise LaunchError(f"{where} is {value!r}; give a finite number")
        return number


@dataclass
class NodeSpec:
    name: str
    type: str
    params: dict[str, Any]
    remap: dict[str, str]
    source: str
    respawn: bool = False
    respawn_delay: float = 1.0
    host: str = ""  # another machine: the launcher says how to start the node there
    line: int = 0  # where the node is declared in `source`, for messages
    namespace: str = ""  # a group's: prefixes the default topics (/NS/...); the name is already NS.name
    max_age: dict[str, float] = field(default_factory=dict)  # input port -> wall-time maximum age [s]
    container: str = ""  # run in this process with the nodes naming the same (checked by the launcher)
    isolated: bool = False  # never in a container (a pinned hardware driver; checked by the launcher)


@dataclass
class Skipped:
    name: str
    source: str
    reason: str


@dataclass
class Scene:
    path: str
    description: str
    rate: float
    duration: float | None
    args: dict[str, ArgSpec]
    values: dict[str, Any]  # arguments and `let` variables
    nodes: list[NodeSpec] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)
    lets: dict[str, Any] = field(default_factory=dict)
    texts: dict[str, str] = field(default_factory=dict)  # absolute path -> text of every launch file read

    @property
    def dt(self) -> float:
        return 1.0 / self.rate


def parse_overrides(items: list[str]) -> dict[str, str]:
    """`name:=value` strings from the command line -> {name: text}."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name:
            hint = f"; did you mean {item.replace('=', ':=', 1)}?" if "=" in item and name else ""
            raise LaunchError(f"launch argument {item!r} is not of the form name:=value{hint}")
        if name in out:  # which one was meant is a guess: ask
            raise LaunchError(f"{name} is given twice ({name}:={out[name]}, {item}); give it once")
        out[name] = value
    return out


def load(path: str | Path | None, overrides: dict[str, Any] | None = None, only: frozenset[str] | None = None) -> Scene:
    """Read a launch file (a path, or a shipped scene by name), apply arguments,
    resolve includes and conditions. `only`: the absolute, normalised paths of the files it may read (a
    recorded scene's: anything else is refused without being opened)."""
    if path is None:
        raise LaunchError("give a launch file, e.g. hil.yaml (a shipped scene) or a path to your own")
    path = Path(path) if only is not None else find_shipped(path)
    budget = _Budget(only=only)
    scene = _load(path, overrides or {}, from_cli=True, stack=(), budget=budget)
    scene.texts = budget.texts
    if not scene.nodes:
        raise LaunchError(f"{path}: no node to start after conditions; check the file's `nodes:` and `if:`")
    return scene


@dataclass
class _Budget:
    """What one scene may read and start, includes counted: an include tree cannot multiply without bound."""

    files: int = 0
    nodes: int = 0
    text: int = 0  # characters built by substitution inside longer strings
    texts: dict[str, str] = field(default_factory=dict)  # what a bag records to rebuild the scene
    only: frozenset[str] | None = None  # the files it may read (None: any)
    group: str = field(default_factory=lambda: draw_group())  # $(var multicast_group)


def draw_group() -> str:
    """A multicast group 239.74.x.y (x, y in 1-254; never python-can's default 239.74.163.2)."""
    group = f"239.74.{1 + secrets.randbelow(254)}.{1 + secrets.randbelow(254)}"
    return draw_group() if group == "239.74.163.2" else group


def _read_yaml(path: Path, budget: _Budget, included_from: Path | None = None) -> tuple[dict, Any]:
    """The file's document. An included file that is not a launch file (a YAML mapping of launch-file
    keys) is refused naming it, never with what it holds: an include can name any file the user reads."""
    budget.files += 1
    if budget.files > MAX_INCLUDES:
        raise LaunchError(f"{path}: more than {MAX_INCLUDES} launch files read for one scene; include fewer files")
    if budget.only is not None and os.path.normpath(os.path.abspath(path)) not in budget.only:
        # Not stat'ed, not opened: a recorded scene names paths of another machine, and a reader of what they
        # name here could hang (a FIFO) or tell what the disk holds.
        raise LaunchError(
            f"{os.path.normpath(path)}: not among the launch files the scene recorded; an include is resolved "
            f"only among them"
        )
    if not path.is_file():
        raise LaunchError(f"launch file {str(path)!r} not found (or not a file)")
    try:
        with open(path, "rb") as f:
            raw = f.read(boundedyaml.MAX_BYTES + 1)
        if len(raw) > boundedyaml.MAX_BYTES:
            raise LaunchError(f"{path}: larger than {boundedyaml.MAX_BYTES} bytes; a launch file is a page or two")
        text = raw.decode("utf-8")
        budget.texts[os.path.abspath(path)] = text
    except UnicodeDecodeError:
        raise LaunchError(_not_launch_file(path, included_from, "not UTF-8 text")) from None
    except OSError as exc:
        raise LaunchError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        data, root = boundedyaml.load(text, str(path))
    except boundedyaml.YamlError as exc:
        if included_from is not None:
            at = f" at line {exc.line}" if exc.line else ""
            raise LaunchError(_not_launch_file(path, included_from, f"not valid YAML{at}")) from None
        raise LaunchError(str(exc)) from None
    if (
        isinstance(data, dict)
        and included_from is None
        and data
        and not any(isinstance(k, str) and difflib.get_close_matches(k, LAUNCH_KEYS, n=1) for k in data)
    ):
        # Not one key is, or is close to, a launch file's: some other file, whose keys are its content.
        raise LaunchError(f"{path}: not a launch file (a YAML mapping of {', '.join(LAUNCH_KEYS)})")
    if included_from is not None and (not isinstance(data, dict) or not set(data) <= LAUNCH_KEYS):
        raise LaunchError(_not_launch_file(path, included_from, f"not a YAML mapping of {', '.join(LAUNCH_KEYS)}"))
    if not isinstance(data, dict):
        raise LaunchError(f"{path}: a launch file is a YAML mapping with `nodes:`; got {type(data).__name__}")
    return data, root


LAUNCH_KEYS = {f.encode_name: None for f in msgspec.structs.fields(LaunchFile)}.keys()


def _not_launch_file(path: Path, included_from: Path | None, why: str) -> str:
    return f"{path} (included from {included_from}): not a launch file ({why})"


def _where(path: Path, root: Any, at: list) -> str:
    line = boundedyaml.line_of(root, at)
    spot = "".join(f"[{s}]" if isinstance(s, int) else f".{s}" for s in at).lstrip(".")
    head = f"{path}:{line}" if line else str(path)
    return f"{head}: {spot}" if spot else head


def _load(path: Path, given: dict[str, Any], from_cli: bool, stack: tuple, budget: _Budget) -> Scene:
    why = unopenable(path)
    if why is not None:
        raise LaunchError(f"launch file {str(path)!r} cannot be opened: {why}")
    try:
        resolved = path.resolve()
    except (OSError, RuntimeError, ValueError) as exc:
        raise LaunchError(f"launch file {str(path)!r} cannot be opened: {exc}") from None
    if resolved in stack:
        chain = " -> ".join(str(p) for p in (*stack, resolved))
        raise LaunchError(f"include cycle: {chain}")
    data, root = _read_yaml(path, budget, stack[-1] if stack else None)
    try:
        return _scene(path, data, root, given, from_cli, stack, budget)
    except SchemaError as exc:
        raise LaunchError(f"{_where(path, root, exc.path)}: {exc.reason}") from None


def _scene(
    path: Path, data: dict, root: Any, given: dict[str, Any], from_cli: bool, stack: tuple, budget: _Budget
) -> Scene:
    decls = convert(data.get("args"), dict[str, ArgDecl | Scalar | Numbers] | None, prefix=("args",)) or {}
    specs = {name: _arg_spec(name, body, _where(path, root, ["args", name])) for name, body in decls.items()}
    values = {name: spec.default for name, spec in specs.items()}
    if from_cli and "loop" in specs and given.get("loop"):
        # name:=value on the command line wins (ft_bias:=[] drops the file's tare unread)
        given = {**loop_args(str(given["loop"]), specs, set(given), str(path)), **given}
    for name, value in given.items():
        if name not in specs:
            declared = data.get("let")
            if isinstance(declared, list) and any(isinstance(d, dict) and d.get("name") == name for d in declared):
                raise LaunchError(
                    f"{path}: {name!r} is a `let` variable, made from the arguments: set those "
                    f"instead ({suggest('', specs, 'known args')})"
                )
            raise LaunchError(f"{path}: unknown arg {name!r}; {suggest(name, specs, 'known args')}")
        where = f"{path}" if from_cli else f"{path} (included)"
        spec = specs[name]
        values[name] = (
            spec.parse(value, where) if isinstance(value, str) and spec.type is not str else spec.check(value, where)
        )

    # `let` variables, in order: each may use the arguments and the variables before it.
    lets = {}
    for i, let in enumerate(convert(data.get("let"), Lets, prefix=("let",)) or []):
        if let.name in values:
            what = "an argument" if let.name in specs else "a variable defined above"
            raise SchemaError(["let", i, "name"], f"{let.name!r} is already {what}; give the variable another name")
        scope = {"multicast_group": budget.group, **values}
        values[let.name] = lets[let.name] = _subst(let.value, scope, ["let", i, "value"], budget)

    # Arguments are substituted everywhere but in `args:` and `let:`; then the whole file meets the
    # schema, so `rate: $(arg rate)` is bounded exactly like `rate: 500`.
    scope = {"multicast_group": budget.group, **values}
    body = {
        key: value if key in ("args", "let") else _subst(value, scope, [key], budget) for key, value in data.items()
    }
    doc = convert(body, LaunchFile)
    scene = Scene(str(path), doc.description, doc.rate, doc.duration, specs, values, lets=lets)

    # Top-level nodes, then each group's (under its namespace and condition).
    entries = [(nd, ["nodes", i], "") for i, nd in enumerate(doc.nodes or [])]
    for g, group in enumerate(doc.group or []):
        ns = (group.namespace or "").lstrip("/")
        keep, reason = _condition(group.if_, group.unless, data["group"][g], ["group", g])
        for i, nd in enumerate(group.nodes):
            at = ["group", g, "nodes", i]
            if keep:
                entries.append((nd, at, ns))
            else:
                scene.skipped.append(Skipped(_in_namespace(ns, nd.name, [*at, "name"]), str(path), f"group {reason}"))
    for nd, at, ns in entries:
        keep, reason = _condition(nd.if_, nd.unless, _value_at(data, at), at)
        name = _in_namespace(ns, nd.name, [*at, "name"])
        if not keep:
            scene.skipped.append(Skipped(name, str(path), reason))
            continue
        budget.nodes += 1
        if budget.nodes > MAX_NODES:
            raise SchemaError(at, f"more than {MAX_NODES} nodes in one scene")
        scene.nodes.append(
            NodeSpec(
                name,
                nd.node,
                _params(nd, at),
                _remaps(nd.remap, [*at, "remap"]),
                str(path),
                nd.respawn,
                nd.respawn_delay,
                nd.host,
                boundedyaml.line_of(root, at) or 0,
                ns,
                dict(nd.max_age or {}),
                nd.container,
                nd.isolated,
            )
        )

    for i, inc in enumerate(doc.include or []):
        keep, reason = _condition(inc.if_, inc.unless, data["include"][i], ["include", i])
        if not keep:
            scene.skipped.append(Skipped(f"include {data['include'][i]['file']}", str(path), reason))
            continue
        child = _load(
            path.parent / inc.file, inc.args or {}, from_cli=False, stack=(*stack, path.resolve()), budget=budget
        )
        scene.nodes.extend(child.nodes)
        scene.skipped.extend(child.skipped)

    names = [n.name for n in scene.nodes]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup:
        raise LaunchError(f"{path}: two nodes are named {dup!r}; node names must be unique")
    return scene


def _value_at(data: Any, at: list) -> Any:
    for step in at:
        data = data[step]
    return data


def _in_namespace(ns: str, name: str, at: list) -> str:
    """A node's name in its group's namespace: NS.name (a name is also a file name: no /)."""
    if not ns:
        return name
    full = f"{ns}.{name}"
    if len(full) > 64:
        raise SchemaError(at, f"the name in its namespace, {full!r}, is {len(full)} characters; at most 64")
    return full


def _params(nd: NodeDecl, at: list) -> dict[str, Any]:
    """`params` and `param`, each a mapping or a list of {name, value}, as one mapping."""
    out: dict[str, Any] = {}
    for key in ("params", "param"):
        given = getattr(nd, key)
        items = given.items() if isinstance(given, dict) else ((p.name, p.value) for p in given or [])
        for j, (name, value) in enumerate(items):
            if name in out:
                spot = [*at, key, name] if isinstance(given, dict) else [*at, key, j, "name"]
                raise SchemaError(spot, f"parameter {name!r} is given twice; give it once")
            out[name] = value
    return out


def _remaps(remap: Any, at: list) -> dict[str, str]:
    """`remap` as a mapping {from: to} or a list [{from, to}] (ROS 2), as one mapping."""
    if isinstance(remap, dict) or remap is None:
        return dict(remap or {})
    out: dict[str, str] = {}
    for j, r in enumerate(remap):
        if r.from_ in out:
            raise SchemaError(
                [*at, j, "from"], f"{r.from_!r} is remapped twice ({out[r.from_]}, {r.to}); remap it once"
            )
        out[r.from_] = r.to
    return out


def _arg_spec(name: str, body: Any, where: str) -> ArgSpec:
    if not _ARG_NAME.fullmatch(name):
        raise LaunchError(f"{where}: arg name {name!r} cannot be written $(arg {name}); use letters, digits and _")
    if not isinstance(body, ArgDecl):
        body = ArgDecl(default=body)
    typ = _TYPES[body.type] if body.type else type(body.default)
    spec = ArgSpec(name, body.default, typ, body.help)
    if body.choices is not None:
        spec.choices = tuple(spec.typed(c, f"{where}.choices") for c in body.choices)
    spec.default = spec.check(body.default, f"{where}.default")
    return spec


def _subst(value: Any, values: dict[str, Any], at: list, budget: _Budget) -> Any:
    if isinstance(value, str):
        whole = _ARG.fullmatch(value.strip())
        if whole:
            return _lookup(whole, values, at)
        parts = [(m, _text(_lookup(m, values, at))) for m in _ARG.finditer(value)]
        size = len(value) + sum(len(text) - len(m.group(0)) for m, text in parts)
        if size > MAX_TEXT:  # sized before it is built: arguments that repeat arguments grow fast
            raise SchemaError(at, f"is {size} characters after $(arg ...) substitution; at most {MAX_TEXT}")
        budget.text += size if parts else 0
        if budget.text > MAX_SUBSTITUTED:  # many strings that each repeat a long argument
            raise SchemaError(
                at,
                f"substitution builds more than {MAX_SUBSTITUTED} characters for one scene; "
                f"use fewer or shorter $(arg ...) in strings",
            )
        return _ARG.sub(lambda m: _text(values[m.group(1)]), value)
    if isinstance(value, dict):
        return {k: _subst(v, values, [*at, k], budget) for k, v in value.items()}
    if isinstance(value, list):
        return [_subst(v, values, [*at, i], budget) for i, v in enumerate(value)]
    return value


def _text(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(map(_text, value)) + "]"
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


def _lookup(m: re.Match, values: dict[str, Any], at: list) -> Any:
    name = m.group(1)
    if name not in values:
        raise SchemaError(at, f"{m.group(0)} is not declared in `args:` or `let:`; {suggest(name, values, 'declared')}")
    return values[name]


def _condition(if_: Any, unless: Any, raw: dict, at: list) -> tuple[bool, str]:
    for key, value, want in (("if", if_, True), ("unless", unless, False)):
        if value is None:
            continue
        result = _truth(value, [*at, key])
        if result != want:
            return False, f"{key}: {raw[key]} is {_text(result)}"
    return True, ""


def _truth(value: Any, at: list) -> bool:
    if isinstance(value, bool):
        return value
    text = str(value).strip()
    for op in ("==", "!="):
        if op in text:
            left, _, right = text.partition(op)
            same = left.strip() == right.strip()
            return same if op == "==" else not same
    if text.lower() in ("true", "1"):
        return True
    if text.lower() in ("false", "0"):
        return False
    raise SchemaError(at, f"{text!r} is neither true/false nor `A == B` / `A != B`")
