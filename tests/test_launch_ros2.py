"""Launch files a ROS 2 user can read: `$(var)`, `let`, `group` with a namespace, `remap` as
[{from, to}], `param` as [{name, value}]; a launch file's maximum age of an input; `dockhil graph`
drawing what runs and showing the scene check that `dockhil launch` applies."""

from __future__ import annotations

import re

import pytest
import zmq

from dockhil.errors import DockhilError, LaunchError
from dockhil.msgs import Header, Vector3, Wrench, WrenchStamped
from dockhil.msgs.codec import encode
from dockhil.node import ManualClock, default_max_age
from dockhil.runtime import validity
from dockhil.runtime.composed import ComposedGraph
from dockhil.runtime.executor import NodeExecutor, PortWire, RunSpec, StaleInput, Stop
from dockhil.runtime.plan import Endpoints, run_specs
from dockhil.runtime.transport import GraphKeys, Publisher
from dockhil.scene import launchfile
from dockhil.scene.graph import build
from tests.conftest import ROOT
from tests.test_launch_refusals import run_main

P = 1 / 1024  # a period that binary floating point adds up exactly

LOOP = """
args:
  gain: {default: 2.0, help: feedback gain}
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator", %s}
  - {name: gain, node: "tests.support.graphnodes:Gain", params: {gain: %s}}
"""


def graph_of(write_launch, text: str, *overrides: str):
    path = write_launch(text)
    return build(launchfile.load(str(path), launchfile.parse_overrides(list(overrides))))


def refusal(write_launch, text: str, *overrides: str) -> str:
    """The one line `dockhil graph` refuses `text` with (exit 2)."""
    path = write_launch(text)
    code, out, err = run_main("graph", path, *overrides)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and out == "" and "Traceback" not in err, (code, err)
    return lines[0].replace(str(path), "scene.yaml")


# -- $(var) and let ----------------------------------------------------------------------------


def test_var_and_arg_substitute_the_same_argument(write_launch):
    for form in ("$(arg gain)", "$(var gain)"):
        g = graph_of(write_launch, LOOP % ("params: {x0: 0.5}", form), "gain:=3.5")
        assert g.nodes["gain"].params["gain"] == 3.5  # standing alone: the argument's type
        g = graph_of(write_launch, LOOP % (f'host: "lab{form}"', "1.0"), "gain:=4")
        assert g.nodes["integ"].host == "lab4.0"  # inside a string: its text


def test_let_defines_variables_from_arguments_and_earlier_variables(write_launch):
    text = LOOP % ("params: {x0: $(var start)}", "$(var g)") + (
        "let:\n  - {name: g, value: $(var gain)}\n  - {name: start, value: $(var g)}\n"
        '  - {name: label, value: "gain $(var g)"}\n'
    )
    g = graph_of(write_launch, text, "gain:=1.25")
    assert g.nodes["gain"].params["gain"] == 1.25 and g.nodes["integ"].params["x0"] == 1.25
    assert g.scene.lets == {"g": 1.25, "start": 1.25, "label": "gain 1.25"}
    code, out, _ = run_main("graph", write_launch(text), "gain:=1.25")
    assert code == 0 and "let:\n  g = 1.25\n  start = 1.25\n  label = 'gain 1.25'\n" in out


def test_a_let_variable_is_not_set_on_the_command_line(write_launch):
    text = LOOP % ("params: {x0: 0.5}", "$(var g)") + "let:\n  - {name: g, value: $(var gain)}\n"
    assert refusal(write_launch, text, "g:=3") == (
        "dockhil graph: error: scene.yaml: 'g' is a `let` variable, made from the arguments: set those instead "
        "(known args: gain)"
    )
    assert "unknown arg 'gian'; did you mean 'gain'?" in refusal(write_launch, text, "gian:=3")


