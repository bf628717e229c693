"""Campaigns: `dockhil sweep` runs a scene over a grid and random draws into Parquet rows,
the same rows on a local pool and on a Dask LocalCluster, resumable, with failed runs
recorded, and a stability map that agrees with the delay equation's exact boundary."""

from __future__ import annotations

import json
import math
import os
import textwrap
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from dockhil import cli
from dockhil.analysis import sweep
from dockhil.analysis.sweep import LocalPool
from dockhil.analysis.sweep import campaign as sweep_campaign
from dockhil.analysis.sweep import executors as sweep_executors
from dockhil.node import Node

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "launch" / "stability.yaml"
DT = 1e-3  # stability.yaml runs at 1000 Hz

# A light body (m = 20 kg) makes the loop fast (rad/s in the tens), so one simulated
# second shows its growth or decay; K brackets the boundary (~6140 N/m at b = 100,
# ~12440 N/m at b = 200 for h = 16 ms).
MAP_CAMPAIGN = """
scene: stability.yaml
# The map is of the loop the graph runs (sampled, forces held): run it where it and the delay
# equation disagree too, which the scene check would otherwise refuse.
args: {m: 20.0, delay: 0.016, allow_coarse: true}
duration: 1.0
grid:
  b: [100, 200]
  k: [5000, 5900, 6400, 7500, 11500, 12800]
"""


def write(tmp_path: Path, text: str, name: str = "campaign.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def rows_of(path: Path) -> list[dict]:
    return pq.read_table(path).to_pylist()


def without_timing(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("run_time_s", "real_time_factor")} for r in rows]


class Counting:
    """An executor that counts the runs it is given and can stop (Ctrl-C) after some."""

    def __init__(self, inner, stop_after: int | None = None):
        self.inner, self.stop_after = inner, stop_after
        self.workers, self.name = inner.workers, "counting"
        self.executed: list[int] = []

    def map(self, batches):
        for rows in self.inner.map(batches):
            self.executed.extend(r["run"] for r in rows)
            yield rows
            if self.stop_after is not None and len(self.executed) >= self.stop_after:
                raise KeyboardInterrupt

    def close(self):
        self.inner.close()


SMALL = """
scene: stability.yaml
args: {m: 20.0, delay: 0.016, b: 150}
duration: 0.3
grid:
  k: {range: [6000, 9000], num: 3}
random:
  thrust: {uniform: [8, 12]}
samples: 2
seed: 7
"""


def test_runs_are_the_grid_product_times_samples_with_reproducible_draws(tmp_path):
    c = sweep.load_campaign(write(tmp_path, SMALL))
    specs = sweep.runs(c)
    assert [s["run"] for s in specs] == list(range(6))
    assert [s["args"]["k"] for s in specs] == [6000.0, 6000.0, 7500.0, 7500.0, 9000.0, 9000.0]
    thrusts = [s["args"]["thrust"] for s in specs]
    assert all(8.0 <= t <= 12.0 for t in thrusts) and len(set(thrusts)) == 6
    assert [s["args"]["thrust"] for s in sweep.runs(c)] == thrusts  # per run index, not per call
    c2 = sweep.load_campaign(write(tmp_path, SMALL.replace("seed: 7", "seed: 8"), "other.yaml"))
    assert [s["args"]["thrust"] for s in sweep.runs(c2)] != thrusts
    assert len({s["args_hash"] for s in specs}) == 6


def test_log_range_and_value_forms():
    axis = sweep_campaign._axis_points(sweep_campaign._axis({"range": [100.0, 10000.0], "num": 3, "log": True}, "x"))
    assert axis == pytest.approx([100.0, 1000.0, 10000.0])
    assert sweep_campaign._axis_points(sweep_campaign._axis({"values": [1, 2]}, "x")) == [1, 2]


