"""Fuzzing `dockhil graph` and `dockhil launch` with bad launch files and arguments.

Each generated case is a valid scene with one defect put in (a wrong type, a non-finite or huge
number, deep nesting, an unknown key, a bad node path, a bad `name:=value`), or a file of junk.
Every one must be refused: exit code 2, one line on stderr, no traceback, nothing on stdout.
The CLI runs in this process for speed; the cases that would take time or memory if unbounded
(an alias bomb, an include tree, deep nesting, a large file) run in a subprocess under a memory
limit and a timeout.
"""

from __future__ import annotations

import copy
import math
import re
import resource
import subprocess
import time

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import ROOT, dockhil_cmd
from tests.test_launch_refusals import run_main

BASE = {
    "description": "fuzz base scene",
    "rate": 1000,
    "duration": 0.05,
    "args": {"gain": {"default": 2.0, "help": "feedback gain"}, "use_trace": {"default": False}},
    "nodes": [
        {"name": "integ", "node": "tests.support.graphnodes:Integrator", "params": {"x0": 1.0}},
        {"name": "gain", "node": "tests.support.graphnodes:Gain", "params": {"gain": "$(arg gain)"}},
        {"name": "trace", "node": "tests.support.graphnodes:Trace", "if": "$(arg use_trace)"},
    ],
}
TOP_KEYS = {"description", "rate", "duration", "args", "let", "nodes", "group", "include"}
NODE_KEYS = {"name", "node", "params", "param", "remap", "max_age", "if", "unless", "respawn", "respawn_delay", "host"}
ARG_KEYS = {"default", "help", "choices", "type"}
PORTS = {"x", "u", "/x", "/u"}  # Integrator and Gain ports and their topics


class _Dumper(yaml.SafeDumper):
    """Quotes a string that the launch loader would read as a number (1e3), as it does `1.5`."""


_Dumper.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def dump(doc) -> str:
    return yaml.dump(doc, Dumper=_Dumper, sort_keys=False)


# --- values that no field of the mutated kind accepts ---------------------------------------------

non_finite = st.sampled_from([math.inf, -math.inf, math.nan])
words = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=12)
identifiers = st.tuples(
    st.sampled_from("abcdefghijklmnopqrstuvwxyz_"),
    st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_", max_size=10),
).map("".join)
# Any character but a lone surrogate (not text that a file can hold).
chars = st.characters(exclude_categories=["Cs"])
# Text: never an `$(arg` that could name a declared argument.
text = st.text(chars, max_size=30).filter(lambda s: "$(" not in s)
containers = st.one_of(st.lists(st.integers(), max_size=3), st.dictionaries(words, st.integers(), max_size=2))
not_a_number = st.one_of(text, st.booleans(), containers, st.none())
subnormal = st.floats(min_value=5e-324, max_value=2.2e-308, exclude_max=True)


def number_outside(low: float, high: float, low_open: bool = False):
    """Floats outside [low, high] ((low, high] with low_open), non-finite ones and non-numbers."""
    below = st.floats(max_value=low, exclude_max=not low_open, allow_nan=False)
    above = st.floats(min_value=high, exclude_min=True, allow_nan=False)
    return st.one_of(below, above, non_finite, not_a_number.filter(lambda v: v is not None))


