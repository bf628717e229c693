"""The node parameter `dof` of satellite_dynamics, virtual_impedance, ft_sim and robot_sim: dof 1
(or none) is the 1-DOF node bit for bit, dof 6 the 6-DOF type that the `*6` names still spell;
a dof other than 1 or 6, or a parameter only the other dof's node takes, is one line."""

import json
import subprocess

import pytest

from dockhil.analysis.summary import SummaryCollector
from dockhil.msgs.codec import encode
from dockhil.runtime.composed import ComposedGraph
from dockhil.scene import graph as graphmod
from dockhil.scene import launchfile
from dockhil.testing import NodeHarness
from tests.conftest import ROOT, dockhil_cmd
from tests.support.inprocess import run_main

HIL, HIL6 = ROOT / "launch" / "hil.yaml", ROOT / "launch" / "hil6.yaml"
DOF_TYPES = ("satellite_dynamics", "virtual_impedance", "ft_sim", "robot_sim")


def composed_run(scene, n_ticks: int):
    """(graph, every message as (topic, tick, encoded bytes) in publishing order, summary as JSON text)."""
    graph = graphmod.build(scene)
    summary = SummaryCollector(graph)
    seen = []
    g = ComposedGraph(
        graph,
        log=lambda name, msg: None,
        taps=[lambda topic, msg: seen.append((topic, msg.header.tick, encode(msg))), summary],
    )
    g.setup()
    try:
        g.run(n_ticks)
    finally:
        g.close()
    return graph, seen, json.dumps(summary.summary(), sort_keys=True)


def test_dof_1_is_the_node_without_dof_bit_for_bit():
    plain = launchfile.load(HIL)
    explicit = launchfile.load(HIL)
    for spec in explicit.nodes:
        if spec.type in DOF_TYPES:
            spec.params = {**spec.params, "dof": 1}
    assert sum("dof" in spec.params for spec in explicit.nodes) == 4
    n = 1800  # the whole contact (about 1.6 s) and the rebound: the summary has its exit
    g1, a, summary_a = composed_run(plain, n)
    g2, b, summary_b = composed_run(explicit, n)
    assert [(gn.type_name, gn.cls, gn.params) for gn in g1.nodes.values()] == [
        (gn.type_name, gn.cls, gn.params) for gn in g2.nodes.values()
    ]
    assert len(a) > 5 * n and a == b
    assert summary_a == summary_b
    assert json.loads(summary_a)["exit_velocity_mps"] < -0.02  # a real contact: the chaser rebounded


def test_dof_6_is_the_6dof_types_bit_for_bit():
    new = launchfile.load(HIL6)
    assert {spec.type for spec in new.nodes} == {*DOF_TYPES, "delay_injector"}  # the shipped spelling
    old = launchfile.load(HIL6)
    for spec in old.nodes:
        if spec.params.pop("dof", None) == 6:
            spec.type += "6"
    assert {spec.type for spec in old.nodes} == {f"{t}6" for t in DOF_TYPES} | {"delay_injector"}
    n = 200  # contact from 7 ms, the delayed command from 32 ms
    g_new, a, summary_a = composed_run(new, n)
    g_old, b, summary_b = composed_run(old, n)
    for name, gn in g_new.nodes.items():
        assert (gn.type_name, gn.cls, gn.params) == (
            g_old.nodes[name].type_name,
            g_old.nodes[name].cls,
            g_old.nodes[name].params,
        )
    assert g_new.nodes["dynamics"].cls.__name__ == "SatelliteDynamics6"
    assert len(a) > 5 * n and a == b
    assert summary_a == summary_b and json.loads(summary_a)["dof"] == 6
    readings = [m for topic, _, m in a if topic == "/ft/wrench"]
    assert len(set(readings)) > 100  # the contact moves the sensor's reading tick after tick


def test_the_6dof_names_take_dof_6_too():
    scene = launchfile.load(HIL6)
    for spec in scene.nodes:
        if "dof" in spec.params:
            spec.type += "6"
    graph = graphmod.build(scene)
    assert graph.nodes["robot"].cls.__name__ == "RobotSim6"
    assert "dof" not in graph.nodes["robot"].params  # dof picks the class; the class takes no dof


