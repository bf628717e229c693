"""topic info, node info, hz's period statistics, echo --field and echo --wait.

The statistics are a pure function of arrival times, tested exactly; the commands run against a
wall-time graph (marked wall_time) and wait for conditions with deadlines, asserting what they
name, not rates within a wall-clock window."""

import json
import math
import signal
import subprocess
import time
from types import SimpleNamespace

import pytest

from dockhil import cli, msgs
from dockhil.commands.topic import field_reader, format_stats, period_stats
from dockhil.errors import DockhilError
from tests.conftest import Lines, dockhil_cmd, registered, sigint_as_a_terminal_sends_it

# gain runs in a container; sink reads /x beside it. Inputs may be 5 s old: a busy machine
# pausing a node must not stop the graph these tests look at.
SCENE = """
rate: 100
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator", params: {x0: 0.25}, max_age: {u: 5.0}}
  - {name: gain, node: "tests.support.graphnodes:Gain", container: box, params: {gain: 3.5}, max_age: {x: 5.0}}
  - {name: sink, node: "tests.support.graphnodes:Sink", max_age: {x: 5.0}}
"""


def dockhil(capsys, *args):
    """A `dockhil` command run in this process: exit code and output."""
    capsys.readouterr()
    code = cli.main(list(args))
    out = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)


