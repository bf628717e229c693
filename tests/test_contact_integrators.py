"""Integrators: the numpy matrix exponential, each method against the closed
form with its convergence order, the largest stable steps against their closed
forms, the refusal of unstable explicit steps, and unilateral contact runs."""

import math

import numpy as np
import pytest

from dockhil.contact import (
    TABLE1,
    ContactScenario,
    Integrator,
    LinearSecondOrderSystem,
    StepTooLargeError,
    UnstableStepWarning,
    expm,
    ideal_contact_force,
    ideal_contact_summary,
    ideal_trajectory,
    max_stable_step,
    simulate_contact,
    simulate_reference,
)

CONTACT = LinearSecondOrderSystem.ideal_contact(TABLE1)
M = TABLE1.reduced_mass
SIGMA = TABLE1.bcs / (2 * M)
OMEGA_N = math.sqrt(TABLE1.kcs / M)


def test_expm_matches_scipy():
    from scipy.linalg import expm as scipy_expm

    rng = np.random.default_rng(7)
    cases = [rng.normal(size=(n, n)) * scale for n in (1, 4, 6) for scale in (1e-6, 1.0, 30.0)]
    cases.append(np.array([[0.0, 1.0], [0.0, 0.0]]))  # nilpotent (free body)
    cases.append(step_aug := np.block([[CONTACT.A, CONTACT.B], [np.zeros((2, 6))]]) * 0.5)
    for a in cases:
        expected = scipy_expm(a)
        assert np.allclose(expm(a), expected, rtol=1e-12, atol=1e-14 * np.max(np.abs(expected)))
    assert step_aug.shape == (6, 6)


def _contact_phase(method, dt, t_end=1.0):
    """Integrate the contact phase from onset to t_end (inside the contact)."""
    integ = Integrator(CONTACT, method)
    x = np.array([0.0, 0.0, TABLE1.v1, TABLE1.v2])
    steps = int(round(t_end / dt))
    for _ in range(steps):
        x = integ.step(x, None, dt)
    ref = ideal_trajectory(TABLE1, [steps * dt])
    return np.max(np.abs(x - np.array([ref.x1[0], ref.x2[0], ref.v1[0], ref.v2[0]])))


@pytest.mark.parametrize(
    "method, dt, order",
    [("euler", 0.01, 1), ("symplectic_euler", 0.01, 1), ("rk4", 0.05, 4)],
)
def test_convergence_order_against_closed_form(method, dt, order):
    errors = [_contact_phase(method, dt / 2**i) for i in range(3)]
    observed = [math.log2(a / b) for a, b in zip(errors, errors[1:])]
    for rate in observed:
        assert rate == pytest.approx(order, abs=0.15), (errors, observed)


def test_exact_step_is_exact_for_any_step():
    for dt in (1e-3, 0.1, 0.5):
        assert _contact_phase("exact", dt) < 1e-14


def test_exact_step_with_zero_order_hold_input():
    # one free body under a constant force: x = F t^2 / (2 m) exactly
    integ = Integrator(LinearSecondOrderSystem.free([750.0]), "exact")
    x = integ.step(np.array([0.0, 0.0]), np.array([10.0]), 2.0)
    assert x == pytest.approx([10.0 * 4.0 / (2 * 750.0), 10.0 * 2.0 / 750.0], rel=1e-14)


def test_largest_stable_steps_against_closed_forms():
    assert max_stable_step(CONTACT, "exact") == math.inf
    # explicit Euler on a damped oscillator: |1 + lambda dt| <= 1  <=>  dt <= 2 sigma / omega_n^2 = bcs / kcs
    assert max_stable_step(CONTACT, "euler") == pytest.approx(TABLE1.bcs / TABLE1.kcs, rel=1e-9)
    # semi-implicit Euler: Jury's test on its 2x2 step gives 2 (sqrt(sigma^2 + omega_n^2) - sigma) / omega_n^2
    expected = 2 * (math.sqrt(SIGMA**2 + OMEGA_N**2) - SIGMA) / OMEGA_N**2
    assert max_stable_step(CONTACT, "symplectic_euler") == pytest.approx(expected, rel=1e-9)
    # RK4 reaches 2 sqrt(2) on the imaginary axis
    undamped = LinearSecondOrderSystem.ideal_contact(TABLE1.replace(bcs=0.0))
    assert max_stable_step(undamped, "rk4") == pytest.approx(2 * math.sqrt(2) / OMEGA_N, rel=1e-9)
    assert max_stable_step(undamped, "symplectic_euler") == pytest.approx(2 / OMEGA_N, rel=1e-9)
    assert max_stable_step(undamped, "euler") == 0.0
    # free bodies: no limit for any method
    assert max_stable_step(LinearSecondOrderSystem.free([1.0, 2.0]), "euler") == math.inf


def test_growing_physics_is_not_blamed_on_the_method():
    # a negative spring grows like e^{t}: RK4 is limited by the decaying mode only (2.785 on the real axis)
    saddle = LinearSecondOrderSystem([1.0], [[-1.0]])
    assert max_stable_step(saddle, "rk4") == pytest.approx(2.785293563, rel=1e-6)


