"""The compensation benchmark on the campaign engine: the same rows, in the grid's order, in this process,
on a local pool and on a Dask LocalCluster; a point that raises (or kills its worker) is a failed row that
names it and the rest of the grid runs; Ctrl-C ends a benchmark with workers in one line, and neither it
nor a SIGKILL leaves a worker behind."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import pytest

from dockhil.analysis.compensation_runs import failed_point, make_executor, run_grid, run_points
from dockhil.analysis.sweep import LocalPool
from dockhil.contact import compensation_grid as grid
from tests.support.inprocess import run_main
from tests.test_sweep_workers import assert_gone, signal_mid_run

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def todo() -> list[tuple]:
    """28 points of the quick grid: Table 1 and the spring's targets, none and smith, both hardware cases."""
    return grid.tasks(False, ["table1", "spring"], ["none", "smith"])[::6]


def untimed(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "cpu_s"} for r in rows]


class Reversed:
    """An executor whose batches come back last first: the rows must still be in the grid's order."""

    def __init__(self, inner):
        self.inner, self.workers, self.name = inner, inner.workers, inner.name

    def map(self, batcher):
        yield from list(self.inner.map(batcher))[::-1]


def test_the_grid_is_deterministic_and_a_local_pool_gives_its_rows_in_its_order(todo):
    here = run_grid(todo)
    assert untimed(run_grid(todo)) == untimed(here)  # the same floats twice: noise is seeded per point
    assert [(r["scene"], r["target"], r["hardware"], r["method"], r["omega_h_grid"]) for r in here] == [
        (t[0].name, t[0].target_name, t[4], t[2], t[3]) for t in todo
    ]
    pool = make_executor(2, None)
    assert isinstance(pool, LocalPool) and pool.workers == 2
    labels: list[str] = []
    try:
        pooled = run_grid(todo, Reversed(pool), labels.append)
    finally:
        pool.close()
    assert untimed(pooled) == untimed(here)
    assert sorted(labels) == sorted(grid.label(t) for t in todo)  # one step per finished point
    assert make_executor(1, None) is None and make_executor(None, None) is None  # in this process


def test_dask_local_cluster_gives_the_rows_of_this_process(tmp_path):
    import dask.distributed  # noqa: F401  (a dev dependency: fails, never skips)

    rows = {}
    for name, extra in (("here", ()), ("dask", ("--dask", "local", "--workers", "2"))):
        out = tmp_path / name
        code, stdout, err = run_main(
            "benchmark", "compensation", "--scenes", "table1", "--methods", "smith", "--out", out, "--quiet",
            "--no-figures", "--json", *extra,
        )  # fmt: skip
        assert code == 0, err
        summary = json.loads(stdout)
        rows[name] = (untimed([json.loads(line) for line in (out / "rows.jsonl").open()]), summary)
    (here, s_here), (dask, s_dask) = rows["here"], rows["dask"]
    assert len(here) == 2 * len(grid.OMEGA_H_QUICK) * 2 and dask == here  # methods, omega h, hardware
    assert (s_here["executor"], s_here["workers"]) == ("this process", 1)
    assert (s_dask["executor"], s_dask["workers"], s_dask["failed"]) == ("dask local", 2, 0)


def raising(todo: list[tuple]) -> tuple[list[tuple], int]:
    """`todo` with one point whose omega h is NaN (run_point cannot round its delay): (points, its index)."""
    bad = len(todo) // 2
    return [*todo[:bad], (*todo[bad][:3], float("nan"), *todo[bad][4:]), *todo[bad + 1 :]], bad


@pytest.mark.parametrize("workers", [1, 2])
def test_a_point_that_raises_is_a_failed_row_naming_it_and_the_rest_of_the_grid_runs(todo, workers):
    points, bad = raising(todo)
    executor = make_executor(workers, None)
    try:
        rows = run_grid(points, executor)
    finally:
        if executor is not None:
            executor.close()
    assert len(rows) == len(points)
    failed = rows[bad]
    assert failed["failed"] is True and failed["method"] == points[bad][2]
    assert failed["error"].startswith(grid.label(points[bad]) + ": ValueError: cannot convert float NaN")
    assert "\n" not in failed["error"]
    good = run_grid(todo)
    assert untimed(rows[:bad] + rows[bad + 1 :]) == untimed(good[:bad] + good[bad + 1 :])


