"""`dockhil figures` recomputes the paper's figures and says their numbers."""

import json

import pytest

from dockhil.contact.stability import pade1_bound
from tests.support.inprocess import run_main


def test_figures_command_writes_pngs_and_numbers(tmp_path):
    code, out, err = run_main("figures", "--out", tmp_path)  # in this process: no interpreter start-up
    assert code == 0, err
    for name in ("fig7", "fig9", "fig10", "fig11_12", "sixdof"):
        assert (tmp_path / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    numbers = json.loads((tmp_path / "figures.json").read_text())
    f9 = numbers["fig9"]
    assert f9["hybrid, no delay"]["peak_force_N"] == pytest.approx(f9["ideal"]["peak_force_N"], abs=0.05)
    assert f9["hybrid, 32 ms delay"]["peak_force_N"] > f9["hybrid, no delay"]["peak_force_N"] + 0.3
    rows = numbers["fig10"]["rows"]
    errors = [r["peak_force_delay_N"] - r["peak_force_no_delay_N"] for r in rows]
    assert all(b > a for a, b in zip(errors, errors[1:]))
    grows, settles = numbers["fig11_12"]
    assert grows["growth_rate_1_s"] > 0 > settles["growth_rate_1_s"]
    assert grows["eq12_bound_N_per_m"] == pytest.approx(pade1_bound(750.0, 20.0, 0.016))
    assert "Figs. 11-12: b = 20: growth +" in out
    six = numbers["sixdof"]  # the off-axis 6-DOF docking against its ideal contact
    assert six["dof"] == 6 and six["peak_torque_Nm"] > 1.0 and six["ideal"]["peak_torque_Nm"] > 1.0
    assert "6-DOF (hil6.yaml): peak |F|" in out


def test_figures_refuses_a_bad_delay(tmp_path):
    code, _, err = run_main("figures", "--out", tmp_path, "--delay", "-1")
    assert code == 2 and "--delay must be between 0 and 1 s" in err
