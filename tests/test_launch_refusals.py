"""Every launch refusal: one clear line, exit code 2, nothing started."""

import json
import subprocess

import pytest

from tests.conftest import ROOT, dockhil_cmd
from tests.support.inprocess import run_main

# The line each node of the shipped hil.yaml is declared on, read from the file (a refusal names it).
HIL_LINE = {
    line.split("name:", 1)[1].strip(): n
    for n, line in enumerate((ROOT / "launch" / "hil.yaml").read_text().splitlines(), 1)
    if line.strip().startswith("- name:")
}

LOOP = """
rate: 1000
duration: 0.05
args:
  gain: {default: 2.0, help: feedback gain}
  use_trace: {default: false, help: add a tracer}
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator"}
  - {name: gain, node: "tests.support.graphnodes:Gain", params: {gain: $(arg gain)}}
  - {name: trace, node: "tests.support.graphnodes:Trace", if: $(arg use_trace)}
"""

CASES = {
    "unknown node type": ("nodes:\n  - {name: a, node: no_such_node}\n", [], "unknown node type 'no_such_node'"),
    "unknown param": (
        'nodes:\n  - {name: a, node: "tests.support.graphnodes:Source", params: {speed: 1}}\n',
        [],
        "unknown parameter 'speed'",
    ),
    "mistyped param": (
        'nodes:\n  - {name: i, node: "tests.support.graphnodes:Integrator", params: {x0: fast}}\n'
        '  - {name: g, node: "tests.support.graphnodes:Gain"}\n',
        [],
        "parameter 'x0': expected float, got str",
    ),
    "param out of range": (
        'nodes:\n  - {name: i, node: "tests.support.graphnodes:Integrator"}\n'
        '  - {name: g, node: "tests.support.graphnodes:Gain", params: {gain: -1}}\n',
        [],
        "'gain': -1.0 is out of range, must be >= 0.0",
    ),
    "unknown arg": (LOOP, ["gian:=3"], "unknown arg 'gian'; did you mean 'gain'? (known args: gain, use_trace)"),
    "mistyped arg": (LOOP, ["gain:=high"], "arg 'gain' expects float, got 'high'"),
    "unconnected input": (
        'nodes:\n  - {name: g, node: "tests.support.graphnodes:Gain"}\n',
        [],
        "node 'g' input 'x' needs topic /x but no node publishes it",
    ),
    "type mismatch": (
        'nodes:\n  - {name: s, node: "tests.support.graphnodes:Source"}\n'
        '  - {name: k, node: "tests.support.graphnodes:StateSink"}\n',
        [],
        "topic /x: s.x publishes dockhil/WrenchStamped but k.x expects dockhil/RobotState",
    ),
    "algebraic loop": (
        'nodes:\n  - {name: g1, node: "tests.support.graphnodes:Gain"}\n'
        '  - {name: g2, node: "tests.support.graphnodes:Gain", remap: {x: /u, u: /x}}\n',
        [],
        "algebraic loop g1 -> g2 -> g1",
    ),
    "two publishers": (
        'nodes:\n  - {name: a, node: "tests.support.graphnodes:Source"}\n'
        '  - {name: b, node: "tests.support.graphnodes:Source"}\n',
        [],
        "topic /x is published by both a.x and b.x",
    ),
    "bad yaml": ("nodes: [\n  - {name: a\n", [], "not valid YAML"),
    "not a mapping": ("- a\n- b\n", [], "a launch file is a YAML mapping"),
    "unknown key": ("nodez: []\n", [], "unknown key 'nodez'"),
    "bad topic name": (
        'nodes:\n  - {name: a, node: "tests.support.graphnodes:Source", remap: {x: "no slash"}}\n',
        [],
        "topic 'no slash' of port 'x' must start with /",
    ),
    "bad remap": (
        'nodes:\n  - {name: a, node: "tests.support.graphnodes:Source", remap: {y: /z}}\n',
        [],
        "remap 'y' names no port or topic",
    ),
    "undeclared arg": (
        'nodes:\n  - {name: a, node: "tests.support.graphnodes:Source", if: $(arg sim)}\n',
        [],
        "$(arg sim) is not declared",
    ),
    "bad condition": (
        'nodes:\n  - {name: a, node: "tests.support.graphnodes:Source", if: maybe}\n',
        [],
        "neither true/false nor",
    ),
    "duplicate name": (
        'nodes:\n  - {name: a, node: "tests.support.graphnodes:Source"}\n  - {name: a, node: "tests.support.graphnodes:Sink"}\n',
        [],
        "two nodes are named 'a'",
    ),
    "bad override syntax": (LOOP, ["gain=3"], "is not of the form name:=value"),
    "no nodes left": (
        'args: {enabled: {default: false}}\nnodes:\n  - {name: a, node: "tests.support.graphnodes:Source", if: $(arg enabled)}\n',
        [],
        "no node to start after conditions",
    ),
    "boolean arg name": (
        "args: {on: {default: false}}\nnodes: []\n",
        [],
        "args: keys must be text (YAML reads on/off/yes/no as booleans",
    ),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("command", ["graph", "launch"])
def test_refusal_is_one_line(case, command, write_launch):
    text, overrides, expected = CASES[case]
    path = write_launch(text)
    # In this process (a refusal needs no interpreter of its own); test_missing_file and the
    # `graph` runs below hold the same one-line refusal for a real `dockhil` process.
    code, out, err = run_main(command, path, *overrides, *(["--duration", "0.01"] if command == "launch" else []))
    assert_one_line_refusal(code, err, expected)
    assert out == ""  # nothing started, nothing shown


def test_missing_file():
    r = subprocess.run(dockhil_cmd("launch", "launch/nope.yaml"), capture_output=True, text=True)
    assert_one_line_refusal(r.returncode, r.stderr, "launch file 'launch/nope.yaml' not found")
    assert r.stdout == ""


def test_include_and_conditions(write_launch, tmp_path):
    (tmp_path / "child.yaml").write_text(
        'args: {g: {default: 1.0}}\nnodes:\n  - {name: gain, node: "tests.support.graphnodes:Gain", params: {gain: $(arg g)}}\n'
    )
    path = write_launch(
        'args:\n  g: {default: 5.0}\n  trace: {default: "off", choices: ["on", "off"]}\n'
        'nodes:\n  - {name: integ, node: "tests.support.graphnodes:Integrator"}\n'
        '  - {name: tr, node: "tests.support.graphnodes:Trace", if: $(arg trace) == on}\n'
        "include:\n  - {file: child.yaml, args: {g: $(arg g)}}\n"
    )
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    g = build(launchfile.load(path, {"g": "7"}))
    assert sorted(g.nodes) == ["gain", "integ"]
    assert g.nodes["gain"].params["gain"] == 7.0
    assert [s.name for s in g.scene.skipped] == ["tr"]
    g = build(launchfile.load(path, {"trace": "on"}))
    assert "tr" in g.nodes
    code, _, err = run_main("graph", path, "trace:=maybe")
    assert code == 2 and "must be one of on, off" in err


def test_graph_shows_what_conditions_left_out(write_launch):
    path = write_launch(LOOP)
    r = subprocess.run(dockhil_cmd("graph", path), capture_output=True, text=True)
    assert r.returncode == 0
    assert "left out by conditions:\n  trace (if: $(arg use_trace) is false)" in r.stdout
    assert "in  u: /u dockhil/WrenchStamped <- gain.u, previous tick" in r.stdout
    code, dot, _ = run_main("graph", path, "--dot")
    assert code == 0
    assert dot.startswith("digraph") and '"integ" -> "gain" [label="/x"]' in dot


# Each bad input reported against the first release: (what, launch file or None, command line after the
# command, the words that say what and where). Every one is refused in one line, exit 2, before anything runs.
SOURCE = '  - {name: a, node: "tests.support.graphnodes:Source"'
BAD_INPUTS = {
    "rate .inf": (
        "graph",
        "rate: .inf\nnodes:\n" + SOURCE + "}\n",
        [],
        "scene.yaml:1: rate: expected a number <= 1000000.0, got inf",
    ),
    "rate 1e308": (
        "graph",
        "rate: 1e308\nnodes:\n" + SOURCE + "}\n",
        [],
        "scene.yaml:1: rate: expected a number <= 1000000.0, got 1e+308",
    ),
    "rate nan": (
        "graph",
        "nodes:\n" + SOURCE + "}\nrate: .nan\n",
        [],
        "scene.yaml:3: rate: expected a number >= 0.001, got nan",
    ),
    "duration .inf": (
        "graph",
        "duration: .inf\nnodes:\n" + SOURCE + "}\n",
        [],
        "scene.yaml:1: duration: expected a number <= 1000000.0, got inf",
    ),
    "respawn_delay soon": (
        "graph",
        "nodes:\n" + SOURCE + ", respawn: true, respawn_delay: soon}\n",
        [],
        "scene.yaml:2: nodes[0].respawn_delay: expected a number, got 'soon'",
    ),
    "respawn_delay -5": (
        "launch",
        "nodes:\n" + SOURCE + ", respawn: true, respawn_delay: -5}\n",
        ["--duration", "0.01"],
        "scene.yaml:2: nodes[0].respawn_delay: expected a number >= 0.0, got -5",
    ),
    "choices 5": (
        "graph",
        "args:\n  x: {default: 5, choices: 5}\nnodes:\n" + SOURCE + "}\n",
        [],
        "scene.yaml:2: args.x.choices: expected a list, got 5",
    ),
    "node os:system": (
        "graph",
        "nodes:\n  - {name: a, node: 'os:system'}\n",
        [],
        "scene.yaml:2: node 'a': node type 'os:system': system is not a dockhil node",
    ),
    "node json:dumps": (
        "graph",
        "nodes:\n  - {name: a, node: 'json:dumps'}\n",
        [],
        "scene.yaml:2: node 'a': node type 'json:dumps': ",
    ),  # not a class: not a node
    "20000 nested [": ("graph", "nodes: " + "[" * 20000 + "\n", [], "scene.yaml:1: nested deeper than 32 levels"),
    "--duration inf": ("launch", LOOP, ["--duration", "inf"], "argument --duration: 'inf' is not a finite number"),
    "--duration nan": ("launch", LOOP, ["--duration", "nan"], "argument --duration: 'nan' is not a finite number"),
    "--duration -1": ("launch", LOOP, ["--duration=-1"], "argument --duration: -1 s must be > 0"),
    "delay:=1e308": (
        "graph",
        "launch/hil.yaml",
        ["delay:=1e308"],
        # The virtual impedance is told the delay too (its compensation), and is checked first.
        f"hil.yaml:{HIL_LINE['impedance']}: node 'impedance' parameter 'delay': 1e+308 s is longer than 1 s: a "
        "robot delay is a few ms to a few hundred ms; give it in seconds, at most 1 s",
    ),
    "params --m1 1e-320": ("params", None, ["--table1", "--m1", "1e-320"], "--m1 1e-320 is too small to compute with"),
    "params --m1 1e308": ("params", None, ["--table1", "--m1", "1e308"], "--m1 1e+308 kg is outside 0.01 to 1e+08 kg"),
    "params --m1 2e150 (solve_ivp never ended)": (
        "params",
        None,
        ["--table1", "--states", "solve_ivp", "--m1", "2e150", "--m2", "6e-5"],
        "--m1 2e+150 kg is outside 0.01 to 1e+08 kg",
    ),
    # sqrt(m / kcs) with m = 750 * 1e6 / (750 + 1e6) kg = 749.44 kg and kcs = 1e-300 N/m: 2.74e151 s
    "params --kcs 1e-300": (
        "params",
        None,
        ["--table1", "--kcs", "1e-300", "--k", "0", "--bcs", "0"],
        "the contact's time scale sqrt(m/kcs) = 2.74e+151 s is outside 1e-09 to 1e+09 s",
    ),
    "params --dt 1e-9": (
        "params",
        None,
        ["--table1", "--states", "rk4", "--dt", "1e-9"],
        "--dt 1e-09 s takes 1.18e+09 steps",
    ),
    "arg typo": ("graph", "launch/hil.yaml", ["delya:=0.1"], "unknown arg 'delya'; did you mean 'delay'?"),
    "key typo": (
        "graph",
        "nodes:\n" + SOURCE + ", parms: {}}\n",
        [],
        "scene.yaml:2: nodes[0].parms: unknown key 'parms'; did you mean 'params'?",
    ),
    "subnormal param": (
        "graph",
        "launch/hil.yaml",
        ["m1:=1e-320"],
        f"hil.yaml:{HIL_LINE['dynamics']}: node 'dynamics' parameter 'm1': 1e-320 is too small to compute with",
    ),
    "rate arg 2e6": (
        "graph",
        "rate: $(arg rate)\nargs: {rate: {default: 1000.0}}\nnodes:\n" + SOURCE + "}\n",
        ["rate:=2e6"],
        "scene.yaml:1: rate: expected a number <= 1000000.0, got 2000000.0",
    ),
    "recursive alias": ("graph", "nodes: &n [*n]\n", [], "scene.yaml:1: alias *n refers to the value that contains it"),
}


def assert_one_line_refusal(code, err, expected):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert expected in lines[0], lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_reported_bad_input_is_one_line(case, write_launch):
    command, text, argv, expected = BAD_INPUTS[case]
    where = [] if text is None else [text if text.startswith("launch/") else write_launch(text)]
    code, _, err = run_main(command, *where, *argv)
    assert_one_line_refusal(code, err, expected)


def test_summary_naming_a_directory_is_refused_before_the_run(tmp_path):
    code, out, err = run_main("launch", "launch/ideal.yaml", "--composed", "--summary", tmp_path)
    assert_one_line_refusal(code, err, f"--summary {tmp_path}: is a directory")
    assert "simulated" not in out + err  # nothing ran


def test_summary_in_a_missing_folder_is_refused(tmp_path):
    code, _, err = run_main("launch", "launch/ideal.yaml", "--composed", "--summary", tmp_path / "no" / "s.json")
    assert_one_line_refusal(code, err, "does not exist")


def test_summary_never_replaces_the_bag_or_a_file_that_is_no_summary(tmp_path):
    bag = tmp_path / "run.mcap"
    # the same file for --bag and --summary: the summary would overwrite the recording
    for spelling in (bag, tmp_path / "." / "run.mcap"):
        code, out, err = run_main(
            "launch", "launch/ideal.yaml", "--composed", "--quiet", "--bag", bag, "--summary", spelling
        )
        assert_one_line_refusal(code, err, f"--summary {spelling}: is the file --bag records to")
        assert not bag.exists()  # nothing ran
    # an existing file that is not a summary (a bag, data, a script) is left alone
    for name, content in (
        ("old.mcap", b"\x89MCAP0\r\n" + bytes(100)),
        ("table.csv", b"a,b\n1,2\n"),
        ("other.json", b'{"name": "not a run summary"}'),
    ):
        path = tmp_path / name
        path.write_bytes(content)
        code, out, err = run_main("launch", "launch/ideal.yaml", "--composed", "--quiet", "--summary", path)
        assert_one_line_refusal(code, err, f"--summary {path}: exists and is not the summary of a run")
        assert path.read_bytes() == content
    # the summary of an earlier run is replaced, complete
    path = tmp_path / "s.json"
    assert (
        run_main("launch", "launch/ideal.yaml", "--composed", "--quiet", "--duration", "0.05", "--summary", path)[0]
        == 0
    )
    first = json.loads(path.read_text())
    code, _, err = run_main(
        "launch", "launch/ideal.yaml", "--composed", "--quiet", "--duration", "0.1", "--summary", path
    )
    assert code == 0, err
    second = json.loads(path.read_text())
    assert (first["sim_time_s"], second["sim_time_s"]) == (0.05, 0.1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.mcap", "other.json", "s.json", "table.csv"]


def _ft_bag(path):
    from dockhil.bags.writer import BagWriter
    from dockhil.msgs import Header, Vector3, Wrench, WrenchStamped, type_name
    from dockhil.msgs.codec import encode

    with BagWriter(path) as bag:
        bag.add_topic("/ft/wrench", type_name(WrenchStamped))
        for k in range(10):
            msg = WrenchStamped(Header(stamp=k * 1e-3, tick=k, seq=k), Wrench(Vector3(1.0, 0, 0), Vector3(0, 0, 0)))
            bag.write("/ft/wrench", k * 1_000_000, k * 1_000_000, encode(msg))
    return path


@pytest.mark.parametrize("command", ["graph", "launch"])
def test_a_real_robot_never_moves_on_a_replayed_recording(command, tmp_path, write_launch):
    """robot:=modbus with ft:=bag: the driver's force limit and F/T watchdog would be fed by a file, and
    the command it follows computed from forces of another run; refused before anything starts."""
    bag = _ft_bag(tmp_path / "ft.mcap")
    code, _, err = run_main(command, "launch/hil.yaml", "robot:=modbus", "ft:=bag", f"ft_bag:={bag}")
    assert_one_line_refusal(code, err, "node 'robot' (robot_modbus) moves real hardware")
    assert "from 'ft' (bag_source), which replays a recording" in err and "input 'wrench' (/ft/wrench)" in err, err
    # a command that only depends on the recording, through other nodes, is refused as well
    scene = write_launch(
        "rate: 200\nduration: 1\nnodes:\n"
        "  - {name: ft, node: bag_source, params: {path: BAG, topics: [/ft/wrench]}}\n"
        "  - {name: dynamics, node: satellite_dynamics}\n"
        "  - {name: impedance, node: virtual_impedance}\n"
        "  - {name: robot, node: robot_modbus, remap: {wrench: /unused}}\n".replace("BAG", str(bag))
    )
    code, _, err = run_main(command, scene)
    assert_one_line_refusal(code, err, "input 'command' (/robot/command) depends on /ft/wrench")
    assert "from 'ft' (bag_source), which replays a recording" in err, err
    # replaying the sensor in front of the simulated robot stays possible
    if command == "graph":
        code, _, err = run_main("graph", "launch/hil.yaml", "ft:=bag", f"ft_bag:={bag}")
        assert code == 0, err


@pytest.mark.parametrize("command", ["graph", "launch"])
@pytest.mark.parametrize(
    "overrides, ticks", [(["delay:=0.9", "rate:=30000"], 27000), (["delay:=0.5", "rate:=100000"], 50000)]
)
def test_a_delay_of_more_ticks_than_the_scene_check_resolves_is_refused_at_once(command, overrides, ticks):
    """delay:=30 made the scene check build a 30000-tick polynomial: minutes and 11 GB before anything ran."""
    code, _, err = run_main(command, "launch/hil.yaml", *overrides, "--composed" if command == "launch" else "--dot")
    assert_one_line_refusal(code, err, f"is {ticks} ticks of delay")
    assert "the scene check resolves up to 20000" in err


def test_a_driver_beside_a_robot_emulator_commands_that_emulator_only():
    """emulators:=true with modbus_host:= another machine ran the emulator and drove the real robot there."""
    code, _, err = run_main("graph", "launch/hil.yaml", "robot:=modbus", "emulators:=true", "modbus_host:=192.0.2.10")
    assert_one_line_refusal(code, err, "node 'robot' (robot_modbus) commands the controller at 192.0.2.10:5020")
    assert "node 'robot_emulator' emulates one at 127.0.0.1:5020" in err, err
    code, _, err = run_main("graph", "launch/hil.yaml", "robot:=modbus", "emulators:=true", "modbus_port:=5999")
    assert code == 0, err  # both follow modbus_port
    code, _, err = run_main("graph", "launch/hil.yaml", "robot:=modbus", "emulators:=true", "modbus_host:=localhost")
    assert code == 0, err  # the same machine by another name
    code, _, err = run_main("graph", "launch/hil.yaml", "robot:=modbus", "modbus_host:=192.0.2.10")
    assert code == 0, err  # no emulator: the lab's controller


def test_a_run_that_writes_no_summary_leaves_no_earlier_one_behind(tmp_path):
    """A valid summary of an earlier run at --summary PATH, then a run refused by its scene check: what is at
    PATH afterwards must not say "valid" about a run that did not happen."""
    path = tmp_path / "s.json"
    assert (
        run_main("launch", "launch/ideal.yaml", "--composed", "--quiet", "--duration", "0.05", "--summary", path)[0]
        == 0
    )
    assert json.loads(path.read_text())["valid"] is True
    code, _, err = run_main("launch", "launch/hil.yaml", "rate:=2", "--composed", "--quiet", "--summary", path)
    assert_one_line_refusal(code, err, "refused: the step does not resolve the contact")
    assert not path.exists()


def test_rate_from_an_argument_sets_the_step(write_launch):
    path = write_launch(
        "rate: $(arg rate)\nduration: $(arg T)\nargs:\n  rate: {default: 1000.0}\n  T: {default: 0.5}\n"
        'nodes:\n  - {name: integ, node: "tests.support.graphnodes:Integrator"}\n'
        '  - {name: gain, node: "tests.support.graphnodes:Gain"}\n'
    )
    from dockhil.scene import launchfile

    scene = launchfile.load(path, {"rate": "250", "T": "2"})
    assert (scene.rate, scene.dt, scene.duration) == (250.0, 1 / 250, 2.0)
    assert launchfile.load(path).rate == 1000.0


def test_aliases_within_bounds_still_work(write_launch):
    path = write_launch(
        'nodes:\n  - {name: integ, node: "tests.support.graphnodes:Integrator"}\n'
        '  - {name: gain, node: "tests.support.graphnodes:Gain", params: &p {gain: 3.0}}\n'
        '  - {name: g2, node: "tests.support.graphnodes:Gain", params: *p, remap: {x: /u, u: /y}}\n'
    )
    from dockhil.scene import launchfile

    scene = launchfile.load(path)
    assert [n.params for n in scene.nodes[1:]] == [{"gain": 3.0}, {"gain": 3.0}]


def test_schema_is_printed_as_json_schema():
    import json

    code, out, _ = run_main("graph", "--schema")
    schema = json.loads(out)
    assert code == 0
    scene = schema["$defs"]["LaunchFile"]["properties"]
    assert scene["rate"]["maximum"] == 1e6 and scene["rate"]["minimum"] == 1e-3
    node = schema["$defs"]["NodeDecl"]["properties"]
    assert node["respawn_delay"]["minimum"] == 0 and node["respawn_delay"]["maximum"] == 600
    assert "if" in node and schema["$defs"]["NodeDecl"]["additionalProperties"] is False


def test_node_path_must_name_a_node_class(tmp_path, monkeypatch):
    from dockhil import node_types
    from dockhil.errors import LaunchError

    marker = tmp_path / "imported"
    (tmp_path / "sidefx_mod.py").write_text(
        f"open({str(marker)!r}, 'w').close()\n\ndef run():\n    pass\n\n\nclass Helper:\n    pass\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(LaunchError, match="module 'sidefx_mod' defines no class 'run'"):
        node_types.load("sidefx_mod:run")
    assert not marker.exists()  # refused from its source: the module was never imported
    with pytest.raises(LaunchError, match="Helper is not a dockhil node"):
        node_types.load("sidefx_mod:Helper")
    assert marker.exists()
    for path, words in [
        ("os:system", "system is not a dockhil node"),
        ("dockhil.node:Node", "Node is not a dockhil node"),
        ("a..b:X", "not of the form package.module:Class"),
        ("no_such_pkg.x:Y", "cannot import"),
    ]:
        with pytest.raises(LaunchError, match=words.replace(".", r"\.")):
            node_types.load(path)
    assert node_types.load("tests.support.graphnodes:Gain").__name__ == "Gain"


@pytest.mark.parametrize("error, words", [(RecursionError, "nested too deeply"), (MemoryError, "out of memory")])
def test_exhaustion_anywhere_is_one_line(monkeypatch, error, words):
    """Whatever check is missing, exhausting the stack or memory ends in one line, exit 2."""
    import dockhil.commands.graph as graph_command

    def exhaust(args):
        raise error()

    monkeypatch.setattr(graph_command, "run", exhaust)
    code, out, err = run_main("graph", "launch/hil.yaml")
    assert_one_line_refusal(code, err, words)
    assert out == ""


@pytest.mark.parametrize(
    "given, meant, what",
    [
        ("delay:=16", "delay:=0.016", "a robot delay is a few ms to a few hundred ms"),
        ("delay:=3", "delay:=0.003", "a robot delay is a few ms to a few hundred ms"),  # ran, 19 N off, no word
        ("lag:=20", "lag:=0.02", "a servo time constant is a few ms to a few hundred ms"),
    ],
)
@pytest.mark.parametrize("command", ["graph", "launch"])
def test_a_time_given_in_milliseconds_is_refused_naming_the_unit_and_the_value_in_seconds(command, given, meant, what):
    args = ("--dot",) if command == "graph" else ("--composed", "--duration", "0.01")
    code, _, err = run_main(command, "launch/hil.yaml", given, *args)
    seconds = given.split(":=")[1]
    assert_one_line_refusal(code, err, f"{given} is {seconds} s: {what}; did you mean {meant}?")


def test_a_time_in_a_launch_file_is_refused_naming_the_parameter_and_the_value_in_seconds(write_launch):
    scene = write_launch("nodes:\n  - {name: late, node: delay_injector, params: {delay: 0.01, jitter: 5}}\n")
    code, _, err = run_main("graph", scene, "--dot")
    assert_one_line_refusal(
        code,
        err,
        "node 'late' parameter 'jitter': 5 s is longer than 1 s: a robot delay is a few ms to a few "
        "hundred ms; did you mean 0.005?",
    )


def test_a_delay_of_a_second_still_runs_and_one_past_it_is_refused():
    code, _, err = run_main("graph", "launch/hil.yaml", "delay:=1", "--dot")
    assert code == 0, err
    code, _, err = run_main("graph", "launch/hil.yaml", "delay:=1.5", "--dot")
    assert_one_line_refusal(code, err, "delay:=1.5 is 1.5 s: a robot delay is a few ms to a few hundred ms")
