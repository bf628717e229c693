"""The ideal contact (Eq. 1): closed form against an independent integration,
the summary (peak force, duration, exit velocity), and unilateral contact."""

import math

import numpy as np
import pytest

from dockhil.contact import (
    TABLE1,
    ContactModelError,
    ContactScenario,
    contact_duration,
    ideal_contact_force,
    ideal_contact_summary,
    ideal_trajectory,
    relative_motion,
    simulate_reference,
)

SCENARIOS = {
    "table1": TABLE1,
    "heavy damping, underdamped": TABLE1.replace(bcs=2000.0),
    "overdamped": TABLE1.replace(bcs=5000.0),
    "pure damper": TABLE1.replace(kcs=0.0),
    "equal masses": ContactScenario(m1=10.0, m2=10.0, kcs=5e4, bcs=30.0, v1=0.2, v2=-0.1),
}


def test_table1_summary_values():
    s = ideal_contact_summary(TABLE1)
    m = 750.0 * 1e6 / (1e6 + 750.0)
    sigma = 40.0 / (2 * m)
    omega_d = math.sqrt(3000.0 / m - sigma**2)
    assert s.duration == pytest.approx(math.pi / omega_d, rel=1e-14)
    assert s.restitution == pytest.approx(math.exp(-sigma * math.pi / omega_d), rel=1e-14)
    assert s.exit_relative_velocity == pytest.approx(-0.03 * s.restitution, rel=1e-14)
    # momentum is conserved through the contact
    assert 750.0 * s.exit_v1 + 1e6 * s.exit_v2 == pytest.approx(750.0 * 0.03, rel=1e-12)
    assert s.regime == "underdamped"
    assert 40.0 < s.peak_force < 0.03 * math.sqrt(3000.0 * m)  # below the undamped peak v0 sqrt(kcs m)


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_closed_form_matches_solve_ivp(name):
    scn = SCENARIOS[name]
    s = ideal_contact_summary(scn)
    end = s.duration * 1.3 if math.isfinite(s.duration) else 20.0 * scn.reduced_mass / scn.bcs
    t = np.linspace(0.0, end, 400)
    ref = simulate_reference(scn, t)
    cf = ideal_trajectory(scn, t)
    scale_x = max(np.max(np.abs(ref.x1)), 1e-12)
    assert np.max(np.abs(cf.x1 - ref.x1)) < 1e-8 * scale_x
    assert np.max(np.abs(cf.v1 - ref.v1)) < 1e-8 * abs(scn.closing_velocity)
    assert np.max(np.abs(cf.force - ref.force)) < 1e-7 * max(s.peak_force, 1.0)
    if math.isfinite(s.duration):
        assert ref.exit == pytest.approx(s.duration, rel=1e-9)
        assert ref.v1[-1] == pytest.approx(s.exit_v1, rel=1e-8)
    else:
        assert ref.exit is None


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_peak_force_is_the_maximum_over_the_contact(name):
    scn = SCENARIOS[name]
    s = ideal_contact_summary(scn)
    end = s.duration if math.isfinite(s.duration) else 50.0 * scn.reduced_mass / scn.bcs
    t = np.linspace(0.0, end, 200001)[:-1]
    p, pd = relative_motion(scn.reduced_mass, scn.kcs, scn.bcs, scn.closing_velocity, t)
    force = scn.kcs * p + scn.bcs * pd
    assert s.peak_force == pytest.approx(force.max(), rel=1e-8)
    assert s.peak_force >= force.max() - 1e-12
    assert abs(s.time_of_peak - t[np.argmax(force)]) <= 2 * (t[1] - t[0]) + 1e-9


def test_force_pulls_just_before_separation_and_penetration_ends_at_zero():
    s = ideal_contact_summary(TABLE1)
    m = TABLE1.reduced_mass
    p_end, pd_end = relative_motion(m, 3000.0, 40.0, 0.03, s.duration)
    assert abs(p_end) < 1e-15
    late = s.duration * (1 - 1e-3)
    p, pd = relative_motion(m, 3000.0, 40.0, 0.03, late)
    assert p > 0.0
    assert ideal_contact_force(p, pd, 3000.0, 40.0) < 0.0  # the documented pull
    assert ideal_contact_force(-1e-9, -0.1, 3000.0, 40.0) == 0.0
    arr = ideal_contact_force(np.array([-1.0, 0.0, 0.01]), np.array([1.0, 1.0, 0.0]), 3000.0, 40.0)
    assert arr.tolist() == [0.0, 0.0, 30.0]


def test_unilateral_trajectory_phases():
    gap = 0.006
    t = np.linspace(0.0, 3.0, 3001)
    tr = ideal_trajectory(TABLE1, t, gap=gap)
    s = ideal_contact_summary(TABLE1)
    assert tr.onset == pytest.approx(gap / 0.03)
    assert tr.exit == pytest.approx(tr.onset + s.duration)
    before = t < tr.onset
    after = t > tr.exit
    assert not tr.in_contact[before].any() and not tr.in_contact[after].any()
    assert tr.in_contact[(t > tr.onset) & (t < tr.exit)].all()
    assert np.all(tr.force[before] == 0.0) and np.all(tr.force[after] == 0.0)
    assert np.allclose(tr.v1[before], 0.03) and np.allclose(tr.v1[after], s.exit_v1)
    assert np.all(tr.penetration[after] < 0.0)  # separating
    # continuous positions across onset and exit
    assert np.max(np.abs(np.diff(tr.x1))) < 0.03 * (t[1] - t[0]) * 1.01


def test_overdamped_contact_never_ends():
    s = ideal_contact_summary(SCENARIOS["overdamped"])
    assert s.regime == "overdamped"
    assert math.isinf(s.duration)
    assert s.as_dict()["duration"] is None
    assert s.exit_v1 == pytest.approx(s.exit_v2)
    assert math.isinf(contact_duration(1.0, 1.0, 3.0))


def test_summary_refuses_no_contact():
    with pytest.raises(ContactModelError, match=r"does not close in \(v1 - v2 = -0.1 m/s"):
        ideal_contact_summary(TABLE1.replace(v1=-0.1))
    with pytest.raises(ContactModelError, match=r"gap must be"):
        ideal_trajectory(TABLE1, [0.0, 1.0], gap=-1.0)
