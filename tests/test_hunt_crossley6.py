"""A Hunt-Crossley target on the normal of the 6-DOF contact (hil6.yaml's contact:=hunt_crossley): the ideal
6-DOF contact's normal follows hunt_crossley.py's law and restitution and is, head on, the 1-DOF ideal; the
hybrid loop with a delay compensation reproduces it along the normal; hil6.yaml runs it and refuses a bad
value in one line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dockhil.contact import compensation_grid as grid
from dockhil.contact.compensation import CompensationSettings
from dockhil.contact.comploop import Hardware
from dockhil.contact.contact6 import Contact6, hunt_crossley_normal, simulate_contact6
from dockhil.contact.hunt_crossley import TargetContact, alpha_for_restitution, ideal_relative_run, restitution
from dockhil.contact.hybrid6 import NormalCompensation6, simulate_hybrid6
from dockhil.contact.passivity import DEFAULT_MAX_DAMPING, Passivity
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.scenario import ContactModelError
from tests.support.inprocess import completed
from tests.test_sixdof_graph import HIL6

M1, M2, V = 750.0, 1e6, 0.03
REDUCED = M1 * M2 / (M1 + M2)
KCS = 30000.0  # N/m^1.5: about the depth of hil6.yaml's linear normal (kcs 3000 N/m), 15 mm


def head_on(gap: float = 0.0) -> tuple:
    """hil6.yaml's bodies with offset, tilt and spin 0: the chaser's interface `gap` [m] short of the target's."""
    chaser = RigidBody(M1, np.diag([300.0, 400.0, 500.0]), interface_position=[1.0, 0.0, 0.0])
    target = RigidBody(M2, np.diag([4e6, 5e6, 6e6]), interface_position=[-2.0, 0.0, 0.0])
    s1 = BodyState([-1.0 - gap, 0.0, 0.0], (0.0, 0.0, 0.0, 1.0), [V, 0.0, 0.0], [0.0, 0.0, 0.0])
    s2 = BodyState([2.0, 0.0, 0.0], (0.0, 0.0, 0.0, 1.0), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    return chaser, target, s1, s2


def contacts(target: TargetContact) -> tuple[Contact6, Contact6]:
    """(ideal with the target on its normal, passive) of hil6.yaml's defaults."""
    linear = Contact6([3000.0] * 3 + [300.0] * 3, [40.0] * 3 + [4.0] * 3)
    return hunt_crossley_normal(linear, target, REDUCED, V), Contact6([1000.0] * 3 + [100.0] * 3)


@pytest.mark.parametrize("e", [0.9, 0.6])
def test_the_ideal_6dof_contact_head_on_is_the_exact_hunt_crossley_contact_and_the_1dof_ideal(e):
    target = TargetContact("hunt_crossley", KCS, n=1.5, alpha=alpha_for_restitution(e, V))
    ideal, _passive = contacts(target)
    run = simulate_contact6(*head_on(gap=0.003), ideal, dt=1e-3, t_end=2.0)
    assert run.onset == pytest.approx(0.1, abs=1e-9) and run.exit is not None
    # The restitution of the exact relation, alpha v - ln(1 + alpha v) = -alpha e v - ln(1 - alpha e v).
    assert -run.rate[-1, 0] / run.rate[0, 0] == pytest.approx(restitution(target.alpha, V), abs=1e-8)
    assert restitution(target.alpha, V) == pytest.approx(e, abs=1e-9)
    # Its normal is hunt_crossley.py's law at each sample: kcs d^n (1 + alpha d'), 0 apart.
    law = np.array([target.force(d, r) for d, r in zip(run.e[:, 0], run.rate[:, 0])])
    assert np.max(np.abs(run.normal_force - law)) <= 1e-9 * np.max(law) and np.max(law) > 30.0
    assert np.all(run.normal_force >= 0.0)
    # ... and, head on, the 1-DOF ideal on the relative coordinate, from the onset on.
    start = 100
    one = ideal_relative_run(target, REDUCED, V, 1e-3, run.t.size - start)
    assert run.exit - run.onset == pytest.approx(one.duration, abs=1e-8)
    assert np.max(np.abs(run.e[start:, 0] - np.array(one.p))) <= 1e-8 * np.max(one.p)
    assert np.max(np.abs(run.normal_force[start:] - np.array(one.force))) <= 1e-8 * one.peak_force
    # Nothing off the axis moves; kinetic energy and the law's potential kcs d^(n+1) / (n+1) only fall.
    assert np.all(run.e[:, 1:] == 0.0)
    energy = run.energy[run.in_contact]
    assert np.all(np.diff(energy) <= 1e-9 * energy[0])
    moving = 0.5 * (M1 * V) ** 2 / (M1 + M2)  # the centre of mass's, which the contact keeps
    e2 = (energy[-1] - moving) / (energy[0] - moving)
    assert e2 == pytest.approx(restitution(target.alpha, V) ** 2, abs=1e-6)


def test_a_hunt_crossley_normal_refuses_what_it_cannot_be_in_one_error():
    target = TargetContact("hunt_crossley", KCS, alpha=2.0)
    coupled = np.diag([3000.0] * 3 + [300.0] * 3)
    coupled[0, 4] = coupled[4, 0] = 10.0
    with pytest.raises(ContactModelError, match="normal row couples x to the other axes"):
        hunt_crossley_normal(Contact6(coupled), target, REDUCED, V)
    with pytest.raises(ContactModelError, match="kcs .* must be > 0"):
        hunt_crossley_normal(Contact6([1.0] * 6), TargetContact("hunt_crossley", 0.0), REDUCED, V)
    with pytest.raises(ContactModelError, match="must be a hunt_crossley contact"):
        Contact6([1.0] * 6, normal=TargetContact("linear", 1.0))
    # Where the law would pull (alpha d' < -1, which a loop that makes energy can reach), it gives 0.
    assert target.force(0.01, -0.6) == 0.0 and target.force(0.01, -0.4) > 0.0


def loop6(target: TargetContact, method: str, delay: float, gap: float = 0.0, n: int = 2000):
    """The 6-DOF hybrid loop head on with the target, `method` along the normal told `delay`."""
    ideal, passive = contacts(target)
    comp = None
    if method != "none":
        omega = math.sqrt(float(ideal.stiffness[0, 0]) / REDUCED)
        settings = CompensationSettings(method, 1000.0, delay, 0.0, omega, 0.0, 0.0)
        passivity = Passivity(1000.0, DEFAULT_MAX_DAMPING) if "passivity" in method else None
        comp = NormalCompensation6(ideal, passive, settings, REDUCED, 1e-3, passivity)
    return simulate_hybrid6(
        *head_on(gap),
        ideal,
        passive,
        dt=1e-3,
        t_end=(n - 1) * 1e-3,
        delay_ticks=round(delay / 1e-3),
        order=2,
        compensation=comp,
    )


def test_a_phase_lead_on_a_hunt_crossley_normal_is_tuned_at_its_secant_stiffness():
    from dockhil.contact.comploop import target_frequency

    target = TargetContact("hunt_crossley", KCS, n=1.5, alpha=2.0)
    ideal, _passive = contacts(target)
    # The normal entry is the linear equivalent: its frequency is the 1-DOF loop's for the target.
    assert math.sqrt(ideal.stiffness[0, 0] / REDUCED) == pytest.approx(target_frequency(target, REDUCED, V), 1e-12)
    deepest = (2.5 * REDUCED * V * V / (2.0 * KCS)) ** (1.0 / 2.5)
    assert ideal.stiffness[0, 0] == pytest.approx(KCS * deepest**0.5, rel=1e-12)  # the secant F / d there


@pytest.mark.parametrize("e", [0.9, 0.6])
def test_the_compensated_6dof_loop_reproduces_the_hunt_crossley_restitution_off_the_axis(e):
    scene = next(s for s in grid.OFFAXIS6_SCENES if s.target_name == f"hunt_crossley e {e:g}")
    ref = grid.reference6(scene)
    ideal_e = grid.normal_metrics6(ref.run, ref.run, M1)["restitution"]
    # Off the axis the contact turns the chaser; on the normal its restitution is still about the law's.
    assert ideal_e == pytest.approx(e, abs=0.01)
    rows = {m: grid.run_point(scene, ref, m, 0.16, "as_told", Hardware()) for m in ("none", "passivity", "predictor")}
    assert all(r["error"] is None for r in rows.values()), rows
    for method in ("passivity", "predictor"):
        assert abs(rows[method]["restitution_error"]) <= 0.005, rows[method]
        assert abs(rows[method]["peak_force_error"]) <= 0.02, rows[method]
    assert rows["none"]["restitution_error"] > 0.03  # the delay makes energy
    assert all(rows["none"]["restitution_error"] > 20 * abs(rows[m]["restitution_error"]) for m in rows if m != "none")
    mismatch = Hardware(k_scale=0.7, delay_scale=1.2)
    predictor = grid.run_point(scene, ref, "predictor", 0.16, "mismatch", mismatch)
    assert abs(predictor["restitution_error"]) <= 0.01 and abs(predictor["impulse_error"]) <= 0.02, predictor


def test_head_on_the_6dof_loop_with_a_hunt_crossley_target_and_the_predictor_is_the_1dof_loop():
    from dockhil.contact.comploop import ZERO, simulate_compensated, target_frequency

    target = TargetContact("hunt_crossley", KCS, n=1.5, alpha=alpha_for_restitution(0.6, V))
    delay, n = 0.08, 2000
    six = loop6(target, "predictor", delay, n=n)
    one = simulate_compensated(
        m1=M1,
        m2=M2,
        k=1000.0,
        impedance=ZERO,
        dt=1e-3,
        n_ticks=n,
        delay=delay,
        settings=CompensationSettings("predictor", 1000.0, delay, 0.0, target_frequency(target, REDUCED, V)),
        contact=target,
        v1=V,
    )
    v1 = six.velocities[:, 0, 0]
    assert np.max(np.abs(v1 - one.v1)) <= 1e-9 * V
    e_loop = -(one.v1[-1] - one.v2[-1]) / V
    assert e_loop == pytest.approx(restitution(target.alpha, V), abs=0.003)
    plain = loop6(target, "none", delay, n=n)
    assert -plain.rate[-1, 0] / V > restitution(target.alpha, V) + 0.03  # uncompensated: the delay makes energy


def summary_of(tmp_path, *args: str) -> tuple:
    out = tmp_path / "s.json"
    r = completed("launch", HIL6, *args, "--composed", "--duration", "2", "--quiet", "--summary", out)
    return r, (json.loads(out.read_text()) if out.exists() else None)


def test_hil6_runs_a_hunt_crossley_target_valid_against_its_ideal(tmp_path):
    alpha = 8.0
    r, s = summary_of(tmp_path, "contact:=hunt_crossley", f"kcs:={KCS:g}", f"hc_alpha:={alpha:g}")
    assert r.returncode == 0, r.stderr
    assert s["valid"] is not False and s["dof"] == 6
    # The summary's ideal is the Hunt-Crossley one: off the axis, about the law's restitution at 0.03 m/s.
    assert s["ideal"]["restitution"] == pytest.approx(restitution(alpha, V), abs=0.01)
    assert abs(s["error"]["restitution"]) > 0.01  # 32 ms, uncompensated: the delay makes energy
    r, c = summary_of(
        tmp_path, "contact:=hunt_crossley", f"kcs:={KCS:g}", f"hc_alpha:={alpha:g}", "compensation:=predictor"
    )
    assert r.returncode == 0, r.stderr
    assert c["ideal"] == s["ideal"] and abs(c["error"]["restitution"]) <= 0.005, c["error"]


@pytest.mark.parametrize(
    "args, words",
    [
        (("hc_n:=0.5",), "hc_n"),
        (("hc_alpha:=-1",), "hc_alpha"),
        (("kcs:=0",), "kcs"),
        (("contact:=hertz",), "contact"),
    ],
)
def test_hil6_refuses_a_bad_hunt_crossley_value_in_one_line(args, words):
    r = completed("launch", HIL6, "contact:=hunt_crossley", *args, "--composed", "--duration", "0.05", "--quiet")
    lines = [line for line in (r.stderr + r.stdout).splitlines() if line.strip()]
    assert r.returncode == 2 and len(lines) == 1 and words in lines[0], lines
    assert "Traceback" not in r.stderr