def test_dockhil_graph_shows_the_type_as_the_file_writes_it_with_its_dof(tmp_path):
    """`dynamics [satellite_dynamics, dof 6]`, as hil6.yaml declares it (not the registered
    satellite_dynamics6, a name the file does not hold); a 1-DOF scene's types as they were."""
    code, out, _ = run_main("graph", HIL6)
    assert code == 0
    section = out.split("\nnodes (", 1)[1].split("\nprocesses (", 1)[0].splitlines()[1:]
    shown = dict(line[2:].split("]", 1)[0].split(" [") for line in section if not line.startswith("   "))
    assert shown == {
        "delay": "delay_injector",
        "robot": "robot_sim, dof 6",
        "ft": "ft_sim, dof 6",
        "dynamics": "satellite_dynamics, dof 6",
        "impedance": "virtual_impedance, dof 6",
    }
    code, dot, _ = run_main("graph", HIL6, "--dot")
    assert '"dynamics" [label="dynamics\\nsatellite_dynamics, dof 6"];' in dot
    six = edited(tmp_path, HIL6, DYNAMICS6, "    node: satellite_dynamics6\n    params:\n")  # the 6-DOF name itself
    assert "  dynamics [satellite_dynamics6] " in run_main("graph", six)[1]
    code, out, _ = run_main("graph", HIL)
    assert (
        "  dynamics [satellite_dynamics] " in out and "  impedance [virtual_impedance] " in out and ", dof" not in out
    )


def edited(tmp_path, source, old: str, new: str):
    text = source.read_text()
    assert old in text
    path = tmp_path / "scene.yaml"
    path.write_text(text.replace(old, new, 1))
    return path


DYNAMICS6 = "    node: satellite_dynamics\n    params:\n      dof: 6\n"
# The line of hil6.yaml's dynamics node, where a refusal of its parameters points.
DYNAMICS6_LINE = HIL6.read_text().splitlines().index("  - name: dynamics") + 1