@pytest.mark.parametrize(
    "let, expected",
    [
        ("[{name: gain, value: 1.0}]", "scene.yaml:7: let[0].name: 'gain' is already an argument"),
        ("[{name: a, value: 1}, {name: a, value: 2}]", "scene.yaml:7: let[1].name: 'a' is already a variable defined"),
        (
            "[{name: a, value: $(var b)}, {name: b, value: 1}]",
            "scene.yaml:7: let[0].value: $(var b) is not declared in `args:` or `let:`",
        ),
        ("[{name: a, value: $(var gian)}]", "did you mean 'gain'?"),
        ("[{name: 1a, value: 1}]", "let[0].name: `name` must be a variable name"),
        ("[{name: a, value: [1, 2]}]", "scene.yaml:7: let[0].value: expected"),
        ("[{name: a}]", "scene.yaml:7: let[0]: `value` is required"),
        ("{a: 1}", "scene.yaml:7: let: expected a list, got {'a': 1}"),
        (
            "[" + ", ".join(f"{{name: v{i}, value: 1}}" for i in range(1001)) + "]",
            "scene.yaml:7: let: expected a list of length <= 1000, got",
        ),
    ],
)
def test_a_bad_let_is_refused_in_one_line_with_its_place(write_launch, let, expected):
    line = refusal(write_launch, LOOP % ("params: {x0: 0.5}", "1.0") + f"let: {let}\n")
    assert expected in line, line


# -- remap and param in either form ------------------------------------------------------------


def topics(g) -> dict:
    return {(n, p): r.topic for n, gn in g.nodes.items() for p, r in {**gn.inputs, **gn.outputs}.items()}


def test_remap_as_a_list_of_from_to_connects_as_the_mapping_does(write_launch):
    base = (
        'nodes:\n  - {name: s, node: "tests.support.graphnodes:Source", remap: %s}\n'
        '  - {name: k, node: "tests.support.graphnodes:Sink", remap: %s}\n'
    )
    as_map = graph_of(write_launch, base % ("{x: /a}", "{/x: /a, opt: /b}"))
    as_list = graph_of(write_launch, base % ("[{from: x, to: /a}]", "[{from: /x, to: /a}, {from: opt, to: /b}]"))
    assert topics(as_list) == topics(as_map) == {("s", "x"): "/a", ("k", "x"): "/a", ("k", "opt"): "/b"}


def test_param_as_a_list_of_name_value_sets_what_the_mapping_sets(write_launch):
    g = graph_of(write_launch, LOOP % ("param: [{name: x0, value: 0.75}]", "1.5"))
    h = graph_of(write_launch, LOOP % ("params: [{name: x0, value: 0.75}]", "1.5"))
    assert g.nodes["integ"].params["x0"] == h.nodes["integ"].params["x0"] == 0.75


@pytest.mark.parametrize(
    "field, expected",
    [
        (
            "remap: [{from: u, to: /a}, {from: u, to: /b}]",
            "scene.yaml:5: nodes[0].remap[1].from: 'u' is remapped twice",
        ),
        ("remap: [{from: u}]", "scene.yaml:5: nodes[0].remap[0]: `to` is required"),
        ("remap: [{frm: u, to: /a}]", "nodes[0].remap[0].frm: unknown key 'frm'; did you mean 'from'?"),
        ("remap: [{from: u, to: 3}]", "nodes[0].remap[0].to: expected text, got 3"),
        ("remap: [3]", "nodes[0].remap[0]: expected a mapping, got 3"),
        ("remap: [{from: u, to: a}]", "topic 'a' of port 'u' must start with /"),
        (
            "remap: [{from: uu, to: /a}]",
            "remap 'uu' names no port or topic of tests.support.graphnodes:Integrator; did you mean 'u'? ports: u, x",
        ),
        ("params: {x0: 1.0}, param: [{name: x0, value: 2.0}]", "nodes[0].param[0].name: parameter 'x0' is given twice"),
        ("param: [{name: x0, value: 1.0}, {name: x0, value: 2.0}]", "nodes[0].param[1].name: parameter 'x0' is given"),
        ("param: [{nme: x0, value: 1.0}]", "nodes[0].param[0].nme: unknown key 'nme'; did you mean 'name'?"),
        ("param: [{name: x9, value: 1.0}]", "unknown parameter 'x9'"),
    ],
)
def test_a_bad_remap_or_param_list_is_refused_with_its_place(write_launch, field, expected):
    line = refusal(write_launch, LOOP % (field, "1.0"))
    assert expected in line, line


# -- groups ------------------------------------------------------------------------------------

GROUPS = """
args:
  right: {default: false}
group:
  - namespace: left
    nodes:
      - {name: src, node: "tests.support.graphnodes:Source"}
      - {name: sink, node: "tests.support.graphnodes:Sink", remap: [{from: opt, to: /shared}]}
  - namespace: /right
    if: $(var right)
    nodes:
      - {name: src, node: "tests.support.graphnodes:Source"}
      - {name: sink, node: "tests.support.graphnodes:Sink", remap: [{from: opt, to: /shared}]}
nodes:
  - {name: shared, node: "tests.support.graphnodes:Source", remap: {x: /shared}}
"""


