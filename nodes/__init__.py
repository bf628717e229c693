"""Node types by name. Values are "module:Class" strings, imported only
when a scene uses the node, so a scene loads only what it runs."""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import sys

from dockhil.errors import LaunchError

REGISTRY: dict[str, str] = {
    "satellite_dynamics": "nodes.satellite_dynamics:SatelliteDynamics",
    "virtual_impedance": "nodes.virtual_impedance:VirtualImpedance",
    "ft_sim": "nodes.ft_sim:FtSensorSim",
    "robot_sim": "nodes.robot_sim:RobotSim",
    "delay_injector": "nodes.delay_injector:DelayInjector",
    "ft_can": "nodes.ft_can:FtCanDriver",
    "ft_emulator": "nodes.ft_emulator:FtSensorEmulator",
    "robot_modbus": "nodes.robot_modbus:RobotModbusDriver",
    "robot_emulator": "nodes.robot_emulator:RobotControllerEmulatorNode",
    "bag_source": "nodes.bag_source:BagSource",
    "satellite_dynamics6": "nodes.satellite_dynamics6:SatelliteDynamics6",
    "virtual_impedance6": "nodes.virtual_impedance6:VirtualImpedance6",
    "ft_sim6": "nodes.ft_sim6:FtSensorSim6",
    "robot_sim6": "nodes.robot_sim6:RobotSim6",
}


_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*")


def load(type_name: str):
    """The Node subclass for a registered name or a "package.module:Class" path.

    A module is imported only if its source defines the class, so a path such as
    `antigravity:X` is refused before the module's import could do anything."""
    from dockhil.node import Node

    target = REGISTRY.get(type_name, type_name)
    if ":" not in target:
        known = ", ".join(sorted(REGISTRY)) or "none"
        raise LaunchError(f"unknown node type {type_name!r}; known types: {known} (or give module:Class)")
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
