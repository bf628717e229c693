"""Exit 0 means the result is valid.

The wall-time loop runs here on a ManualClock, so its figures (ticks, lateness, coverage) and
the maximum age of an input are exact; the expected numbers are worked out by hand from the
schedule. A few true wall-time runs check the outcome end to end (marked wall_time)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import zmq

from dockhil.errors import DockhilError
from dockhil.msgs import Header, Vector3, Wrench, WrenchStamped
from dockhil.msgs.codec import encode
from dockhil.node import ManualClock, default_max_age
from dockhil.runtime import validity
from dockhil.runtime.executor import NodeExecutor, PortWire, RunSpec, StaleInput, Stop
from dockhil.runtime.transport import HWM, GraphKeys, Publisher, Subscriber
from tests.conftest import dockhil_cmd
from tests.support.faultnodes import Follow, Hiccup

P = 1 / 1024  # a period that binary floating point adds up exactly


def executor(node_cls, clock, params=None, inputs=None, name="n", keys=None) -> NodeExecutor:
    """keys: the GraphKeys of the test's publisher (written to a 0600 key file the node reads)."""
    spec = RunSpec(name, f"tests.support.faultnodes:{node_cls.__name__}", params or {}, P, "wall", inputs=inputs or {})
    if keys is not None:
        folder = tempfile.mkdtemp(prefix="dh-keys-")
        spec.key_file = str(keys.write(Path(folder) / "graph.keys"))
    ex = NodeExecutor(spec, node_cls, Stop(), log=lambda line: None, clock=clock)
    ex.start()
    return ex


# -- the rules -------------------------------------------------------------------------------


def figures(**over) -> dict:
    t = {
        "node": "dynamics",
        "ticks": 3000,
        "deadline_misses": 0,
        "period_s": 0.001,
        "elapsed_s": 3.0,
        "covered_s": 3.0,
        "worst_late_s": 0.002,
        "max_age_s": {"ft": 0.1},
        "worst_input_age_s": {"ft": 0.003},
        "dropped_in": 0,
        "dropped_out": 0,
    }
    t.update(over)
    return t


def test_a_run_that_kept_real_time_is_valid():
    assert validity.node_reasons(figures(), 0.001) == []


def test_a_run_that_fell_behind_is_invalid_with_the_figures():
    # The reported failure: 1.666 s simulated in 6.19 s.
    reasons = validity.node_reasons(figures(ticks=1666, covered_s=1.666, elapsed_s=6.19), 0.001)
    assert reasons == [
        "node 'dynamics' simulated 1.666 s in 6.190 s of wall time (fell behind real time; at least 80% needed)"
    ]


def test_lateness_misses_ages_and_drops_each_make_a_run_invalid():
    dt = 0.001
    assert validity.node_reasons(figures(worst_late_s=0.12), dt) == [
        "node 'dynamics': a tick started 0.120 s late (> 0.1 s)"
    ]
    assert validity.node_reasons(figures(deadline_misses=751), dt) == [
        "node 'dynamics' missed 751 of 3000 deadlines (25% > 25%)"
    ]
    assert validity.node_reasons(figures(deadline_misses=750), dt) == []  # exactly a quarter: still valid
    assert validity.node_reasons(figures(worst_input_age_s={"ft": 0.1001}), dt) == [
        "node 'dynamics': input 'ft' was used 0.100 s old (> max_age 0.1 s)"
    ]
    assert validity.node_reasons(figures(dropped_out=7), dt) == [
        "node 'dynamics' dropped 7 output message(s): a subscriber did not keep up"
    ]
    assert validity.node_reasons(figures(dropped_in=2), dt) == ["node 'dynamics' dropped 2 bad input message(s)"]


def test_an_emulated_device_is_not_judged_on_its_schedule_but_on_what_it_lost():
    slow = figures(covered_s=1.0, worst_late_s=1.0, deadline_misses=2000, dropped_out=3)
    assert validity.node_reasons(slow, 0.001, device=True) == [
        "node 'dynamics' dropped 3 output message(s): a subscriber did not keep up"
    ]


def test_a_node_that_did_not_report_makes_the_run_invalid():
    assert validity.wall_time_reasons({}, {"ft": False}, 0.001) == ["node 'ft' reported no loop timing"]


def test_default_max_age_is_twenty_periods_but_at_least_a_tenth_of_a_second():
    assert default_max_age(0.001) == 0.1
    assert default_max_age(0.01) == pytest.approx(0.2)


# -- the wall-time loop on a controlled clock --------------------------------------------------


