"""`dockhil benchmark compensation`: one JSON row per run with the metrics against the ideal contact,
the goals per scene, the table and the figures; bad input is one line."""

import json

import pytest

from dockhil.contact import compensation_grid as grid
from tests.support.inprocess import run_main


@pytest.fixture(scope="module")
def spring(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    code, stdout, err = run_main(
        "benchmark", "compensation", "--quick", "--scenes", "spring", "--methods", "energy", "--out", out, "--quiet"
    )
    assert code == 0, err
    rows = [json.loads(line) for line in (out / "rows.jsonl").read_text().splitlines()]
    return out, stdout, rows, json.loads((out / "summary.json").read_text())


def test_one_row_per_run_with_the_metrics(spring):
    _out, _stdout, rows, summary = spring
    assert len(rows) == summary["runs"] == 6 * 2 * len(grid.OMEGA_H_QUICK) * 2  # targets, methods, omega h, hardware
    for r in rows:
        assert r["error"] is None
        for key in ("restitution_error", "peak_force_error", "duration_error", "impulse_error", "energy_residual"):
            assert isinstance(r[key], float), (key, r)


def test_the_pure_delayed_spring_rebounds_as_the_closed_form_says(spring):
    _out, _stdout, rows, _summary = spring
    (plain,) = [
        r
        for r in rows
        if r["target"] == "linear e 1"
        and r["method"] == "none"
        and r["hardware"] == "as_told"
        and r["omega_h_grid"] == 0.16
    ]
    # 16 ms at 1 kHz on 100 kg and 1e4 N/m: the sampled loop's 1.293 (the continuous delay equation's 1.284).
    assert plain["delay_s"] == pytest.approx(0.016) and plain["restitution"] == pytest.approx(1.2933, abs=1e-3)
    assert plain["energy_residual"] == pytest.approx(plain["restitution"] ** 2 - 1.0, abs=1e-9)
    (matched,) = [
        r
        for r in rows
        if r["target"] == "linear e 1"
        and r["method"] == "energy"
        and r["hardware"] == "as_told"
        and r["omega_h_grid"] == 0.0
    ]
    assert abs(matched["restitution_error"]) < 1e-3  # without delay only the hold, which it is told of


def test_the_goals_name_a_best_method_and_the_table_says_it(spring):
    _out, stdout, _rows, summary = spring
    for scene, r in summary["scenes"].items():
        assert r["best"] in ("none", "energy")
        assert set(r["methods"]) == {"none", "energy"}
        assert f"{scene}: best {r['best']}" in stdout
    assert summary["goal_omega_h"] == 0.5 and summary["goals"]["restitution_error"] == 0.02


def test_the_figures_are_written(tmp_path):
    code, _stdout, err = run_main(
        "benchmark", "compensation", "--scenes", "table1", "--methods", "smith", "--out", tmp_path, "--quiet", "--json"
    )
    assert code == 0, err
    for name in ("error_vs_omega_h.png", "method_map.png", "table.txt", "rows.jsonl", "summary.json"):
        assert (tmp_path / name).stat().st_size > 1000, name
    summary = json.loads(_stdout)
    assert summary["scenes"]["table1: linear e 0.959"]["best"] == "smith"


@pytest.mark.parametrize(
    "args, words",
    [
        ((), "name the benchmark"),
        (("compensation", "--scenes", "moon"), "unknown scene 'moon'"),
        (("compensation", "--methods", "wave"), "unknown method 'wave'"),
        (("compensation", "--out", "/proc/no/such"), "--out /proc/no/such: cannot make the directory"),
        (("compensation", "--workers", "0"), "--workers must be between 1 and 64"),
    ],
)
def test_bad_input_is_one_line(args, words):
    code, _out, err = run_main("benchmark", *args)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and words in lines[0], err


def test_workers_give_the_same_rows(tmp_path):
    rows = []
    for workers in ("1", "2"):
        out = tmp_path / workers
        args = (
            "--scenes",
            "spring",
            "--methods",
            "smith",
            "--out",
            out,
            "--quiet",
            "--no-figures",
            "--workers",
            workers,
        )
        code, _stdout, err = run_main("benchmark", "compensation", *args)
        assert code == 0, err
        rows.append(
            [{k: v for k, v in json.loads(line).items() if k != "cpu_s"} for line in (out / "rows.jsonl").open()]
        )
    assert rows[0] == rows[1] and len(rows[0]) == 6 * 2 * len(grid.OMEGA_H_QUICK) * 2
