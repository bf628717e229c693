"""From a launch scene to a validated graph: who publishes, who listens, in what order.

Like Drake's DiagramBuilder, the graph is checked before anything runs:
unknown node types, bad parameters, unconnected required inputs, ports of
different types on one topic, two publishers on one topic, and algebraic
loops (cycles whose every input is read at the same tick) are refused with one line.
"""

from __future__ import annotations

import collections
import difflib
import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from dockhil import msgs
from dockhil import node_types as node_registry
from dockhil.errors import LaunchError, ParamError, suggest
from dockhil.scene.launchfile import Scene
from dockhil.scene.schema import MAX_DURATION

if TYPE_CHECKING:
    from dockhil.node import Node


@dataclass
class PortRef:
    node: str
    port: str
    topic: str
    type: type
    lag: int = 0  # ticks: the input at tick k reads the message of tick k - lag
    required: bool = True
    max_age: float | None = None  # inputs, wall time: the launch file's maximum age [s] (None: the node's)

    @property
    def feedthrough(self) -> bool:
        return self.lag == 0


@dataclass
class GraphNode:
    name: str
    type_name: str
    cls: type[Node]
    params: dict[str, Any]
    inputs: dict[str, PortRef]
    outputs: dict[str, PortRef]
    respawn: bool = False
    respawn_delay: float = 1.0
    host: str = ""


@dataclass
class Graph:
    scene: Scene
    nodes: dict[str, GraphNode]
    order: list[str]  # a topological order over feedthrough edges
    publishers: dict[str, PortRef]  # topic -> the output publishing it
    subscribers: dict[str, list[PortRef]] = field(default_factory=dict)  # topic -> inputs
    unconnected: list[PortRef] = field(default_factory=list)  # optional inputs with no publisher

    def topic_type(self, topic: str) -> type:
        return self.publishers[topic].type

    def wall_max_ages(self) -> dict[str, float]:
        """Each input's maximum age in wall time ("node.port" -> s) as a node process applies it (see
        NodeExecutor): the launch file's, else the node's declared, else the rate's default; none
        (inf) for a free-running node's undeclared ones. The composed loop's lateness is judged on them."""
        out = {}
        for gn in self.nodes.values():
            ins, _ = gn.cls.ports(gn.params)
            for port, ref in gn.inputs.items():
                if ref.max_age is not None:
                    out[f"{gn.name}.{port}"] = ref.max_age
                elif not (gn.cls.free_running and ins[port].max_age is None):
                    out[f"{gn.name}.{port}"] = ins[port].age_limit(self.scene.dt)
        return out


_TOPIC = re.compile(r"/[A-Za-z0-9_./-]*")


def _topic_for(port: str, default: str, remap: dict[str, str], where: str, namespace: str = "") -> str:
    """A remap names the exact topic; a default topic is put under the group's namespace."""
    topic = remap.get(port, remap.get(default))
    if topic is None:
        topic = f"/{namespace}{default}" if namespace else default
    if not _TOPIC.fullmatch(topic):
        raise LaunchError(
            f"{where}: topic {topic!r} of port {port!r} must start with / and use only letters, digits and _ . - /"
        )
    return topic


def _slipped_argument(scene: Scene, exc: ParamError) -> str | None:
    """A time given in milliseconds for seconds, said of the argument the user typed (delay:=16), when one
    given away from its default holds that value."""
    if exc.slip is None:
        return None
    seconds, what, meant = exc.slip
    for name, arg in scene.args.items():
        value = scene.values.get(name)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value == seconds != arg.default:
            return f"{name}:={value:g} is {seconds:g} s: {what}; did you mean {name}:={meant:g}?"
    return None


