"""A meaningless campaign is refused in one line, exit 2, before any run is expanded or started:
counts and seeds out of range, a run length that would never end, a grid too large to hold, a
file the launch reader's bounds refuse, and arguments the scene refuses (by the path `dockhil
launch` takes)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from dockhil import cli
from dockhil.analysis import sweep
from dockhil.analysis.sweep import campaign as sweep_campaign
from dockhil.scene.schema import MAX_DURATION

ROOT = Path(__file__).resolve().parent.parent
HEAD = "scene: stability.yaml\nargs: {m: 20.0, delay: 0.016}\n"
LAUGHS = "".join(f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]\n" for i in range(1, 10))


def refused(tmp_path: Path, capsys, text: str | None = None, path: Path | None = None) -> str:
    """The one line `dockhil sweep` refuses the campaign with (exit 2, no result written)."""
    if path is None:
        path = tmp_path / "campaign.yaml"
        path.write_text(text)
    out = tmp_path / "r.parquet"
    code = cli.main(["sweep", str(path), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("dockhil sweep: error:"), lines[0]
    assert not out.exists() and not sweep.journal_path(out).exists()
    return lines[0]


@pytest.mark.parametrize(
    "text, expect",
    [
        (
            "grid: {k: [6000.0]}\nduration: 0.1\nsamples: 1e12\n",
            "`samples` must be a whole number from 1 to 100,000, got 1000000000000.0",
        ),
        ("grid: {k: [6000.0]}\nduration: 0.1\nsamples: 1000000000000\n", "`samples` must be a whole number from 1 to"),
        ("grid: {k: [6000.0]}\nduration: 0.1\nsamples: 0\n", "`samples` must be a whole number from 1 to"),
        ("grid: {k: [6000.0]}\nduration: 0.1\nsamples: 2.5\n", "`samples` must be a whole number"),
        ("grid: {k: [6000.0]}\nduration: 0.1\nsamples: true\n", "`samples` must be a whole number"),
        (
            "grid: {k: [6000.0]}\nduration: 0.1\nseed: -1\n",
            "`seed` must be a whole number from 0 to 4,294,967,295, got -1",
        ),
        (
            "grid: {k: [6000.0]}\nduration: 0.1\nseed: 4294967296\n",
            "`seed` must be a whole number from 0 to 4,294,967,295",
        ),
        (
            "grid: {k: [6000.0]}\nduration: 1.0e+300\n",
            "`duration` must be simulated seconds per run, > 0 and at most 1e+06",
        ),
        ("grid: {k: [6000.0]}\nduration: 0\n", "`duration` must be"),
        ("grid: {k: [6000.0]}\nduration: -1.0\n", "`duration` must be"),
        ("grid: {k: [6000.0]}\nduration: .nan\n", "got nan"),
        ("grid: {k: [6000.0]}\nduration: .inf\n", "got inf"),
        ("grid: {k: [6000.0]}\nduration: forever\n", "got 'forever'"),
        (
            "duration: 0.1\ngrid:\n  k: {range: [5000, 9000], num: 1000}\n  b: {range: [10, 200], num: 1000}\n"
            "  thrust: {range: [1, 10], num: 1000}\n",
            "1000 x 1000 x 1000 grid points x 1 samples = 1,000,000,000 runs; a campaign has at most 100,000",
        ),
        ("duration: 0.1\ngrid: {k: {range: [5000, 9000], num: 1000}}\nsamples: 101\n", "= 101,000 runs"),
        ("duration: 0.1\ngrid: {k: {range: [5000, 9000], num: 1000000000}}\n", "`num:` from 1 to 100,000 points"),
        ("duration: 0.1\ngrid: {k: {range: [5000, 9000], num: 0}}\n", "`num:` from 1 to 100,000 points"),
        ("duration: 0.1\nrandom: {thrust: {uniform: [-1.0e+308, 1.0e+308]}}\n", "b - a finite"),
        ("duration: 0.1\nrandom: {thrust: {normal: [0.0, 1.0e+308]}}\nsamples: 100\n", "give a narrower distribution"),
        ("duration: 0.1\ngrid: {k: [6000.0, -5.0]}\n", "grid.k = -5.0: refused by the scene: "),
        ("duration: 0.1\ngrid: {b: [100.0]}\nargs: {m: -1.0}\n", "run 0: refused by the scene: "),
        ("duration: 0.1\ngrid: {thrust: [10.0, 1.0e+30]}\n", "grid.thrust = 1e+30: refused by the scene: "),
        ("duration: 0.1\ngrid: {rate: [1000.0, 1.0e+9]}\n", "grid.rate = 1000000000.0: refused by the scene: "),
        ("duration: 0.1\ngrid: {k: " + "[" * 100 + "]" * 100 + "}\n", "nested deeper than 32 levels"),
        (
            "duration: 0.1\ngrid: {k: [6000.0]}\nl0: &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + LAUGHS,
            "expands to more than 100000 values",
        ),
    ],
)
def test_a_meaningless_campaign_is_refused_before_anything_runs(tmp_path, capsys, text, expect):
    line = refused(tmp_path, capsys, ("scene: stability.yaml\n" + text) if "args:" in text else HEAD + text)
    assert expect in line, line


def test_a_grid_value_the_scene_refuses_is_named_with_the_scene_s_line(tmp_path, capsys):
    line = refused(tmp_path, capsys, HEAD.replace("m: 20.0, ", "") + "duration: 0.1\ngrid: {m: [20.0, 5.0, -1.0]}\n")
    assert "grid.m = -1.0: refused by the scene: " in line
    scene = Path(__file__).resolve().parent.parent / "launch" / "stability.yaml"
    at = next(n for n, text in enumerate(scene.read_text().splitlines(), 1) if text.strip() == "- name: dynamics")
    assert f"stability.yaml:{at}: node 'dynamics' parameter 'm1': -1.0 is out of range, must be > 0.0" in line


def test_a_random_draw_the_scene_refuses_names_its_run(tmp_path, capsys):
    # A mass drawn from a normal distribution around 1 kg: some of 200 draws are negative.
    text = HEAD.replace("m: 20.0, ", "") + "duration: 0.1\nrandom: {m: {normal: [1.0, 1.0]}}\nsamples: 200\nseed: 3\n"
    line = refused(tmp_path, capsys, text)
    c_line = line.split("random.m = ", 1)[1]
    value, run = float(c_line.split(" ")[0]), int(c_line.split("(run ")[1].split(")")[0])
    assert value < 0 and "parameter 'm1'" in line and "must be > 0.0" in line
    # ... the least draw, of the run named: the same draw the campaign would make for that run.
    (tmp_path / "ok.yaml").write_text(text.replace("normal: [1.0, 1.0]", "uniform: [1.0, 2.0]"))
    c = sweep.load_campaign(tmp_path / "ok.yaml")
    import numpy as np

    assert sweep.draw("normal", 1.0, 1.0, np.random.default_rng([3, run])) == pytest.approx(value, rel=1e-3)
    draws = [sweep.draw("normal", 1.0, 1.0, np.random.default_rng([3, i])) for i in range(c.total)]
    assert min(draws) == pytest.approx(value, rel=1e-3)


def test_the_most_runs_is_accepted_and_one_more_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sweep_campaign, "MAX_RUNS", 12)
    path = tmp_path / "c.yaml"
    path.write_text(HEAD + "duration: 0.1\ngrid: {k: [6000.0, 7000.0, 8000.0]}\nsamples: 4\n")
    assert sweep.load_campaign(path).total == 12
    line = refused(
        tmp_path, capsys, HEAD + "duration: 0.1\ngrid: {k: [6000.0, 7000.0, 8000.0], b: [1.0, 2.0]}\nsamples: 3\n"
    )
    assert "3 x 2 grid points x 3 samples = 18 runs; a campaign has at most 12" in line


def test_the_ends_of_each_range_are_accepted(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(HEAD + f"duration: {MAX_DURATION:.0f}\ngrid: {{k: [6000.0]}}\nseed: {sweep.MAX_SEED}\nsamples: 1\n")
    c = sweep.load_campaign(path)
    assert (c.duration, c.seed) == (MAX_DURATION, 2**32 - 1)
    assert sweep.runs(c)[0]["args"]["k"] == 6000.0


def test_a_file_larger_than_the_launch_reader_takes_is_not_read(tmp_path, capsys):
    path = tmp_path / "big.yaml"
    with open(path, "w") as f:
        f.write(HEAD + "grid: {k: [6000.0]}\n#")
        f.truncate(100_000_000)  # 100 MB (sparse: no disk used)
    line = refused(tmp_path, capsys, path=path)
    assert "larger than 1048576 bytes" in line


def _measured(args: list[str], cwd: Path) -> tuple[int, str, float, float]:
    """(exit code, stderr, CPU seconds, peak resident MB) of `dockhil ARGS` in its own process. CPU
    time, not wall time: what the refusal costs, the same on a machine whose cores are busy."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "dockhil.cli", *args],
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    err = proc.stderr.read()
    _pid, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return proc.returncode, err, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


