"""How a validated graph becomes processes: each topic's endpoint (ipc in the run directory, or tcp
ports reachable from every host), which nodes share a process (containers), and each process's
spec. No process is started here (dockhil.runtime.launcher does that)."""

from __future__ import annotations

import math
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from dockhil import msgs
from dockhil.errors import LaunchError
from dockhil.runtime.executor import PortWire, RunSpec
from dockhil.runtime.registry import KEY_FILE, new_run_id
from dockhil.runtime.rundir import new_run_dir
from dockhil.runtime.transport import GraphKeys, ipc_endpoint

if TYPE_CHECKING:  # the graph module loads the launch-file parser (yaml)
    from dockhil.scene.graph import Graph


@dataclass
class ExtraProcess:
    """A helper process that subscribes to topics (a recorder): it counts as
    a subscriber so that sim time waits for it before tick 0.

    verdict: once the nodes are done (or stopped) it says RECORDED and reads the run's verdict, one
    JSON line, on its stdin before it exits (the recorder writes it into the bag); the launcher gets
    the verdict from its `judge`."""

    name: str
    argv: list[str]
    topics: list[str]
    verdict: bool = False


@dataclass
class Endpoints:
    run_id: str
    run_dir: Path
    topics: dict[str, str]  # topic -> endpoint subscribers connect to
    types: dict[str, str]  # topic -> wire type name
    binds: dict[str, str] = field(default_factory=dict)  # topic -> endpoint the publisher binds
    key_file: Path | None = None  # the graph's CURVE keys, mode 0600, in run_dir


def _free_tcp_port(taken: set[int]) -> int:
    """A free port whose next two are free too (a publisher's observers get the next, its trailing
    readers the one after: see transport.observer_endpoint and trailing_endpoint); none in `taken`,
    to which all three are added."""
    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        ports = {port, port + 1, port + 2}
        if port >= 65534 or ports & taken:
            continue
        try:
            for after in (port + 1, port + 2):
                with socket.socket() as s:
                    s.bind(("127.0.0.1", after))
        except OSError:
            continue
        taken.update(ports)
        return port


def is_local(host: str) -> bool:
    return host in ("", "localhost", "127.0.0.1", socket.gethostname(), socket.getfqdn())


def bind_address(host: str) -> str:
    """The address of the one interface a publisher on `host` binds (ZeroMQ binds addresses, not names)."""
    try:
        return socket.gethostbyname(host)
    except OSError as exc:
        raise LaunchError(
            f"host {host!r}: cannot resolve its address to bind ({exc.strerror or exc}); "
            f"give the node's host as an address"
        ) from None


def _check_reachable(graph: Graph, here: str, addresses: dict[str, str]) -> None:
    """Publishers bind one address, not every interface: the one this machine is reached by must not be
    loopback when a node on another machine is to reach it."""
    import ipaddress

    local = addresses.get(here) or bind_address(here)
    if not ipaddress.ip_address(local).is_loopback:
        return
    for gn in graph.nodes.values():
        if is_local(gn.host):
            continue
        address = addresses.get(gn.host) or bind_address(gn.host)
        if not ipaddress.ip_address(address).is_loopback:
            raise LaunchError(
                f"node {gn.name!r} runs on {gn.host} ({address}), but this machine's name {here!r} "
                f"resolves to {local}, a loopback address it could not reach; map {here} to this "
                f"machine's network address (/etc/hosts or DNS)"
            )


def assign_endpoints(graph: Graph, transport: str = "ipc", advertise: str | None = None) -> Endpoints:
    """ipc sockets on one host; tcp when asked or when a node runs on another host. Over tcp a
    publisher binds only the interface the others reach it by, its host: the node's `host`, or
    for nodes started here `advertise` (default: this machine's name, 127.0.0.1 if all is local).
    Every endpoint speaks CURVE with keys made here for this graph alone."""
    run_id = new_run_id()
    remote = any(not is_local(gn.host) for gn in graph.nodes.values())
    here = advertise or (socket.gethostname() if remote else "127.0.0.1")
    topics, binds = {}, {}
    addresses: dict[str, str] = {}
    ports: set[int] = set()
    for topic, ref in graph.publishers.items():
        if transport == "ipc" and not remote:
            continue
        host = graph.nodes[ref.node].host
        host = host if not is_local(host) else here
        if host not in addresses:
            addresses[host] = bind_address(host)
        port = _free_tcp_port(ports)
        binds[topic] = f"tcp://{addresses[host]}:{port}"
        topics[topic] = f"tcp://{host}:{port}"
    if remote:
        _check_reachable(graph, here, addresses)
    run_dir = new_run_dir(run_id)
    for topic in graph.publishers:
        if topic not in topics:
            topics[topic] = binds[topic] = ipc_endpoint(run_dir, topic)
    key_file = GraphKeys.make().write(run_dir / KEY_FILE)
    types = {topic: msgs.type_name(ref.type) for topic, ref in graph.publishers.items()}
    return Endpoints(run_id, run_dir, topics, types, binds, key_file)


