"""Node types by name. Values are "module:Class" strings, imported only
when a scene uses the node, so a scene loads only what it runs."""

from __future__ import annotations

import importlib
import os
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


def load(type_name: str):
    """The node class for a registered name or a "package.module:Class" path."""
    target = REGISTRY.get(type_name, type_name)
    if ":" not in target:
        known = ", ".join(sorted(REGISTRY)) or "none"
        raise LaunchError(f"unknown node type {type_name!r}; known types: {known} (or give module:Class)")
    module_name, _, class_name = target.partition(":")
    if os.getcwd() not in sys.path:  # user nodes next to the launch file, as `python -m` would find them
        sys.path.append(os.getcwd())
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise LaunchError(f"node type {type_name!r}: cannot import {module_name!r} ({exc})") from None
    try:
        return getattr(module, class_name)
    except AttributeError:
        raise LaunchError(f"node type {type_name!r}: module {module_name!r} has no {class_name!r}") from None