@pytest.mark.wall_time
def test_each_refusal_takes_under_10_s_and_500_mb(tmp_path):
    files = {
        "samples": HEAD + "grid: {k: [6000.0]}\nduration: 0.1\nsamples: 1000000000000\n",
        "seed": HEAD + "grid: {k: [6000.0]}\nduration: 0.1\nseed: -1\n",
        "duration": HEAD + "grid: {k: [6000.0]}\nduration: 1.0e+300\n",
        "grid": HEAD + "duration: 0.1\ngrid:\n  k: {range: [5000, 9000], num: 1000}\n"
        "  b: {range: [10, 200], num: 1000}\n  thrust: {range: [1, 10], num: 1000}\n",
        # the largest campaign, some of whose draws are refused: every draw is made to find the least
        "draw": "scene: stability.yaml\nduration: 0.1\ngrid: {k: {range: [5000, 9000], num: 1000}}\n"
        "random: {m: {normal: [20.0, 10.0]}}\nsamples: 100\n",
    }
    for name, text in files.items():
        (tmp_path / f"{name}.yaml").write_text(text)
    with open(tmp_path / "size.yaml", "w") as f:
        f.write(HEAD + "grid: {k: [6000.0]}\n#")
        f.truncate(100_000_000)
    for name in [*files, "size"]:
        code, err, cpu_s, rss_mb = _measured(["sweep", f"{name}.yaml", "--out", "r.parquet", "--quiet"], tmp_path)
        assert code == 2 and len(err.strip().splitlines()) == 1, (name, err)
        assert cpu_s < 10.0 and rss_mb < 500.0, (name, cpu_s, rss_mb)
        assert not (tmp_path / "r.parquet").exists()
