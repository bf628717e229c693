"""Launch files: YAML scenes with arguments, conditions and includes.

    description: one line shown by `dockhil graph`
    rate: 1000                 # Hz; the sim-time step is 1/rate
    duration: 3.0              # s; default for --duration
    args:
      delay: {default: 0.032, help: "robot response delay [s]"}
      ft: {default: sim, choices: [sim, can], help: "F/T sensor implementation"}
    nodes:
      - name: dynamics
        node: satellite_dynamics          # registered type, or module:Class
        params: {m1: $(arg m1)}
        remap: {command: /robot/command_raw}   # port name or topic -> topic
        host: lab-pc-2                          # run on another machine (tcp)
        if: $(arg ft) == sim                   # or `unless:`
        respawn: false                          # wall time only
    include:
      - file: other.yaml                        # relative to this file
        args: {delay: $(arg delay)}

`$(arg NAME)` standing alone keeps the argument's type; inside a longer
string it is replaced by its text. A condition is true/false, or
`A == B` / `A != B` compared as text after substitution.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dockhil.errors import LaunchError

_ARG = re.compile(r"\$\(arg ([A-Za-z_][A-Za-z0-9_]*)\)")
_TOP_KEYS = {"description", "rate", "duration", "args", "nodes", "include"}
_NODE_KEYS = {"name", "node", "params", "remap", "if", "unless", "respawn", "respawn_delay", "host", "container",
              "isolated"}
_INCLUDE_KEYS = {"file", "args", "if", "unless"}
_ARG_KEYS = {"default", "help", "choices", "type"}
_TYPES = {"float": float, "int": int, "bool": bool, "str": str}


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
            else:
                value = self.type(text)
        except ValueError:
            raise LaunchError(
                f"{where}: arg {self.name!r} expects {self.type.__name__}, got {text!r} ({self.help or 'no help'})"
            ) from None
        return self.check(value, where)

    def check(self, value: Any, where: str) -> Any:
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, self.type) or (self.type is not bool and isinstance(value, bool)):
            raise LaunchError(
                f"{where}: arg {self.name!r} expects {self.type.__name__}, got {type(value).__name__} {value!r}"
            )
        if self.type is float and value != value:
            raise LaunchError(f"{where}: arg {self.name!r} is NaN; give a number")
        if self.choices is not None and value not in self.choices:
            raise LaunchError(
                f"{where}: arg {self.name!r} must be one of {', '.join(map(str, self.choices))}, got {value!r}"
            )
        return value


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
    container: Any = ""  # run in this process with the nodes naming the same (checked by the launcher)
    isolated: Any = False  # never in a container (a pinned hardware driver; checked by the launcher)


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
    values: dict[str, Any]
    nodes: list[NodeSpec] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)

    @property
    def dt(self) -> float:
        return 1.0 / self.rate


def parse_overrides(items: list[str]) -> dict[str, str]:
    """`name:=value` strings from the command line -> {name: text}."""
    out = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name:
            raise LaunchError(f"launch argument {item!r} is not of the form name:=value")
        out[name] = value
    return out


def load(path: str | Path | None, overrides: dict[str, Any] | None = None) -> Scene:
    """Read a launch file, apply arguments, resolve includes and conditions."""
    if path is None:
        raise LaunchError("give a launch file, e.g. launch/hil.yaml (the scenes are in launch/)")
    path = Path(path)
    scene = _load(path, overrides or {}, from_cli=True, stack=())
    if not scene.nodes:
        raise LaunchError(f"{path}: no node to start after conditions; check the file's `nodes:` and `if:`")
    return scene


def _read_yaml(path: Path) -> dict:
    import yaml

    if not path.is_file():
        raise LaunchError(f"launch file {str(path)!r} not found (or not a file)")
    try:
        data = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml: ~9x faster
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise LaunchError(f"{where}: not valid YAML: {problem}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise LaunchError(f"{path}: cannot read: {exc}") from None
    if not isinstance(data, dict):
        raise LaunchError(f"{path}: a launch file is a YAML mapping with `nodes:`; got {type(data).__name__}")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise LaunchError(f"{path}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(_TOP_KEYS))}")
    return data


def _arg_specs(path: Path, raw: Any) -> dict[str, ArgSpec]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise LaunchError(f"{path}: `args:` must be a mapping name -> {{default, help}}")
    specs = {}
    for name, body in raw.items():
        if not isinstance(name, str):
            raise LaunchError(f"{path}: arg name {name!r} is not a string (YAML reads on/off/yes/no as booleans: quote it)")
        if not isinstance(body, dict):
            body = {"default": body}
        unknown = sorted(set(body) - _ARG_KEYS)
        if unknown:
            raise LaunchError(f"{path}: arg {name!r}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(_ARG_KEYS))}")
        if "default" not in body:
            raise LaunchError(f"{path}: arg {name!r} has no default; every arg needs one")
        default = body["default"]
        if "type" in body:
            if body["type"] not in _TYPES:
                raise LaunchError(f"{path}: arg {name!r}: type must be one of {', '.join(_TYPES)}")
            typ = _TYPES[body["type"]]
        else:
            typ = type(default) if type(default) in (float, int, bool, str) else str
        choices = tuple(body["choices"]) if body.get("choices") is not None else None
        spec = ArgSpec(str(name), default, typ, str(body.get("help", "")), choices)
        spec.default = spec.check(default, f"{path}: default")
        specs[str(name)] = spec
    return specs


def _load(path: Path, given: dict[str, Any], from_cli: bool, stack: tuple) -> Scene:
    if path.resolve() in stack:
        chain = " -> ".join(str(p) for p in (*stack, path.resolve()))
        raise LaunchError(f"include cycle: {chain}")
    data = _read_yaml(path)
    specs = _arg_specs(path, data.get("args"))
    values = {name: spec.default for name, spec in specs.items()}
    for name, value in given.items():
        if name not in specs:
            known = ", ".join(sorted(specs)) or "none"
            raise LaunchError(f"{path}: unknown arg {name!r}; known args: {known}")
        where = f"{path}" if from_cli else f"{path} (included)"
        spec = specs[name]
        values[name] = spec.parse(value, where) if isinstance(value, str) and spec.type is not str else spec.check(value, where)
    # `rate: $(arg rate)` and `duration: $(arg duration)` take launch arguments like params do.
    rate = _subst(data.get("rate", 1000.0), values, f"{path}: rate")
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not rate > 0:
        raise LaunchError(f"{path}: `rate` must be a positive number of Hz, got {rate!r}")
    duration = _subst(data.get("duration"), values, f"{path}: duration")
    if duration is not None and (isinstance(duration, bool) or not isinstance(duration, (int, float)) or duration <= 0):
        raise LaunchError(f"{path}: `duration` must be a positive number of seconds, got {duration!r}")
    scene = Scene(str(path), str(data.get("description", "")), float(rate),
                  None if duration is None else float(duration), specs, values)

    raw_nodes = data.get("nodes") or []
    if not isinstance(raw_nodes, list):
        raise LaunchError(f"{path}: `nodes:` must be a list of nodes")
    for i, raw in enumerate(raw_nodes):
        where = f"{path}: nodes[{i}]"
        if not isinstance(raw, dict):
            raise LaunchError(f"{where}: a node is a mapping with `name` and `node`")
        unknown = sorted(set(raw) - _NODE_KEYS)
        if unknown:
            raise LaunchError(f"{where}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(_NODE_KEYS))}")
        for key in ("name", "node"):
            if not isinstance(raw.get(key), str) or not raw[key]:
                raise LaunchError(f"{where}: `{key}` is required and must be a string")
        where = f"{path}: node {raw['name']!r}"
        keep, reason = _condition(raw, values, where)
        if not keep:
            scene.skipped.append(Skipped(raw["name"], str(path), reason))
            continue
        params = _subst(raw.get("params") or {}, values, where)
        if not isinstance(params, dict):
            raise LaunchError(f"{where}: `params:` must be a mapping")
        remap = _subst(raw.get("remap") or {}, values, where)
        if not isinstance(remap, dict) or not all(isinstance(v, str) for v in remap.values()):
            raise LaunchError(f"{where}: `remap:` must map port names or topics to topic strings")
        respawn = raw.get("respawn", False)
        if not isinstance(respawn, bool):
            raise LaunchError(f"{where}: `respawn` must be true or false")
        scene.nodes.append(NodeSpec(raw["name"], raw["node"], params, {str(k): v for k, v in remap.items()},
                                    str(path), respawn, float(raw.get("respawn_delay", 1.0)),
                                    _host(raw.get("host", ""), values, where),
                                    _subst(raw.get("container", ""), values, where),
                                    _subst(raw.get("isolated", False), values, where)))

    raw_includes = data.get("include") or []
    if not isinstance(raw_includes, list):
        raise LaunchError(f"{path}: `include:` must be a list of {{file, args}}")
    for i, raw in enumerate(raw_includes):
        where = f"{path}: include[{i}]"
        if not isinstance(raw, dict) or not isinstance(raw.get("file"), str):
            raise LaunchError(f"{where}: an include is a mapping with `file:`")
        unknown = sorted(set(raw) - _INCLUDE_KEYS)
        if unknown:
            raise LaunchError(f"{where}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(_INCLUDE_KEYS))}")
        keep, reason = _condition(raw, values, where)
        child_path = (path.parent / _subst(raw["file"], values, where)).resolve()
        if not keep:
            scene.skipped.append(Skipped(f"include {raw['file']}", str(path), reason))
            continue
        child_args = _subst(raw.get("args") or {}, values, where)
        child = _load(child_path, child_args, from_cli=False, stack=(*stack, path.resolve()))
        scene.nodes.extend(child.nodes)
        scene.skipped.extend(child.skipped)

    names = [n.name for n in scene.nodes]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup:
        raise LaunchError(f"{path}: two nodes are named {dup!r}; node names must be unique")
    return scene


def _host(raw: Any, values: dict[str, Any], where: str) -> str:
    host = _subst(raw, values, where)
    if not isinstance(host, str) or any(c in host for c in " /:"):
        raise LaunchError(f"{where}: `host` must be a host name or address, got {host!r}")
    return host


def _subst(value: Any, values: dict[str, Any], where: str) -> Any:
    if isinstance(value, str):
        whole = _ARG.fullmatch(value.strip())
        if whole:
            return _lookup(whole.group(1), values, where)
        return _ARG.sub(lambda m: _text(_lookup(m.group(1), values, where)), value)
    if isinstance(value, dict):
        return {k: _subst(v, values, where) for k, v in value.items()}
    if isinstance(value, list):
        return [_subst(v, values, where) for v in value]
    return value


def _text(value: Any) -> str:
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


def _lookup(name: str, values: dict[str, Any], where: str) -> Any:
    if name not in values:
        known = ", ".join(sorted(values)) or "none"
        raise LaunchError(f"{where}: $(arg {name}) is not declared in `args:`; declared: {known}")
    return values[name]


def _condition(raw: dict, values: dict[str, Any], where: str) -> tuple[bool, str]:
    for key, want in (("if", True), ("unless", False)):
        if key not in raw:
            continue
        text = raw[key]
        result = _truth(_subst(text, values, where), where, key)
        if result != want:
            return False, f"{key}: {text} is {_text(result)}"
    return True, ""


def _truth(value: Any, where: str, key: str) -> bool:
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
    raise LaunchError(f"{where}: `{key}: {text}` is neither true/false nor `A == B` / `A != B`")
