"""What a first run shows: the real-time factor counts the run's ticks (not the start-up), the summary's
temporary bag says nothing at info level, a wall-time input's max_age is set from the command line,
`dockhil --version` says which arithmetic runs, and the README's first screen says what to do."""

from __future__ import annotations

import json
import time

import pytest

from dockhil import session
from dockhil.node import ManualClock
from dockhil.runtime.executor import NodeExecutor, RunSpec, Stop
from tests.faultnodes import Hiccup
from tests.inprocess import run_main

P = 1 / 1024  # a period that binary floating point adds up exactly


# -- the real-time factor counts from the first tick ------------------------------------------


def test_the_ticking_span_runs_from_the_graphs_first_tick_to_its_last():
    timings = {"dynamics": {"first_tick_at_s": 100.5, "last_tick_at_s": 108.5},
               "robot": {"first_tick_at_s": 100.6, "last_tick_at_s": 108.4},
               "ft": {"first_tick_at_s": 97.0, "last_tick_at_s": 108.6},  # an emulated device: ticks before the go
               "remote": {"first_tick_at_s": None, "last_tick_at_s": 108.0}}  # stopped before its first tick
    assert session.ticking_span(timings, {"ft"}) == pytest.approx(8.0)
    assert session.ticking_span(timings) == pytest.approx(11.6)
    assert session.ticking_span({"ft": timings["ft"]}, {"ft"}) == pytest.approx(11.6)  # devices alone: theirs
    assert session.ticking_span({}) is None and session.ticking_span({"remote": timings["remote"]}) is None


def test_a_wall_time_loop_reports_its_first_and_last_tick_on_its_own_clock():
    clock = ManualClock(50.0)
    spec = RunSpec("n", "tests.faultnodes:Hiccup", {"at": 10, "seconds": 0.0}, P, "wall")
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