@st.composite
def mutated_scene(draw) -> str | bytes:
    """YAML text of BASE with one defect (or bytes of junk)."""
    doc = copy.deepcopy(BASE)
    nodes = doc["nodes"]
    kind = draw(
        st.sampled_from(
            [
                "rate",
                "duration",
                "description",
                "top key",
                "node name",
                "node path",
                "respawn",
                "respawn_delay",
                "host",
                "remap",
                "condition",
                "node key",
                "unknown param",
                "param value",
                "deep params",
                "arg default",
                "arg choices",
                "arg type",
                "arg key",
                "arg name",
                "include",
                "alias bomb",
                "junk",
                "max_age",
                "let",
                "group",
                "remap list",
                "param list",
            ]
        )
    )
    i = draw(st.integers(0, 1))  # integ or gain: nodes that conditions keep
    if kind == "rate":
        doc["rate"] = draw(st.one_of(number_outside(1e-3, 1e6), st.none()))
    elif kind == "duration":
        doc["duration"] = draw(number_outside(0.0, 1e6, low_open=True))
    elif kind == "description":
        doc["description"] = draw(st.one_of(st.integers(), st.floats(), containers, st.booleans()))
    elif kind == "top key":
        doc[draw(identifiers.filter(lambda k: k not in TOP_KEYS))] = draw(st.integers())
    elif kind == "node name":
        nodes[i]["name"] = draw(
            st.one_of(
                st.integers(),
                containers,
                st.none(),
                st.just(""),
                st.text(min_size=65, max_size=80, alphabet="ab"),
                st.tuples(words, st.sampled_from("/ :\n*"), words).map("".join),
            )
        )
    elif kind == "node path":
        nodes[i]["node"] = draw(
            st.one_of(
                st.sampled_from(
                    [
                        "os:system",
                        "json:dumps",
                        "builtins:print",
                        "dockhil.node:Param",
                        "dockhil.node:Node",
                        "tests.support.graphnodes:Nope",
                        "no_such_pkg.mod:Node",
                        "tests.support.graphnodes:",
                        ":Gain",
                        "a..b:C",
                        "tests/support/graphnodes:Gain",
                    ]
                ),
                words.filter(
                    lambda w: (
                        w
                        not in (
                            "satellite_dynamics",
                            "virtual_impedance",
                            "ft_sim",
                            "robot_sim",
                            "delay_injector",
                            "ft_can",
                            "ft_emulator",
                            "robot_modbus",
                            "robot_emulator",
                            "bag_source",
                        )
                    )
                ),
                st.integers(),
                containers,
                st.none(),
            )
        )
    elif kind == "respawn":
        nodes[i]["respawn"] = draw(st.one_of(st.integers(), st.floats(), text, containers, st.none()))
    elif kind == "respawn_delay":
        nodes[i]["respawn_delay"] = draw(number_outside(0.0, 600.0))
    elif kind == "host":
        nodes[i]["host"] = draw(
            st.one_of(st.integers(), containers, st.tuples(words, st.sampled_from(" /:\n@"), words).map("".join))
        )
    elif kind == "remap":
        nodes[i]["remap"] = draw(
            st.one_of(
                st.integers(),
                text,
                st.lists(st.integers(), min_size=1, max_size=2),
                st.fixed_dictionaries({"x": st.one_of(st.integers(), st.booleans(), containers, st.floats())}),
                st.fixed_dictionaries({"x": words}),  # a topic without the leading /
                st.dictionaries(words.filter(lambda w: w not in PORTS), st.just("/y"), min_size=1, max_size=1),
            )
        )
    elif kind == "condition":
        bad = st.one_of(
            st.floats(),
            containers,
            text.filter(
                lambda s: "==" not in s and "!=" not in s and s.strip().lower() not in ("true", "false", "1", "0")
            ),
        )
        nodes[i][draw(st.sampled_from(["if", "unless"]))] = draw(bad)
    elif kind == "node key":
        nodes[i][draw(identifiers.filter(lambda k: k not in NODE_KEYS))] = draw(st.integers())
    elif kind == "unknown param":
        nodes[i]["params"] = {draw(identifiers.filter(lambda k: k not in ("x0", "gain", "die_at"))): 1.0}
    elif kind == "param value":
        bad = st.one_of(
            non_finite,
            text,
            st.booleans(),
            containers,
            st.none(),
            subnormal,
            st.integers(min_value=2**1024, max_value=2**1100),
        )
        name = "x0" if i == 0 else "gain"
        if i == 1:  # gain must also be >= 0
            bad = st.one_of(bad, st.floats(max_value=-1e-300, allow_infinity=False))
        nodes[i]["params"] = {name: draw(bad)}
    elif kind == "deep params":
        nodes[i]["params"] = {"x0": "__DEEP__"}
        depth = draw(st.integers(min_value=30, max_value=400))  # 20,000: in the subprocess cases below
        return dump(doc).replace("__DEEP__", "[" * depth + "]" * depth)
    elif kind == "arg default":
        doc["args"]["gain"]["default"] = draw(
            st.one_of(non_finite, containers, st.none(), st.integers(min_value=2**1024, max_value=2**1030))
        )
    elif kind == "arg choices":
        doc["args"]["gain"]["choices"] = draw(
            st.one_of(
                st.integers(),
                st.floats(allow_nan=False),
                text,
                st.dictionaries(words, st.integers(), max_size=2),
                st.lists(st.floats(allow_nan=False).filter(lambda v: v != 2.0), min_size=1, max_size=3),
                st.just([]),
            )
        )
    elif kind == "arg type":
        doc["args"]["gain"]["type"] = draw(
            st.one_of(text.filter(lambda s: s not in ("float", "int", "bool", "str")), st.integers(), containers)
        )
    elif kind == "arg key":
        doc["args"]["gain"][draw(identifiers.filter(lambda k: k not in ARG_KEYS))] = 1
    elif kind == "arg name":
        doc["args"][draw(st.one_of(st.integers(), st.tuples(words, st.sampled_from("- .$"), words).map("".join)))] = 1.0
    elif kind == "include":
        doc["include"] = draw(
            st.one_of(
                st.integers(),
                text,
                st.lists(
                    st.fixed_dictionaries({"file": st.one_of(words.map(lambda w: w + ".yaml"), text)}),
                    min_size=1,
                    max_size=2,
                ),
                st.just([{"file": "scene.yaml"}]),  # itself: a cycle
                st.just([{"args": {"a": 1}}]),
            )
        )
    elif kind == "alias bomb":
        fan = draw(st.integers(2, 10))
        levels = math.ceil(math.log(200_000) / math.log(fan))
        lines = ["a0: &a0 [" + ", ".join(["x"] * fan) + "]"]
        lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * fan) + "]" for k in range(1, levels + 1)]
        return "\n".join(lines) + "\n" + dump(doc)
    elif kind == "max_age":  # Integrator's input is u, Gain's x
        nodes[i]["max_age"] = draw(
            st.one_of(
                st.fixed_dictionaries({"u" if i == 0 else "x": number_outside(0.0, 600.0, low_open=True)}),
                st.dictionaries(
                    words.filter(lambda w: w != ("u" if i == 0 else "x")), st.just(0.05), min_size=1, max_size=1
                ),
                st.integers(),
                text,
                st.lists(st.integers(), max_size=2),
            )
        )
    elif kind == "let":
        doc["let"] = draw(
            st.one_of(
                st.integers(),
                text,
                st.just([{"name": "gain", "value": 1.0}]),  # an argument's name
                st.lists(
                    st.fixed_dictionaries(
                        {
                            "name": st.one_of(
                                st.integers(),
                                st.just(""),
                                st.tuples(words, st.sampled_from("- .$/"), words).map("".join),
                            ),
                            "value": st.integers(),
                        }
                    ),
                    min_size=1,
                    max_size=2,
                ),
                st.lists(
                    st.fixed_dictionaries({"name": identifiers, "value": st.one_of(containers, st.none())}),
                    min_size=1,
                    max_size=2,
                ),
                st.just([{"name": "a", "value": "$(var nope)"}]),
            )
        )
    elif kind == "group":
        doc["group"] = draw(
            st.one_of(
                st.integers(),
                text,
                st.lists(
                    st.fixed_dictionaries(
                        {
                            "namespace": st.one_of(
                                st.integers(),
                                containers,
                                st.just(""),
                                st.tuples(words, st.sampled_from("/ :.\n"), words).map("".join),
                            ),
                            "nodes": st.just([]),
                        }
                    ),
                    min_size=1,
                    max_size=1,
                ),
                st.just([{"namespace": "ns"}]),  # no nodes
                st.just([{"nodes": [], "scoped": True}]),
                st.just([{"nodes": [{"name": "integ", "node": "tests.support.graphnodes:Source"}]}]),
            )
        )  # a name twice
    elif kind == "remap list":
        nodes[i]["remap"] = draw(
            st.one_of(
                st.lists(
                    st.fixed_dictionaries(
                        {"from": st.sampled_from(["x", "u"]), "to": st.one_of(st.integers(), words, containers)}
                    ),
                    min_size=1,
                    max_size=2,
                ),
                st.lists(
                    st.fixed_dictionaries({"from": words.filter(lambda w: w not in PORTS), "to": st.just("/y")}),
                    min_size=1,
                    max_size=1,
                ),
                st.just([{"from": "x", "to": "/y"}, {"from": "x", "to": "/z"}]),
                st.just([{"from": "x"}]),
            )
        )
    elif kind == "param list":
        name = "x0" if i == 0 else "gain"
        nodes[i]["param"] = draw(
            st.one_of(
                st.just([{"name": name, "value": 1.0}]) if i == 0 else st.just([{"name": name, "value": 1.0}] * 2),
                st.lists(
                    st.fixed_dictionaries(
                        {
                            "name": st.one_of(
                                st.integers(),
                                st.just(""),
                                identifiers.filter(lambda k: k not in ("x0", "gain", "die_at")),
                            ),
                            "value": st.just(1.0),
                        }
                    ),
                    min_size=1,
                    max_size=1,
                ),
                st.just([{"name": name}]),
                st.integers(),
                text,
            )
        )
    elif kind == "junk":
        return draw(st.one_of(st.text(chars, max_size=200), st.binary(max_size=200)))
    return dump(doc)


