"""What a first run shows: the real-time factor counts the run's ticks (not the start-up), the summary's
temporary bag says nothing at info level, a wall-time input's max_age is set from the command line,
`dockhil --version` says which arithmetic runs, and the README's first screen says what to do."""

from __future__ import annotations

import json
import math
import time

import pytest

from dockhil import session
from dockhil.node import ManualClock
from dockhil.runtime.executor import NodeExecutor, RunSpec, Stop
from tests.conftest import ROOT
from tests.support.faultnodes import Hiccup
from tests.support.inprocess import run_main

P = 1 / 1024  # a period that binary floating point adds up exactly


# -- the real-time factor counts from the first tick ------------------------------------------


def test_the_ticking_span_runs_from_the_graphs_first_tick_to_its_last():
    timings = {
        "dynamics": {"first_tick_at_s": 100.5, "last_tick_at_s": 108.5},
        "robot": {"first_tick_at_s": 100.6, "last_tick_at_s": 108.4},
        "ft": {"first_tick_at_s": 97.0, "last_tick_at_s": 108.6},  # an emulated device: ticks before the go
        "remote": {"first_tick_at_s": None, "last_tick_at_s": 108.0},
    }  # stopped before its first tick
    assert session.ticking_span(timings, {"ft"}) == pytest.approx(8.0)
    assert session.ticking_span(timings) == pytest.approx(11.6)
    assert session.ticking_span({"ft": timings["ft"]}, {"ft"}) == pytest.approx(11.6)  # devices alone: theirs
    assert session.ticking_span({}) is None and session.ticking_span({"remote": timings["remote"]}) is None


def test_a_wall_time_loop_reports_its_first_and_last_tick_on_its_own_clock():
    clock = ManualClock(50.0)
    spec = RunSpec("n", "tests.support.faultnodes:Hiccup", {"at": 10, "seconds": 0.0}, P, "wall")
    ex = NodeExecutor(spec, Hiccup, Stop(), log=lambda line: None, clock=clock)
    ex.start()
    clock.advance(3.0)  # a slow start-up: not part of the loop
    try:
        report = ex.run_wall(256 * P)
    finally:
        ex.close()
    assert report["ticks"] == 256
    assert report["last_tick_at_s"] - report["first_tick_at_s"] == pytest.approx(256 * P, abs=1e-6)


def test_a_composed_summary_counts_the_ticks_not_the_set_up(monkeypatch, tmp_path):
    """On a clock the test moves: set-up takes 40 s, the ticks 2 s; the summary says 2 s."""
    from dockhil.runtime.composed import ComposedGraph

    now = [1000.0]
    monkeypatch.setattr(time, "perf_counter", lambda: now[0])
    setup, run = ComposedGraph.setup, ComposedGraph.run

    def slow_setup(self, *a, **kw):
        now[0] += 40.0
        return setup(self, *a, **kw)

    def timed_run(self, *a, **kw):
        done = run(self, *a, **kw)
        now[0] += 2.0
        return done

    monkeypatch.setattr(ComposedGraph, "setup", slow_setup)
    monkeypatch.setattr(ComposedGraph, "run", timed_run)
    out = tmp_path / "s.json"
    code, stdout, err = run_main("launch", "ideal.yaml", "--composed", "--duration", "0.5", "--summary", out)
    assert code == 0, err
    summary = json.loads(out.read_text())
    assert summary["run_time_s"] == 2.0 and summary["sim_time_s"] == pytest.approx(0.5)
    assert stdout.splitlines()[0] == "simulated 0.5 s in 2.00 s (0.2x real time)"


def test_a_multi_process_run_counts_its_ticks_and_keeps_its_temporary_bag_quiet(tmp_path):
    out = tmp_path / "s.json"
    started = time.perf_counter()
    code, _, err = run_main("launch", "ideal.yaml", "--duration", "0.05", "--summary", out)
    total = time.perf_counter() - started
    assert code == 0, err
    # Starting the node and recorder processes takes most of the call (imports alone: 0.3 CPU-s);
    # 51 ticks of the ideal contact, a few milliseconds.
    run_time = json.loads(out.read_text())["run_time_s"]
    assert 0 < run_time < total / 2, (run_time, total)
    assert "dockhil-summary-" not in err and "recording" not in err and "recorded" not in err
    code, _, err = run_main("launch", "ideal.yaml", "--duration", "0.05", "--log-level", "debug")
    assert code == 0, err
    assert "[bag-recorder] debug: recording 2 topics to " in err
    assert "[bag-recorder] debug: recorded 102 messages on 2 topics to " in err


