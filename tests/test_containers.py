"""Component containers: nodes naming one `container:` run in one process, with in-process
delivery between them and the transport to the rest; the results are those of separate processes."""

import subprocess
from pathlib import Path

import pytest

from dockhil.bags.reader import BagReader
from tests.conftest import dockhil_cmd
from tests.support.inprocess import completed

HIL = Path(__file__).resolve().parent.parent / "launch" / "hil.yaml"


def hil_with(tmp_path, containers: dict[str, str], isolated: str = "") -> Path:
    """launch/hil.yaml with `container:` on the named simulated nodes, and `isolated: true` on one."""
    text = HIL.read_text().replace("file: emulators.yaml", f"file: {HIL.parent / 'emulators.yaml'}")
    for name, node_type in (
        ("delay", "delay_injector"),
        ("robot", "robot_sim"),
        ("ft", "ft_sim"),
        ("dynamics", "satellite_dynamics"),
        ("impedance", "virtual_impedance"),
    ):
        head = f"  - name: {name}\n    node: {node_type}\n"
        assert head in text
        if name in containers:
            text = text.replace(head, head + f"    container: {containers[name]}\n")
        if name == isolated:
            text = text.replace(head, head + "    isolated: true\n")
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    return path


def run(*args, timeout=180):
    return subprocess.run(dockhil_cmd(*map(str, args)), capture_output=True, text=True, timeout=timeout)


def run_here(*args):
    """A command that starts no process (`graph`, a refusal, a composed run) through dockhil.cli.main here."""
    return completed(*args)


def messages(path):
    with BagReader(path) as bag:
        return sorted((m.topic, m.log_time_ns, m.data) for m in bag)


def test_a_container_gives_the_bytes_of_separate_processes(tmp_path):
    hw = hil_with(tmp_path, {"delay": "hw", "robot": "hw", "ft": "hw"})
    separate, contained = tmp_path / "separate.mcap", tmp_path / "contained.mcap"
    for scene, bag in ((HIL, separate), (hw, contained)):  # 0.1 s: past the 32 ms the delayed topics start at
        r = run("launch", scene, "--duration", "0.1", "--bag", bag, "--quiet")
        assert r.returncode == 0, r.stdout + r.stderr
    a, b = messages(separate), messages(contained)
    # Seven topics every tick (/energy among them), but no delayed command and no robot pose in
    # the first 32 ms; a recorder sees the container's internal topics too.
    assert len(a) == 7 * 101 - 2 * 32
    assert a == b


def test_dockhil_graph_shows_the_processes(tmp_path):
    r = run_here("graph", hil_with(tmp_path, {"delay": "hw", "robot": "hw", "ft": "hw"}))
    assert r.returncode == 0, r.stderr
    shown = r.stdout.split("processes (3):\n")[1].splitlines()[:3]
    assert sorted(shown) == ["  dynamics", "  hw: delay, robot, ft", "  impedance"]
    r = run_here("graph", HIL)
    assert "processes (5):" in r.stdout


@pytest.mark.parametrize(
    "containers, isolated, command, expected",
    [
        ({"ft": "hw", "robot": "hw"}, "ft", "graph", "node 'ft': `isolated: true` keeps it in a process of its own"),
        ({}, "ft", "--composed", "node 'ft' is `isolated: true` (its own process), so the graph cannot run --composed"),
        (
            {"delay": "hw", "ft": "hw"},
            "",
            "graph",
            "container processes hw -> robot -> hw read each other at the same tick",
        ),
        ({"delay": "ft"}, "", "graph", "container 'ft' has the name of a node"),
        ({"delay": "h w"}, "", "graph", "`container` must be a name of letters, digits"),
    ],
)
def test_refused_containment_is_one_line(tmp_path, containers, isolated, command, expected):
    scene = hil_with(tmp_path, containers, isolated)
    args = ("graph", scene) if command == "graph" else ("launch", scene, "--duration", "0.01", command, "--quiet")
    r = run_here(*args)
    assert r.returncode != 0
    out = (r.stdout + r.stderr).strip().splitlines()
    assert len(out) == 1 and expected in out[0] and "Traceback" not in r.stderr, out


def test_an_isolated_node_runs_alone_and_the_rest_may_share(tmp_path):
    r = run_here("graph", hil_with(tmp_path, {"delay": "hw", "robot": "hw"}, "ft"))
    assert r.returncode == 0, r.stderr
    assert "  hw: delay, robot\n" in r.stdout and "  ft\n" in r.stdout


def test_a_member_s_refused_output_is_said_as_the_member_s_own_process_says_it(tmp_path):
    """A member's message that its readers would refuse (a bool in a float field) names the member
    and its port, as a composed run and node processes do; not the container and "member.port":
    the container's tick refuses it, as its screen judges the values' types too."""
    lines = {}
    for box in ("", "\n    container: box"):
        path = tmp_path / "scene.yaml"
        path.write_text(f"""rate: 100
duration: 0.1
nodes:
  - name: source
    node: tests.support.faultnodes:BoolAt{box}
  - name: other
    node: tests.support.faultnodes:NanAt{box}
    params: {{at: 1000}}
    remap: {{x: /y}}
  - name: follow
    node: tests.support.faultnodes:Follow
""")
        r = run("launch", path)
        assert r.returncode == 1, r.stderr
        lines[box] = [line.split("] ", 1)[1] for line in r.stderr.splitlines() if "invalid message" in line]
    want = (
        "error: node 'source' produced an invalid message at tick 5 on output 'x' (/x): WrenchStamped: "
        "Expected `float`, got `bool` - at `$.wrench.force.x`; stopping the graph"
    )
    assert lines == {"": [want], "\n    container: box": [want]}
