"""What a lab does not know, on the 6-DOF scene as on hil.yaml's axis: hil6.yaml's simulated hardware
takes hw_k_scale (its true compliance over the told one, all six axes), hw_delay_scale (its true robot
delay over the told one) and ft_delay (the sensor's own delay), while the loop is told the nominal ones."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dockhil.testing import NodeHarness, robot_command, robot_state
from tests.support.inprocess import completed

HIL6 = Path(__file__).resolve().parents[1] / "launch" / "hil6.yaml"
CONTACT = robot_state(x=0.002)  # A 2 mm into B along the normal


def test_the_delay_injector_delays_by_the_told_delay_times_the_hardwares_scale():
    arrivals = {}
    for scale in (1.0, 1.5):
        with NodeHarness("delay_injector", dt=0.001, delay=0.004, delay_scale=scale) as h:
            ticks = [k for k in range(12) if "output" in h.step(inputs={"input": robot_command(x=0.001 * k)})]
        arrivals[scale] = ticks[0]
    assert arrivals == {1.0: 4, 1.5: 6}


def test_the_6dof_sensor_reads_the_hardwares_true_compliance_and_reports_it_late_by_its_delay():
    def forces(**params) -> list[float]:
        with NodeHarness("ft_sim", dof=6, dt=0.001, params=params) as h:
            return [h.step(inputs={"robot": CONTACT})["wrench"].wrench.force.x for _ in range(5)]

    nominal, softer, late = forces(), forces(k_scale=0.7), forces(delay=0.002)
    assert nominal[0] != 0.0 and softer == pytest.approx([0.7 * f for f in nominal], rel=1e-12)
    assert late == [0.0, 0.0, *nominal[:3]]


def test_hil6_runs_with_the_hardware_unlike_the_told_one_and_each_mismatch_changes_the_contact(tmp_path):
    def restitution(*args: str) -> float:
        summary = tmp_path / "s.json"
        r = completed("launch", HIL6, *args, "--composed", "--quiet", "--summary", summary)
        assert r.returncode == 0, r.stderr
        return json.loads(summary.read_text())["restitution"]

    nominal = restitution()
    assert restitution("hw_k_scale:=1.0", "hw_delay_scale:=1.0", "ft_delay:=0.0") == nominal
    for mismatch in ("hw_k_scale:=0.7", "hw_delay_scale:=1.2", "ft_delay:=0.002"):
        assert abs(restitution(mismatch) - nominal) > 1e-3, mismatch