bad_override = st.one_of(
    st.tuples(identifiers.filter(lambda k: k not in ("gain", "use_trace")), text).map(lambda t: f"{t[0]}:={t[1]}"),
    st.sampled_from(
        [
            "gain:=inf",
            "gain:=nan",
            "gain:=-inf",
            "gain:=1e999",
            "gain:=-1",
            "gain:=1e-320",
            "gain:=",
            "use_trace:=maybe",
            ":=3",
            "gain=3",
            "gain:=0x10",
        ]
    ),
    # With a character no finite decimal number has (float() takes spaces, _ and any script's digits).
    text.filter(lambda s: re.search(r"[^\s\d.eE+_-]", s) and not s.startswith("-")).map(lambda s: f"gain:={s}"),
    text.filter(lambda s: s.strip().lower() not in ("true", "false", "1", "0") and not s.startswith("-")).map(
        lambda s: f"use_trace:={s}"
    ),
)
good_override = st.sampled_from(["gain:=3.5", "use_trace:=false", "gain:=0"])

FUZZ = settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.filter_too_much],
)


def assert_refused(code, out, err):
    assert code == 2, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and lines[0].startswith("dockhil ") and " error: " in lines[0], err
    assert out == ""


def write(path, text: str | bytes) -> None:
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)