def test_a_stalled_tick_shows_as_lateness_and_lost_coverage_exactly():
    clock = ManualClock()
    ex = executor(Hiccup, clock, {"at": 50, "seconds": 256 * P})
    try:
        report = ex.run_wall(1024 * P)
    finally:
        ex.close()
    # Ticks 0..50 on schedule; tick 50 ends at 306 P, 255 P after its deadline (51 P): one miss, and
    # the schedule restarts one period later; tick k >= 52 then starts at (256 + k) P, the last one
    # before 1024 P being tick 767.
    assert report["ticks"] == 768 and report["deadline_misses"] == 1
    assert report["elapsed_s"] == 1.0 and report["covered_s"] == 768 * P
    assert report["worst_late_s"] == 255 * P
    assert validity.node_reasons(report, P) == [
        "node 'n' simulated 0.750 s in 1.000 s of wall time (fell behind real time; at least 80% needed)",
        "node 'n': a tick started 0.249 s late (> 0.1 s)",
    ]


def test_an_input_older_than_its_maximum_age_stops_the_node_with_one_line(tmp_path):
    """/x is published until 50 P and then no more: the node stops on the first tick that finds
    its latest message more than max_age (0.1 s) old, that is at 153 P (103 P = 0.1006 s)."""
    ctx = zmq.Context()  # not the executor's: it ends its own context when it closes
    endpoint = f"ipc://{tmp_path}/x"
    keys = GraphKeys.make()
    pub = Publisher(ctx, "/x", endpoint, keys=keys)
    sent = []

    class Upstream(ManualClock):
        def sleep_until(self, deadline):
            super().sleep_until(deadline)
            if self.now <= 50 * P:
                pub.send(
                    encode(WrenchStamped(header=Header(stamp=1.0, seq=len(sent)), wrench=Wrench(force=Vector3(x=1.0))))
                )
                sent.append(self.now)
                assert ex.sub.sock.poll(5000), "the message did not arrive"  # there before the next tick

    clock = Upstream()
    ex = executor(
        Follow, clock, inputs={"x": PortWire("/x", endpoint, "dockhil/WrenchStamped")}, name="follow", keys=keys
    )
    try:
        pub.wait_subscribers(1, 10.0)
        with pytest.raises(StaleInput) as err:
            ex.run_wall(None)
        assert str(err.value) == ("node 'follow': input 'x' (/x) is 0.101 s old > max_age 0.1 s; stopping")
        assert clock() == 153 * P and sent[-1] == 50 * P
        assert isinstance(err.value, DockhilError)  # a node process turns it into one line and exit 2
    finally:
        ex.close()
        pub.close()
        ctx.term()


# -- a non-finite value stops its producer, the same in both modes ---------------------------


NAN_SCENE = """
rate: 100
duration: 1.0
nodes:
  - {name: source, node: "tests.support.faultnodes:NanAt", params: {at: 7}}
  - {name: follow, node: "tests.support.faultnodes:Follow"}
"""


def test_a_non_finite_output_stops_the_graph_with_the_same_line_in_both_modes(write_launch):
    scene = write_launch(NAN_SCENE)
    want = (
        "node 'source' produced an invalid message at tick 7 on output 'x' (/x): WrenchStamped: NaN or Inf "
        "refused (physical fields must be finite) - at `$.wrench.force.x`; stopping the graph"
    )
    lines = {}
    for mode in ("multi", "composed"):
        r = subprocess.run(
            dockhil_cmd("launch", scene, *(["--composed"] if mode == "composed" else [])),
            capture_output=True,
            text=True,
            timeout=120,
        )
        text = r.stdout + r.stderr
        assert r.returncode == 1 and "Traceback" not in text, text
        lines[mode] = [line for line in text.splitlines() if want in line]
        assert len(lines[mode]) == 1, text
        assert "bad message" not in text  # the reader never sees it: nothing to drop
    assert lines["multi"][0] == f"[source] error: {want}"
    assert lines["composed"][0] == f"[launch] error: {want}"


def test_a_diverging_hil_loop_stops_both_modes_with_the_same_line():
    """k:=1e12, the stiffest compliance in range, makes the virtual stiffness -1e15 N/m: the loop overflows
    within tens of ticks."""
    found = {}
    for mode in ("multi", "composed"):
        r = subprocess.run(
            dockhil_cmd(
                "launch", "launch/hil.yaml", "k:=1e12", "--quiet", *(["--composed"] if mode == "composed" else [])
            ),
            capture_output=True,
            text=True,
            timeout=120,
        )
        text = r.stdout + r.stderr
        assert r.returncode == 1 and "Traceback" not in text, text
        found[mode] = [
            line.split("error: ", 1)[1] for line in text.splitlines() if "produced an invalid message" in line
        ]
        assert len(found[mode]) == 1, text
    assert found["multi"] == found["composed"]
    assert "NaN or Inf refused" in found["multi"][0]


