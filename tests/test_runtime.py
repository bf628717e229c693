"""The runtime in motion: determinism, shutdown, node death, bad input.

The shutdown and bad-input tests run wall-time graphs (marked wall_time); they wait for
conditions with deadlines, so a busy machine makes them slower, not wrong."""

import json
import os
import signal
import subprocess
import time

import msgpack
import pytest
import zmq

from dockhil import msgs
from dockhil.msgs.codec import decode, encode
from dockhil.runtime.transport import split
from tests.conftest import dockhil_cmd, registered
from tests.support.inprocess import launch_here_or_process

LOOP = """
rate: 1000
duration: 0.4
nodes:
  - {{name: integ, node: "tests.support.graphnodes:Integrator"}}
  - {{name: gain, node: "tests.support.graphnodes:Gain", params: {{die_at: {die_at}}}}}
  - {{name: trace, node: "tests.support.graphnodes:Trace", params: {{path: "{trace}"}}}}
"""


def run_loop(write_launch, tmp_path, tag, *extra, die_at=-1, timeout=60):
    trace = tmp_path / f"trace-{tag}.txt"
    path = write_launch(LOOP.format(trace=trace, die_at=die_at), f"loop-{tag}.yaml")
    return launch(path, *extra, timeout=timeout), trace


def launch(path, *args, timeout=60):
    """`dockhil launch PATH ARGS`; a composed run needs no process of its own, so it runs through
    dockhil.cli.main in this process (no interpreter start-up)."""
    return launch_here_or_process(path, *args, timeout=timeout)


def test_multiprocess_runs_are_identical_and_equal_composed(write_launch, tmp_path):
    r1, t1 = run_loop(write_launch, tmp_path, "a")
    r2, t2 = run_loop(write_launch, tmp_path, "b", "--transport", "tcp")
    r3, t3 = run_loop(write_launch, tmp_path, "c", "--composed")
    for r in (r1, r2, r3):
        assert r.returncode == 0, r.stdout + r.stderr
    a, b, c = t1.read_text(), t2.read_text(), t3.read_text()
    assert len(a.splitlines()) == 401  # ticks 0..400 at 1 kHz for 0.4 s
    assert a == b == c


def test_lockstep_has_no_hidden_delay(write_launch, tmp_path):
    """x[k] = x[k-1] + dt u[k-1] and u[k] = f(x[k]) exactly: the trace matches a plain loop.
    Composed: multi-process runs give the composed run's trace, bit for bit (the test above)."""
    r, trace = run_loop(write_launch, tmp_path, "d", "--composed")
    assert r.returncode == 0
    x, rows = 1.0, []
    u = None
    for k in range(401):
        if u is not None:
            x += 0.001 * u
        u = -2.0 * x + 0.1 * x * x
        rows.append(f"{k} {x.hex()} {u.hex()}")
    assert trace.read_text().splitlines() == rows


def test_killed_node_stops_graph_nonzero(write_launch, tmp_path):
    r, _ = run_loop(write_launch, tmp_path, "e", die_at=100)
    assert r.returncode != 0
    assert "[launch] node 'gain' exited with code 3 while running; stopping the graph" in r.stderr
    assert "Traceback" not in r.stdout + r.stderr


def _children_of(pid):
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    st = open(f"/proc/{pid}/stat").read().split()[2] if os.path.exists(f"/proc/{pid}/stat") else "X"
    return st != "Z"


def _still_alive(pids, timeout=30.0):
    """The processes among `pids` still alive after waiting up to `timeout` for all to end."""
    deadline = time.monotonic() + timeout
    while True:
        alive = [p for p in pids if _alive(p)]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.05)


def _wait_children(pid, n, timeout=60.0):
    deadline = time.monotonic() + timeout
    kids = []
    while time.monotonic() < deadline and len(kids) < n:
        time.sleep(0.1)
        kids = _children_of(pid)
    return kids