def test_a_bag_kept_only_for_the_summary_records_what_the_summary_reads(tmp_path):
    """Less for a recorder on a busy machine to keep up with; a bag asked for records every topic."""
    from dockhil.analysis.summary import SUMMARY_TOPICS
    from dockhil.bags.live import recorder_process

    graph = _hil_graph()
    kept = recorder_process("run.mcap", graph, "wall", None, quiet=True, topics=SUMMARY_TOPICS)
    assert set(kept.topics) == set(SUMMARY_TOPICS) < set(graph.publishers)  # /robot/state is left out
    assert kept.argv[kept.argv.index("--topics") + 1 :][: len(kept.topics)] == kept.topics
    asked = recorder_process("run.mcap", graph, "wall", None)
    assert asked.topics == list(graph.publishers) and "--topics" not in asked.argv
    out = tmp_path / "s.json"
    code, _, err = run_main("launch", "hil.yaml", "--duration", "0.05", "--log-level", "debug", "--summary", out)
    assert code == 0, err
    assert f"[bag-recorder] debug: recording {len(kept.topics)} topics to " in err
    assert json.loads(out.read_text())["valid"] is True  # the summary has what it reads


# -- --max-age NODE.INPUT=SECONDS ---------------------------------------------------------------


def _hil_graph():
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    return build(launchfile.load(ROOT / "launch" / "hil.yaml"))


def test_max_age_from_the_command_line_reaches_each_node_process_and_the_composed_loop(tmp_path):
    import msgspec

    from dockhil.node import default_max_age
    from dockhil.runtime.plan import Endpoints, run_specs
    from dockhil.runtime.transport import GraphKeys
    from dockhil.scene.graph import set_max_ages

    graph = _hil_graph()
    set_max_ages(graph, [("dynamics", "ft", 0.05), ("robot", "command", math.inf)])
    ages = graph.wall_max_ages()
    assert ages["dynamics.ft"] == 0.05 and ages["robot.command"] == math.inf
    assert ages["dynamics.impedance"] == default_max_age(graph.scene.dt)  # the others keep theirs
    types = {t: "t" for t in graph.publishers}
    ends = {t: f"ipc://{tmp_path}/{t.strip('/').replace('/', '.')}" for t in types}
    keys = GraphKeys.make().write(tmp_path / "graph.keys")
    specs = run_specs(graph, Endpoints("r", tmp_path, ends, types, ends, keys), "wall", None, [])
    # As a node process reads its spec: JSON, which has no infinity (NodeExecutor takes
    # unlimited_age as no limit and max_age over the node's own: tests/test_launch_ros2.py).
    dyn, robot = (msgspec.json.decode(msgspec.json.encode(specs[n]), type=RunSpec) for n in ("dynamics", "robot"))
    assert dyn.inputs["ft"].max_age == 0.05 and not dyn.inputs["ft"].unlimited_age
    assert dyn.inputs["impedance"].max_age is None and not dyn.inputs["impedance"].unlimited_age
    assert robot.inputs["command"].unlimited_age and robot.inputs["command"].max_age is None


@pytest.mark.parametrize(
    "given, line",
    [
        (
            "dynamics.ft=0",
            "argument --max-age: 'dynamics.ft=0': the maximum age must be > 0 and at most 600 s, or inf for no limit",
        ),
        ("dynamics.ft=-inf", "the maximum age must be > 0 and at most 600 s, or inf for no limit"),
        ("dynamics.ft=nan", "the maximum age must be > 0 and at most 600 s, or inf for no limit"),
        ("dynamics.ft=601", "the maximum age must be > 0 and at most 600 s, or inf for no limit"),
        ("dynamics.ft=soon", "'soon' is not a number of seconds (or inf for no limit)"),
        ("dynamics=0.1", "'dynamics=0.1' is not NODE.INPUT=SECONDS"),
        ("dynamics.ft", "'dynamics.ft' is not NODE.INPUT=SECONDS"),
        (
            "dynamic.ft=0.1",
            "hil.yaml has no node 'dynamic'; did you mean 'dynamics'? (nodes: delay, dynamics, ft, impedance, robot)",
        ),
        (
            "dynamics.fts=0.1",
            "--max-age dynamics.fts: node 'dynamics' (satellite_dynamics) has no input 'fts'; "
            "did you mean 'ft'? (inputs: ft, impedance)",
        ),
    ],
)
def test_a_bad_max_age_is_one_line_and_exit_2_before_anything_runs(given, line):
    code, out, err = run_main("launch", "hil.yaml", "--wall-time", "--duration", "1", "--max-age", given)
    assert code == 2 and line in err and len(err.strip().splitlines()) == 1, err
    assert out == ""


def test_a_node_name_may_hold_dots_and_the_input_is_after_the_last():
    from dockhil.argtypes import max_age_setting

    assert max_age_setting("arm.left.wrench=inf") == ("arm.left", "wrench", math.inf)
    assert max_age_setting("dynamics.ft=0.25") == ("dynamics", "ft", 0.25)


