"""Step one node in this process with the inputs and parameters a test chooses.

No processes, no sockets, no wall clock: the node runs in a one-node graph
whose inputs come from the test, scheduled exactly as in a launched graph
(dockhil.runtime.composed), so the node sees what it would see there. Drake's
FixInputPort + CalcOutput and dora's MockNode are the models.

    from dockhil.testing import NodeHarness, wrench

    with NodeHarness("satellite_dynamics", dt=0.001, m1=750.0, v1=0.0) as h:
        out = h.step(inputs={"ft": wrench(fx=10.0)})   # tick 0
        out = h.step()                                  # tick 1: reads tick 0's wrench
        x1 = out["state"].bodies[0].pose.position.x

Semantics, as in a launched graph:

- `step()` computes tick k = 0, 1, 2, ... in turn and returns the node's
  outputs for it (port -> message; ports the node left empty are absent).
- The messages given with `inputs=` are the ones published at tick k. A
  feedthrough input reads them at tick k; a `feedthrough=False` input reads
  the message of tick k - 1, an input with a `delay` that of tick
  k - round(delay/dt); before that, and at ticks where nothing was given, the
  node reads None (sim time). In wall time (`sim_time=False`) an input keeps
  its latest message, as a running node's would.
- The harness stamps each given message's header with tick k (tick, seq,
  stamp; the frame is kept), and refuses an unknown input or a message of the
  wrong type. Outputs are checked like the executor checks them: undeclared
  ports, wrong types and headers not stamped with tick k are errors.
- Time is the test's: tick.t is k*dt unless `step(t=...)` says otherwise.
- Log lines go to `h.logs` (and stderr with `echo_log=True`).
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, cast

import msgspec

from dockhil.errors import DockhilError
from dockhil.msgs import (
    BodyState,
    BodyWrenches,
    EStop,
    Header,
    Pose,
    RobotCommand,
    RobotState,
    SatelliteState,
    Twist,
    Vector3,
    Wrench,
    WrenchStamped,
)
from dockhil.node import ManualClock, Node, Output, Tick
from dockhil.runtime.composed import ComposedGraph
from dockhil.runtime.executor import check_outputs
from dockhil.scene.graph import Graph, GraphNode, PortRef

FEEDER = "harness-inputs"  # name of the node that publishes the test's inputs


class _Feeder(Node):
    """Publishes, at each tick, the messages the test gave for it; its outputs are set per harness."""

    pending: dict[str, Any]

    def setup(self):
        self.pending = {}

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        header = {"tick": tick.index, "seq": tick.index, "stamp": tick.t if tick.stamp is None else tick.stamp}
        out = {
            port: msgspec.structs.replace(msg, header=msgspec.structs.replace(msg.header, **header))
            for port, msg in self.pending.items()
        }
        self.pending = {}
        return out


class NodeHarness:
    """One node, stepped tick by tick with the test's inputs; see the module docstring.

    `node` is a registered node type ("satellite_dynamics"), a "module:Class"
    path, or a Node subclass. Parameters are checked as a launch file's are.
    """

    def __init__(
        self,
        node: str | type,
        *,
        dt: float = 0.001,
        sim_time: bool = True,
        name: str | None = None,
        params: dict[str, Any] | None = None,
        echo_log: bool = False,
        **more_params: Any,
    ):
        if isinstance(node, str):
            from dockhil import node_types as registry

            cls = registry.load(node)
        else:
            cls = node
        if not (isinstance(cls, type) and issubclass(cls, Node)):
            raise DockhilError(f"NodeHarness: {node!r} is not a Node subclass")
        self.name = name or (node if isinstance(node, str) and ":" not in node else cls.__name__)
        given = {**(params or {}), **more_params}
        if isinstance(node, str):  # as a launch file's node: `dof` picks the class
            _, cls, resolved = registry.resolve(node, self.name, given)
        else:
            resolved = cls.resolve_params(self.name, given)
        self.cls = cls
        self.dt = dt
        self.sim_time = sim_time
        self.logs: list[str] = []
        self.echo_log = echo_log
        ins, outs = cls.ports(resolved)
        self.input_ports = dict(ins)
        self.output_ports = dict(outs)
        # Private topics: the harness graph is only the feeder and the node.
        in_topic = {port: f"/in/{port}" for port in ins}
        feeder_cls = type(
            "HarnessInputs",
            (_Feeder,),
            {"outputs": {port: Output(spec.type, in_topic[port]) for port, spec in ins.items()}},
        )
        feeder = GraphNode(
            FEEDER,
            "harness inputs",
            feeder_cls,
            {},
            {},
            {port: PortRef(FEEDER, port, in_topic[port], spec.type) for port, spec in ins.items()},
        )
        target = GraphNode(
            self.name,
            self.name,
            cls,
            resolved,
            {
                port: PortRef(self.name, port, in_topic[port], spec.type, spec.lag_ticks(dt), spec.required)
                for port, spec in ins.items()
            },
            {port: PortRef(self.name, port, f"/out/{port}", spec.type) for port, spec in outs.items()},
        )
        publishers = {ref.topic: ref for gn in (feeder, target) for ref in gn.outputs.values()}
        subscribers = {ref.topic: [ref] for ref in target.inputs.values()}
        # Only graph.scene.dt is read: a namespace keeps dt exactly as given (1/(1/dt) need not be dt).
        scene = SimpleNamespace(path=f"<NodeHarness {self.name}>", dt=dt)
        graph = Graph(
            scene,  # type: ignore[arg-type]
            {FEEDER: feeder, self.name: target},
            [FEEDER, self.name],
            publishers,
            subscribers,
        )
        # The node's clock (NodeContext.clock: watchdogs, speed checks) is the tick time: it moves only
        # when the test steps, so a verdict does not depend on how fast the machine runs the test.
        self.clock = ManualClock()
        self.graph = ComposedGraph(graph, sim_time=sim_time, log=self._log, clock=self.clock)
        self.node = self.graph.nodes[self.name]
        self._feeder = cast(_Feeder, self.graph.nodes[FEEDER])  # built from `feeder` above
        self.k = 0  # the tick the next step() computes
        self._set_up = False

    # -- life cycle ------------------------------------------------------------------
    def setup(self) -> NodeHarness:
        self.graph.setup(name_failures=False)  # a test of the node sees its own exception
        self._set_up = True
        return self

    def close(self) -> None:
        """The node's close(): hardware drivers hold the robot here."""
        self._set_up = False
        self.graph.close()

    def __enter__(self) -> NodeHarness:
        return self.setup()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- stepping --------------------------------------------------------------------
    def step(self, inputs: dict[str, Any] | None = None, t: float | None = None) -> dict[str, Any]:
        """Compute the next tick with these messages published on the inputs; the node's outputs."""
        if not self._set_up:
            raise DockhilError(f"NodeHarness {self.name!r}: call setup() before step()")
        given = dict(inputs or {})
        for port, msg in given.items():
            spec = self.input_ports.get(port)
            if spec is None:
                raise DockhilError(
                    f"node {self.name!r} has no input {port!r}; inputs: {', '.join(self.input_ports) or 'none'}"
                )
            if msg is not None and type(msg) is not spec.type:
                raise DockhilError(
                    f"node {self.name!r} input {port!r} takes {spec.type.__name__}, got {type(msg).__name__}"
                )
        self._feeder.pending = {port: msg for port, msg in given.items() if msg is not None}
        k = self.k
        tick_t = k * self.dt if t is None else t
        self.clock.sleep_until(tick_t)
        tick = Tick(k, tick_t, self.dt, stamp=None if self.sim_time else tick_t)
        outs = self.graph.step(tick, wall=not self.sim_time)[self.name]
        if not self.sim_time and k > 0:  # the composed wall-time loop checks tick 0 only; a test checks all
            check_outputs(self.name, self.output_ports, k, outs, sim=False)
        self.k += 1
        return {port: msg for port, msg in outs.items() if msg is not None}

    def run(
        self, n: int, inputs: dict[str, Any] | Callable[[int], dict[str, Any] | None] | None = None
    ) -> list[dict[str, Any]]:
        """n steps; `inputs` the same every tick, or a function of the tick index. The outputs of each."""
        return [self.step(inputs(self.k) if callable(inputs) else inputs) for _ in range(n)]

    def _log(self, name: str, line: str) -> None:
        self.logs.append(line)
        if self.echo_log:
            from dockhil.log import node_line

            node_line(name, line)


