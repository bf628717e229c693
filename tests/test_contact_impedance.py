"""Impedance determination (Sec. 3.3): Table 1 by computation, the two-time fit
against the closed form, independence of the initial velocities, refusals, and
the hybrid model (no delay) moving exactly like the ideal one (Fig. 9, cases 1-2)."""

import math
import warnings

import numpy as np
import pytest

from dockhil.contact import (
    TABLE1,
    TABLE1_PRINTED_IMPEDANCE,
    ContactModelError,
    ContactScenario,
    FitError,
    NegativeVirtualStiffnessWarning,
    VirtualImpedance,
    fit_impedance,
    hybrid_contact_forces,
    ideal_contact_force,
    ideal_trajectory,
    impedance_closed_form,
    simulate_contact,
)
from dockhil.contact.impedance import STATE_SOURCES

# Table 1's hybrid column is printed to 5 significant figures.
PAPER_TOLERANCE = 1e-3


@pytest.mark.parametrize("source", STATE_SOURCES)
def test_table1_reproduced_by_the_fit(source):
    fit = fit_impedance(TABLE1, states=source, dt=1e-3)
    for name, printed in TABLE1_PRINTED_IMPEDANCE.items():
        computed = getattr(fit.impedance, name)
        assert computed == pytest.approx(printed, rel=PAPER_TOLERANCE), (name, computed, printed)
    # Tighter than the paper's rounding: 2001.5, 40.03 exactly, k2 and b2 to 5 digits.
    assert fit.impedance.k1 == pytest.approx(2001.5, rel=1e-12)
    assert fit.impedance.b1 == pytest.approx(40.03, rel=1e-12)
    assert fit.impedance.k2 == pytest.approx(2.6687e6, rel=2e-5)
    assert fit.impedance.b2 == pytest.approx(53373.0, rel=1e-5)
    assert fit.agrees


def test_closed_form_matches_table1_and_formula():
    closed = impedance_closed_form(TABLE1)
    assert closed.k1 == pytest.approx(2001.5, rel=1e-14)
    assert closed.b1 == pytest.approx(40.03, rel=1e-14)
    assert closed.k2 == pytest.approx(2000.0 * (1.0 + 1e6 / 750.0), rel=1e-14)
    assert closed.b2 == pytest.approx(40.0 * (1.0 + 1e6 / 750.0), rel=1e-14)
    for name, printed in TABLE1_PRINTED_IMPEDANCE.items():
        assert getattr(closed, name) == pytest.approx(printed, rel=PAPER_TOLERANCE)


@pytest.mark.parametrize("v1, v2", [(0.03, 0.0), (0.3, 0.0), (0.001, -0.002), (-0.1, -0.25), (2.0, 1.5)])
def test_fit_does_not_depend_on_initial_velocities(v1, v2):
    reference = fit_impedance(TABLE1).impedance
    fit = fit_impedance(TABLE1.replace(v1=v1, v2=v2)).impedance
    for name in ("k1", "b1", "k2", "b2"):
        assert getattr(fit, name) == pytest.approx(getattr(reference, name), rel=1e-8)


@pytest.mark.parametrize(
    "scenario",
    [
        TABLE1,
        ContactScenario(m1=10.0, m2=10.0, kcs=5e4, bcs=30.0, k=2e4, v1=0.2, v2=-0.1),
        ContactScenario(m1=2000.0, m2=500.0, kcs=1e5, bcs=3000.0, k=0.0, v1=0.05),
        # over-damped ideal contact: the contact never ends, the fit still works
        ContactScenario(m1=100.0, m2=100.0, kcs=100.0, bcs=500.0, k=50.0, v1=0.1),
        ContactScenario(m1=750.0, m2=1e6, kcs=3000.0, bcs=0.0, k=1000.0, v1=0.03),
    ],
)
def test_fit_equals_closed_form(scenario):
    fit = fit_impedance(scenario)
    closed = impedance_closed_form(scenario)
    assert fit.max_relative_deviation < 1e-9
    for name in ("k1", "b1", "k2", "b2"):
        assert getattr(fit.impedance, name) == pytest.approx(getattr(closed, name), rel=1e-8, abs=1e-8)


def test_fit_at_chosen_times_inside_contact():
    for t1, t2 in [(0.1, 1.4), (1.2, 0.3), (0.7, 0.9)]:
        fit = fit_impedance(TABLE1, t1, t2)
        assert (fit.t1, fit.t2) == (t1, t2)
        assert fit.agrees


def test_refuses_equal_times():
    with pytest.raises(FitError, match=r"t1 = t2 = 0\.5 s .*singular.*choose two distinct times"):
        fit_impedance(TABLE1, 0.5, 0.5)


@pytest.mark.parametrize("t1, t2", [(0.5, 2.0), (-0.1, 0.5), (0.0, 0.5), (0.5, 1.5703473066360272)])
def test_refuses_times_outside_contact(t1, t2):
    with pytest.raises(
        FitError, match=r"outside the contact \(0, 1\.57035\) s.*e\.g\. t1 = 0\.3926 s and t2 = 1\.178 s"
    ):
        fit_impedance(TABLE1, t1, t2)


def test_refuses_ill_conditioned_times():
    with pytest.raises(FitError, match=r"ill-conditioned fit \(condition number .*\).*choose two distinct times"):
        fit_impedance(TABLE1, 0.5, 0.5 + 1e-9)