@pytest.mark.wall_time
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_shutdown_leaves_no_process(write_launch, tmp_path, sig):
    path = write_launch(
        "rate: 200\nnodes:\n  - {name: integ, node: 'tests.support.graphnodes:Integrator'}\n"
        "  - {name: gain, node: 'tests.support.graphnodes:Gain'}\n"
    )
    p = subprocess.Popen(
        dockhil_cmd("launch", path, "--wall-time"), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    kids = _wait_children(p.pid, 2)
    assert len(kids) == 2
    registered(p.pid)  # the graph is up
    p.send_signal(sig)
    out, _ = p.communicate(timeout=60)
    assert p.returncode == 128 + sig
    assert f"[launch] {signal.Signals(sig).name}: stopping the graph" in out
    assert _still_alive(kids) == []


@pytest.mark.wall_time
def test_launcher_killed_outright_leaves_no_orphans(write_launch):
    path = write_launch(
        "rate: 200\nnodes:\n  - {name: integ, node: 'tests.support.graphnodes:Integrator'}\n"
        "  - {name: gain, node: 'tests.support.graphnodes:Gain'}\n"
    )
    p = subprocess.Popen(dockhil_cmd("launch", path, "--wall-time"), stdout=subprocess.DEVNULL)
    kids = _wait_children(p.pid, 2)
    assert len(kids) == 2
    p.kill()
    p.wait()
    assert _still_alive(kids) == []  # the nodes notice their launcher is gone and stop


@pytest.mark.wall_time
def test_node_fed_garbage_keeps_running_and_counts(tmp_path):
    """`dockhil run` wires a node to a (fake) running graph; garbage on its input is dropped and counted."""
    from dockhil.runtime.transport import GraphKeys

    ctx = zmq.Context.instance()
    keys = GraphKeys.make()
    key_file = keys.write(tmp_path / "graph.keys")
    pub = ctx.socket(zmq.PUB)
    pub.curve_server, pub.curve_secretkey = True, keys.server_secret
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    env = dict(os.environ)
    graphs = os.path.join(env["DOCKHIL_RUNTIME_DIR"], "graphs")
    os.makedirs(graphs, mode=0o700, exist_ok=True)
    with open(os.path.join(graphs, "fake.json"), "w") as f:
        json.dump(
            {
                "run_id": "fake",
                "pid": os.getpid(),
                "file": "test",
                "clock": "wall",
                "nodes": {},
                "keys": str(key_file),
                "topics": {
                    "/x": {"type": "dockhil/WrenchStamped", "endpoint": f"tcp://127.0.0.1:{port}", "publisher": "test"}
                },
            },
            f,
        )
    # 20 Hz: an input's default maximum age is then 20 periods, 1 s, so a busy machine pausing this
    # test's sender for more than 0.1 s does not stop the node on a stale input (what this test is
    # not about; the maximum age is tested on its own).
    node = subprocess.Popen(
        dockhil_cmd("run", "tests.support.graphnodes:Gain", "gain:=3.0", "--rate", "20"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        # Find the node's output endpoint in the registry, subscribe to it.
        endpoint = None
        deadline = time.time() + 20
        while endpoint is None and time.time() < deadline:
            for name in os.listdir(graphs):
                if name.startswith("run-"):
                    try:
                        endpoint = json.load(open(os.path.join(graphs, name)))["topics"]["/u"]["endpoint"]
                    except (ValueError, KeyError):
                        pass
            time.sleep(0.1)
        assert endpoint
        sub = ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.curve_serverkey, sub.curve_publickey, sub.curve_secretkey = (
            keys.server_public,
            keys.client_public,
            keys.client_secret,
        )
        sub.connect(endpoint)
        good = msgs.WrenchStamped(header=msgs.Header(), wrench=msgs.Wrench(force=msgs.Vector3(x=2.0)))

        def latest_output(seconds):
            got = None
            deadline = time.time() + seconds
            while time.time() < deadline:  # the newest output, after queued older ones
                pub.send(b"/x\x00" + encode(good))  # fresh good data: a wall-time input has a maximum age
                if sub.poll(50):
                    got = decode(split(sub.recv_multipart())[1], msgs.WrenchStamped)
            return got

        # Until the node's subscription is live, PUB/SUB drops: send good data until it answers to it.
        deadline = time.time() + 10
        while time.time() < deadline:
            pub.send(b"/x\x00" + encode(good))
            got = latest_output(0.2)
            if got is not None and got.wrench.force.x == pytest.approx(-5.6):
                break
        nan = msgpack.unpackb(encode(good))
        nan["wrench"]["force"]["x"] = float("nan")
        bad = [
            b"\xc1garbage",
            msgpack.packb([1, 2, 3]),
            msgpack.packb(nan),
            encode(msgs.RobotState(header=msgs.Header())),
        ]
        for _ in range(3):
            for b in bad:
                pub.send(b"/x\x00" + b)
            pub.send(b"/x")  # no payload at all
            pub.send(b"/x\x00" + encode(good))
            time.sleep(0.05)
        # Still running, and still computing from the last good value: u = -3*2 + 0.1*4.
        assert node.poll() is None
        got = latest_output(0.5)
        deadline = time.time() + 20
        while got is None and time.time() < deadline:  # a busy machine: the next output comes later
            got = latest_output(0.5)
        assert got is not None and got.wrench.force.x == pytest.approx(-5.6)
        node.send_signal(signal.SIGINT)
        out, _ = node.communicate(timeout=10)
        assert node.returncode == 0, out
        assert "dropped bad message on /x" in out
        assert (
            "NaN or Inf refused" in out
            and "not msgpack" in out
            and "Expected `object`, got `array`" in out
            and "dockhil/RobotState" in out
        )
        assert "15 bad message(s) dropped" in out
        assert "Traceback" not in out
    finally:
        if node.poll() is None:
            node.kill()
        pub.close()


def test_observers_are_not_counted_as_subscribers(tmp_path):
    """A progress probe or `topic echo` joining first must not let sim time start early."""
    from dockhil.errors import DockhilError
    from dockhil.runtime.transport import GraphKeys, Publisher, Subscriber

    ctx = zmq.Context.instance()
    endpoint = f"ipc://{tmp_path}/t"
    keys = GraphKeys.make()
    pub = Publisher(ctx, "/t", endpoint, keys=keys)
    observer = Subscriber(ctx, observer=True)
    observer.connect(endpoint, keys=keys)
    with pytest.raises(DockhilError, match="0 of 1 subscribers joined"):
        pub.wait_subscribers(1, 0.5)
    member = Subscriber(ctx)
    member.connect(endpoint, keys=keys)
    pub.wait_subscribers(1, 5.0)
    pub.send(b"\x80")
    assert member.recv(5.0) == [b"/t", b"\x80"] and observer.recv(5.0) == [b"/t", b"\x80"]
    for s in (pub, observer, member):
        s.close()


BURSTS = """
rate: 1000
duration: 0.3
nodes:
  - {{name: integ, node: "tests.support.graphnodes:Integrator", remap: {{u: /u2}}}}
  - {{name: gain, node: "tests.support.graphnodes:Gain"}}
  - {{name: d1, node: delay_injector, params: {{delay: 0.004, type: dockhil/WrenchStamped, input: /u, output: /u1}}}}
  - {{name: d2, node: delay_injector, params: {{delay: 0.006, type: dockhil/WrenchStamped, input: /u1, output: /u2}}}}
  - {{name: trace, node: "tests.support.graphnodes:Trace", params: {{path: "{trace}"}}, remap: {{u: /u2}}}}
"""


def test_delayed_hops_send_in_bursts_and_change_no_bit(write_launch, tmp_path):
    """A loop through two delayed hops (4 and 6 ticks): their publishers send 2 and 3 ticks at a
    time, the others as soon as their node would wait. The run still ends (no cycle waits for a
    held message) and gives the plain loop's bits, as the composed run does."""
    from dockhil.runtime.plan import burst
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    traces = {}
    for mode in ("processes", "composed"):
        traces[mode] = tmp_path / f"trace-{mode}.txt"
        scene = write_launch(BURSTS.format(trace=traces[mode]), f"bursts-{mode}.yaml")
        r = launch(scene, "--quiet", *(["--composed"] if mode == "composed" else []), timeout=120)
        assert r.returncode == 0, r.stdout + r.stderr
    graph = build(launchfile.load(scene))
    # lag // 2 of the readers: /u by d1 (4 ticks), /u1 by d2 (6); /x and /u2 are read at once too.
    assert {topic: burst(graph, topic) for topic in graph.publishers} == {"/x": 1, "/u": 2, "/u1": 3, "/u2": 1}
    # x[k] = x[k-1] + dt u2[k-1], u2[k] = u[k-10] (none before tick 10), u[k] = -2 x[k] + 0.1 x[k]^2.
    us, rows = [], []
    x = 1.0
    for k in range(301):
        if k >= 11:
            x += 0.001 * us[k - 11]
        us.append(-2.0 * x + 0.1 * x * x)
        rows.append(f"{k} {x.hex()} {us[k - 10].hex() if k >= 10 else '-'}")
    assert traces["processes"].read_text().splitlines() == rows
    assert traces["composed"].read_text() == traces["processes"].read_text()


def test_bursts_are_sim_time_only_and_follow_the_declared_delay(tmp_path):
    """hil.yaml: the robot command, which the delay injector reads 32 ticks late, goes out 16 ticks at
    a time in sim time; in wall time every message leaves when it is made."""
    from pathlib import Path

    from dockhil.runtime.plan import Endpoints, run_specs
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    graph = build(launchfile.load(Path(__file__).resolve().parent.parent / "launch" / "hil.yaml"))
    types = {t: "t" for t in graph.publishers}
    ends = {t: f"ipc://{tmp_path}/{t.strip('/').replace('/', '.')}" for t in types}
    ep = Endpoints("r", tmp_path, ends, types, ends)
    for clock, want in (("sim", 32 // 2), ("wall", 1)):
        specs = run_specs(graph, ep, clock, None, [])
        bursts = {w.topic: w.burst for spec in specs.values() for w in spec.outputs.values()}
        assert bursts.pop("/robot/command") == want
        assert set(bursts.values()) == {1}, bursts


def test_a_burst_is_read_message_by_message_and_an_envelope_is_joined(tmp_path):
    """A publisher holding 3 ticks sends them as one ZeroMQ message of 3 frames: a node's receive
    path and an observer each see 3 messages (the empty tick sent apart), in order. A [topic,
    payload] envelope of two frames, as `bag play` sends, reads as the same message."""
    from dockhil.runtime.transport import EMPTY_TICK, MESSAGE, GraphKeys, Publisher, Subscriber

    ctx = zmq.Context.instance()
    endpoint = f"ipc://{tmp_path}/t"
    keys = GraphKeys.make()
    pub = Publisher(ctx, "/t", endpoint, keys=keys, burst=3)
    member, observer = Subscriber(ctx), Subscriber(ctx, observer=True)
    for sub in (member, observer):
        sub.connect(endpoint, keys=keys)
    raw = ctx.socket(zmq.SUB)  # plain pyzmq, as a foreign reader would
    raw.curve_serverkey, raw.curve_publickey, raw.curve_secretkey = (
        keys.server_public,
        keys.client_public,
        keys.client_secret,
    )
    raw.setsockopt(zmq.SUBSCRIBE, b"/t\x00")
    raw.connect(endpoint)
    joined, deadline = set(), time.monotonic() + 20  # all three subscriptions in, the observer's on its own socket
    while joined != {b"\x01", b"\x01/t\x00"} or not pub.watchers:
        assert time.monotonic() < deadline, joined
        pub.look()
        if pub.sock.poll(50):
            joined.add(pub.sock.recv())
    pub.send_empty(0)
    pub.send(b"\x81\xa1a\x01")
    assert member.recv_frame(0.05) is None  # held: two of three
    pub.send(b"\x81\xa1a\x02")  # the third: out go the empty tick, then the two messages together
    want = [
        b"/t" + EMPTY_TICK + (0).to_bytes(8, "little"),
        b"/t" + MESSAGE + b"\x81\xa1a\x01",
        b"/t" + MESSAGE + b"\x81\xa1a\x02",
    ]
    assert [member.recv_frame(5.0) for _ in range(3)] == want
    assert [observer.recv(5.0) for _ in range(3)] == [
        [b"/t", b"", (0).to_bytes(8, "little")],
        [b"/t", b"\x81\xa1a\x01"],
        [b"/t", b"\x81\xa1a\x02"],
    ]
    assert raw.poll(5000)  # the two messages as one ZeroMQ message, each frame read by the reference msgpack
    assert [msgpack.unpackb(f.split(b"\x00", 1)[1]) for f in raw.recv_multipart()] == [{"a": 1}, {"a": 2}]
    raw.close(linger=0)
    pub.send_multipart([b"/t", b"\x81\xa1a\x03"])  # an envelope
    first = member.recv_frame(5.0)
    assert first == b"/t" and member.joined(first) == b"/t" + MESSAGE + b"\x81\xa1a\x03"
    assert observer.recv(5.0) == [b"/t", b"\x81\xa1a\x03"]
    for s in (pub, member, observer):
        s.close()


def test_loop_figures_are_numpys_percentiles_within_a_tenth_of_a_percent_without_numpy():
    """A node's loop report (jitter, input ages) gives numpy.percentile's figures to within the
    histogram's bins (0.1 %, the extremes exact), though the node process that writes it need not
    import numpy."""
    import random

    import numpy as np

    from dockhil.runtime.looptime import LoopTiming

    rng = random.Random(7)
    for n in (2, 3, 10, 1001):
        timing = LoopTiming(["ft"], period=1e-3)
        started, ages = [], []
        for _ in range(n):
            started.append(rng.uniform(-2e-4, 3e-3))
            ages.append(rng.uniform(0.0, 5e-3))
            timing.started(started[-1])
            timing.ages["ft"].add(ages[-1])
        out = timing.report("node")
        late = np.abs(np.asarray(started[1:]))  # the first tick has no schedule to keep
        for figures, values in ((out["jitter_us"], late), (out["input_age_us"]["ft"], np.asarray(ages))):
            us = np.abs(values) * 1e6
            assert figures["max"] == float(us.max())
            for p in (50, 99):
                assert figures[f"p{p}"] == pytest.approx(float(np.percentile(us, p)), rel=1e-3, abs=0.05)
        assert out["worst_tick"] == int(np.argmax(late)) + 1
        assert out["worst_late_s"] == float(late.max())
    assert LoopTiming([], period=1e-3).report("idle")["jitter_us"] == {}


def test_a_long_loop_keeps_its_figures_in_the_memory_it_started_with():
    """A million ticks' lateness and input ages take no memory beyond what the loop's figures took
    before the first tick (they grew by reallocation, copying into fresh pages while the loop ran)."""
    import tracemalloc
    from types import SimpleNamespace

    from dockhil.runtime.looptime import LoopTiming

    timing = LoopTiming(["ft", "command"], period=1e-3)
    message = SimpleNamespace(header=SimpleNamespace(stamp=0.0))
    latest = {"ft": message, "command": message}
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(200_000):
            timing.started(1e-5 * (k % 97))
            timing.inputs(1e-3 * (k % 13), latest)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 4096, f"the loop's figures grew by {grown} bytes over 200,000 ticks"
    assert timing.lateness.count == 199_999 and timing.ages["command"].count == 200_000