def build(scene: Scene) -> Graph:
    gnodes: dict[str, GraphNode] = {}
    for spec in scene.nodes:
        declared = f"{spec.source}:{spec.line}" if spec.line else spec.source
        where = f"{declared}: node {spec.name!r}"
        try:  # the class that runs, by its registered name (`dof: 6` names the 6-DOF type)
            type_name, cls, params = node_registry.resolve(spec.type, spec.name, spec.params)
        except LaunchError as exc:
            raise LaunchError(f"{where}: {exc}") from None
        except ParamError as exc:
            raise LaunchError(_slipped_argument(scene, exc) or f"{declared}: {exc}") from None
        ins, outs = cls.ports(params)
        for name, p in ins.items():
            # A declared input delay is kept as that many ticks of messages: bounded by the longest run.
            if not 0.0 <= p.delay <= MAX_DURATION:
                raise LaunchError(
                    f"{where}: input {name!r} delay {p.delay:g} s is not between 0 and "
                    f"{MAX_DURATION:g} s (the longest run)"
                )
        known = set(ins) | set(outs) | {p.topic for p in ins.values()} | {p.topic for p in outs.values()}
        bad = sorted(set(spec.remap) - known)
        if bad:
            near = difflib.get_close_matches(bad[0], sorted(known), n=1)
            hint = f"did you mean {near[0]!r}? " if near else ""
            raise LaunchError(
                f"{where}: remap {bad[0]!r} names no port or topic of {spec.type}; {hint}"
                f"ports: {', '.join(sorted(set(ins) | set(outs)))}"
            )
        for port in spec.max_age:
            if port not in ins:
                near = difflib.get_close_matches(port, list(ins), n=1)
                hint = f"did you mean {near[0]!r}? " if near else ""
                raise LaunchError(
                    f"{where}: max_age {port!r} names no input of {spec.type}; {hint}"
                    f"inputs: {', '.join(sorted(ins)) or 'none'}"
                )
        ns = spec.namespace
        inputs = {
            name: PortRef(
                spec.name,
                name,
                _topic_for(name, p.topic, spec.remap, where, ns),
                p.type,
                p.lag_ticks(scene.dt),
                p.required,
                spec.max_age.get(name),
            )
            for name, p in ins.items()
        }
        outputs = {
            name: PortRef(spec.name, name, _topic_for(name, p.topic, spec.remap, where, ns), p.type)
            for name, p in outs.items()
        }
        gnodes[spec.name] = GraphNode(
            spec.name, type_name, cls, params, inputs, outputs, spec.respawn, spec.respawn_delay, spec.host
        )

    mixed = node_registry.mixed_dof({name: gn.type_name for name, gn in gnodes.items()})
    if mixed:
        raise LaunchError(f"{scene.path}: {mixed}")

    publishers: dict[str, PortRef] = {}
    for gn in gnodes.values():
        for ref in gn.outputs.values():
            other = publishers.get(ref.topic)
            if other is not None:
                raise LaunchError(
                    f"{scene.path}: topic {ref.topic} is published by both {other.node}.{other.port} and "
                    f"{ref.node}.{ref.port}; remap one of them"
                )
            publishers[ref.topic] = ref

    subscribers: dict[str, list[PortRef]] = {}
    unconnected = []
    for gn in gnodes.values():
        for ref in gn.inputs.values():
            pub = publishers.get(ref.topic)
            if pub is None:
                if ref.required:
                    raise LaunchError(
                        f"{scene.path}: node {ref.node!r} input {ref.port!r} needs topic {ref.topic} but no node "
                        f"publishes it; add a node that does, or remap the input"
                    )
                unconnected.append(ref)
                continue
            if pub.type is not ref.type:
                raise LaunchError(
                    f"{scene.path}: topic {ref.topic}: {pub.node}.{pub.port} publishes {msgs.type_name(pub.type)} "
                    f"but {ref.node}.{ref.port} expects {msgs.type_name(ref.type)}; connect ports of one type"
                )
            _refuse_age_of_respawned(scene.path, ref, pub, gnodes)
            subscribers.setdefault(ref.topic, []).append(ref)

    _refuse_replay_into_hardware(scene.path, gnodes, publishers)
    _refuse_driver_past_its_emulator(scene.path, gnodes)
    _refuse_ft_driver_off_its_emulator(scene.path, gnodes)
    order = _feedthrough_order(scene.path, gnodes, publishers)
    return Graph(scene, gnodes, order, publishers, subscribers, unconnected)


def _refuse_age_of_respawned(where: str, ref: PortRef, pub: PortRef, gnodes: dict[str, GraphNode]) -> None:
    """A topic from a node that respawns may pause while it restarts: no finite maximum age on it."""
    if ref.max_age is not None and math.isfinite(ref.max_age) and gnodes[pub.node].respawn:
        raise LaunchError(
            f"{where}: node {ref.node!r} input {ref.port!r} has max_age {ref.max_age:g} s but reads "
            f"{ref.topic} from {pub.node!r}, which respawns (and may pause): drop one of the two"
        )


def set_max_ages(graph: Graph, given: list[tuple[str, str, float]]) -> None:
    """Command-line maximum ages (`--max-age NODE.INPUT=SECONDS`; math.inf: no limit) over the
    launch file's and the node's: each names a node of the graph and one of its inputs."""
    for node, port, age in given:
        where = f"--max-age {node}.{port}"
        gn = graph.nodes.get(node)
        if gn is None:
            raise LaunchError(
                f"{where}: {graph.scene.path} has no node {node!r}; {suggest(node, graph.nodes, 'nodes')}"
            )
        ref = gn.inputs.get(port)
        if ref is None:
            raise LaunchError(
                f"{where}: node {node!r} ({gn.type_name}) has no input {port!r}; {suggest(port, gn.inputs, 'inputs')}"
            )
        ref.max_age = age
        pub = graph.publishers.get(ref.topic)
        if pub is not None:
            _refuse_age_of_respawned(where, ref, pub, graph.nodes)


