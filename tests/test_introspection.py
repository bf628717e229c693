"""topic list | echo | hz and node list against a running graph; respawn in wall time.

True wall-time end-to-end tests (marked wall_time): they wait for conditions with
deadlines and assert outcomes, not rates or counts within a wall-clock window."""

import json
import signal
import subprocess
import time
from types import SimpleNamespace

import pytest

from dockhil import cli
from tests.conftest import Lines, dockhil_cmd

# Inputs may be 5 s old: what these tests look at is the introspection, not a node stopping on a
# stale input because a busy machine paused its peer for more than the default 0.1 s.
WALL = """
rate: 200
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator"INTEG_AGE}
  - {name: gain, node: "tests.support.graphnodes:Gain", respawn: RESPAWN, respawn_delay: 0.2, params: {die_at: DIE},
     max_age: {x: 5.0}}
"""


def dockhil(capsys, *args):
    """A `dockhil` command run in this process (no interpreter start-up): exit code and output."""
    capsys.readouterr()
    code = cli.main(list(args))
    out = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)


def start(write_launch, respawn=False, die_at=-1, capsys=None):
    # An input that reads a respawning node has no maximum age at all (it is refused there).
    path = write_launch(
        WALL.replace("RESPAWN", str(respawn).lower())
        .replace("DIE", str(die_at))
        .replace("INTEG_AGE", "" if respawn else ", max_age: {u: 5.0}")
    )
    p = subprocess.Popen(
        dockhil_cmd("launch", path, "--wall-time"), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    lines = Lines(p)
    if capsys is None:  # not waiting for the nodes to run
        return p, lines, ""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        r = dockhil(capsys, "node", "list")
        if r.stdout.count("running") == 2:
            return p, lines, r.stdout
        time.sleep(0.2)
    p.kill()
    raise AssertionError("graph did not start: " + lines.rest())


def stop(p, lines):
    p.send_signal(signal.SIGINT)
    return lines.rest(timeout=30)


@pytest.mark.wall_time
def test_topic_and_node_commands_see_a_running_graph(write_launch, capsys):
    p, lines, nodes = start(write_launch, capsys=capsys)
    try:
        assert "integ  tests.support.graphnodes:Integrator" in nodes and "gain  tests.support.graphnodes:Gain" in nodes
        topics = dockhil(capsys, "topic", "list").stdout
        assert "/x  dockhil/WrenchStamped  from integ" in topics and "/u  dockhil/WrenchStamped  from gain" in topics
        echo = dockhil(capsys, "topic", "echo", "/x", "-n", "3")
        rows = [json.loads(line) for line in echo.stdout.splitlines()]
        assert len(rows) == 3 and rows[0]["type"] == "dockhil/WrenchStamped", echo.stderr + "".join(lines.lines)
        assert rows[1]["header"]["seq"] == rows[0]["header"]["seq"] + 1
        hz = dockhil(capsys, "topic", "hz", "/u", "-n", "2", "--every", "0.25")
        rates = [float(line.split("average rate: ")[1].split(" ")[0]) for line in hz.stdout.splitlines()]
        # The scene runs at 200 Hz; a busy machine may deliver fewer, or a backlog in a burst: the
        # outcome is that hz sees the topic flowing, at a rate of the scene's order, not of another.
        assert len(rates) == 2 and all(0 < r < 400 for r in rates), hz.stdout
        missing = dockhil(capsys, "topic", "echo", "/nope")
        assert missing.returncode == 2 and "topic /nope is not published by any running graph" in missing.stderr
    finally:
        stop(p, lines)


def test_no_running_graph_is_said_plainly():
    r = subprocess.run(dockhil_cmd("topic", "hz", "/x"), capture_output=True, text=True)
    assert r.returncode == 2 and "no running graph found" in r.stderr


@pytest.mark.wall_time
def test_respawn_restarts_a_dead_node_in_wall_time(write_launch):
    # Not via `node list`: on a busy machine it may catch the node between death and respawn every time.
    p, lines, _ = start(write_launch, respawn=True, die_at=20)
    try:
        # Dies at its tick 20 (0.1 s at 200 Hz) and comes back, again and again.
        lines.wait_for("[launch] node 'gain' exited with code 3; respawning in 0.2 s", count=2)
    finally:
        out = stop(p, lines)
    assert out.count("[launch] node 'gain' exited with code 3; respawning in 0.2 s") >= 2, out
    assert p.returncode == 128 + signal.SIGINT