def test_local_pool_and_dask_local_cluster_give_identical_rows(tmp_path):
    import dask.distributed  # noqa: F401  (a dev dependency: fails, never skips)

    campaign = write(tmp_path, SMALL)
    local, dask = tmp_path / "local.parquet", tmp_path / "dask.parquet"
    assert cli.main(["sweep", str(campaign), "--out", str(local), "--workers", "2", "--quiet"]) == 0
    c = sweep.load_campaign(campaign)
    executor = sweep.DaskExecutor("local", 2)  # LocalCluster(n_workers=2, processes=True, threads_per_worker=1)
    try:
        # Worker processes, not threads: each task runs in another process than this one.
        pids = set(executor.client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids
        out = sweep.sweep(c, dask, executor, progress=False)
    finally:
        executor.close()
    assert out["ok"] == 6 and out["executed"] == 6
    a, b = rows_of(local), rows_of(dask)
    assert len(a) == 6 and all(r["status"] == "ok" for r in a)
    assert without_timing(a) == without_timing(b)
    assert pq.read_table(local).schema.names == pq.read_table(dask).schema.names
    for r in a:
        assert {
            "m",
            "delay",
            "b",
            "k",
            "thrust",
            "status",
            "error",
            "run_time_s",
            "peak_force_N",
            "growth_rate_per_s",
            "stable",
        } <= set(r)


def test_an_interrupted_campaign_resumes_without_rerunning_finished_rows(tmp_path):
    c = sweep.load_campaign(write(tmp_path, SMALL))
    out = tmp_path / "r.parquet"
    first = Counting(LocalPool(1), stop_after=2)
    with pytest.raises(KeyboardInterrupt):
        sweep.sweep(c, out, first, progress=False)
    done_first = sorted(first.executed)
    assert 2 <= len(done_first) < 6
    kept = {r["run"]: r for r in rows_of(out)}  # written on interruption
    assert sorted(kept) == done_first
    # As after a crash: the Parquet file is gone, the journal still has the rows.
    out.unlink()
    assert sweep.journal_path(out).exists()
    second = Counting(LocalPool(1))
    result = sweep.sweep(c, out, second, progress=False)
    assert sorted(second.executed) == sorted(set(range(6)) - set(done_first))
    assert result["executed"] == 6 - len(done_first) and result["skipped"] == len(done_first)
    rows = rows_of(out)
    assert [r["run"] for r in rows] == list(range(6)) and all(r["status"] == "ok" for r in rows)
    for r in rows:
        if r["run"] in kept:
            assert r["run_time_s"] == kept[r["run"]]["run_time_s"]  # the first run's row, not a new one
    assert not sweep.journal_path(out).exists()
    third = Counting(LocalPool(1))
    assert sweep.sweep(c, out, third, progress=False)["executed"] == 0 and third.executed == []


def test_results_of_another_campaign_are_refused_not_overwritten(tmp_path, capsys):
    out = tmp_path / "r.parquet"
    a = write(tmp_path, SMALL.replace("samples: 2", "samples: 1"), "a.yaml")
    b = write(tmp_path, SMALL.replace("samples: 2", "samples: 1").replace("b: 150", "b: 160"), "b.yaml")
    assert cli.main(["sweep", str(a), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    assert cli.main(["sweep", str(b), "--out", str(out), "--workers", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another campaign" in err[0]
    assert out.read_bytes() == before


def test_refused_and_diverging_runs_are_rows_and_the_campaign_goes_on(tmp_path, capsys):
    # b = -1e4 (a damper that feeds energy) moves too fast for the 1 ms step: the scene check refuses
    # it (an invalid row), and with allow_coarse it runs and diverges (a failed row).
    campaign = write(
        tmp_path,
        """
        scene: stability.yaml
        args: {m: 1.0, delay: 0.016, k: 10000}
        duration: 0.5
        grid:
          allow_coarse: [false, true]
          b: [-1.0e+4, 100]
        """,
    )
    out = tmp_path / "r.parquet"
    code = cli.main(["sweep", str(campaign), "--out", str(out), "--workers", "2", "--quiet"])
    assert code == 1  # some run failed; every row is there
    rows = {(r["allow_coarse"], r["b"]): r for r in rows_of(out)}
    assert len(rows) == 4
    refused = rows[(False, -1.0e4)]
    assert refused["status"] == "invalid" and "does not resolve the contact" in refused["error"]
    assert refused["stable"] is None
    diverged = rows[(True, -1.0e4)]
    assert diverged["status"] == "failed" and "diverged" in diverged["error"]
    for coarse in (False, True):
        assert rows[(coarse, 100.0)]["status"] == "ok" and rows[(coarse, 100.0)]["error"] is None
    assert "1 failed" in capsys.readouterr().out


def _dies_once(batch):
    """run_batch whose first call kills its worker process (as the OOM killer would)."""
    marker = Path(os.environ["DOCKHIL_TEST_KILL_MARKER"])
    if not marker.exists():
        marker.write_text("x")
        os._exit(1)
    return _real_run_batch(batch)


_real_run_batch = sweep.run_batch


def test_a_lost_worker_s_batch_is_sent_again(tmp_path, monkeypatch):
    # The first batch to start kills its worker; the pool is replaced and the batch sent again.
    marker = tmp_path / "killed-once"
    monkeypatch.setenv("DOCKHIL_TEST_KILL_MARKER", str(marker))
    monkeypatch.setattr(sweep_executors, "run_batch", _dies_once)  # what the local pool submits
    c = sweep.load_campaign(write(tmp_path, SMALL.replace("duration: 0.3", "duration: 0.05")))
    out = tmp_path / "r.parquet"
    result = sweep.sweep(c, out, LocalPool(2), progress=False)
    assert marker.exists()
    assert result["ok"] == 6 and [r["status"] for r in rows_of(out)] == ["ok"] * 6


@pytest.mark.parametrize(
    "text, expect",
    [
        ("scene: stability.yaml\ngrd: {k: [1]}\n", "unknown key 'grd'"),
        ("scene: stability.yaml\ngrid: {k: [1.0]}\nrandom: {b: {gauss: [1, 2]}}\n", "random.b"),
        ("scene: stability.yaml\ngrid: {k: {uniform: [1, 2]}}\n", "grid.k"),
        ("scene: stability.yaml\ngrid: {k: []}\n", "empty grid"),
        ("scene: stability.yaml\ngrid: {}\n", "empty grid"),
        ("scene: stability.yaml\ngrid: {stiffness: [1.0]}\n", "no arg 'stiffness'"),
        ("scene: stability.yaml\ngrid: {k: {range: [1, 2]}}\n", "num"),
        ("scene: stability.yaml\nrandom: {b: {loguniform: [0, 2]}}\n", "loguniform"),
        ("scene: nowhere.yaml\ngrid: {k: [1.0]}\n", "not found"),
        ("scene: stability.yaml\ngrid: {k: ['1e3']}\n", "expects float, got str '1e3'"),
        ("scene: stability.yaml\nargs: {k: 1.0}\ngrid: {k: [1.0]}\n", "give it once"),
        ("grid: {k: [1.0]}\n", "`scene:` is required"),
        ("scene: [\n", "not valid YAML"),
        ("scene: stability.yaml\ngrid: {k: [5000.0]}\noutputs: [peak_force]\n", "'peak_force' is not a summary field"),
    ],
)
def test_a_bad_campaign_file_is_one_line_and_exit_2(tmp_path, capsys, text, expect):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    code = cli.main(["sweep", str(path), "--out", str(tmp_path / "r.parquet"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("dockhil sweep: error:") and expect in lines[0], lines[0]
    assert not (tmp_path / "r.parquet").exists()


def _k_crit_independent(m: float, b: float, h: float) -> float:
    """Stiffness where m s^2 + b s + K e^{-sh} = 0 first has roots s = +-j w: the phase
    condition tan(w h) = b / (m w) (solved by brentq) and the gain K = w sqrt(m^2 w^2 + b^2).
    Below it the loop is stable (at K -> 0 the roots are 0- and -b/m)."""
    from scipy.optimize import brentq

    w = brentq(lambda w: math.tan(w * h) - b / (m * w), 1e-9, (math.pi / 2 - 1e-12) / h)
    return w * math.sqrt((m * w) ** 2 + b * b)


def _has_right_half_plane_root(m: float, b: float, K: float, h: float) -> bool:
    """Argument principle on a large half-disc in the right half-plane, simulation-free."""
    import numpy as np

    R = 40.0 * math.sqrt(K / m) + 4.0 * b / m + 50.0
    w = np.linspace(R, -R, 100001)
    s_axis = 1j * w
    arc = R * np.exp(1j * np.linspace(-math.pi / 2, math.pi / 2, 20001))
    s = np.concatenate([s_axis, arc])
    f = m * s * s + b * s + K * np.exp(-s * h)
    winding = np.sum(np.diff(np.unwrap(np.angle(f)))) / (2 * math.pi)
    return round(winding) > 0


def test_the_exact_boundary_used_as_oracle_matches_a_simulation_free_check():
    from dockhil.contact.stability import exact_bound

    m, b, h = 20.0, 100.0, 0.016 + DT / 2
    k_lib = exact_bound(m, b, h, damper="undelayed").k_max
    k_ind = _k_crit_independent(m, b, h)
    assert k_lib == pytest.approx(k_ind, rel=1e-9)
    assert not _has_right_half_plane_root(m, b, 0.97 * k_ind, h)
    assert _has_right_half_plane_root(m, b, 1.03 * k_ind, h)


def test_empirical_stability_map_agrees_with_the_exact_boundary(tmp_path, capsys):
    campaign = write(tmp_path, MAP_CAMPAIGN)
    out = tmp_path / "map.parquet"
    assert cli.main(["sweep", str(campaign), "--out", str(out), "--workers", "2", "--quiet"]) == 0
    rows = rows_of(out)
    assert len(rows) == 12
    counted = {True: 0, False: 0}
    for r in rows:
        assert r["status"] == "ok", r
        # The scene's sampled loop: damper on the undelayed velocity, forces held over a step (h + dt/2).
        k_crit = _k_crit_independent(r["m"], r["b"], r["delay"] + DT / 2)
        if abs(r["k"] / k_crit - 1.0) <= 0.02:
            continue
        expect = r["k"] < k_crit
        assert r["stable"] is expect, (r["b"], r["k"], k_crit, r["growth_rate_per_s"])
        assert (r["growth_rate_per_s"] < 0) is expect
        counted[expect] += 1
    assert counted[True] >= 4 and counted[False] >= 4  # both sides of the boundary, near it too
    png = tmp_path / "map.png"
    capsys.readouterr()
    assert cli.main(["sweep", "plot", str(out), "--png", str(png)]) == 0
    said = capsys.readouterr().out
    assert "stability map: 12 of 12 runs" in said
    assert png.stat().st_size > 20_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_refuses_what_it_cannot_draw(tmp_path, capsys):
    assert cli.main(["sweep", "plot", str(tmp_path / "none.parquet"), "--png", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such results file" in err[0]
    assert cli.main(["sweep", "plot", str(tmp_path / "none.parquet")]) == 2
    assert "--png" in capsys.readouterr().err


def test_outputs_keep_only_the_named_summary_columns(tmp_path):
    campaign = write(tmp_path, SMALL.replace("samples: 2", "samples: 1") + "outputs: [peak_force_N, stable]\n")
    out = tmp_path / "r.parquet"
    assert cli.main(["sweep", str(campaign), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    names = pq.read_table(out).schema.names
    assert {"peak_force_N", "stable", "k", "thrust", "status", "error", "run_time_s"} <= set(names)
    assert "contact_duration_s" not in names and "growth_rate_per_s" not in names
    meta = json.loads(pq.read_table(out).schema.metadata[b"dockhil.campaign"])
    assert meta["rate"] == 1000.0 and meta["grid"] == ["k"]


def test_bags_true_keeps_one_readable_bag_per_run(tmp_path):
    from dockhil.bags.reader import BagReader

    campaign = write(
        tmp_path,
        """
        scene: stability.yaml
        args: {m: 20.0, delay: 0.016, b: 150}
        duration: 0.05
        grid:
          k: [6000, 9000]
        bags: true
        """,
    )
    out = tmp_path / "r.parquet"
    assert cli.main(["sweep", str(campaign), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    rows = rows_of(out)
    assert [Path(r["bag"]).name for r in rows] == ["run-000000.mcap", "run-000001.mcap"]
    for r in rows:
        with BagReader(r["bag"]) as bag:
            states = [m for topic, _t, m in bag.decoded(["/satellite/state"])]
        assert len(states) == 51  # ticks 0..50 of 1 ms


def test_the_shipped_fig7_campaign_brackets_the_boundary_at_every_point():
    from dockhil.contact.stability import exact_bound

    c = sweep.load_campaign(ROOT / "launch" / "campaigns" / "fig7.yaml")
    assert c.total == 480 and c.fixed["m"] == 750.0
    ks = c.grid["k"]
    for h in c.grid["delay"]:
        for b in c.grid["b"]:
            k_max = exact_bound(750.0, b, h + DT / 2, damper="undelayed").k_max
            below = [k for k in ks if k < k_max]
            above = [k for k in ks if k > k_max]
            assert len(below) >= 2 and len(above) >= 2, (b, h, k_max)


def one_row(scene: Path, args: dict, duration: float) -> dict:
    """The row of one run of `scene` with `args`, as a campaign's worker makes it."""
    return sweep.run_one(
        {
            "run": 0,
            "sample": 0,
            "args": args,
            "args_hash": "h",
            "scene": str(scene),
            "duration": duration,
            "bag": None,
            "outputs": None,
        }
    )


def hil_with(tmp_path: Path, node: str) -> Path:
    """launch/hil.yaml with one more node (its YAML, as a list entry of `nodes:`)."""
    return write(
        tmp_path,
        f"""
        rate: 1000
        include:
          - file: {ROOT / "launch" / "hil.yaml"}
        nodes:
          {node}
        """,
        "scene.yaml",
    )


def test_a_rows_warnings_carry_what_its_nodes_warned():
    """A row has no log: a node's warning (here the virtual impedance's negative virtual
    stiffness, kcs below the passive k) lands in the row's warnings column, and a row whose
    nodes said nothing has none."""
    soft, stiff = (one_row(ROOT / "launch" / "hil.yaml", {"kcs": kcs}, 0.05) for kcs in ("500", "3000"))
    assert soft["status"] == "ok" and stiff["status"] == "ok"
    assert soft["warnings"].startswith("impedance: kcs = 500 N/m is below the passive stiffness k = 1000 N/m")
    assert stiff["warnings"] is None


class LogsAnError(Node):
    """says an error line once and goes on (a driver that lost a reading, say)"""

    def step(self, tick, inputs):
        if tick.index == 1:
            self.log("error: lost its sensor")
        return {}


def test_a_rows_warnings_carry_its_nodes_error_lines_too(tmp_path):
    row = one_row(hil_with(tmp_path, "- {name: talker, node: 'tests.test_sweep:LogsAnError'}"), {}, 0.01)
    assert row["status"] == "ok"
    assert row["warnings"] == "talker: error: lost its sensor"


def test_a_node_s_nan_is_its_own_failure_and_a_diverging_loop_is_labelled_diverged(tmp_path):
    """A NaN a node produces while the bodies are where docking hardware can be is that node's
    failure: the row carries its line. The loop diverging shows as a NaN or Inf too, once the
    bodies have left that range: that row says diverged, and where the bodies were."""
    node = one_row(
        hil_with(tmp_path, "- {name: nan, node: 'tests.support.faultnodes:NanAt', params: {at: 5}}"), {}, 0.1
    )
    assert node["status"] == "failed"
    assert node["error"] == (
        "node 'nan' produced an invalid message at tick 5 on output 'x' (/x): WrenchStamped: "
        "NaN or Inf refused (physical fields must be finite) - at `$.wrench.force.x`; "
        "stopping the graph"
    )
    diverged = one_row(ROOT / "launch" / "hil.yaml", {"k": 1e12}, 0.1)  # a virtual stiffness of -1e15 N/m
    assert diverged["status"] == "failed"
    head, line = diverged["error"].split("): ", 1)
    assert head.startswith("diverged (at tick ") and "of docking hardware" in head
    assert line.startswith("node 'impedance' produced an invalid message at tick ") and "NaN or Inf refused" in line