def launch(write_launch):
    return subprocess.Popen(
        dockhil_cmd("launch", write_launch(SCENE), "--wall-time"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def stop(p, timeout=30):
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
    try:
        p.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


# -- the statistics, on arrival times the test gives --------------------------------------------


def test_period_stats_are_exact_over_given_arrivals():
    stats = period_stats([0.0, 0.001, 0.002, 0.004, 0.005])  # periods 1, 1, 2, 1 ms
    assert stats["window"] == 4
    assert stats["rate"] == pytest.approx(800.0)
    assert stats["min"] == pytest.approx(0.001) and stats["max"] == pytest.approx(0.002)
    # mean 1.25 ms; deviations -0.25, -0.25, 0.75, -0.25 ms: population std sqrt(0.75/4) ms
    assert stats["std"] == pytest.approx(math.sqrt(0.75e-6 / 4))
    assert format_stats(stats) == ("average rate: 800.0 / min: 0.001s max: 0.002s std dev: 0.00043s window: 4")
    assert format_stats(stats, lost=7).endswith("window: 4 / lost: 7")


def test_period_stats_of_a_steady_rate_and_of_too_few_messages():
    steady = period_stats([k * 0.01 for k in range(101)])
    assert steady["rate"] == pytest.approx(100.0) and steady["std"] == pytest.approx(0.0, abs=1e-12)
    assert steady["window"] == 100
    assert period_stats([]) is None and period_stats([3.0]) is None
    assert period_stats([1.0, 1.0])["rate"] == math.inf  # two at once: no period to divide by


# -- --field, on messages built here --------------------------------------------------------------


def test_field_reader_reads_nested_fields_and_list_items():
    w = msgs.WrenchStamped(header=msgs.Header(), wrench=msgs.Wrench(force=msgs.Vector3(x=1.5, y=-2.0)))
    assert field_reader(msgs.WrenchStamped, "wrench.force.x")(w) == 1.5
    assert field_reader(msgs.WrenchStamped, "wrench.force")(w) == msgs.Vector3(x=1.5, y=-2.0)
    body = msgs.BodyState(name="chaser", mass=700.0)
    state = msgs.SatelliteState(header=msgs.Header(), bodies=(body, msgs.BodyState(name="target", mass=900.0)))
    assert field_reader(msgs.SatelliteState, "bodies.1.mass")(state) == 900.0
    assert field_reader(msgs.SatelliteState, "bodies.0.pose.position.x")(state) == 0.0
    with pytest.raises(DockhilError, match=r"bodies has 2 item\(s\) in this message; index 5 is beyond"):
        field_reader(msgs.SatelliteState, "bodies.5.mass")(state)


@pytest.mark.parametrize(
    "path, said",
    [
        ("wrench.foo", "--field wrench.foo: wrench (Wrench) has no field 'foo'; fields: force, torque"),
        ("nope", "--field nope: the message (WrenchStamped) has no field 'nope'; fields: header, wrench"),
        ("wrench.force.x.y", "--field wrench.force.x.y: wrench.force.x is a value (float) with no fields"),
    ],
)
def test_field_reader_refuses_an_unknown_field_naming_those_there_are(path, said):
    with pytest.raises(DockhilError) as exc:
        field_reader(msgs.WrenchStamped, path)
    assert str(exc.value).startswith(said) and "\n" not in str(exc.value)


def test_field_reader_wants_a_number_for_a_list():
    with pytest.raises(DockhilError, match=r"--field bodies.first: bodies is a list; index it by number"):
        field_reader(msgs.SatelliteState, "bodies.first")


# -- against a running graph ----------------------------------------------------------------------


@pytest.mark.wall_time
def test_info_hz_and_echo_field_on_a_running_graph(write_launch, capsys):
    p = launch(write_launch)
    lines = Lines(p)
    try:
        entry = registered(p.pid, timeout=60)
        run_id = entry["run_id"]

        r = dockhil(capsys, "topic", "info", "/x", "--json", "--window", "0.5")
        assert r.returncode == 0, r.stderr
        info = json.loads(r.stdout)
        assert info["type"] == "dockhil/WrenchStamped" and info["publisher"] == "integ"
        assert sorted(info["subscribers"]) == ["gain.x", "sink.x"]
        assert info["kind"] == "ipc" and info["graph"] == run_id and info["window_s"] == 0.5
        assert info["rate_hz"] is not None and info["rate_hz"] >= 0  # measured (0 before the nodes' go)
        text = dockhil(capsys, "topic", "info", "/u", "--window", "0").stdout
        assert "Type: dockhil/WrenchStamped" in text and "Subscribers: integ.u" in text
        assert "Publisher: gain (process box" in text and "Rate:" not in text

        r = dockhil(capsys, "node", "info", "gain", "--json")
        assert r.returncode == 0, r.stderr
        node = json.loads(r.stdout)
        assert (
            node["type"] == "tests.support.graphnodes:Gain" and node["process"] == "box" and node["host"] == "localhost"
        )
        assert node["params"] == {"gain": 3.5, "die_at": -1}
        assert node["inputs"]["x"] == {
            "topic": "/x",
            "type": "dockhil/WrenchStamped",
            "lag": 0,
            "delay": 0.0,
            "required": True,
            "max_age": 5.0,
        }
        assert node["outputs"] == {"u": {"topic": "/u", "type": "dockhil/WrenchStamped"}}
        assert node["pid"] == entry["nodes"]["box"]["pid"]
        text = dockhil(capsys, "node", "info", "integ").stdout
        assert "Type: tests.support.graphnodes:Integrator" in text and "x0: 0.25" in text
        assert "u: /u  dockhil/WrenchStamped  (previous tick, 1 tick(s) back, max_age 5 s)" in text
        assert "x: /x  dockhil/WrenchStamped" in text
        missing = dockhil(capsys, "node", "info", "nobody")
        assert missing.returncode == 2 and "node nobody runs in no running graph" in missing.stderr
        assert "gain, integ, sink" in missing.stderr

        # Statistics once the graph flows: three reports of every 0.3 s.
        hz = dockhil(capsys, "topic", "hz", "/x", "--window", "50", "--every", "0.3", "-n", "8")
        stats = [line for line in hz.stdout.splitlines() if line.startswith("average rate: ")]
        assert stats, hz.stdout + hz.stderr
        last = stats[-1]
        assert " / min: " in last and "s max: " in last and "s std dev: " in last
        assert int(last.split("window: ")[1].split()[0]) <= 50

        r = dockhil(capsys, "topic", "echo", "/x", "--field", "wrench.force.x", "-n", "3")
        assert r.returncode == 0, r.stderr
        values = [float(v) for v in r.stdout.split()]  # bare numbers: only the field
        assert len(values) == 3
        r = dockhil(capsys, "topic", "echo", "/x", "--field", "wrench.forse.x", "-n", "1")
        assert r.returncode == 2 and r.stdout == ""
        said = r.stderr.strip().splitlines()
        assert (
            len(said) == 1
            and "--field wrench.forse.x: wrench (Wrench) has no field 'forse'; fields: force, torque" in said[0]
        ), r.stderr
    finally:
        stop(p)
        lines.rest(timeout=30)


@pytest.mark.wall_time
def test_echo_wait_started_before_the_graph_prints_its_first_message(write_launch):
    echo = subprocess.Popen(
        dockhil_cmd("topic", "echo", "/u", "--wait", "--field", "header", "-n", "1"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    p = None
    try:
        said = Lines(echo, echo.stderr)
        said.wait_for("[topic] waiting for /u: no running graph found", timeout=60)
        assert echo.poll() is None  # waits rather than fails
        p = launch(write_launch)
        lines = Lines(p)
        out, _ = echo.communicate(timeout=120)
        assert echo.returncode == 0
        header = json.loads(out.splitlines()[0])
        assert set(header) == {"stamp", "tick", "seq", "frame"}  # only the field asked for
    finally:
        stop(echo)
        if p is not None:
            stop(p)
            lines.rest(timeout=30)


@pytest.mark.wall_time
def test_echo_wait_ends_cleanly_on_ctrl_c():
    echo = subprocess.Popen(
        dockhil_cmd("topic", "echo", "/nothing", "--wait"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=sigint_as_a_terminal_sends_it,
    )
    try:
        Lines(echo, echo.stderr).wait_for("[topic] waiting for /nothing", timeout=60)
        echo.send_signal(signal.SIGINT)
        echo.wait(timeout=30)
        assert echo.returncode == 0 and echo.stdout.read() == ""
    finally:
        stop(echo)


def test_echo_without_wait_fails_in_one_line_as_before():
    r = subprocess.run(dockhil_cmd("topic", "echo", "/x"), capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "no running graph found" in r.stderr


def test_refusals_before_anything_runs():
    for args in (("topic", "hz", "/x", "--window", "1"), ("topic", "info", "/x", "--window", "-1")):
        r = subprocess.run(dockhil_cmd(*args), capture_output=True, text=True)
        assert r.returncode == 2 and "--window" in r.stderr, r.stderr


@pytest.mark.wall_time
def test_node_info_follows_a_respawned_node_to_its_new_pid(write_launch, capsys):
    from tests.test_introspection import start
    from tests.test_introspection import stop as stop_graph

    p, lines, _ = start(write_launch, respawn=True, die_at=20)
    try:
        first = registered(p.pid, timeout=60)["nodes"]["gain"]["pid"]
        lines.wait_for("[launch] node 'gain' exited with code 3; respawning in 0.2 s", count=2)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the registry names the newest process once it started
            node = json.loads(dockhil(capsys, "node", "info", "gain", "--json").stdout)
            if node["pid"] != first:
                break
            time.sleep(0.1)
        assert node["pid"] != first and node["params"]["die_at"] == 20
    finally:
        stop_graph(p, lines)


@pytest.mark.wall_time
def test_a_composed_graph_is_listed_and_its_nodes_described(write_launch, capsys):
    p = subprocess.Popen(
        dockhil_cmd("launch", write_launch(SCENE.replace("container: box, ", "")), "--wall-time", "--composed"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines = Lines(p)
    try:
        entry = registered(p.pid, timeout=60)
        assert entry["topics"] == {}  # nothing to observe: its nodes pass messages in one process
        node = json.loads(dockhil(capsys, "node", "info", "gain", "--json").stdout)
        assert node["process"] == "composed" and node["pid"] == p.pid and node["state"] == "running"
        assert node["params"]["gain"] == 3.5 and node["inputs"]["x"]["topic"] == "/x"
        listed = dockhil(capsys, "node", "list").stdout
        assert f"composed  composed  pid {p.pid}  running" in listed
    finally:
        stop(p)
        lines.rest(timeout=30)
    from dockhil.runtime.registry import registry_dir

    assert list(registry_dir().glob("*.json")) == []  # the entry goes with the run