@pytest.fixture(scope="module")
def scene_path(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz") / "scene.yaml"


@FUZZ
@given(mutated_scene())
def test_graph_refuses_every_bad_launch_file(scene_path, text):
    write(scene_path, text)
    assert_refused(*run_main("graph", scene_path))


@settings(FUZZ, max_examples=150)
@given(st.lists(st.one_of(good_override, bad_override), max_size=2), bad_override, st.lists(good_override, max_size=1))
def test_graph_refuses_every_bad_argument(scene_path, before, bad, after):
    scene_path.write_text(dump(BASE))
    assert_refused(*run_main("graph", scene_path, *before, bad, *after))


@settings(FUZZ, max_examples=40)
@given(mutated_scene())
def test_launch_refuses_every_bad_launch_file_before_running(scene_path, text):
    write(scene_path, text)
    assert_refused(*run_main("launch", scene_path, "--duration", "0.01", "--composed", "--quiet"))


def _seconds_in_range(text: str) -> bool:
    try:
        value = float(text)
    except ValueError:
        return False
    return math.isfinite(value) and 0.0 < value <= 1e6


bad_seconds = st.one_of(st.floats().map(repr), st.integers().map(str), text).filter(
    lambda s: not s.startswith("-") and not _seconds_in_range(s)
)


@settings(FUZZ, max_examples=60)
@given(bad_seconds)
def test_launch_refuses_every_bad_duration_before_reading_the_file(scene_path, seconds):
    scene_path.write_text(dump(BASE))
    code, out, err = run_main("launch", scene_path, "--duration", seconds, "--composed", "--quiet")
    assert_refused(code, out, err)
    assert "argument --duration" in err


extreme = st.one_of(st.floats(), st.sampled_from([0.0, 5e-324, 1e-320, 1e-300, 1e-10, 1e10, 1e300, 1e308, -1.0]))


@settings(FUZZ, max_examples=60)
@given(
    st.dictionaries(
        st.sampled_from(["m1", "m2", "kcs", "bcs", "k", "v1", "v2", "t1", "t2", "dt"]), extreme, min_size=1, max_size=4
    ),
    st.sampled_from(["exact", "closed_form", "rk4", "euler", "symplectic_euler", "solve_ivp"]),
)
def test_params_answers_or_refuses_absurd_values_in_one_line(values, states):
    code, out, err = run_main("params", "--table1", "--states", states, *(f"--{k}={v!r}" for k, v in values.items()))
    assert code in (0, 2), err
    if code == 2:
        assert_refused(code, out, err)
    else:
        assert "fit and closed form" in out


def test_the_base_scene_is_valid(scene_path):
    """The fuzzed scenes are refused for their defect, not for something in the base."""
    scene_path.write_text(dump(BASE))
    code, out, err = run_main("graph", scene_path, "gain:=3.5", "use_trace:=true")
    assert code == 0 and err == "", err
    assert "nodes (3, in step order):" in out and "gain=3.5" in out


# --- bounded time and memory: a subprocess under a memory limit and a timeout ----------------------

MEMORY_LIMIT = 512 << 20  # bytes of address space; `dockhil graph` needs about a fifth of it


def _limited():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def _billion_laughs() -> str:
    """A classic 9-level alias bomb: about 500 bytes, 10**9 values expanded."""
    lines = ["a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for k in range(1, 9):
        prev, cur = chr(ord("a") + k - 1), chr(ord("a") + k)
        lines.append(f"{cur}: &{cur} [" + ", ".join([f"*{prev}"] * 10) + "]")
    return "\n".join(lines) + "\nnodes: *i\n"


BOUNDED = {
    "alias bomb": (_billion_laughs(), "expands to more than 100000 values"),
    "20000 nested [": ("nodes: " + "[" * 20000 + "\n", "nested deeper than 32 levels"),
    "200 nested mappings": ("".join(" " * k + f"k{k}:\n" for k in range(200)) + "\n", "nested deeper than 32 levels"),
    "2 MB file": ("description: " + "x" * (2 << 20) + "\n", "larger than 1048576 bytes"),
    "5000-digit number": ("rate: " + "9" * 5000 + "\n", "not valid YAML: Exceeds the limit"),
    "symlink loop": (
        "include: [{file: loop.yaml}]\n",
        "loop.yaml' cannot be opened: it is a symbolic link that leads back to itself",
    ),
    "NUL in a file name": ('include: [{file: "a\\x00b.yaml"}]\n', "cannot be opened: its name holds a NUL character"),
    "include cycle": ("include: [" + ", ".join(["{file: scene.yaml}"] * 2) + "]\n", "include cycle"),
}


@pytest.mark.parametrize("case", list(BOUNDED))
def test_expensive_inputs_are_refused_within_bounds(case, tmp_path):
    text, expected = BOUNDED[case]
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    (tmp_path / "loop.yaml").symlink_to("loop.yaml")
    started = time.monotonic()
    r = subprocess.run(
        dockhil_cmd("graph", path), cwd=ROOT, capture_output=True, text=True, timeout=120, preexec_fn=_limited
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert expected in lines[0], lines[0]
    print(f"{case}: refused in {time.monotonic() - started:.2f} s")  # for the record, not asserted


def test_an_include_fan_out_is_bounded(tmp_path):
    """Each file includes the next one twice, with different names: 2**12 files' worth of includes."""
    for k in range(12):
        child = f"f{k + 1}.yaml"
        (tmp_path / f"f{k}.yaml").write_text(
            "args: {p: {default: n}}\n"
            'nodes:\n  - {name: "$(arg p)", node: "tests.support.graphnodes:Source", remap: {x: "/$(arg p)"}}\n'
            f"include:\n  - {{file: {child}, args: {{p: $(arg p)a}}}}\n  - {{file: {child}, args: {{p: $(arg p)b}}}}\n"
        )
    (tmp_path / "f12.yaml").write_text("args: {p: {default: n}}\nnodes: []\n")
    r = subprocess.run(
        dockhil_cmd("graph", tmp_path / "f0.yaml"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=_limited,
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "more than 100 launch files read for one scene" in lines[0]


def test_arguments_that_double_through_includes_are_bounded(tmp_path):
    """Each file passes `$(arg p)$(arg p)` to the next: the text doubles at every include."""
    for k in range(40):
        (tmp_path / f"f{k}.yaml").write_text(
            f'args: {{p: {{default: ab}}}}\ninclude:\n  - {{file: f{k + 1}.yaml, args: {{p: "$(arg p)$(arg p)"}}}}\n'
        )
    (tmp_path / "f40.yaml").write_text(
        'args: {p: {default: ab}}\nnodes:\n  - {name: a, node: "tests.support.graphnodes:Source"}\n'
    )
    r = subprocess.run(
        dockhil_cmd("graph", tmp_path / "f0.yaml"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=_limited,
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "f15.yaml:3: include[0].args.p: is 131072 characters after $(arg ...) substitution" in lines[0]