def test_explicit_step_outside_stability_region_is_refused():
    integ = Integrator(CONTACT, "euler")
    x = np.array([0.0, 0.0, 0.03, 0.0])
    with pytest.raises(
        StepTooLargeError, match=r"explicit Euler with dt = 0\.02 s .* largest stable step is 0\.0133333 s"
    ):
        integ.step(x, None, 0.02)
    integ.step(x, None, 0.013)  # inside: fine
    with pytest.raises(StepTooLargeError, match=r"RK4 with dt = 2 s .* largest stable step is 1\.42"):
        Integrator(CONTACT, "rk4").step(x, None, 2.0)
    undamped = LinearSecondOrderSystem.ideal_contact(TABLE1.replace(bcs=0.0))
    with pytest.raises(StepTooLargeError, match=r"no step is stable.*symplectic_euler"):
        Integrator(undamped, "euler").step(x, None, 1e-4)
    with pytest.raises(StepTooLargeError, match=r"largest stable step is 0\.0133333 s"):
        simulate_contact(TABLE1, method="euler", dt=0.05)


def test_unstable_step_only_warns_when_asked():
    integ = Integrator(CONTACT, "euler", on_unstable="warn")
    x = np.array([0.0, 0.0, 0.03, 0.0])
    with pytest.warns(UnstableStepWarning, match=r"largest stable step is 0\.0133333 s"):
        y = integ.step(x, None, 0.02)
    assert np.all(np.isfinite(y))
    # and the instability is real: the step amplifies the contact mode
    for _ in range(20000):  # |1 + lambda dt| = 1.00027: 200-fold in 400 s
        y = integ.step(y, None, 0.02)
    assert abs(y[0] - y[1]) > 100 * 0.015


@pytest.mark.parametrize(
    "method, dt, tol",
    [("exact", 1e-2, 1e-12), ("rk4", 1e-2, 1e-8), ("symplectic_euler", 1e-3, 2e-3), ("euler", 1e-3, 5e-2)],
)
def test_unilateral_run_matches_closed_form(method, dt, tol):
    gap = 0.0046  # onset between samples: no sample sits on the contact instant
    run = simulate_contact(TABLE1, method=method, dt=dt, gap=gap)
    ref = ideal_trajectory(TABLE1, run.t, gap=gap)
    summary = ideal_contact_summary(TABLE1)
    assert run.onset == pytest.approx(ref.onset, abs=max(tol, 1e-12))
    assert run.exit == pytest.approx(ref.exit, rel=tol)
    assert run.v1[-1] == pytest.approx(summary.exit_v1, rel=tol)
    assert np.max(np.abs(run.force - ref.force)) < tol * summary.peak_force


def test_event_location_keeps_the_order_of_rk4():
    summary = ideal_contact_summary(TABLE1)
    exact_exit = ideal_trajectory(TABLE1, [0.0], gap=0.0013).exit
    errors = [abs(simulate_contact(TABLE1, method="rk4", dt=dt, gap=0.0013).exit - exact_exit) for dt in (0.05, 0.025)]
    assert math.log2(errors[0] / errors[1]) == pytest.approx(4, abs=0.2)
    # the exit velocity converges at least as fast
    assert abs(simulate_contact(TABLE1, method="rk4", dt=0.025, gap=0.0013).v1[-1] - summary.exit_v1) < 1e-9


def test_run_with_thrust_matches_solve_ivp():
    # constant 10 N thrust on the chaser into the target (the paper's capture-mode setup, Sec. 5.2)
    scn = ContactScenario(m1=750.0, m2=1e6, kcs=2510.0, bcs=60.0, v1=0.01)
    run = simulate_contact(scn, method="exact", dt=1e-2, t_end=6.0, gap=0.002, thrust=(10.0, 0.0))
    ref = simulate_reference(scn, run.t, gap=0.002, thrust=(10.0, 0.0))
    assert run.onset == pytest.approx(ref.onset, rel=1e-9)
    assert np.max(np.abs(run.x1 - ref.x1)) < 1e-9
    assert np.max(np.abs(run.force - ref.force)) < 1e-6


def test_per_step_node_style_coupling_converges_to_closed_form():
    # A simulation node integrates free bodies and feeds the contact force back as a held input.
    free = Integrator(LinearSecondOrderSystem.free([TABLE1.m1, TABLE1.m2]), "exact")
    ref_t = 1.0

    def run(dt):
        x = np.array([0.0, 0.0, TABLE1.v1, TABLE1.v2])
        for _ in range(int(round(ref_t / dt))):
            f = ideal_contact_force(x[0] - x[1], x[2] - x[3], TABLE1.kcs, TABLE1.bcs)
            x = free.step(x, np.array([-f, f]), dt)
        return x

    ref = ideal_trajectory(TABLE1, [ref_t])
    errors = [abs(run(dt)[2] - ref.v1[0]) for dt in (4e-3, 2e-3)]
    assert math.log2(errors[0] / errors[1]) == pytest.approx(1, abs=0.15)
    assert errors[1] < 1e-3 * TABLE1.v1