# -- true wall-time runs ----------------------------------------------------------------------


HICCUP_SCENE = """
rate: 200
nodes:
  - {name: source, node: "tests.support.faultnodes:Hiccup", params: {at: 40, seconds: 0.5}}
"""


@pytest.mark.wall_time
def test_a_wall_time_run_that_stalled_says_invalid_and_exits_3(write_launch):
    scene = write_launch(HICCUP_SCENE)
    # The stall is recorded once tick 40 (0.2 s) has begun before the 1 s run ends.
    r = subprocess.run(
        dockhil_cmd("launch", scene, "--wall-time", "--duration", "1"), capture_output=True, text=True, timeout=120
    )
    text = r.stdout + r.stderr
    assert r.returncode == validity.INVALID_EXIT == 3, text
    invalid = [line for line in text.splitlines() if "INVALID" in line]
    assert len(invalid) == 1 and invalid[0].startswith("[launch] INVALID: node 'source'"), text
    assert "late" in invalid[0] and invalid[0].endswith("(exit 3)")
    assert "Traceback" not in text


STALE_SCENE = """
rate: 200
nodes:
  - {name: source, node: "tests.support.faultnodes:Hiccup", params: {at: 40, seconds: 0.5}}
  - {name: follow, node: "tests.support.faultnodes:Follow"}
"""


@pytest.mark.wall_time
def test_a_stalled_publisher_stops_its_reader_naming_node_input_and_age(write_launch):
    scene = write_launch(STALE_SCENE)
    r = subprocess.run(
        dockhil_cmd("launch", scene, "--wall-time", "--duration", "3"), capture_output=True, text=True, timeout=120
    )
    text = r.stdout + r.stderr
    assert r.returncode == 1 and "Traceback" not in text, text
    stale = [line for line in text.splitlines() if "max_age" in line]
    assert stale and stale[0].startswith("[follow] error: node 'follow': input 'x' (/x from node 'source') is 0."), text
    # The publisher was alive and late (its step slept): said so, not "stalled or died".
    stop = next(line for line in text.splitlines() if line.startswith("[launch] node 'follow' exited"))
    assert stop.startswith(
        "[launch] node 'follow' exited with code 2 while running: its input /x's publisher, node 'source', is "
        "running but its message was late by 0."
    ) and stop.endswith(" s; a busy machine? try --realtime; stopping the graph"), stop


def test_a_stale_input_blames_a_publisher_that_had_exited_by_its_exit_code():
    """Told apart by the publisher's process: one that ended is said so, with its code."""
    from types import SimpleNamespace

    from dockhil.runtime.launcher import Launcher, _Child

    ended = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    ended.wait()
    reader = _Child("follow", [], stale={"port": "x", "topic": "/x", "publisher": "source", "late": 0.2})
    fake = SimpleNamespace(children=[reader, _Child("source", [], proc=ended)])
    assert Launcher._blame(fake, reader) == ": its input /x's publisher, node 'source', had exited with code 3"
    assert Launcher._blame(fake, _Child("other", [])) == ""  # stopped for another reason: no blame


def test_the_first_node_to_find_a_stale_input_is_the_one_the_stop_names_with_the_fault_it_saw():
    """A node stopped (SIGSTOP) and then resumed finds its own inputs stale too, and may exit before the
    reader that found it stopped is seen to: the stop names the first reader, with the fault as it was
    when that reader said so (the stopped publisher), not as the resumed publisher's exit makes it look."""
    from types import SimpleNamespace

    from dockhil.runtime.launcher import Launcher, _Child

    exited = [subprocess.Popen([sys.executable, "-c", "raise SystemExit(2)"]) for _ in range(2)]
    for p in exited:
        p.wait()
    stopped = ": its input /robot/command's publisher, node 'dynamics', is stopped (SIGSTOP, a debugger)"
    reader = _Child("delay", [], proc=exited[0], ready=True)
    reader.stale = {"topic": "/robot/command", "publisher": "dynamics", "late": 0.1, "at": 1.0, "fault": stopped}
    resumed = _Child("dynamics", [], proc=exited[1], ready=True)
    resumed.stale = {"topic": "/ft/wrench", "publisher": "ft", "late": 0.1, "at": 2.0, "fault": ": late"}
    said: list[str] = []
    fake = SimpleNamespace(
        children=[resumed, reader],  # the watch loop meets the resumed node first
        say=SimpleNamespace(error=lambda line, tag=None: said.append(line)),
        stop_all=lambda: None,
    )
    fake._blame = lambda child: Launcher._blame(fake, child)
    assert Launcher._died(fake, resumed, 2) == 1
    assert said == [f"node 'delay' exited with code 2 while running{stopped}; stopping the graph"]


