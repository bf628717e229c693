"""Stability with delay (Sec. 4): Eq. 12's numbers, Pade orders, the exact
boundary cross-checked by the rightmost root, the 'no stabilizing K' case,
the undelayed-damper loop, Figs. 11-12 and the Fig. 7 map."""

import math
import time

import numpy as np
import pytest

from dockhil.contact import (
    ContactModelError,
    characteristic_roots,
    critical_stiffness_map,
    exact_bound,
    growth_rate,
    pade1_bound,
    pade_bound,
    rightmost_root,
    stability_report,
)

M, H = 750.0, 0.016


def test_eq12_numbers_of_the_paper():
    assert pade1_bound(M, 20.0, H) == pytest.approx(1250.0, abs=0.5)  # paper: K < 1250 N/m
    assert pade1_bound(M, 60.0, H) == pytest.approx(3748.8, abs=0.05)  # paper: K < 3748.8 N/m
    assert pade1_bound(M, 20.0, H) == pytest.approx(1249.8666524, rel=1e-9)
    assert pade1_bound(M, 60.0, H) == pytest.approx(3748.7996159, rel=1e-9)


@pytest.mark.parametrize("damper", ["delayed", "undelayed"])
@pytest.mark.parametrize("m, b, h", [(M, 20.0, H), (M, 60.0, H), (M, 150.0, 0.032), (1.0, 50.0, 0.02)])
def test_pade_order_1_is_routh_and_higher_orders_converge_to_exact(damper, m, b, h):
    assert pade_bound(m, b, h, 1, damper) == pytest.approx(pade1_bound(m, b, h, damper), rel=1e-9)
    exact = exact_bound(m, b, h, damper).k_max
    errors = [abs(pade_bound(m, b, h, n, damper) - exact) / exact for n in range(1, 7)]
    assert all(later < max(earlier, 1e-12) for earlier, later in zip(errors, errors[1:]))
    assert errors[5] < 1e-9


@pytest.mark.parametrize("damper", ["delayed", "undelayed"])
@pytest.mark.parametrize(
    "m, b, h", [(M, 20.0, H), (M, 60.0, H), (M, 200.0, 0.032), (1.0, 80.0, 0.016), (5.0, 1.0, 0.03)]
)
def test_exact_boundary_is_where_the_rightmost_root_changes_sign(damper, m, b, h):
    bound = exact_bound(m, b, h, damper)
    k = bound.k_max
    assert k is not None and k > 0
    below = growth_rate(m, k * (1 - 1e-4), b, h, damper)
    above = growth_rate(m, k * (1 + 1e-4), b, h, damper)
    assert below < 0.0 < above
    at = rightmost_root(m, k, b, h, damper)
    assert abs(at.real) < 1e-9 * abs(at)
    assert at.imag == pytest.approx(bound.crossing_frequency, rel=1e-7)
    # stable all the way down to small K, unstable well above
    for fraction in (1e-3, 0.1, 0.5, 0.9):
        assert growth_rate(m, k * fraction, b, h, damper) < 0.0
    for factor in (1.5, 4.0):
        assert growth_rate(m, k * factor, b, h, damper) > 0.0


def test_exact_values_at_paper_points_and_pade1_is_slightly_optimistic():
    exact20 = exact_bound(M, 20.0, H).k_max
    exact60 = exact_bound(M, 60.0, H).k_max
    assert exact20 == pytest.approx(1249.8222045, rel=1e-8)
    assert exact60 == pytest.approx(3748.3995219, rel=1e-8)
    # small b h / m: K_max ~ (b / h)(1 - b h / (3 m)) for exact, (b / h)(1 - b h / (4 m)) for Eq. 12
    for b, exact in ((20.0, exact20), (60.0, exact60)):
        beta = b * H / M
        assert exact == pytest.approx(b / H * (1 - beta / 3), rel=1e-6)
        assert pade1_bound(M, b, H) > exact


def test_roots_satisfy_the_characteristic_equation():
    for damper in ("delayed", "undelayed"):
        for K in (100.0, 2510.0, 1e5):
            for s in characteristic_roots(M, K, 20.0, H, damper, count=4):
                e = np.exp(-s * H)
                if damper == "delayed":
                    residual = M * s * s + (K + 20.0 * s) * e
                else:
                    residual = M * s * s + 20.0 * s + K * e
                assert abs(residual) < 1e-8 * (M * abs(s) ** 2 + K + 20 * abs(s))


def test_without_delay_roots_are_the_quadratic_ones():
    root = rightmost_root(M, 3000.0, 40.0, 0.0)
    expected = np.roots([M, 40.0, 3000.0])
    assert root.real == pytest.approx(expected[0].real)
    assert abs(root.imag) == pytest.approx(abs(expected[0].imag))


