"""The delay compensations along the normal of the 6-DOF loop (hybrid6.NormalCompensation6): the composed
hil6.yaml graph with compensation:= equals the library loop bit for bit; on the off-axis impact the
compensated loop gives the ideal 6-DOF contact's restitution on the normal; hil6.yaml refuses a bad
compensation in one line."""

import subprocess

import numpy as np
import pytest

from dockhil.contact import compensation_grid as grid
from dockhil.contact.compensation import METHODS
from dockhil.contact.comploop import Hardware
from tests.conftest import ROOT, dockhil_cmd
from tests.test_sixdof_graph import HIL6, assert_equals_library, run_composed

OMEGA_H = 0.16


@pytest.fixture(scope="module")
def reference():
    return grid.reference6()


def delay_for(ref, omega_h):
    return round(omega_h / ref.omega / grid.DT) * grid.DT


@pytest.mark.parametrize("method", ["passivity", "predictor", "phase_lead"])
def test_composed_hil6_with_compensation_equals_the_library_loop_bit_for_bit(method):
    n = 300
    seen = run_composed(HIL6, dict(delay=0.04, compensation=method), n)
    run = grid.simulate_offaxis6(method, 0.04, Hardware(), n)
    assert run.onset is not None and run.onset < 0.01
    assert_equals_library(seen["/satellite/state"], run)
    plain = grid.simulate_offaxis6("none", 0.04, Hardware(), n)
    assert not np.array_equal(plain.velocities, run.velocities)  # the compensation acted


def test_compensated_6dof_loop_reproduces_the_ideal_restitution_on_the_normal(reference):
    delay = delay_for(reference, OMEGA_H)
    assert delay == pytest.approx(0.08)
    errors = {}
    for method in METHODS:
        row = grid.run_point(grid.OFFAXIS6, reference, method, OMEGA_H, "as_told", Hardware())
        assert row["error"] is None, row
        errors[method] = row["restitution_error"]
    # The off-axis contact turns the chaser: torques act on the ideal run as on the loop.
    assert np.max(np.abs(reference.run.omegas[:, 0, 2])) > 1e-4
    assert 0.9 < grid.normal_metrics6(reference.run, reference.run, 750.0)["restitution"] < 0.97
    for method in ("passivity", "predictor"):
        assert abs(errors[method]) <= 0.02, errors
    assert errors["none"] > 0.05  # the delay makes energy: the chaser leaves faster than the ideal
    assert all(abs(errors["none"]) > 5 * abs(errors[m]) for m in ("passivity", "predictor")), errors
    # No method errs clearly more than no compensation.
    assert all(abs(e) <= abs(errors["none"]) + 1e-9 for e in errors.values()), errors


def test_the_predictor_holds_the_normal_with_the_hardware_softer_and_later_than_told(reference):
    hw = Hardware(k_scale=0.7, delay_scale=1.2)
    rows = {m: grid.run_point(grid.OFFAXIS6, reference, m, OMEGA_H, "mismatch", hw) for m in ("none", "predictor")}
    assert abs(rows["predictor"]["restitution_error"]) <= 0.02
    assert abs(rows["predictor"]["peak_force_error"]) <= 0.05 and abs(rows["predictor"]["impulse_error"]) <= 0.05
    assert abs(rows["none"]["restitution_error"]) > 10 * abs(rows["predictor"]["restitution_error"])


def test_hil6_accepts_compensation_and_refuses_a_bad_one_in_one_line():
    ok = subprocess.run(
        dockhil_cmd("launch", HIL6, "--composed", "--duration", "0.05", "--quiet", "compensation:=passivity"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert ok.returncode == 0, ok.stdout + ok.stderr
    for args, line in (
        (["compensation:=wave"], "arg 'compensation' must be one of none, passivity"),
        (["compensation:=passivity", "max_damping:=0"], "compensation 'passivity' needs max_damping > 0 N s/m"),
        (
            ["compensation:=phase_lead", "delay:=0.4", "lead_tau:=0.5"],
            "compensation 'phase_lead': a first-order lead cannot advance",
        ),
    ):
        r = subprocess.run(
            dockhil_cmd("launch", HIL6, "--composed", "--duration", "0.05", *args),
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
        )
        out = r.stderr + r.stdout
        lines = [s for s in out.splitlines() if s.strip()]
        assert r.returncode not in (0, None) and "Traceback" not in out
        assert len(lines) == 1 and line in lines[0], lines