def test_a_group_namespace_prefixes_names_and_default_topics_but_not_remaps(write_launch):
    g = graph_of(write_launch, GROUPS, "right:=true")
    assert sorted(g.nodes) == ["left.sink", "left.src", "right.sink", "right.src", "shared"]
    assert topics(g) == {
        ("left.src", "x"): "/left/x",
        ("left.sink", "x"): "/left/x",
        ("left.sink", "opt"): "/shared",
        ("right.src", "x"): "/right/x",
        ("right.sink", "x"): "/right/x",
        ("right.sink", "opt"): "/shared",
        ("shared", "x"): "/shared",
    }
    # Each copy connects within its namespace; both read the one shared topic.
    assert {r.node for r in g.subscribers["/left/x"]} == {"left.sink"}
    assert {r.node for r in g.subscribers["/shared"]} == {"left.sink", "right.sink"}


def test_a_group_condition_leaves_out_its_nodes_and_says_why(write_launch):
    g = graph_of(write_launch, GROUPS)
    assert sorted(g.nodes) == ["left.sink", "left.src", "shared"]
    assert [(s.name, s.reason) for s in g.scene.skipped] == [
        ("right.src", "group if: $(var right) is false"),
        ("right.sink", "group if: $(var right) is false"),
    ]


@pytest.mark.parametrize(
    "group, expected",
    [
        ("[{namespace: a/b, nodes: []}]", "scene.yaml:3: group[0].namespace: `namespace` must be a namespace"),
        ("[{namespace: a}]", "scene.yaml:3: group[0]: `nodes` is required"),
        ("[{namespace: a, nodes: [], scoped: true}]", "group[0].scoped: unknown key 'scoped'"),
        (
            "[{namespace: a, nodes: [{name: s, node: 'tests.support.graphnodes:Source', remap: {x: /y}}]},"
            " {namespace: a, nodes: [{name: s, node: 'tests.support.graphnodes:Sink'}]}]",
            "two nodes are named 'a.s'",
        ),
        (
            "[{namespace: "
            + "n" * 32
            + ", nodes: [{name: "
            + "s" * 40
            + ", node: 'tests.support.graphnodes:Source'}]}]",
            "group[0].nodes[0].name: the name in its namespace, "
            + repr("n" * 32 + "." + "s" * 40)
            + ", is 73 characters; at most 64",
        ),
    ],
)
def test_a_bad_group_is_refused_with_its_place(write_launch, group, expected):
    line = refusal(write_launch, f"description: groups\nrate: 1000\ngroup: {group}\n")
    assert expected in line, line


# -- dockhil graph --dot ------------------------------------------------------------------------


def dot_nodes(dot: str) -> dict[str, list[str]]:
    """Every node statement's id -> its attribute lists (a node declared twice shows twice)."""
    out: dict[str, list[str]] = {}
    for m in re.finditer(r'^  "([^"]+)" \[(.*)\];$', dot, re.M):
        out.setdefault(m.group(1), []).append(m.group(2))
    return out


def test_dot_draws_the_running_robot_and_ft_as_running_beside_what_was_left_out():
    code, dot, err = run_main("graph", ROOT / "launch" / "hil.yaml", "--dot")
    assert code == 0, err
    g = build(launchfile.load(str(ROOT / "launch" / "hil.yaml")))
    left_out = [s.name for s in g.scene.skipped]
    assert "robot" in left_out and "ft" in left_out  # hil.yaml's other robot and sensor kinds
    decl = dot_nodes(dot)
    for name in g.nodes:  # declared once, not dotted
        assert len(decl[name]) == 1 and "dotted" not in decl[name][0], (name, decl.get(name))
    dotted = [a for attrs in decl.values() for a in attrs if "dotted" in a]
    assert sorted(re.search(r'label="(.*)\\n\(left out\)"', a).group(1) for a in dotted) == sorted(left_out)


# -- max_age per input ---------------------------------------------------------------------------


