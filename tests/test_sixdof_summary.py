"""The run summary of the 6-DOF scene (dockhil/analysis/summary/dof6.py): along the axis it is the 1-DOF
summary of hil.yaml and its ideal the 1-DOF closed form; off the axis its numbers are those of the
library's own hybrid and ideal runs, computed here from their arrays; a recorded run's summary is
the live one's."""

import json
import math
import subprocess

import numpy as np
import pytest

from dockhil.analysis.summary import SummaryCollector, format_summary
from dockhil.contact.contact6 import Contact6, simulate_contact6
from dockhil.contact.ideal import ideal_contact_summary
from dockhil.contact.scenario import ContactScenario
from dockhil.scene import graph as graphmod
from dockhil.scene import launchfile
from tests.conftest import ROOT, dockhil_cmd
from tests.test_sixdof_graph import DT, library_run, run_taps

HIL6 = ROOT / "launch" / "hil6.yaml"


def summary_of(path, args: dict, n_ticks: int) -> dict:
    """The summary of a composed sim-time run, as `dockhil launch --composed` makes it."""
    graph = graphmod.build(launchfile.load(path, {k: str(v) for k, v in args.items()}))
    collector = SummaryCollector(graph)
    run_taps(graph, [collector], n_ticks)
    return collector.summary(1.0)


def rel(a, b):
    return abs(a - b) / abs(b)


def test_along_the_axis_the_summary_is_the_1dof_summary_and_its_ideal_the_closed_form():
    n = 1800  # the whole contact (1.57 s) and the delayed passive force after it
    one = summary_of(ROOT / "launch" / "hil.yaml", {}, n)
    six = summary_of(HIL6, dict(offset=0.0, tilt=0.0, spin=0.0), n)
    assert six["dof"] == 6 and "note" not in six, six.get("note")
    for key in ("peak_force_N", "contact_duration_s", "entry_velocity_mps", "exit_velocity_mps", "restitution"):
        assert rel(six[key], one[key]) < 1e-9, (key, six[key], one[key])
    # Nothing off the axis: the normal components are the whole vectors, and no torque acts.
    assert six["exit_relative_velocity_mps"][0] == six["exit_velocity_mps"]
    assert six["exit_relative_velocity_mps"][1:] == [0.0, 0.0]
    assert six["exit_relative_angular_velocity_radps"] == [0.0, 0.0, 0.0] and six["peak_torque_Nm"] == 0.0
    # The ideal 6-DOF contact, sampled at 1 kHz, against the 1-DOF closed form (hil.yaml's values).
    cs = ideal_contact_summary(ContactScenario(750.0, 1e6, 3000.0, 40.0, 0.0, 0.03, 0.0))
    ideal = six["ideal"]
    assert rel(ideal["peak_force_N"], cs.peak_force) < 1e-6  # a sampled peak (6e-8 below the continuous one)
    assert abs(ideal["contact_duration_s"] - cs.duration) < 1e-7  # zero crossings interpolated between ticks
    assert rel(ideal["exit_velocity_mps"], cs.exit_relative_velocity) < 1e-9
    assert rel(ideal["entry_velocity_mps"], 0.03) < 1e-12
    # The run against it: the 1-DOF hybrid loop's errors (32 ms delay), in the summary's error entries.
    assert 0.005 < six["error"]["peak_force_N"] / cs.peak_force < 0.05
    assert math.isclose(six["error"]["peak_force_N"], six["peak_force_N"] - ideal["peak_force_N"], rel_tol=1e-12)


def _first_contact_metrics(t, p, pd, force, torque, vel, spin, acting):
    """The summary's definitions, written out on whole arrays: contact while p > 0; peaks over it;
    entry at its first sample; exit at the first sample after the last one with a force acting."""
    inside = np.flatnonzero(p > 0.0)
    start = inside[0]
    end = start + np.flatnonzero(p[start:] <= 0.0)[0]  # first sample out
    last_acting = end + np.flatnonzero(acting[end:])[-1] if acting[end:].any() else end - 1
    out = {
        "peak_force_N": float(np.max(np.linalg.norm(force[start:end], axis=1))),
        "peak_torque_Nm": float(np.max(np.linalg.norm(torque[start:end], axis=1))),
        "entry": (vel[start], spin[start]),
        "exit": (vel[last_acting + 1], spin[last_acting + 1]),
        "duration": float(
            (t[end] - p[end] * (t[end] - t[end - 1]) / (p[end] - p[end - 1]))
            - (t[start] - p[start] * (t[start] - t[start - 1]) / (p[start] - p[start - 1]))
        ),
    }
    return out


def _relative_spin(run, target_interface=(0.0, 0.0, 0.0, 1.0)):
    """R_B^T (omega_1 - omega_2) from the run's attitudes (the target's interface is its body frame here)."""
    from scipy.spatial.transform import Rotation

    rb = Rotation.from_quat(run.orientations[:, 1]) * Rotation.from_quat(target_interface)
    return rb.inv().apply(run.omegas[:, 0] - run.omegas[:, 1])


