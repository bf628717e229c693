"""The stability.yaml loop simulated for many points at once (dockhil.contact.sheet_sweep), and the
compensated region of `dockhil stability map`: the lanes run the library loop's trajectories, and
their verdicts agree with what is known without simulating."""

import json
import subprocess

import numpy as np
import pytest

from dockhil.cli import main
from dockhil.contact.hilloop import simulate_hil
from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.passivity import DEFAULT_MAX_DAMPING, Passivity, left_in_loop
from dockhil.contact.sheet_sweep import simulate_sheets
from dockhil.contact.stability import exact_bound, stability_report
from tests.conftest import dockhil_cmd

M = 750.0


def test_each_lane_runs_the_library_loop():
    # (b, K, h, max_damping): uncompensated unstable, compensated, saturating, another delay.
    points = [
        (20.0, 2510.0, 0.016, 0.0),
        (20.0, 2510.0, 0.016, DEFAULT_MAX_DAMPING),
        (20.0, 12500.0, 0.016, 40.0),
        (60.0, 6000.0, 0.03, DEFAULT_MAX_DAMPING),
    ]
    b, K, h, md = (np.array(v) for v in zip(*points))
    seconds = 8.0
    lanes = simulate_sheets(M, b, K, h, md, seconds=seconds, record=True)
    for i, (bi, Ki, hi, mdi) in enumerate(points):
        run = simulate_hil(
            m1=M,
            m2=0.0,
            k=Ki,
            impedance=VirtualImpedance(0.0, bi, 0.0, 0.0),
            dt=1e-3,
            n_ticks=int(seconds * 1000) + 1,
            delay=hi,
            thrust=10.0,
            x1=20.0 / Ki,
            passivity=Passivity(Ki, mdi) if mdi > 0 else None,
            energy=True,
        )
        p = run.x1 - run.x2
        # The free mass's step in closed form against the library's matrix exponential: roundings.
        assert np.allclose(lanes["p"][:, i], p, rtol=0, atol=1e-10 * np.max(np.abs(p))), points[i]
        left, allowed = left_in_loop(run.extra)
        assert lanes["left_J"][i] == pytest.approx(left, rel=1e-6, abs=1e-15)
        assert lanes["saturated"][i] == (mdi > 0 and left > allowed)
    assert list(lanes["saturated"]) == [False, False, True, False]


def test_verdicts_agree_with_the_exact_bound_and_the_damping_the_delay_needs():
    b, h = 20.0, 0.016
    bound = exact_bound(M, b, h, damper="undelayed").k_max
    inside, outside = 0.5 * bound, 10.0 * bound
    assert stability_report(M, b, h, K=outside, damper="undelayed")["growth_rate"] > 0.0  # the exact analysis
    # The delay makes energy like a damper -K h: a bound well below K h cannot take it out.
    too_small = outside * h / 4
    K = np.array([inside, inside, outside, outside, outside])
    md = np.array([0.0, DEFAULT_MAX_DAMPING, 0.0, DEFAULT_MAX_DAMPING, too_small])
    r = simulate_sheets(M, b, K, h, md, seconds=30.0)
    assert list(r["grows"][:2]) == [False, False]  # inside the bound both are stable
    assert not r["saturated"][1]
    assert r["grows"][2] and not r["diverged"][2]  # outside it the paper's loop grows...
    assert not r["grows"][3] and not r["saturated"][3]  # ...and the compensated one does not
    assert r["saturated"][4]  # with too little damping the controller saturates
    # Compensated, the loop is passive: it decays as the damper alone would, -b / (2 m).
    assert r["growth_rate"][3] == pytest.approx(-b / (2 * M), rel=0.15)


def map_args(tmp_path, *extra):
    return [
        "stability",
        "map",
        "--m",
        M,
        "--png",
        tmp_path / "m.png",
        "--n",
        20,
        "--compensation",
        "passivity",
        "--sim-n",
        2,
        "--seconds",
        20,
        *extra,
    ]


def map_cmd(tmp_path, *extra):
    return dockhil_cmd(*map_args(tmp_path, *extra))


def run_map(capsys, tmp_path, *extra) -> str:
    """The map command in this process (the test_bad_sweep_arguments run it as a command): its stdout."""
    capsys.readouterr()
    assert main([str(a) for a in map_args(tmp_path, *extra)]) == 0
    return capsys.readouterr().out


def test_the_map_draws_the_compensated_region(tmp_path, capsys):
    s = json.loads(run_map(capsys, tmp_path, "--multiples", 0.5, 10, "--json"))["passivity"]
    assert s["grid"] == [2, 2] and s["multiples"] == [0.5, 10.0] and s["points"] == 8
    assert s["largest_stable_multiple"] == [[10.0, 10.0], [10.0, 10.0]]
    assert (tmp_path / "m.png").stat().st_size > 10000
    # A bound far below K h: the delay's energy stays in the loop (even inside the bound, where the
    # damper b outweighs it: the controller takes out what the delay makes, not the net), so every run
    # saturates and none counts as stable.
    s = json.loads(run_map(capsys, tmp_path, "--multiples", 0.5, 10, "--max-damping", 1, "--json"))["passivity"]
    assert s["largest_stable_multiple"] == [[0.0, 0.0], [0.0, 0.0]] and s["saturated_points"] == 8
    out = run_map(capsys, tmp_path, "--multiples", 0.5)
    assert "stable (neither grows nor saturates) in 4 of 4 runs" in out, out


@pytest.mark.parametrize(
    "args, words",
    [
        (("--sim-n", 1), "--sim-n must be between 2 and 40"),
        (("--multiples", -1), "--multiples must be"),
        (("--max-damping", -3), "--max-damping must be > 0"),
        (("--seconds", 0.5), "--seconds must be between"),
    ],
)
def test_bad_sweep_arguments_give_one_line(tmp_path, args, words):
    r = subprocess.run(map_cmd(tmp_path, *args), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], r.stderr


@pytest.mark.parametrize(
    "args, words",
    [
        (
            (
                "stability",
                "map",
                "--m",
                749.4,
                "--kcs",
                3000,
                "--bcs",
                40,
                "--png",
                "x.png",
                "--compensation",
                "passivity",
            ),
            "the hybrid map (--kcs, --bcs) has none",
        ),
        (("stability", "--scene", "launch/hil.yaml", "--compensation", "passivity"), "the hybrid loop (--scene"),
    ],
)
def test_compensation_on_the_hybrid_loop_is_refused_in_one_line(args, words):
    r = subprocess.run(dockhil_cmd(*args), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], r.stderr
