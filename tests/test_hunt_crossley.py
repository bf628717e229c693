"""The Hunt-Crossley target contact: its simulated restitution follows the exact relation
alpha v - ln(1 + alpha v) = -alpha e v - ln(1 - alpha e v), whatever k, n and m, and the linear
target's ideal run agrees with Eq. 1's closed form."""

import math

import pytest
from scipy.optimize import brentq

from dockhil.contact.hunt_crossley import (
    TargetContact,
    alpha_for_restitution,
    ideal_relative_run,
    linear_damping_for_restitution,
    restitution,
)
from dockhil.contact.ideal import ideal_contact_summary
from dockhil.contact.scenario import ContactModelError, ContactScenario


def relation_e(alpha, v):
    """e from the relation, solved here with scipy's brentq (independently of the module's bisection)."""
    lhs = alpha * v - math.log(1.0 + alpha * v)
    return brentq(lambda e: -alpha * e * v - math.log(1.0 - alpha * e * v) - lhs, 1e-12, (1 - 1e-12) / (alpha * v))


@pytest.mark.parametrize(
    "k, n, m, alpha, v0",
    [
        (1e5, 1.5, 100.0, 2.0, 0.1),
        (1e7, 1.5, 100.0, 2.0, 0.1),  # 100 x stiffer: the same e
        (1e5, 1.0, 100.0, 2.0, 0.1),
        (3e4, 2.2, 750.0, 2.0, 0.1),
        (1e5, 1.5, 5.0, 6.0, 0.05),
        (2e6, 1.5, 100.0, 0.5, 0.3),
    ],
)
def test_simulated_restitution_follows_the_exact_relation(k, n, m, alpha, v0):
    contact = TargetContact("hunt_crossley", k, n=n, alpha=alpha)
    # A tick that resolves the contact: its duration is of order (m / k)^(1/(n+1)) v0^((1-n)/(n+1)).
    scale = (m / k) ** (1 / (n + 1)) * v0 ** ((1 - n) / (n + 1))
    dt = scale / 100
    run = ideal_relative_run(contact, m, v0, dt, n_ticks=1000)
    expected = relation_e(alpha, v0)
    assert run.restitution == pytest.approx(expected, abs=2e-7)
    assert restitution(alpha, v0) == pytest.approx(expected, abs=1e-12)
    # The force is continuous: it starts and ends at 0 (no jump at impact).
    assert run.force[0] == 0.0


def test_restitution_does_not_depend_on_stiffness_exponent_or_mass():
    es = []
    for k, n, m in ((1e5, 1.5, 100.0), (1e6, 1.2, 40.0), (5e4, 2.0, 300.0)):
        scale = (m / k) ** (1 / (n + 1)) * 0.1 ** ((1 - n) / (n + 1))
        es.append(ideal_relative_run(TargetContact("hunt_crossley", k, n=n, alpha=3.0), m, 0.1, scale / 100, 1000))
    assert max(r.restitution for r in es) - min(r.restitution for r in es) < 5e-7
    # ... but on the closing velocity it does: faster, more dissipation (e falls).
    assert restitution(3.0, 0.2) < restitution(3.0, 0.1) < restitution(3.0, 0.05)


@pytest.mark.parametrize("e", [0.3, 0.6, 0.9])
def test_alpha_for_a_restitution_gives_that_restitution(e):
    alpha = alpha_for_restitution(e, 0.1)
    assert relation_e(alpha, 0.1) == pytest.approx(e, abs=1e-10)


def test_the_linear_target_agrees_with_the_closed_form_of_eq1():
    scn = ContactScenario(750.0, 1e6, 3000.0, 40.0, 1000.0, 0.03, 0.0)
    ref = ideal_contact_summary(scn)
    run = ideal_relative_run(TargetContact("linear", 3000.0, 40.0), scn.reduced_mass, 0.03, 1e-3, 2000)
    assert run.restitution == pytest.approx(ref.restitution, abs=1e-6)
    assert run.peak_force == pytest.approx(ref.peak_force, rel=1e-6)
    assert run.duration == pytest.approx(ref.duration, abs=1e-6)
    assert run.impulse == pytest.approx(scn.reduced_mass * 0.03 * (1 + ref.restitution), rel=1e-6)


@pytest.mark.parametrize("e", [0.3, 0.6, 0.9])
def test_linear_damping_for_a_restitution(e):
    b = linear_damping_for_restitution(e, 100.0, 1e4)
    run = ideal_relative_run(TargetContact("linear", 1e4, b), 100.0, 0.1, 1e-4, 5000)
    assert run.restitution == pytest.approx(e, abs=1e-6)


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"kind": "hertz", "kcs": 1.0}, "contact must be one of"),
        ({"kind": "hunt_crossley", "kcs": 1.0, "n": 0.5}, "hc_n must be between 1 and 3"),
        ({"kind": "hunt_crossley", "kcs": 1.0, "alpha": -1.0}, "alpha must be finite and >= 0"),
        ({"kind": "linear", "kcs": math.nan}, "kcs must be finite"),
    ],
)
def test_bad_contacts_are_refused_in_one_line(kw, words):
    with pytest.raises(ContactModelError, match=words):
        TargetContact(**kw)