CONTAINER_TYPE = "dockhil.runtime.container:Container"


def processes(graph: Graph) -> dict[str, list[str]]:
    """Process name -> the nodes it runs, in step order: a node alone, or the nodes naming one
    `container:`. Refused in one line: a malformed key, an isolated node in a container, a
    container named like a node, a remote or respawned member, and a container that would
    wait for itself (a same-tick path that leaves it and comes back)."""
    import re

    specs = {s.name: s for s in graph.scene.nodes}
    unit: dict[str, str] = {}
    for name in graph.order:
        spec, where = specs.get(name), f"{graph.scene.path}: node {name!r}"
        if spec is None:  # a graph assembled without a launch file: one process per node
            unit[name] = name
            continue
        container, isolated = spec.container, spec.isolated
        if not isinstance(isolated, bool):
            raise LaunchError(f"{where}: `isolated` must be true or false, got {isolated!r}")
        if not isinstance(container, str) or (container and not re.fullmatch(r"[A-Za-z0-9_.-]+", container)):
            raise LaunchError(f"{where}: `container` must be a name of letters, digits and _ . -, got {container!r}")
        if container and isolated:
            raise LaunchError(
                f"{where}: `isolated: true` keeps it in a process of its own; remove "
                f"`container: {container}` or `isolated`"
            )
        if container and container in graph.nodes:
            raise LaunchError(f"{where}: container {container!r} has the name of a node; name it otherwise")
        if container and (spec.host or spec.respawn):
            why = f"runs on {spec.host}" if spec.host else "is respawned on its own"
            raise LaunchError(f"{where}: it {why}, so it cannot share container {container!r}; remove `container`")
        unit[name] = container or name
    out: dict[str, list[str]] = {}
    for name in graph.order:
        out.setdefault(unit[name], []).append(name)
    _check_no_loop_through(graph, unit)
    return out


def _check_no_loop_through(graph: Graph, unit: dict[str, str]) -> None:
    """A container steps its members together, so a same-tick path from it through other
    processes back into it would wait forever: refuse it and name the path."""
    edges: dict[str, set[str]] = {u: set() for u in unit.values()}
    for gn in graph.nodes.values():
        for ref in gn.inputs.values():
            pub = graph.publishers.get(ref.topic)
            if pub is not None and ref.lag == 0 and unit[pub.node] != unit[gn.name]:
                edges[unit[pub.node]].add(unit[gn.name])
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(u: str) -> None:
        state[u] = 1
        stack.append(u)
        for v in sorted(edges[u]):
            if state.get(v) == 1:
                path = " -> ".join(stack[stack.index(v) :] + [v])
                raise LaunchError(
                    f"{graph.scene.path}: container processes {path} read each other at the same "
                    f"tick, so a container would wait for itself; put those nodes in one container "
                    f"or none"
                )
            if v not in state:
                visit(v)
        stack.pop()
        state[u] = 2

    for u in edges:
        if u not in state:
            visit(u)


def check_composable(graph: Graph) -> None:
    """--composed runs every node in one process: refused for a node that asks to be isolated."""
    for spec in graph.scene.nodes:
        if spec.isolated is True:
            raise LaunchError(
                f"{graph.scene.path}: node {spec.name!r} is `isolated: true` (its own process), "
                f"so the graph cannot run --composed; run it without --composed"
            )


