"""Node types by name. Values are "module:Class" strings, imported only
when a scene uses the node, so a scene loads only what it runs.

Other installed distributions add node types through the entry-point group
`dockhil.nodes` (in their pyproject.toml:
`[project.entry-points."dockhil.nodes"] my_sensor = "my_pkg.sensor:MySensor"`).
A built-in name always wins, and entry points are read only for a name that is
not built in, so a broken third-party package never breaks the built-in types."""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import sys

from dockhil.errors import LaunchError

REGISTRY: dict[str, str] = {
    "satellite_dynamics": "dockhil.nodes.satellite_dynamics:SatelliteDynamics",
    "virtual_impedance": "dockhil.nodes.virtual_impedance:VirtualImpedance",
    "ft_sim": "dockhil.nodes.ft_sim:FtSensorSim",
    "robot_sim": "dockhil.nodes.robot_sim:RobotSim",
    "delay_injector": "dockhil.nodes.delay_injector:DelayInjector",
    "ft_can": "dockhil.nodes.ft_can:FtCanDriver",
    "ft_emulator": "dockhil.nodes.ft_emulator:FtSensorEmulator",
    "robot_modbus": "dockhil.nodes.robot_modbus:RobotModbusDriver",
    "robot_emulator": "dockhil.nodes.robot_emulator:RobotControllerEmulatorNode",
    "bag_source": "dockhil.nodes.bag_source:BagSource",
    "satellite_dynamics6": "dockhil.nodes.satellite_dynamics6:SatelliteDynamics6",
    "virtual_impedance6": "dockhil.nodes.virtual_impedance6:VirtualImpedance6",
    "ft_sim6": "dockhil.nodes.ft_sim6:FtSensorSim6",
    "robot_sim6": "dockhil.nodes.robot_sim6:RobotSim6",
}


ENTRY_POINT_GROUP = "dockhil.nodes"


def plugins() -> dict[str, tuple[str, str]]:
    """Node types of other installed distributions: name -> ("module:Class", "distribution version").
    Names that are built in are left out (the built-in wins); the first distribution found wins."""
    from importlib.metadata import entry_points

    found: dict[str, tuple[str, str]] = {}
    try:
        eps = entry_points(group=ENTRY_POINT_GROUP)
    except Exception as exc:  # a distribution's metadata that does not parse
        raise LaunchError(f"cannot read the installed {ENTRY_POINT_GROUP} entry points "
                          f"({type(exc).__name__}: {exc})") from None
    for ep in eps:
        dist = f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "an unnamed distribution"
        if ep.name not in REGISTRY and ep.name not in found:
            found[ep.name] = (ep.value.strip(), dist)
    return found


_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*")


def load(type_name: str):
    """The Node subclass for a registered name or a "package.module:Class" path.

    A module is imported only if its source defines the class, so a path such as
    `antigravity:X` is refused before the module's import could do anything."""
    if type_name in REGISTRY or ":" in type_name:
        return _load(type_name, REGISTRY.get(type_name, type_name))
    extra = plugins()
    if type_name not in extra:
        known = ", ".join(sorted([*REGISTRY, *extra])) or "none"
        raise LaunchError(f"unknown node type {type_name!r}; known types: {known} (or give module:Class)")
    target, dist = extra[type_name]
    try:
        return _load(type_name, target)
    except LaunchError as exc:
        raise LaunchError(f"{exc} (entry point {ENTRY_POINT_GROUP} {type_name} = {target!r} of {dist}; "
                          f"fix or uninstall that package)") from None


def _load(type_name: str, target: str):
    from dockhil.node import Node

    if not _PATH.fullmatch(target):
        raise LaunchError(f"node type {type_name!r} is not of the form package.module:Class")
    module_name, _, class_name = target.partition(":")
    if os.getcwd() not in sys.path:  # user nodes next to the launch file, as `python -m` would find them
        sys.path.append(os.getcwd())
    if module_name not in sys.modules:
        _check_source(type_name, module_name, class_name)
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise LaunchError(f"node type {type_name!r}: cannot import {module_name!r} ({exc})") from None
    except Exception as exc:  # the module's own code failed: still one line
        raise LaunchError(f"node type {type_name!r}: importing {module_name!r} raised "
                          f"{type(exc).__name__}: {exc}") from None
    cls = getattr(module, class_name, None)
    if cls is None:
        raise LaunchError(f"node type {type_name!r}: module {module_name!r} has no {class_name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Node)) or cls is Node:
        raise LaunchError(f"node type {type_name!r}: {class_name} is not a dockhil node "
                          f"(a subclass of dockhil.node.Node)")
    return cls


def _check_source(type_name: str, module_name: str, class_name: str) -> None:
    """Refuse a module whose source is not Python or defines no class `class_name`."""
    try:
        spec = importlib.util.find_spec(module_name)
    except (ImportError, ValueError) as exc:
        raise LaunchError(f"node type {type_name!r}: cannot import {module_name!r} ({exc})") from None
    if spec is None:
        raise LaunchError(f"node type {type_name!r}: no module {module_name!r}")
    origin = spec.origin or ""
    if not origin.endswith(".py"):
        raise LaunchError(f"node type {type_name!r}: {module_name!r} is not a Python source module, "
                          f"so it defines no dockhil node")
    try:
        with open(origin, encoding="utf-8", errors="replace") as f:
            source = f.read()
    except OSError as exc:
        raise LaunchError(f"node type {type_name!r}: cannot read {origin} ({exc.strerror})") from None
    if not re.search(rf"^\s*class\s+{class_name}\b", source, re.M):
        raise LaunchError(f"node type {type_name!r}: module {module_name!r} defines no class {class_name!r}")
