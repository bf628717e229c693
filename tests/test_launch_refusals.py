"""Every launch refusal: one clear line, exit code 2, nothing started."""

import subprocess

import pytest

from tests.conftest import dockhil_cmd

LOOP = """
rate: 1000
duration: 0.05
args:
  gain: {default: 2.0, help: feedback gain}
  use_trace: {default: false, help: add a tracer}
nodes:
  - {name: integ, node: "tests.graphnodes:Integrator"}
  - {name: gain, node: "tests.graphnodes:Gain", params: {gain: $(arg gain)}}
  - {name: trace, node: "tests.graphnodes:Trace", if: $(arg use_trace)}
"""

CASES = {
    "unknown node type": ("nodes:\n  - {name: a, node: no_such_node}\n", [], "unknown node type 'no_such_node'"),
    "unknown param": ('nodes:\n  - {name: a, node: "tests.graphnodes:Source", params: {speed: 1}}\n', [],
                      "unknown parameter 'speed'"),
    "mistyped param": ('nodes:\n  - {name: i, node: "tests.graphnodes:Integrator", params: {x0: fast}}\n'
                       '  - {name: g, node: "tests.graphnodes:Gain"}\n', [], "parameter 'x0': expected float, got str"),
    "param out of range": ('nodes:\n  - {name: i, node: "tests.graphnodes:Integrator"}\n'
                           '  - {name: g, node: "tests.graphnodes:Gain", params: {gain: -1}}\n', [],
                           "'gain': -1.0 is out of range, must be >= 0.0"),
    "unknown arg": (LOOP, ["gian:=3"], "unknown arg 'gian'; did you mean 'gain'? (known args: gain, use_trace)"),
    "mistyped arg": (LOOP, ["gain:=high"], "arg 'gain' expects float, got 'high'"),
    "unconnected input": ('nodes:\n  - {name: g, node: "tests.graphnodes:Gain"}\n', [],
                          "node 'g' input 'x' needs topic /x but no node publishes it"),
    "type mismatch": ('nodes:\n  - {name: s, node: "tests.graphnodes:Source"}\n'
                      '  - {name: k, node: "tests.graphnodes:StateSink"}\n', [],
                      "topic /x: s.x publishes dockhil/WrenchStamped but k.x expects dockhil/RobotState"),
    "algebraic loop": ('nodes:\n  - {name: g1, node: "tests.graphnodes:Gain"}\n'
                       '  - {name: g2, node: "tests.graphnodes:Gain", remap: {x: /u, u: /x}}\n', [],
                       "algebraic loop g1 -> g2 -> g1"),
    "two publishers": ('nodes:\n  - {name: a, node: "tests.graphnodes:Source"}\n'
                       '  - {name: b, node: "tests.graphnodes:Source"}\n', [], "topic /x is published by both a.x and b.x"),
    "bad yaml": ("nodes: [\n  - {name: a\n", [], "not valid YAML"),
    "not a mapping": ("- a\n- b\n", [], "a launch file is a YAML mapping"),
    "unknown key": ("nodez: []\n", [], "unknown key 'nodez'"),
    "bad topic name": ('nodes:\n  - {name: a, node: "tests.graphnodes:Source", remap: {x: "no slash"}}\n', [],
                       "topic 'no slash' of port 'x' must start with /"),
    "bad remap": ('nodes:\n  - {name: a, node: "tests.graphnodes:Source", remap: {y: /z}}\n', [],
                  "remap 'y' names no port or topic"),
    "undeclared arg": ('nodes:\n  - {name: a, node: "tests.graphnodes:Source", if: $(arg sim)}\n', [],
                       "$(arg sim) is not declared"),
    "bad condition": ('nodes:\n  - {name: a, node: "tests.graphnodes:Source", if: maybe}\n', [],
                      "neither true/false nor"),
    "duplicate name": ('nodes:\n  - {name: a, node: "tests.graphnodes:Source"}\n'
                       '  - {name: a, node: "tests.graphnodes:Sink"}\n', [], "two nodes are named 'a'"),
    "bad override syntax": (LOOP, ["gain=3"], "is not of the form name:=value"),
    "no nodes left": ('args: {enabled: {default: false}}\nnodes:\n  - {name: a, node: "tests.graphnodes:Source", if: $(arg enabled)}\n',
                      [], "no node to start after conditions"),
    "boolean arg name": ('args: {on: {default: false}}\nnodes: []\n', [], "args: keys must be text (YAML reads on/off/yes/no as booleans"),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("command", ["graph", "launch"])
def test_refusal_is_one_line(case, command, write_launch):
    text, overrides, expected = CASES[case]
    path = write_launch(text)
    r = subprocess.run(dockhil_cmd(command, path, *overrides, "--duration", "0.01")
                       if command == "launch" else dockhil_cmd(command, path, *overrides),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert expected in lines[0]
    assert "Traceback" not in r.stderr


def test_missing_file():
    r = subprocess.run(dockhil_cmd("launch", "launch/nope.yaml"), capture_output=True, text=True)
    assert r.returncode == 2 and "launch file 'launch/nope.yaml' not found" in r.stderr


def test_include_and_conditions(write_launch, tmp_path):
    (tmp_path / "child.yaml").write_text(
        'args: {g: {default: 1.0}}\nnodes:\n  - {name: gain, node: "tests.graphnodes:Gain", params: {gain: $(arg g)}}\n')
    path = write_launch(
        'args:\n  g: {default: 5.0}\n  trace: {default: "off", choices: ["on", "off"]}\n'
        'nodes:\n  - {name: integ, node: "tests.graphnodes:Integrator"}\n'
        '  - {name: tr, node: "tests.graphnodes:Trace", if: $(arg trace) == on}\n'
        'include:\n  - {file: child.yaml, args: {g: $(arg g)}}\n')
    from dockhil import launchfile
    from dockhil.graph import build

    g = build(launchfile.load(path, {"g": "7"}))
    assert sorted(g.nodes) == ["gain", "integ"]
    assert g.nodes["gain"].params["gain"] == 7.0
    assert [s.name for s in g.scene.skipped] == ["tr"]
    g = build(launchfile.load(path, {"trace": "on"}))
    assert "tr" in g.nodes
    r = subprocess.run(dockhil_cmd("graph", path, "trace:=maybe"), capture_output=True, text=True)
    assert r.returncode == 2 and "must be one of on, off" in r.stderr


def test_graph_shows_what_conditions_left_out(write_launch):
    path = write_launch(LOOP)
    r = subprocess.run(dockhil_cmd("graph", path), capture_output=True, text=True)
    assert r.returncode == 0
    assert "left out by conditions:\n  trace (if: $(arg use_trace) is false)" in r.stdout
    assert "in  u: /u dockhil/WrenchStamped <- gain.u, previous tick" in r.stdout
    dot = subprocess.run(dockhil_cmd("graph", path, "--dot"), capture_output=True, text=True).stdout
    assert dot.startswith("digraph") and '"integ" -> "gain" [label="/x"]' in dot
