"""topic list | echo | hz and node list against a running graph; respawn in wall time."""

import json
import signal
import subprocess
import time

from tests.conftest import dockhil_cmd

WALL = """
rate: 200
nodes:
  - {name: integ, node: "tests.graphnodes:Integrator"}
  - {name: gain, node: "tests.graphnodes:Gain", respawn: RESPAWN, respawn_delay: 0.2, params: {die_at: DIE}}
"""


def start(write_launch, respawn=False, die_at=-1):
    path = write_launch(WALL.replace("RESPAWN", str(respawn).lower()).replace("DIE", str(die_at)))
    p = subprocess.Popen(dockhil_cmd("launch", path, "--wall-time"), stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + 20
    while time.time() < deadline:
        r = subprocess.run(dockhil_cmd("node", "list"), capture_output=True, text=True)
        if r.stdout.count("running") == 2:
            return p, r.stdout
        time.sleep(0.2)
    p.kill()
    raise AssertionError("graph did not start: " + p.communicate()[0])


def stop(p):
    p.send_signal(signal.SIGINT)
    return p.communicate(timeout=20)[0]


def test_topic_and_node_commands_see_a_running_graph(write_launch):
    p, nodes = start(write_launch)
    try:
        assert "integ  tests.graphnodes:Integrator" in nodes and "gain  tests.graphnodes:Gain" in nodes
        topics = subprocess.run(dockhil_cmd("topic", "list"), capture_output=True, text=True).stdout
        assert "/x  dockhil/WrenchStamped  from integ" in topics and "/u  dockhil/WrenchStamped  from gain" in topics
        echo = subprocess.run(dockhil_cmd("topic", "echo", "/x", "-n", "3"), capture_output=True, text=True,
                              timeout=20)
        rows = [json.loads(line) for line in echo.stdout.splitlines()]
        assert len(rows) == 3 and rows[0]["type"] == "dockhil/WrenchStamped"
        assert rows[1]["header"]["seq"] == rows[0]["header"]["seq"] + 1
        hz = subprocess.run(dockhil_cmd("topic", "hz", "/u", "-n", "2"), capture_output=True, text=True, timeout=20)
        rates = [float(line.split(": ")[1].split(" Hz")[0]) for line in hz.stdout.splitlines()]
        assert len(rates) == 2 and all(150 < r < 220 for r in rates), hz.stdout  # the scene runs at 200 Hz
        missing = subprocess.run(dockhil_cmd("topic", "echo", "/nope"), capture_output=True, text=True)
        assert missing.returncode == 2 and "topic /nope is not published by any running graph" in missing.stderr
    finally:
        stop(p)


def test_no_running_graph_is_said_plainly():
    r = subprocess.run(dockhil_cmd("topic", "hz", "/x"), capture_output=True, text=True)
    assert r.returncode == 2 and "no running graph found" in r.stderr


def test_respawn_restarts_a_dead_node_in_wall_time(write_launch):
    p, _ = start(write_launch, respawn=True, die_at=100)
    time.sleep(2.0)  # dies every 100 ticks (0.5 s at 200 Hz) and comes back
    out = stop(p)
    assert out.count("[launch] node 'gain' exited with code 3; respawning in 0.2 s") >= 2, out
    assert p.returncode == 128 + signal.SIGINT