@pytest.mark.parametrize("given, expected", [("{u: 0.05}", 0.05), ("{u: 2}", 2.0), ("{u: 600}", 600.0)])
def test_max_age_reaches_the_node_process_spec_and_its_limit(write_launch, tmp_path, given, expected):
    g = graph_of(write_launch, LOOP % (f"max_age: {given}", "1.0"))
    assert g.nodes["integ"].inputs["u"].max_age == expected and g.nodes["gain"].inputs["x"].max_age is None
    types = {"/x": "dockhil/WrenchStamped", "/u": "dockhil/WrenchStamped"}
    ep = Endpoints(
        "r",
        tmp_path,
        {t: f"ipc://{tmp_path}/{t[1:]}" for t in types},
        types,
        {t: f"ipc://{tmp_path}/{t[1:]}" for t in types},
    )
    specs = run_specs(g, ep, "wall", None, [])
    assert specs["integ"].inputs["u"].max_age == expected and specs["gain"].inputs["x"].max_age is None
    assert g.wall_max_ages() == {"integ.u": expected, "gain.x": default_max_age(g.scene.dt)}
    code, out, _ = run_main("graph", write_launch(LOOP % (f"max_age: {given}", "1.0")))
    assert code == 0 and re.search(rf"in  u: /u .*, max_age {expected:g} s$", out, re.M), out


@pytest.mark.parametrize(
    "given, expected",
    [
        (
            "{uu: 0.05}",
            "node 'integ': max_age 'uu' names no input of tests.support.graphnodes:Integrator; did you mean 'u'? inputs: u",
        ),
        ("{u: 0}", "scene.yaml:5: nodes[0].max_age.u: expected a number > 0.0, got 0"),
        ("{u: -1}", "nodes[0].max_age.u: expected a number > 0.0, got -1"),
        ("{u: .inf}", "nodes[0].max_age.u: expected a number <= 600.0, got inf"),
        ("{u: .nan}", "nodes[0].max_age.u: expected a number > 0.0, got nan"),
        ("{u: 601}", "nodes[0].max_age.u: expected a number <= 600.0, got 601"),
        ("{u: soon}", "nodes[0].max_age.u: expected a number, got 'soon'"),
        ("{u: true}", "nodes[0].max_age.u: expected a number, got True"),
        ("0.05", "nodes[0].max_age: expected a mapping, got 0.05"),
    ],
)
def test_a_bad_max_age_is_refused_in_one_line(write_launch, given, expected):
    line = refusal(write_launch, LOOP % (f"max_age: {given}", "1.0"))
    assert expected in line, line


def test_max_age_on_an_input_from_a_respawned_node_is_refused(write_launch):
    text = (LOOP % ("max_age: {u: 0.5}", "1.0")).replace("params: {gain: 1.0}", "respawn: true")
    assert "respawn: true" in text
    line = refusal(write_launch, text)
    assert line.endswith(
        "node 'integ' input 'u' has max_age 0.5 s but reads /u from 'gain', which respawns "
        "(and may pause): drop one of the two"
    ), line


def test_a_launch_max_age_stops_the_node_when_its_input_is_older(tmp_path):
    """/x is published until 50 P and then no more. The launch file's max_age 0.05 s (51.2 P) is met
    first at tick 102 (52 P old), well before the node's own 0.1 s (102.4 P: tick 153)."""
    ctx = zmq.Context()
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
                assert ex.sub.sock.poll(5000), "the message did not arrive"

    clock = Upstream()
    spec = RunSpec(
        "follow",
        "tests.support.faultnodes:Follow",
        {},
        P,
        "wall",
        inputs={"x": PortWire("/x", endpoint, "dockhil/WrenchStamped", max_age=0.05)},
    )
    spec.key_file = str(keys.write(tmp_path / "graph.keys"))
    from tests.support.faultnodes import Follow

    ex = NodeExecutor(spec, Follow, Stop(), log=lambda line: None, clock=clock)
    ex.start()
    try:
        pub.wait_subscribers(1, 10.0)
        with pytest.raises(StaleInput) as err:
            ex.run_wall(None)
        assert str(err.value) == ("node 'follow': input 'x' (/x) is 0.051 s old > max_age 0.05 s; stopping")
        assert clock() == 102 * P and sent[-1] == 50 * P
        assert isinstance(err.value, DockhilError)
    finally:
        ex.close()
        pub.close()
        ctx.term()