@pytest.mark.parametrize(
    "source, old, new, line",
    [
        (
            HIL6,
            DYNAMICS6,
            DYNAMICS6.replace("dof: 6", "dof: 3"),
            f"scene.yaml:{DYNAMICS6_LINE}: node 'dynamics' (satellite_dynamics): dof must be the integer 1 or 6, "
            "got 3; give dof: 1 "
            "(along x) or dof: 6 (the 6-DOF node)",
        ),
        (
            HIL6,
            DYNAMICS6,
            DYNAMICS6.replace("dof: 6", "dof: six"),
            "node 'dynamics' (satellite_dynamics): dof must be the integer 1 or 6, got 'six'; give dof: 1",
        ),
        (HIL6, DYNAMICS6, DYNAMICS6.replace("dof: 6", "dof: 6.0"), "dof must be the integer 1 or 6, got 6.0"),
        # hil6.yaml's dynamics without its dof: the 6-DOF parameters of the 1-DOF node
        (
            HIL6,
            DYNAMICS6,
            DYNAMICS6.replace("      dof: 6\n", ""),
            f"scene.yaml:{DYNAMICS6_LINE}: node 'dynamics' (satellite_dynamics, dof 1): unknown parameter "
            "'attitude1', a parameter of "
            "the 6-DOF node; set dof: 6 for the 6-DOF node",
        ),
        (
            HIL,
            "v1: $(arg v1),",
            "v1: [0.03, 0.0, 0.0],",
            "node 'dynamics' (satellite_dynamics, dof 1): parameter 'v1' is a list [0.03, 0.0, 0.0], as the 6-DOF node "
            "takes it, not a float; set dof: 6 for the 6-DOF node, or give a float",
        ),
        (
            HIL,
            "params: {k: $(arg k), noise",
            "params: {dof: 1, passive_stiffness: [1000, 1000, 1000, 100, 100, 100], noise",
            "node 'ft' (ft_sim, dof 1): unknown parameter 'passive_stiffness', a parameter of the 6-DOF node; "
            "set dof: 6 for the 6-DOF node",
        ),
        (
            HIL6,
            "      dof: 6\n      passive_stiffness",
            "      dof: 6\n      k: 1000.0\n      passive_stiffness",
            "node 'ft' (ft_sim, dof 6): unknown parameter 'k', a parameter of the 1-DOF node; set dof: 1 for the "
            "1-DOF node",
        ),
        (
            HIL6,
            "      v1: [$(arg v1), 0.0, 0.0]",
            "      v1: 0.03",
            "node 'dynamics' (satellite_dynamics, dof 6): parameter 'v1' is a float 0.03, as the 1-DOF node takes it, "
            "not a list; set dof: 1 for the 1-DOF node, or give a list",
        ),
        (
            HIL6,
            DYNAMICS6,
            "    node: satellite_dynamics6\n    params:\n      dof: 1\n",
            "node 'dynamics' (satellite_dynamics6): dof 1, but satellite_dynamics6 is the 6-DOF node; write node: "
            "satellite_dynamics for the 1-DOF one",
        ),
        (
            HIL6,
            DYNAMICS6,
            "    node: satellite_dynamics6\n    params:\n      kcs: 3000.0\n",
            "node 'dynamics' (satellite_dynamics6): unknown parameter 'kcs', a parameter of the 1-DOF node; write "
            "node: satellite_dynamics for the 1-DOF node",
        ),
        # One loop, two dofs: the messages have the same types, so it would connect and run on nonsense.
        (
            HIL6,
            "    node: virtual_impedance\n    params:\n      dof: 6\n      m1: $(arg m1)\n      m2: $(arg m2)\n"
            "      stiffness: [$(arg kcs), $(arg kcs), $(arg kcs), $(arg kr), $(arg kr), $(arg kr)]\n"
            "      damping: [$(arg bcs), $(arg bcs), $(arg bcs), $(arg br), $(arg br), $(arg br)]\n"
            "      passive_stiffness: [$(arg k), $(arg k), $(arg k), $(arg kp_r), $(arg kp_r), $(arg kp_r)]\n",
            "    node: virtual_impedance\n    params:\n      m1: $(arg m1)\n      m2: $(arg m2)\n",
            "scene.yaml: node 'impedance' (virtual_impedance) is 1-DOF and node 'dynamics' (satellite_dynamics with "
            "dof: 6) is 6-DOF: the nodes of one loop take one dof; give 'impedance' dof: 6, or 'dynamics', 'robot', "
            "'ft' dof: 1",
        ),
        (
            HIL,
            "params: {k: $(arg k), noise: $(arg ft_noise), k_scale: $(arg hw_k_scale), delay: $(arg ft_delay)}",
            "params: {dof: 6}",
            "node 'dynamics' (satellite_dynamics) is 1-DOF and node 'ft' (ft_sim with dof: 6) is 6-DOF",
        ),
        # A parameter neither dof takes keeps the node's own refusal; a type without dof refuses dof.
        (
            HIL6,
            DYNAMICS6,
            DYNAMICS6 + "      kcss: 1.0\n",
            "node 'dynamics' (SatelliteDynamics6): unknown parameter 'kcss'; ",
        ),
        (
            HIL,
            "params: {delay: $(arg delay)}",
            "params: {delay: $(arg delay), dof: 6}",
            "node 'delay' (DelayInjector): unknown parameter 'dof'; ",
        ),
    ],
)
def test_a_bad_dof_or_a_parameter_of_the_other_dof_is_one_line(tmp_path, source, old, new, line):
    code, out, err = run_main("graph", edited(tmp_path, source, old, new))
    assert code not in (0, None)
    lines = [s for s in (out + err).splitlines() if s.strip()]
    assert len(lines) == 1 and "Traceback" not in lines[0] and line in lines[0], lines