RESPAWNED = """
nodes:
  - {name: sink, node: "tests.support.graphnodes:Integrator"}
  - {name: src, node: "tests.support.graphnodes:Gain", respawn: true}
"""


def test_a_finite_max_age_on_a_respawned_publisher_is_refused_and_no_limit_is_not(write_launch):
    from dockhil.errors import LaunchError
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build, set_max_ages

    path = write_launch(RESPAWNED)
    graph = build(launchfile.load(path))
    with pytest.raises(
        LaunchError,
        match=r"--max-age sink.u: node 'sink' input 'u' has max_age 0.5 s but reads "
        r"/u from 'src', which respawns",
    ):
        set_max_ages(graph, [("sink", "u", 0.5)])
    graph = build(launchfile.load(path))
    set_max_ages(graph, [("sink", "u", math.inf)])
    assert graph.nodes["sink"].inputs["u"].max_age == math.inf


def test_dockhil_run_takes_max_age_for_its_own_node(monkeypatch, tmp_path):
    from dockhil.runtime import process, registry
    from dockhil.runtime.transport import GraphKeys

    keys = GraphKeys.make().write(tmp_path / "graph.keys")
    graph = {
        "run_id": "g",
        "pid": 1,
        "keys": str(keys),
        "topics": {
            "/robot/command": {
                "type": "dockhil/RobotCommand",
                "endpoint": f"ipc://{tmp_path}/c",
                "publisher": "dynamics",
            }
        },
    }
    monkeypatch.setattr(registry, "running_graphs", lambda: [graph])
    monkeypatch.setattr(registry, "registry_dir", lambda: tmp_path)
    ran = []
    monkeypatch.setattr(process, "run_node", lambda spec: ran.append(spec) or 0)
    assert run_main("run", "robot_sim", "--max-age", "robot_sim.command=0.3")[0] == 0
    assert run_main("run", "robot_sim", "--name", "arm", "--max-age", "arm.command=inf")[0] == 0
    assert ran[0].inputs["command"].max_age == 0.3 and not ran[0].inputs["command"].unlimited_age
    assert ran[1].inputs["command"].unlimited_age
    code, _, err = run_main("run", "robot_sim", "--max-age", "robot.command=0.3")
    assert (
        code == 2
        and "--max-age robot.command: the node run here is 'robot_sim'; give --max-age robot_sim.command=SECONDS" in err
    )
    code, _, err = run_main("run", "robot_sim", "--max-age", "robot_sim.comand=0.3")
    assert code == 2 and "node 'robot_sim' (robot_sim) has no input 'comand'; did you mean 'command'?" in err
    assert len(ran) == 2


# -- dockhil --version names the arithmetic that runs --------------------------------------------


def _imports(monkeypatch, built: set[str]):
    """The compiled modules importable: only those in `built` (as after an install without them)."""
    import importlib

    from dockhil import compiled

    real = importlib.import_module

    def import_module(name, *a):
        if name in compiled.TWINS and name not in built:
            raise ImportError(f"No module named {name!r}")
        return real(name, *a)

    monkeypatch.setattr(compiled.importlib, "import_module", import_module)


@pytest.mark.parametrize(
    "built, pure, says",
    [
        ({"dockhil.contact._rigid", "dockhil.runtime._screen"}, "", "compiled: rigid-body arithmetic, message screen"),
        ({"dockhil.contact._rigid", "dockhil.runtime._screen"}, "1", "pure Python: DOCKHIL_PURE_PYTHON is set"),
        (set(), "", "pure Python: the C twins were not built; install a C compiler and reinstall for speed"),
        ({"dockhil.runtime._screen"}, "", "compiled: message screen; pure Python: rigid-body arithmetic (not built)"),
    ],
)
def test_version_names_the_compiled_or_pure_python_path(monkeypatch, built, pure, says):
    import importlib.util

    from dockhil import __version__

    if not all(importlib.util.find_spec(m) for m in built):
        pytest.skip("the C twins were not built here")
    monkeypatch.setenv("DOCKHIL_PURE_PYTHON", pure)
    _imports(monkeypatch, built)
    code, out, _ = run_main("--version")
    assert code == 0 and out == f"dockhil {__version__} ({says})\n"


def test_a_twin_not_named_in_one_place_is_refused():
    from dockhil.compiled import twin

    with pytest.raises(ValueError, match="dockhil.contact._other is not a compiled twin"):
        twin("dockhil.contact._other")


def test_max_age_in_sim_time_runs_and_says_it_applies_in_wall_time_only():
    code, _, err = run_main(
        "launch", "hil.yaml", "--composed", "--duration", "0.01", "--quiet", "--max-age", "dynamics.ft=0.05"
    )
    assert code == 0, err
    assert "[launch] warning: --max-age applies in wall time only (--wall-time); sim time is lock-step" in err
