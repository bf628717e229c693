"""Node types by name. Values are "module:Class" strings, imported only
when a scene uses the node, so a scene loads only what it runs.

Other installed distributions add node types through the entry-point group
`dockhil.nodes` (in their pyproject.toml:
`[project.entry-points."dockhil.nodes"] my_sensor = "my_pkg.sensor:MySensor"`).
A built-in name always wins, and entry points are read only for a name that is
not built in, so a broken third-party package never breaks the built-in types.

The parameter `dof` of the simulated loop's types (SIX_DOF) picks their class: 1 (the
default) the type itself, along x; 6 its 6-DOF type (docs/sixdof.md), whose own name stays
an alias. `resolve` turns a declared node into what runs: the registered name of the class,
the class, its checked parameters (without `dof`, which the class does not take). A graph
records that name, so whatever looks a node up by type sees one name for both spellings."""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import reprlib
import sys
from typing import TYPE_CHECKING, Any

from dockhil.errors import LaunchError, ParamError, suggest

if TYPE_CHECKING:
    from dockhil.node import Node, Param

REGISTRY: dict[str, str] = {
    "satellite_dynamics": "dockhil.nodes.satellite_dynamics:SatelliteDynamics",
    "virtual_impedance": "dockhil.nodes.virtual_impedance:VirtualImpedance",
    "ft_sim": "dockhil.nodes.ft_sim:FtSensorSim",
    "robot_sim": "dockhil.nodes.robot_sim:RobotSim",
    "delay_injector": "dockhil.nodes.delay_injector:DelayInjector",
    "ft_can": "dockhil.devices.can_ft.driver:FtCanDriver",
    "ft_emulator": "dockhil.devices.can_ft.emulator:FtSensorEmulator",
    "ft_netft": "dockhil.devices.ati_netft.driver:FtNetFtDriver",
    "netft_emulator": "dockhil.devices.ati_netft.emulator_node:NetFtEmulator",
    "robot_modbus": "dockhil.devices.modbus_robot.driver:RobotModbusDriver",
    "robot_emulator": "dockhil.devices.modbus_robot.emulator_node:RobotControllerEmulatorNode",
    "robot_rsi": "dockhil.devices.kuka_rsi.driver:RobotRsiDriver",
    "rsi_emulator": "dockhil.devices.kuka_rsi.emulator_node:RsiControllerEmulatorNode",
    "bag_source": "dockhil.nodes.bag_source:BagSource",
    "identification": "dockhil.nodes.identification:Identification",
    "satellite_dynamics6": "dockhil.nodes.satellite_dynamics6:SatelliteDynamics6",
    "virtual_impedance6": "dockhil.nodes.virtual_impedance6:VirtualImpedance6",
    "ft_sim6": "dockhil.nodes.ft_sim6:FtSensorSim6",
    "robot_sim6": "dockhil.nodes.robot_sim6:RobotSim6",
    "ros2_bridge": "dockhil.nodes.ros2_bridge:Ros2Bridge",
}


# The types `dof` picks between: 1-DOF type -> its 6-DOF type.
SIX_DOF = {
    "satellite_dynamics": "satellite_dynamics6",
    "virtual_impedance": "virtual_impedance6",
    "ft_sim": "ft_sim6",
    "robot_sim": "robot_sim6",
}
ONE_DOF = {six: one for one, six in SIX_DOF.items()}


def dof_param(type_name: str) -> Param | None:
    """The `dof` parameter of a type that takes one (its default and help, as a Param), else None.
    `resolve` checks it: it picks the class, so no class declares it."""
    if type_name not in SIX_DOF and type_name not in ONE_DOF:
        return None
    from dockhil.node import Param

    if type_name in ONE_DOF:
        return Param(
            int,
            6,
            help=f"degrees of freedom: 6, this node ({ONE_DOF[type_name]} with dof: 6); "
            f"for 1 write node: {ONE_DOF[type_name]}",
        )
    return Param(
        int,
        1,
        help=f"degrees of freedom: 1, this node (along x); 6, the 6-DOF node ({SIX_DOF[type_name]}, docs/sixdof.md)",
    )


def resolve(type_name: str, node_name: str, given: dict) -> tuple[str, type[Node], dict]:
    """A declared node as it runs: (registered type name, class, checked parameters).

    `dof` picks the class of a type that takes it and is not passed on; a parameter that only
    the other dof's node takes is refused in one line that says which dof takes it."""
    spec = dof_param(type_name)
    dof = spec.default if spec is not None else None
    if spec is not None and "dof" in given:
        given = dict(given)
        dof = given.pop("dof")
        if type(dof) is not int or dof not in (1, 6):  # not True (== 1) nor 6.0
            raise ParamError(
                f"node {node_name!r} ({type_name}): dof must be the integer 1 or 6, got "
                f"{reprlib.repr(dof)}; give dof: 1 (along x) or dof: 6 (the 6-DOF node)"
            )
        if type_name in ONE_DOF and dof != 6:
            raise ParamError(
                f"node {node_name!r} ({type_name}): dof {dof}, but {type_name} is the 6-DOF node; "
                f"write node: {ONE_DOF[type_name]} for the {dof}-DOF one"
            )
    registered = SIX_DOF[type_name] if type_name in SIX_DOF and dof == 6 else type_name
    cls = load(registered)
    try:
        return registered, cls, cls.resolve_params(node_name, given)
    except ParamError:
        if dof is None:
            raise
        line = _other_dof_line(type_name, registered, dof, node_name, cls, given)
        if line is None:
            raise
        raise ParamError(line) from None