def test_the_composed_loop_is_judged_on_the_tightest_launch_max_age(write_launch):
    """One loop; tick 50 stalls 64 P, so tick 51 starts 63 P = 0.0615 s late: within the default
    0.1 s, past the launch file's 0.05 s."""
    text = (
        "rate: 1024\nnodes:\n  - {name: source, node: 'tests.support.faultnodes:Hiccup', "
        "params: {at: 50, seconds: 0.0625}}\n  - {name: follow, node: 'tests.support.faultnodes:Follow'%s}\n"
    )
    reports = []
    for extra in ("", ", max_age: {x: 0.05}"):
        clock = ManualClock()
        g = ComposedGraph(graph_of(write_launch, text % extra), sim_time=False, log=lambda n, m: None, clock=clock)
        g.setup()
        try:
            assert g.run(1024, wall=True) == 1024
        finally:
            g.close()
        reports.append(g.timing.report("composed"))
    assert reports[0]["worst_late_s"] == reports[1]["worst_late_s"] == 63 * P
    assert validity.node_reasons(reports[0], P) == []
    assert validity.node_reasons(reports[1], P) == ["node 'composed': a tick started 0.062 s late (> 0.05 s)"]


# -- dockhil graph runs the scene check --------------------------------------------------------------


def test_graph_refuses_a_scene_as_launch_does_with_the_same_line():
    hil = ROOT / "launch" / "hil.yaml"
    g_code, g_out, g_err = run_main("graph", hil, "rate:=100")
    l_code, l_out, l_err = run_main("launch", hil, "rate:=100", "--composed", "--quiet", "--duration", "0.01")
    assert g_code == l_code == 2 and g_out == ""
    assert len(g_err.strip().splitlines()) == 1 and "refused: " in g_err
    assert g_err.replace("dockhil graph", "dockhil launch") == l_err


def test_graph_shows_the_scene_checks_warnings_and_still_draws():
    code, out, err = run_main("graph", ROOT / "launch" / "stability.yaml")
    assert code == 0 and "nodes (" in out
    warnings = err.strip().splitlines()
    assert warnings and all(w.startswith("[graph] warning: ") for w in warnings)
    assert any("the loop is unstable" in w for w in warnings), err


def test_the_schema_describes_the_ros2_forms():
    import json

    code, out, _ = run_main("graph", "--schema")
    schema = json.loads(out)
    node = schema["$defs"]["NodeDecl"]["properties"]
    assert {"max_age", "param", "params", "remap"} <= set(node)
    assert {"let", "group"} <= set(schema["$defs"]["LaunchFile"]["properties"])
    assert schema["$defs"]["RemapDecl"]["required"] == ["from", "to"]


def test_load_refuses_through_the_launch_error_type(write_launch):
    with pytest.raises(LaunchError):
        launchfile.load(str(write_launch(LOOP % ("max_age: {u: 0}", "1.0"))))


# -- bounds --------------------------------------------------------------------------------------


def _many_copies(kind: str) -> str:
    """A file of about 0.5 MB whose substitutions would build about 1 GB of text: an argument of
    60,000 characters repeated inside 15,000 parameter strings, or 1,000 `let` variables."""
    head = "args:\n  p: {default: " + "a" * 60000 + "}\n"
    if kind == "params":
        return head + (
            'nodes:\n  - name: a\n    node: "tests.support.graphnodes:Source"\n    params:\n'
            + "".join(f'      k{i}: "x$(arg p)"\n' for i in range(15000))
        )
    return head + "let:\n" + "".join(f'  - {{name: v{i}, value: "x$(var p)"}}\n' for i in range(1000))


@pytest.mark.parametrize("kind, where", [("params", "nodes[0].params.k{}"), ("let", "let[{}].value")])
def test_substitution_that_repeats_a_long_argument_is_bounded(kind, where, tmp_path):
    import subprocess

    from tests.conftest import dockhil_cmd
    from tests.test_fuzz_launch import _limited

    path = tmp_path / "scene.yaml"
    path.write_text(_many_copies(kind))
    r = subprocess.run(
        dockhil_cmd("graph", path), cwd=ROOT, capture_output=True, text=True, timeout=120, preexec_fn=_limited
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    # The copy (of 60,001 characters) that takes the total past 4 * 2**20 characters is refused.
    first_over = (4 << 20) // 60001
    assert (
        f": {where.format(first_over)}: substitution builds more than {4 << 20} characters for one scene" in lines[0]
    ), lines[0]