N_LIVE = 1801  # ticks of the scene's default run: its whole contact (1.57 s) and after


@pytest.fixture(scope="module")
def live():
    """hil6.yaml's defaults (offset 0.05 m, tilt 0.02 rad, spin 0.01 rad/s, 32 ms), composed: its summary."""
    return summary_of(HIL6, {}, N_LIVE)


def test_off_axis_summary_is_the_librarys_hybrid_run_against_its_ideal_run(live):
    n = N_LIVE
    six = live
    hyb = library_run(0.05, 0.02, 0.01, 0.032, n)
    acting = np.any(hyb.force != 0.0, axis=1) | np.any(hyb.generalized != 0.0, axis=1)
    want = _first_contact_metrics(
        hyb.t, hyb.e[:, 0], hyb.rate[:, 0], hyb.force, hyb.torque, hyb.rate[:, :3], _relative_spin(hyb), acting
    )
    assert want["peak_torque_Nm"] > 1.0  # off the axis: torque acts
    assert rel(six["peak_force_N"], want["peak_force_N"]) < 1e-12
    assert rel(six["peak_torque_Nm"], want["peak_torque_Nm"]) < 1e-12
    assert rel(six["contact_duration_s"], want["duration"]) < 1e-9
    for when in ("entry", "exit"):
        assert np.allclose(six[f"{when}_relative_velocity_mps"], want[when][0], rtol=0, atol=1e-15)
        assert np.allclose(six[f"{when}_relative_angular_velocity_radps"], want[when][1], rtol=0, atol=1e-15)
    # The ideal contact on the scene's bodies and start, run by the library with its default order.
    chaser, target = hyb_bodies()
    from dockhil.contact.rigidbody import BodyState
    from dockhil.contact.rotations import quat_from_rotvec

    s1 = BodyState([-1.0, 0.05, 0.0], quat_from_rotvec([0.0, 0.0, 0.02]), [0.03, 0.0, 0.0], [0.01, 0.0, 0.0])
    s2 = BodyState([2.0, 0.0, 0.0], (0.0, 0.0, 0.0, 1.0), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    ideal = Contact6([3000.0] * 3 + [300.0] * 3, [40.0] * 3 + [4.0] * 3)
    ref = simulate_contact6(chaser, target, s1, s2, ideal, dt=DT, t_end=(n - 1) * DT)
    assert abs(six["ideal"]["peak_force_N"] - ref.peak("force")) < 1e-12 * ref.peak("force")
    assert abs(six["ideal"]["peak_torque_Nm"] - ref.peak("torque")) < 1e-12 * ref.peak("torque")
    ideal_metrics = _first_contact_metrics(
        ref.t, ref.e[:, 0], ref.rate[:, 0], ref.force, ref.torque, ref.rate[:, :3], _relative_spin(ref), ref.in_contact
    )
    assert np.allclose(six["ideal"]["exit_relative_velocity_mps"], ideal_metrics["exit"][0], rtol=0, atol=1e-15)
    assert np.allclose(
        six["ideal"]["exit_relative_angular_velocity_radps"], ideal_metrics["exit"][1], rtol=0, atol=1e-15
    )
    # Errors are run - ideal, componentwise; with the robot's 32 ms delay a few per cent (docs/sixdof.md).
    err = six["error"]
    assert err["exit_relative_velocity_mps"] == [
        a - b for a, b in zip(six["exit_relative_velocity_mps"], six["ideal"]["exit_relative_velocity_mps"])
    ]
    assert 0.005 < err["peak_force_N"] / six["ideal"]["peak_force_N"] < 0.05
    text = format_summary(six)
    assert "peak torque |T|" in text and "exit ang. vel." in text and "ideal" in text


def hyb_bodies():
    from dockhil.contact.rigidbody import RigidBody

    return (
        RigidBody(750.0, np.diag([300.0, 400.0, 500.0]), interface_position=[1.0, 0.0, 0.0]),
        RigidBody(1e6, np.diag([4e6, 5e6, 6e6]), interface_position=[-2.0, 0.0, 0.0]),
    )


def test_a_recorded_run_gives_the_live_runs_summary(tmp_path, live):
    path = tmp_path / "summary.json"
    r = subprocess.run(
        dockhil_cmd("launch", HIL6, "--duration", "1.8", "--summary", path, "--quiet"),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    recorded = json.loads(path.read_text())
    for key in (
        "peak_force_N",
        "peak_torque_Nm",
        "contact_duration_s",
        "exit_relative_velocity_mps",
        "exit_relative_angular_velocity_radps",
    ):
        assert recorded[key] == live[key], key
    assert recorded["ideal"] == live["ideal"]


def test_a_run_that_stops_inside_the_contact_says_so():
    six = summary_of(HIL6, {}, 500)
    assert six["contact_duration_s"] is None and six["exit_relative_velocity_mps"] is None
    assert "had not ended" in six["note"]
    assert six["ideal"]["exit_relative_velocity_mps"] is None  # the ideal, run as long, has not ended either
    assert six["error"]["exit_relative_velocity_mps"] is None