def mixed_dof(types: dict[str, str]) -> str | None:
    """The refusal of a graph whose simulated loop mixes 1-DOF and 6-DOF nodes (node name -> its
    registered type), else None. Their messages have the same types, so the graph would connect
    and run, each node reading what the other kind writes for something else."""
    one = [name for name, t in types.items() if t in SIX_DOF]
    six = [name for name, t in types.items() if t in ONE_DOF]
    if not one or not six:
        return None
    return (
        f"node {one[0]!r} ({types[one[0]]}) is 1-DOF and node {six[0]!r} ({ONE_DOF[types[six[0]]]} with dof: 6) "
        f"is 6-DOF: the nodes of one loop take one dof; give {', '.join(map(repr, one))} dof: 6, or "
        f"{', '.join(map(repr, six))} dof: 1"
    )


def _other_dof_line(
    type_name: str, registered: str, dof: int, node_name: str, cls: type[Node], given: dict
) -> str | None:
    """The refusal of a parameter that the node of the other dof takes and this one does not,
    or None (then the class's own refusal stands)."""
    other_dof = 1 if dof == 6 else 6
    other = load(ONE_DOF[registered] if dof == 6 else SIX_DOF[registered])  # only on this error path
    if type_name in ONE_DOF:
        label, fix = type_name, f"write node: {ONE_DOF[type_name]} for the 1-DOF node"
    else:
        label, fix = f"{type_name}, dof {dof}", f"set dof: {other_dof} for the {other_dof}-DOF node"
    for name in sorted(given):
        value, theirs, mine = given[name], other.params.get(name), cls.params.get(name)
        if theirs is None or not _accepts(theirs, name, value):
            continue
        if mine is None:
            return (
                f"node {node_name!r} ({label}): unknown parameter {name!r}, a parameter of the "
                f"{other_dof}-DOF node; {fix}"
            )
        if mine.type is not theirs.type and not _accepts(mine, name, value):
            return (
                f"node {node_name!r} ({label}): parameter {name!r} is a {type(value).__name__} "
                f"{reprlib.repr(value)}, as the {other_dof}-DOF node takes it, not a {mine.type.__name__}; "
                f"{fix}, or give a {mine.type.__name__}"
            )
    return None


def _accepts(param: Param, name: str, value: Any) -> bool:
    try:
        param.check("", name, value)
        return True
    except ParamError:
        return False


ENTRY_POINT_GROUP = "dockhil.nodes"


def plugins() -> dict[str, tuple[str, str]]:
    """Node types of other installed distributions: name -> ("module:Class", "distribution version").
    Names that are built in are left out (the built-in wins); the first distribution found wins."""
    from importlib.metadata import entry_points

    found: dict[str, tuple[str, str]] = {}
    try:
        eps = entry_points(group=ENTRY_POINT_GROUP)
    except Exception as exc:  # a distribution's metadata that does not parse
        raise LaunchError(
            f"cannot read the installed {ENTRY_POINT_GROUP} entry points ({type(exc).__name__}: {exc})"
        ) from None
    for ep in eps:
        dist = f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "an unnamed distribution"
        if ep.name not in REGISTRY and ep.name not in found:
            found[ep.name] = (ep.value.strip(), dist)
    return found


_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*")


def load(type_name: str) -> type[Node]:
    """The Node subclass for a registered name or a "package.module:Class" path.

    A module is imported only if its source defines the class, so a path such as
    `antigravity:X` is refused before the module's import could do anything."""
    if type_name in REGISTRY or ":" in type_name:
        return _load(type_name, REGISTRY.get(type_name, type_name))
    extra = plugins()
    if type_name not in extra:
        raise LaunchError(
            f"unknown node type {type_name!r}; "
            f"{suggest(type_name, [*REGISTRY, *extra], 'known types')} (or give module:Class)"
        )
    target, dist = extra[type_name]
    try:
        return _load(type_name, target)
    except LaunchError as exc:
        raise LaunchError(
            f"{exc} (entry point {ENTRY_POINT_GROUP} {type_name} = {target!r} of {dist}; fix or uninstall that package)"
        ) from None


def _load(type_name: str, target: str) -> type[Node]:
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
        raise LaunchError(
            f"node type {type_name!r}: importing {module_name!r} raised {type(exc).__name__}: {exc}"
        ) from None
    cls = getattr(module, class_name, None)
    if cls is None:
        raise LaunchError(f"node type {type_name!r}: module {module_name!r} has no {class_name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Node)) or cls is Node:
        raise LaunchError(
            f"node type {type_name!r}: {class_name} is not a dockhil node (a subclass of dockhil.node.Node)"
        )
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
        raise LaunchError(
            f"node type {type_name!r}: {module_name!r} is not a Python source module, so it defines no dockhil node"
        )
    try:
        with open(origin, encoding="utf-8", errors="replace") as f:
            source = f.read()
    except OSError as exc:
        raise LaunchError(f"node type {type_name!r}: cannot read {origin} ({exc.strerror})") from None
    if not re.search(rf"^\s*class\s+{class_name}\b", source, re.M):
        raise LaunchError(f"node type {type_name!r}: module {module_name!r} defines no class {class_name!r}")