# -- the recorder: lost messages fail the run --------------------------------------------------


SMALL_SCENE = """
rate: 1000
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator"}
  - {name: gain, node: "tests.support.graphnodes:Gain"}
"""


def _tiny_filesystem(path) -> tuple[bool, object]:
    """A 64 KiB tmpfs at `path` (root can mount one); else a 64 KiB file-size limit for the run."""
    os.makedirs(path, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(path)], capture_output=True)
    if r.returncode == 0:
        return True, None
    return False, lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))


def test_a_full_filesystem_fails_the_run_with_the_count_of_lost_messages(write_launch, tmp_path):
    scene = write_launch(SMALL_SCENE)
    disk = tmp_path / "disk"
    mounted, limit = _tiny_filesystem(disk)
    try:
        r = subprocess.run(
            dockhil_cmd("launch", scene, "--duration", "3", "--bag", disk / "run.mcap"),
            capture_output=True,
            text=True,
            timeout=120,
            preexec_fn=limit,
        )
    finally:
        if mounted:
            subprocess.run(["umount", str(disk)], check=True)
    text = r.stdout + r.stderr
    assert r.returncode != 0 and "Traceback" not in text, text
    report = next(line for line in text.splitlines() if "[bag-recorder] recorded" in line)
    lost = int(report.split("; ")[1].split(" lost")[0])
    on_disk = int(report.split("recorded ")[1].split(" messages")[0])
    assert lost > 0 and on_disk + lost >= 2 * 3001 - 2  # two topics of 3001 ticks, minus what was never sent
    assert f"[bag-recorder] error: {lost} message(s) lost; the recording of this run is incomplete" in text
    assert "[launch] node 'bag-recorder' exited with code 4" in text
    assert ("No space left on device" if mounted else "File too large") in text


# -- bounded queues ------------------------------------------------------------------------------


def test_wall_time_drops_and_counts_for_a_subscriber_that_never_reads(tmp_path):
    ctx = zmq.Context()
    endpoint = f"ipc://{tmp_path}/q"
    pub = Publisher(ctx, "/q", endpoint, linger_s=0, keys=None, lossy=True)
    idle = ctx.socket(zmq.SUB)  # a foreign subscriber that connects and never reads
    idle.setsockopt(zmq.SUBSCRIBE, b"")
    idle.connect(endpoint)
    try:
        pub.wait_subscribers(1, 10.0)
        n = 4 * HWM
        sent = sum(pub.send(b"x" * 100) for _ in range(n))
        assert pub.dropped == n - sent and pub.dropped > 0  # bounded: the rest was refused, and counted
        assert sent <= 3 * HWM  # at most the two queues and the kernel's buffer
    finally:
        idle.close(linger=0)
        pub.close()
        ctx.term()


def test_sim_time_waits_for_a_slow_subscriber_and_loses_nothing(tmp_path):
    import threading

    ctx = zmq.Context()
    endpoint = f"ipc://{tmp_path}/q"
    pub = Publisher(ctx, "/q", endpoint, linger_s=0, keys=None)
    sub = Subscriber(ctx)
    sub.connect(endpoint, keys=None)
    n = 4 * HWM
    done = threading.Event()

    def send_all():
        for i in range(n):
            pub.send(i.to_bytes(4, "little"))
        done.set()

    try:
        pub.wait_subscribers(1, 10.0)
        sender = threading.Thread(target=send_all, daemon=True)
        sender.start()
        assert not done.wait(1.0)  # blocked: the subscriber has not read, and its queues are full
        got = [int.from_bytes(sub.recv(10.0)[1], "little") for _ in range(n)]
        assert got == list(range(n))  # every message, in order
        assert done.wait(10.0)
    finally:
        sub.close()
        pub.close()
        ctx.term()