@pytest.mark.parametrize(
    "params, line",
    [
        (["dof:=3"], "node 'satellite_dynamics' (satellite_dynamics): dof must be the integer 1 or 6, got 3"),
        (
            ["dof:=6", "kcs:=1.0"],
            "node 'satellite_dynamics' (satellite_dynamics, dof 6): unknown parameter 'kcs', a "
            "parameter of the 1-DOF node; set dof: 1 for the 1-DOF node",
        ),
    ],
)
def test_dockhil_run_takes_dof_as_a_launch_file_does(params, line):
    code, out, err = run_main("run", "satellite_dynamics", *params)
    assert code not in (0, None)
    lines = [s for s in (out + err).splitlines() if s.strip()]
    assert len(lines) == 1 and line in lines[0], lines


def test_node_types_shows_dof():
    code, out, _ = run_main("node", "types", "satellite_dynamics")
    assert code == 0
    dof = [s for s in out.splitlines() if s.startswith("  param dof:")]
    assert len(dof) == 1 and dof[0].startswith("  param dof: int = 1  ") and "6, the 6-DOF node" in dof[0]
    code, out, _ = run_main("node", "types", "satellite_dynamics6")
    assert code == 0 and "satellite_dynamics with dof: 6" in out.splitlines()[0]
    assert "  param dof: int = 6  " in out
    code, out, _ = run_main("node", "types", "delay_injector")
    assert code == 0 and "param dof" not in out


def test_the_node_harness_takes_dof_as_a_launch_file_does():
    with NodeHarness("robot_sim", dof=6, lag=0.0) as h:
        assert h.cls.__name__ == "RobotSim6"
    with NodeHarness("robot_sim", dof=1) as h:
        assert h.cls.__name__ == "RobotSim"


def test_a_container_runs_the_dof_6_nodes(tmp_path):
    """The launcher hands a container its members by the registered type: the whole 6-DOF loop in one
    container process gives the composed run's bytes."""
    text = HIL6.read_text()
    for name in ("dynamics", "impedance", "delay", "robot", "ft"):
        head = f"  - name: {name}\n"  # every entry of that name: the conditions pick the one that runs
        assert text.count(head) >= 1
        text = text.replace(head, head + "    container: loop\n")
    scene, bag = tmp_path / "contained.yaml", tmp_path / "contained.mcap"
    scene.write_text(text)
    r = subprocess.run(
        dockhil_cmd("launch", scene, "--duration", "0.05", "--bag", bag, "--quiet"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    from dockhil.bags.reader import BagReader

    with BagReader(str(bag)) as reader:
        got = sorted((m.topic, m.data) for m in reader)
    _, composed, _ = composed_run(launchfile.load(HIL6), 51)
    assert len(got) > 4 * 51 and got == sorted((topic, data) for topic, _, data in composed)


def test_the_scene_check_judges_a_6dof_scenes_step_against_its_contact(tmp_path):
    """As for a 1-DOF scene: a contact the 1 kHz step cannot resolve is refused, naming the rate
    that would; a coarse one is a warning in the summary. The fastest pole is checked against
    the closed form of the stiffest mode: the lateral contact (along z) at the chaser's interface,
    1 m ahead of its CoM, so the force also turns the chaser about y (moment 400 kg m^2); the
    target's share (1e6 kg, 5e6 kg m^2 at 2 m) and the damping move it by well under 1 %."""
    code, out, err = run_main("launch", HIL6, "--composed", "--duration", "0.01", "kcs:=3e9")
    assert code == 2
    assert "refused: the step does not resolve the contact: omega*dt = " in err and "rate:=" in err
    summary = tmp_path / "s.json"
    code, out, err = run_main(
        "launch", HIL6, "--composed", "--duration", "0.01", "--quiet", "kcs:=3e6", "--summary", summary
    )
    assert code == 0
    found = json.loads(summary.read_text())
    assert found["warnings"] and found["warnings"][0].startswith("coarse step: omega*dt = ")
    mobility = 1 / 750.0 + 1.0**2 / 400.0 + 1 / 1e6 + 2.0**2 / 5e6  # [1/kg] at the interface, along z
    assert found["loop"]["omega_rad_s"] == pytest.approx((3e6 * mobility) ** 0.5, rel=0.01)