def _container_spec(graph: Graph, name: str, members: list[str], specs: dict[str, RunSpec]) -> RunSpec:
    """One RunSpec for the nodes of a container: their outside inputs and all their outputs."""
    inside = set(members)
    described, inputs, outputs = [], {}, {}
    for m in members:
        gn, spec = graph.nodes[m], specs[m]
        internal = {
            port: [ref.topic, ref.lag]
            for port, ref in gn.inputs.items()
            if ref.topic in graph.publishers and graph.publishers[ref.topic].node in inside
        }
        external = {
            port: [ref.topic, ref.lag]
            for port, ref in gn.inputs.items()
            if port in spec.inputs and port not in internal
        }
        described.append(
            {
                "name": m,
                "type": gn.type_name,
                "params": gn.params,
                "internal": internal,
                "external": external,
                "outputs": {port: ref.topic for port, ref in gn.outputs.items()},
            }
        )
        inputs.update({f"{m}.{port}": spec.inputs[port] for port in external})
        outputs.update({f"{m}.{port}": wire for port, wire in spec.outputs.items()})
    first = specs[members[0]]
    return RunSpec(
        name,
        CONTAINER_TYPE,
        {"members": described},
        first.dt,
        first.clock,
        first.n_ticks,
        inputs,
        outputs,
        key_file=first.key_file,
        run_id=first.run_id,
    )


def burst(graph: Graph, topic: str) -> int:
    """Sim time: how many ticks of a topic its publisher may send together. A reader that reads it
    `lag` ticks late leaves that much slack: holding fewer than lag/2 ticks keeps every cycle
    through the topic, even with a burst on each of its delayed hops, from waiting for a held
    message (the holds on a cycle add up to under half its lag), and leaves the other half of
    the slack for pipelining. The messages and their ticks are the same; only when they leave."""
    lags = [ref.lag for ref in graph.subscribers.get(topic, [])]
    return max(1, min(lags) // 2) if lags else 1


def run_specs(
    graph: Graph,
    ep: Endpoints,
    clock: str,
    n_ticks: int | None,
    extra: list[ExtraProcess],
    units: dict[str, list[str]] | None = None,
) -> dict[str, RunSpec]:
    """One RunSpec per process (`units`, from processes(); default: one per node)."""
    unit_of = {m: u for u, members in (units or {}).items() for m in members}
    extra_count: dict[str, int] = {}
    for proc in extra:
        for topic in proc.topics:
            extra_count[topic] = extra_count.get(topic, 0) + 1
    specs = {}
    # A topic from a node the launcher respawns may pause while it restarts: no maximum age there.
    respawned = {topic for topic, ref in graph.publishers.items() if graph.nodes[ref.node].respawn}
    for name in graph.order:
        gn = graph.nodes[name]
        # No limit (--max-age NODE.INPUT=inf) travels as a flag: JSON has no infinity.
        inputs = {
            port: PortWire(
                ref.topic,
                ep.topics[ref.topic],
                ep.types[ref.topic],
                ref.lag,
                unlimited_age=ref.topic in respawned or ref.max_age == math.inf,
                max_age=None if ref.max_age == math.inf else ref.max_age,
                publisher=graph.publishers[ref.topic].node if ref.topic in graph.publishers else "",
            )
            for port, ref in gn.inputs.items()
            if ref.topic in ep.topics
        }
        outputs = {
            port: PortWire(
                ref.topic,
                ep.binds[ref.topic],
                ep.types[ref.topic],
                # One subscription per process: a container's members share one socket.
                subscribers=len(
                    {unit_of.get(s.node, s.node) for s in graph.subscribers.get(ref.topic, [])}
                    - {unit_of.get(name, name)}
                )
                + extra_count.get(ref.topic, 0),
                burst=burst(graph, ref.topic) if clock == "sim" else 1,
            )
            for port, ref in gn.outputs.items()
        }
        specs[name] = RunSpec(
            name,
            gn.type_name,
            gn.params,
            graph.scene.dt,
            clock,
            n_ticks,
            inputs,
            outputs,
            key_file=str(ep.key_file or ""),
            run_id=ep.run_id,
        )
    for u, members in (units or {}).items():
        if len(members) > 1 or u != members[0]:
            container = _container_spec(graph, u, members, specs)
            for m in members:
                del specs[m]
            specs[u] = container
    return specs