@pytest.mark.wall_time
def test_a_stopped_composed_wall_time_run_is_invalid_in_its_summary(tmp_path):
    """SIGSTOP of the whole (composed) graph for 0.5 s: nothing goes stale inside one loop, but the
    loop fell half a second behind: the summary says so, the table says INVALID, exit 3."""
    import json
    import signal
    import threading
    import time

    out = tmp_path / "s.json"
    p = subprocess.Popen(
        dockhil_cmd("launch", "launch/hil.yaml", "--composed", "--wall-time", "--duration", "2", "--summary", out),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(p.stderr.readline, "")), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while not any("impedance (closed form" in line for line in lines):  # the last line of set-up
            assert time.monotonic() < deadline and p.poll() is None, lines
            time.sleep(0.02)
        time.sleep(0.3)  # in the loop, which runs 2 s
        p.send_signal(signal.SIGSTOP)
        time.sleep(0.5)
        p.send_signal(signal.SIGCONT)
        p.wait(timeout=120)
        stdout = p.stdout.read()
        reader.join(10)
        stderr = "".join(lines)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 3, stdout + stderr
    summary = json.loads(out.read_text())
    assert summary["valid"] is False
    assert any("node 'composed': a tick started" in r and "late" in r for r in summary["invalid_reasons"]), summary
    invalid = [line for line in (stdout + stderr).splitlines() if "INVALID" in line]
    assert len(invalid) == 1 and invalid[0].startswith("[launch] INVALID: node 'composed'")
    assert "peak force" in stdout  # the table is still there, with the line that says what it is worth


def test_the_composed_bounds_check_refuses_what_a_reader_refuses():
    """A composed run checks outputs with an expression generated from the type; a node process
    decodes what it sends. Both must refuse the same messages, with the same line."""
    import math

    from dockhil import msgs
    from dockhil.msgs import BodyState, BodyWrenches, Pose, SatelliteState, Twist
    from dockhil.runtime.screen import check_message, checked_payload

    def body(mass=1.0, vx=0.0):
        return BodyState(name="b", mass=mass, pose=Pose(), twist=Twist(linear=Vector3(x=vx)))

    good = [msgs.TYPES[name](header=Header()) for name in msgs.TYPES] + [
        SatelliteState(header=Header(stamp=2.0), bodies=[body(), body(0.0, -1e300)]),
        BodyWrenches(header=Header(), wrenches=[Wrench(force=Vector3(x=1e308, y=-1e308))]),
    ]
    bad = [
        SatelliteState(header=Header(), bodies=[body(), body(vx=math.inf)]),
        SatelliteState(header=Header(), bodies=[body(mass=-1.0)]),
        BodyWrenches(header=Header(), wrenches=[Wrench(), Wrench(torque=Vector3(z=math.nan))]),
        WrenchStamped(header=Header(stamp=math.nan)),
        WrenchStamped(header=Header(seq=-1)),
    ]
    for msg in good:
        check_message("n", "p", "/t", 0, msg)
        checked_payload("n", "p", "/t", 0, msg)
    for msg in bad:
        with pytest.raises(DockhilError) as composed:
            check_message("n", "p", "/t", 3, msg)
        with pytest.raises(DockhilError) as process:
            checked_payload("n", "p", "/t", 3, msg)
        assert str(composed.value) == str(process.value)
        assert str(process.value).startswith("node 'n' produced an invalid message at tick 3 on output 'p' (/t): ")


def test_a_composed_wall_time_loop_on_a_controlled_clock_reports_the_stall_exactly(write_launch):
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    scene = write_launch(
        "rate: 1024\nnodes:\n  - {name: source, node: 'tests.support.faultnodes:Hiccup', "
        "params: {at: 50, seconds: 0.25}}\n  - {name: follow, node: 'tests.support.faultnodes:Follow'}\n"
    )
    clock = ManualClock()
    g = ComposedGraph(build(launchfile.load(str(scene))), sim_time=False, log=lambda n, m: None, clock=clock)
    g.setup()
    try:
        assert g.run(1024, wall=True) == 1024
    finally:
        g.close()
    report = g.timing.report("composed")
    # One loop: tick 50 overruns by 0.25 s (ends at 306 P, due at 51 P). The composed loop does not skip
    # ticks: it runs ticks 51..305 back to back (taking no time on this clock) and is on schedule again
    # from tick 306; the run covers its 1024 periods, but tick 51 started 255 P late.
    assert report["ticks"] == 1024 and report["worst_late_s"] == 255 * P
    assert report["elapsed_s"] == 1024 * P and report["deadline_misses"] == 255
    assert validity.node_reasons(report, P) == ["node 'composed': a tick started 0.249 s late (> 0.1 s)"]