# -- messages for tests (headers are stamped by the harness) ---------------------------


def vector(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Vector3:
    return Vector3(float(x), float(y), float(z))


def wrench(
    fx: float = 0.0,
    fy: float = 0.0,
    fz: float = 0.0,
    tx: float = 0.0,
    ty: float = 0.0,
    tz: float = 0.0,
    frame: str = "",
) -> WrenchStamped:
    """A force [N] and torque [N m] on the chaser."""
    return WrenchStamped(header=Header(frame=frame), wrench=Wrench(vector(fx, fy, fz), vector(tx, ty, tz)))


def body_wrenches(*forces_x: float, frame: str = "world") -> BodyWrenches:
    """One wrench per body, force along x [N], in the order of SatelliteState.bodies."""
    return BodyWrenches(header=Header(frame=frame), wrenches=tuple(Wrench(vector(f)) for f in forces_x))


def satellite_state(
    x1: float = 0.0,
    v1: float = 0.0,
    x2: float = 0.0,
    v2: float = 0.0,
    m1: float = 750.0,
    m2: float = 1e6,
    in_contact: bool = False,
) -> SatelliteState:
    """Chaser and target on the x axis: positions [m], velocities [m/s], masses [kg]."""
    return SatelliteState(
        header=Header(frame="world"),
        in_contact=in_contact,
        bodies=(
            BodyState("chaser", m1, Pose(vector(x1)), Twist(vector(v1))),
            BodyState("target", m2, Pose(vector(x2)), Twist(vector(v2))),
        ),
    )


def robot_command(x: float = 0.0, v: float = 0.0, y: float = 0.0, z: float = 0.0, enable: bool = True) -> RobotCommand:
    """A probe pose setpoint relative to the target [m] (x > 0: penetration), its velocity along x [m/s]."""
    return RobotCommand(
        header=Header(frame="target"), pose=Pose(vector(x, y, z)), twist=Twist(vector(v)), enable=enable
    )


def robot_state(x: float = 0.0, v: float = 0.0, status: str = "ok") -> RobotState:
    """The robot's actual probe pose relative to the target [m] and its velocity along x [m/s]."""
    return RobotState(header=Header(frame="target"), pose=Pose(vector(x)), twist=Twist(vector(v)), status=status)


def estop(active: bool = True, reason: str = "") -> EStop:
    return EStop(header=Header(), active=active, reason=reason)