def _dies_on_nan(batch: list[dict]) -> list[dict]:
    """run_points whose worker dies (as the OOM killer would end it) on a batch holding a NaN point."""
    if any(spec["task"][3] != spec["task"][3] for spec in batch):
        os._exit(1)
    return run_points(batch)


def test_a_point_that_kills_its_worker_every_time_is_a_failed_row_and_the_rest_run(todo):
    points, bad = raising(todo)
    pool = LocalPool(2, run=_dies_on_nan, failed=failed_point)
    rows = run_grid(points, pool)
    assert len(rows) == len(points)
    assert rows[bad]["failed"] is True
    good = run_grid(todo)
    # A batch in flight each time the pool broke is lost with it, each point's row naming it; the others
    # (the first points, done before that batch started, and those sent after) have their rows.
    kept = [i for i, r in enumerate(rows) if not r.get("failed")]
    for i, r in enumerate(rows):
        if i not in kept:
            assert r["error"] == f"{grid.label(points[i])}: worker lost 3 times running this batch"
    assert kept and untimed([rows[i] for i in kept]) == untimed([good[i] for i in kept])


def test_the_table_and_the_summary_count_failed_runs_and_the_exit_is_1(tmp_path, monkeypatch):
    real = grid.tasks
    monkeypatch.setattr(grid, "tasks", lambda *a: raising(real(*a))[0])
    code, stdout, err = run_main(
        "benchmark", "compensation", "--scenes", "table1", "--methods", "smith", "--out", tmp_path, "--quiet"
    )
    assert code == 1
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "1 of 24 runs failed, the first: table1 " in lines[0] and "rows.jsonl" in lines[0]
    assert "24 runs, 1 failed" in stdout and "  failed: table1 linear e 0.959 " in stdout
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["failed"] == 1 and "ValueError" in summary["failures"][0]
    assert summary["scenes"]["table1: linear e 0.959"]["best"] in ("none", "smith")
    for name in ("error_vs_omega_h.png", "method_map.png"):
        assert (tmp_path / name).stat().st_size > 1000, name


def test_a_bad_dask_address_is_one_line(tmp_path):
    code, _out, err = run_main("benchmark", "compensation", "--dask", "nonsense", "--out", tmp_path, "--quiet")
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "--dask 'nonsense': not a scheduler's address" in lines[0], err


@pytest.mark.wall_time
@pytest.mark.parametrize(
    "sig, where",
    [(signal.SIGINT, ()), (signal.SIGKILL, ()), (signal.SIGTERM, ("--dask", "local"))],
    ids=["ctrl-c", "sigkill", "sigterm-dask-local"],
)
def test_a_benchmark_with_workers_stopped_by_a_signal_or_killed_leaves_no_worker(tmp_path, sig, where):
    out, stderr = tmp_path / "out", tmp_path / "stderr.txt"
    # The push's 84 points, about 0.35 CPU-s each: the workers are mid-grid when the signal comes.
    command = ("benchmark", "compensation", "--scenes", "push", "--no-figures", "--workers", "2", *where)
    # ready once 3 progress lines say points finished on the workers
    workers, proc, text = signal_mid_run(
        (*command, "--out", out), stderr, lambda: stderr.read_text().count("] ") >= 3, sig
    )
    assert_gone(workers)
    assert not (out / "rows.jsonl").exists()
    if sig == signal.SIGKILL:
        assert proc.returncode == -signal.SIGKILL, text
        return
    said = [line for line in text.splitlines() if line.strip() and not line.startswith("[")]
    assert proc.returncode == 128 + sig, text
    what = "interrupted" if sig == signal.SIGINT else "stopped by SIGTERM"
    assert len(said) == 1 and f"{what}; nothing written to" in said[0], text
