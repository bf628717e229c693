"""The passivity boundary: the least undelayed damping that makes the delayed port k_h + b_h s passive,
against closed forms (k h; Colgate's K T / 2 + |B|), a brute-force search, the stability bound it
guarantees for every mass, and `dockhil stability`'s text and JSON."""

import json
import math

import numpy as np
import pytest

from dockhil.contact.passivity_bound import passivity_min_damping, sampled_passivity_min_damping
from dockhil.contact.stability import exact_bound
from tests.support.inprocess import run_main


@pytest.mark.parametrize("k, h", [(2510.0, 0.016), (1e4, 0.032), (1.0, 1.0)])
def test_a_delayed_spring_needs_k_h(k, h):
    need, at = passivity_min_damping(k, 0.0, h)
    assert need == pytest.approx(k * h, rel=1e-12) and at is None


@pytest.mark.parametrize(
    "k, b, h", [(2510.0, 20.0, 0.016), (2510.0, 60.0, 0.016), (1000.0, 5.0, 0.1), (0.0, 20.0, 0.01)]
)
def test_a_delayed_spring_damper_against_a_brute_force_search(k, b, h):
    w = np.linspace(1e-6, 400.0 / h, 4_000_001)
    brute = float(np.max(k / w * np.sin(w * h) - b * np.cos(w * h)))
    need, _ = passivity_min_damping(k, b, h)
    assert need == pytest.approx(brute, rel=1e-6)
    assert need >= max(k * h - b, b) - 1e-12  # w -> 0, and w h = pi: a delayed damper needs itself again


@pytest.mark.parametrize("K, B, T", [(2510.0, 20.0, 1e-3), (1e5, 0.0, 1e-3), (1e4, -30.0, 1e-4)])
def test_without_delay_the_sampled_bound_is_colgates(K, B, T):
    need, _ = sampled_passivity_min_damping(K, B, 0.0, T)
    assert need == pytest.approx(K * T / 2 + abs(B), rel=1e-9)


def test_the_sampled_bound_tends_to_the_continuous_one_and_counts_each_sample_of_delay():
    for k, b in ((2510.0, 0.0), (2510.0, 20.0)):
        cont, _ = passivity_min_damping(k, b, 0.016)
        fine, _ = sampled_passivity_min_damping(k, b, 0.016, 1e-6)
        assert fine == pytest.approx(cont, rel=1e-3)
    for d in (1, 5, 16):
        need, _ = sampled_passivity_min_damping(2510.0, 0.0, d * 1e-3, 1e-3, k_direct=2000.0)
        assert need == pytest.approx(2510.0 * (d + 0.5) * 1e-3 + 2000.0 * 0.5e-3, rel=1e-12)


def test_passive_is_stable_for_every_mass_and_the_bound_is_tight_for_a_heavy_one():
    b, h = 20.0, 0.016
    K = 0.999 * b / passivity_min_damping(1.0, 0.0, h)[0]  # the largest passive K for the damper b, less 0.1 %
    bounds = [exact_bound(m, b, h, damper="undelayed").k_max for m in (0.1, 1.0, 750.0, 1e6, 1e9)]
    assert all(K < kmax for kmax in bounds)
    assert bounds[-1] == pytest.approx(b / h, rel=1e-6)


def test_stability_prints_the_passivity_boundary():
    code, out, _ = run_main("stability", "--m", "750", "--b", "20", "--h", "0.016", "--K", "2510", "--json")
    r = json.loads(out)
    assert code == 0 and r["passivity_min_damping_Ns_per_m"] == pytest.approx(26.608, abs=1e-3)
    assert r["passive"] is False and r["passivity_max_K"] is None  # the paper's damper acts behind the delay
    code, out, _ = run_main("stability", "--m", "750", "--b", "20", "--h", "0.016", "--damper", "undelayed")
    assert code == 0 and "passive for K <= b/h = 1250 N/m (sampled: 1212.12 N/m)" in out
    code, out, _ = run_main("stability", "--scene", "launch/hil.yaml", "--json")
    r = json.loads(out)
    assert r["passivity_min_damping_Ns_per_m"] == pytest.approx(1000 * 0.032) and r["passive"] is True
    assert r["sampled_passivity_min_damping_Ns_per_m"] == pytest.approx(1000 * 0.0325 + 2000 * 0.0005)
    assert math.isclose(r["sampled_rate_Hz"], 1000.0)


@pytest.mark.parametrize("rate", ["0.5", "nan", "-3"])
def test_a_bad_rate_is_one_line(rate):
    code, out, err = run_main("stability", "--m", "750", "--b", "20", "--h", "0.016", "--rate", rate)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "--rate" in lines[0], err


def test_the_map_draws_the_passivity_bound_under_the_exact_one(tmp_path):
    png = tmp_path / "map.png"
    code, out, err = run_main(
        "stability", "map", "--m", "750", "--damper", "undelayed", "--n", "40", "--png", png, "--json"
    )
    r = json.loads(out)
    assert code == 0 and png.stat().st_size > 1000, err
    assert r["passivity_max_K_min"] == pytest.approx(10.0 / 0.032) and r["passivity_max_K_max"] == pytest.approx(
        200.0 / 0.016
    )
    assert 0.999 < r["passivity_over_exact_max"] <= 1.0  # passive is stable for every mass: never above the exact bound
    code, out, _ = run_main("stability", "map", "--m", "750", "--n", "20", "--png", png, "--json")
    assert code == 0 and json.loads(out)["passivity_max_K_max"] is None  # the damper behind the delay: none passive