def test_figs_11_and_12_verdicts():
    # metal sheet K = 2510 N/m at h = 16 ms: b = 20 grows, b = 60 stays bounded
    grow = stability_report(M, 20.0, H, K=2510.0)
    stay = stability_report(M, 60.0, H, K=2510.0)
    assert grow["stable"] is False and grow["growth_rate"] > 0.0
    assert stay["stable"] is True and stay["growth_rate"] < 0.0
    assert grow["pade1"] < 2510.0 < stay["pade1"]


@pytest.mark.parametrize("beta", [math.pi / 2 + 1e-6, 1.7, 1.92, 2.5, 10.0])
def test_no_stabilizing_stiffness_when_bh_over_m_exceeds_half_pi(beta):
    m, h = 1.0, 0.016
    b = beta * m / h
    bound = exact_bound(m, b, h)
    assert bound.k_max is None
    assert "no stiffness K > 0 stabilizes this loop" in bound.reason
    assert "pi/2" in bound.reason and "undelayed" in bound.reason
    # and indeed every stiffness grows, over many decades
    for K in np.geomspace(1e-3, 1e6, 10):
        assert growth_rate(m, K, b, h) > 0.0
    if beta < 2.0:
        assert pade1_bound(m, b, h) > 0.0  # Eq. 12 still claims a stable range
        assert "Eq. 12 claims a stable range" in stability_report(m, b, h)["pade1_reason"]
    else:
        assert pade1_bound(m, b, h) is None
    # with the damper on the undelayed velocity a stable range exists
    undelayed = exact_bound(m, b, h, "undelayed").k_max
    assert undelayed > 0.0
    assert growth_rate(m, 0.5 * undelayed, b, h, "undelayed") < 0.0


def test_just_below_half_pi_a_small_stable_range_exists():
    m, h = 1.0, 0.016
    b = (math.pi / 2 - 0.05) * m / h
    k = exact_bound(m, b, h).k_max
    assert 0.0 < k
    assert growth_rate(m, 0.5 * k, b, h) < 0.0 < growth_rate(m, 2.0 * k, b, h)


def test_no_damping_no_stable_stiffness():
    for damper in ("delayed", "undelayed"):
        bound = exact_bound(M, 0.0, H, damper)
        assert bound.k_max is None and "without damping" in bound.reason
        assert growth_rate(M, 1000.0, 0.0, H, damper) > 0.0
    assert pade1_bound(M, 0.0, H) is None


@pytest.mark.parametrize(
    "args, match",
    [
        ((-750.0, 20.0, H), r"m must be > 0 kg"),
        ((0.0, 20.0, H), r"m must be > 0 kg"),
        ((M, -1.0, H), r"b must be >= 0"),
        ((M, 20.0, -0.016), r"h must be >= 0"),
        ((M, float("nan"), H), r"b must be a finite number"),
    ],
)
def test_refuses_bad_loop_parameters(args, match):
    with pytest.raises(ContactModelError, match=match):
        exact_bound(*args)
    with pytest.raises(ContactModelError, match=match):
        pade1_bound(*args)


def test_refuses_unknown_damper():
    with pytest.raises(ContactModelError, match=r"damper must be one of delayed, undelayed"):
        exact_bound(M, 20.0, H, "sideways")


def test_map_matches_pointwise_bounds_and_is_fast():
    b = np.linspace(10.0, 200.0, 200)
    h = np.linspace(0.016, 0.032, 200)
    runs = []
    for _ in range(3):
        start = time.perf_counter()
        pade = critical_stiffness_map(M, b, h, "pade1")
        exact = critical_stiffness_map(M, b, h, "exact")
        runs.append(time.perf_counter() - start)
    assert min(runs) < 0.5
    assert pade.shape == exact.shape == (200, 200)
    for i, j in [(0, 0), (17, 150), (199, 199), (100, 3)]:
        assert pade[i, j] == pytest.approx(pade1_bound(M, b[j], h[i]), rel=1e-12)
        assert exact[i, j] == pytest.approx(exact_bound(M, b[j], h[i]).k_max, rel=1e-12)
    # Fig. 7's shape: more damping allows more stiffness, more delay less
    assert np.all(np.diff(pade, axis=1) > 0) and np.all(np.diff(pade, axis=0) < 0)
    assert np.all(pade > exact)


def test_map_marks_points_without_stable_stiffness():
    m = 1.0
    b = np.array([10.0, 90.0, 110.0])  # b h / m = 0.16, 1.44, 1.76 at h = 0.016
    out = critical_stiffness_map(m, b, [0.016], "exact")
    assert np.isfinite(out[0, :2]).all() and np.isnan(out[0, 2])
    pade = critical_stiffness_map(m, b, [0.016], "pade1")
    assert np.isfinite(pade).all()