def _refuse_replay_into_hardware(path: str, gnodes: dict[str, GraphNode], publishers: dict[str, PortRef]) -> None:
    """Only this graph's live run moves real hardware: a recording replayed anywhere upstream of a
    hardware driver's input (the sensor the force limit watches, or the forces the command follows)
    would move the robot on another run's data."""
    for gn in gnodes.values():
        if not gn.cls.moves_hardware:
            continue
        # Breadth first, so a recording that feeds an input directly is the one named.
        todo, seen = collections.deque((ref, ref.topic) for ref in gn.inputs.values()), set()
        while todo:
            ref, topic = todo.popleft()
            pub = publishers.get(topic)
            if pub is None or topic in seen:
                continue
            seen.add(topic)
            source = gnodes[pub.node]
            if source.cls.replays_recording:
                via = "comes" if topic == ref.topic else f"depends on {topic}"
                raise LaunchError(
                    f"{path}: node {gn.name!r} ({gn.type_name}) moves real hardware, but its input "
                    f"{ref.port!r} ({ref.topic}) {via} from {source.name!r} ({source.type_name}), which "
                    f"replays a recording, not this run; replay in front of a simulated robot instead"
                )
            todo.extend((ref, r.topic) for r in source.inputs.values())


_LOOPBACK = {"127.0.0.1", "localhost", "::1"}


def _refuse_driver_past_its_emulator(path: str, gnodes: dict[str, GraphNode]) -> None:
    """A graph that emulates the robot controller means its driver to command that emulator: a driver
    pointed elsewhere (emulators:=true with modbus_host:= a lab machine) would move a real robot
    while the operator believes it emulated."""
    emulators = [gn for gn in gnodes.values() if gn.type_name == "robot_emulator" and gn.params["port"]]
    if not emulators:
        return

    def where(params: dict[str, Any]) -> tuple[str, int]:
        host = params["host"]
        return ("127.0.0.1" if host in _LOOPBACK else host), params["port"]

    served = {where(em.params): em for em in emulators}
    for gn in gnodes.values():
        if gn.type_name == "robot_modbus" and where(gn.params) not in served:
            em = emulators[0]
            raise LaunchError(
                f"{path}: node {gn.name!r} ({gn.type_name}) commands the controller at {gn.params['host']}:"
                f"{gn.params['port']}, but node {em.name!r} emulates one at {em.params['host']}:{em.params['port']}: "
                f"the driver would move a real robot; point it at the emulator, or drop the emulator"
            )


def _refuse_ft_driver_off_its_emulator(path: str, gnodes: dict[str, GraphNode]) -> None:
    """A graph that emulates the CAN F/T sensor means its driver to read that emulator: a driver on
    another bus (emulators:=true with can_interface:=socketcan) would read a real sensor, or none."""
    emulators = [gn for gn in gnodes.values() if gn.type_name == "ft_emulator"]
    if not emulators:
        return

    def reads(driver: dict, em: dict) -> bool:
        interface = "slcan" if driver["interface"] == "pty" else driver["interface"]
        if em["interface"] == "pty":  # an slcan adapter on a pseudo-terminal, linked at its channel
            return interface == "slcan" and driver["channel"] == em["channel"]
        if em["interface"] == "slcan":  # a second serial adapter on the driver's bus
            return interface == "slcan" and driver["channel"] != em["channel"]
        return interface == em["interface"] and driver["channel"] == em["channel"]

    for gn in gnodes.values():
        if gn.type_name == "ft_can" and not any(reads(gn.params, em.params) for em in emulators):
            em = emulators[0]
            raise LaunchError(
                f"{path}: node {gn.name!r} (ft_can) reads CAN {gn.params['interface']} {gn.params['channel']!r}, "
                f"but node {em.name!r} emulates the sensor on {em.params['interface']} {em.params['channel']!r}: "
                f"the driver would read a real sensor, or none; with emulators:=true give can_interface:=auto or pty"
            )


def _feedthrough_order(path: str, gnodes: dict[str, GraphNode], publishers: dict[str, PortRef]) -> list[str]:
    """Topological order over feedthrough edges; refuse a cycle and name it."""
    edges: dict[str, list[str]] = {name: [] for name in gnodes}
    for gn in gnodes.values():
        for ref in gn.inputs.values():
            pub = publishers.get(ref.topic)
            if pub is not None and ref.feedthrough:
                edges[pub.node].append(gn.name)
    # Depth-first search finds a cycle to name; file order keeps the result stable.
    state: dict[str, int] = {}
    stack: list[str] = []
    post: list[str] = []

    def visit(n: str) -> None:
        state[n] = 1
        stack.append(n)
        for m in edges[n]:
            if state.get(m) == 1:
                cycle = stack[stack.index(m) :] + [m]
                raise LaunchError(
                    f"{path}: algebraic loop {' -> '.join(cycle)}: every input on it is feedthrough; "
                    f"put a delay or a state-holding node on the loop"
                )
            if m not in state:
                visit(m)
        stack.pop()
        state[n] = 2
        post.append(n)

    for n in gnodes:
        if n not in state:
            visit(n)
    return post[::-1]