def test_refuses_times_where_the_contact_has_died_out():
    # over-damped: the contact never ends, but after many time constants the
    # states are round-off around the CoM motion and carry nothing to fit
    heavy = ContactScenario(m1=100.0, m2=100.0, kcs=100.0, bcs=500.0, k=50.0, v1=0.1)
    with pytest.raises(
        FitError, match=r"at t2 = 2000 s the contact motion has decayed to .* too little to fit; .*e\.g\. t1 = "
    ):
        fit_impedance(heavy, 0.1, 2000.0)


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"m1": -750.0}, r"m1 must be > 0 kg"),
        ({"m2": 0.0}, r"m2 must be > 0 kg"),
        ({"kcs": float("nan")}, r"kcs must be a finite number"),
        ({"bcs": -1.0}, r"bcs must be >= 0"),
        ({"k": float("inf")}, r"k must be a finite number"),
        ({"kcs": 0.0, "bcs": 0.0}, r"no force"),
    ],
)
def test_refuses_bad_scenarios(changes, match):
    with pytest.raises(ContactModelError, match=match):
        TABLE1.replace(**changes)


def test_refuses_fit_without_contact():
    with pytest.raises(ContactModelError, match=r"does not close in"):
        fit_impedance(TABLE1.replace(v1=0.0, v2=0.0))


def test_warns_when_kcs_below_k():
    soft = TABLE1.replace(kcs=500.0)
    with pytest.warns(NegativeVirtualStiffnessWarning, match=r"kcs = 500 N/m is below .* k = 1000 N/m"):
        fit = fit_impedance(soft)
    assert fit.impedance.k1 < 0.0 and fit.impedance.k2 < 0.0
    assert fit.warnings and "negative" in fit.warnings[0]
    assert fit.agrees
    with pytest.warns(NegativeVirtualStiffnessWarning):
        impedance_closed_form(soft)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit_impedance(TABLE1)  # kcs > k: no warning


def test_hybrid_forces_equal_ideal_force_with_fitted_impedance():
    imp = fit_impedance(TABLE1).impedance
    rng = np.random.default_rng(3)
    for _ in range(20):
        x2, v1, v2 = rng.normal(size=3) * [1.0, 0.05, 0.05]
        p = abs(rng.normal()) * 0.01
        f1, f2 = hybrid_contact_forces(x2 + p, x2, v1, v2, TABLE1.m1, TABLE1.m2, TABLE1.k, imp)
        ideal = ideal_contact_force(p, v1 - v2, TABLE1.kcs, TABLE1.bcs)
        assert -f1 == pytest.approx(ideal, rel=1e-12)
        assert f2 == pytest.approx(ideal, rel=1e-12)
    assert hybrid_contact_forces(0.0, 0.01, 0.1, 0.0, 750.0, 1e6, 1000.0, imp) == (0.0, 0.0)


def test_hybrid_run_reproduces_ideal_run():
    # Fig. 9, cases 1 and 2: without delay the hybrid model and the ideal one coincide.
    imp = fit_impedance(TABLE1).impedance
    hybrid = simulate_contact(TABLE1, impedance=imp, dt=1e-3, gap=0.005)
    ideal = ideal_trajectory(TABLE1, hybrid.t, gap=0.005)
    assert hybrid.exit == pytest.approx(ideal.exit, abs=1e-9)
    assert np.max(np.abs(hybrid.v1 - ideal.v1)) < 1e-12
    assert np.max(np.abs(hybrid.force - ideal.force)) < 1e-8
    # A wrong impedance does not: the test can tell them apart.
    wrong = VirtualImpedance(imp.k1 * 1.1, imp.b1, imp.k2 * 1.1, imp.b2)
    other = simulate_contact(TABLE1, impedance=wrong, dt=1e-3, gap=0.005)
    assert np.max(np.abs(other.force - ideal.force)) > 1.0


def test_recommended_times_in_fit_result():
    fit = fit_impedance(TABLE1)
    assert fit.t1 == pytest.approx(fit.contact_duration / 4)
    assert fit.t2 == pytest.approx(3 * fit.contact_duration / 4)
    m = TABLE1.reduced_mass
    assert fit.contact_duration == pytest.approx(math.pi / math.sqrt(3000 / m - (40 / (2 * m)) ** 2))


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


def _log_uniform(lo, hi):
    return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: 10.0**e)


@settings(max_examples=150, deadline=None)
@given(
    m1=_log_uniform(1.0, 1e6),
    m2=_log_uniform(1.0, 1e6),
    kcs=_log_uniform(1.0, 1e7),
    zeta=_log_uniform(1e-3, 30.0),
    k_fraction=st.floats(0.0, 0.99),
    v1=st.floats(-1.0, 1.0),
    closing=_log_uniform(1e-4, 1.0),
)
def test_fit_equals_closed_form_for_any_scenario(m1, m2, kcs, zeta, k_fraction, v1, closing):
    bcs = 2.0 * zeta * math.sqrt(kcs * m1 * m2 / (m1 + m2))
    scn = ContactScenario(m1=m1, m2=m2, kcs=kcs, bcs=bcs, k=k_fraction * kcs, v1=v1, v2=v1 - closing)
    fit = fit_impedance(scn)
    # The fit works on absolute states, so it loses the digits by which the
    # velocities exceed the closing velocity, and heavy damping (kcs p drowned
    # in bcs p') costs more: a round-off bound, far below any physical effect.
    speed_ratio = max(abs(scn.v1), abs(scn.v2)) / closing
    assert fit.max_relative_deviation < 1e-9 * (1.0 + speed_ratio) * (1.0 + zeta), fit
