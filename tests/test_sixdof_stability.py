"""Multi-axis stability of the delayed loop: one axis is the 1-DOF exact bound,
decoupled axes take the smallest of theirs and name the axis, and a coupled
planar loop's bound separates growth from decay of the simulated sampled loop."""

import math

import numpy as np
import pytest

from dockhil.contact.hybrid_stability import hybrid_rightmost
from dockhil.contact.scenario import ContactModelError
from dockhil.contact.stability6 import (
    MultiAxisLoop,
    hybrid_loop6,
    modal_loops,
    planar_loop,
    rightmost,
    stiffness_margin,
)


def exact_k_max(m, b, h):
    """Delayed spring-damper m s^2 + (K + b s) e^{-sh} = 0 on the imaginary axis (NOTES):
    b h / m = theta sin(theta), K = (m / h^2) theta^2 cos(theta), theta in (0, pi/2); by bisection."""
    beta = b * h / m
    lo, hi = 0.0, math.pi / 2
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mid * math.sin(mid) < beta else (lo, mid)
    theta = 0.5 * (lo + hi)
    return m / h**2 * theta**2 * math.cos(theta)


def test_one_axis_is_the_1dof_exact_bound():
    m, b, h = 750.0, 60.0, 0.016  # the paper's Fig. 11-12 loop
    loop = MultiAxisLoop([[m]], [[0.0]], [[0.0]], [[1000.0]], [[b]], h, ("x",))
    margin = stiffness_margin(loop)
    assert margin.alpha * 1000.0 == pytest.approx(exact_k_max(m, b, h), rel=1e-6)
    # The same roots as the 1-DOF hybrid loop (virtual impedance direct, passive delayed).
    loop = MultiAxisLoop([[m]], [[800.0]], [[30.0]], [[1200.0]], [[b]], h, ("x",))
    assert rightmost(loop).s == pytest.approx(hybrid_rightmost(m, 800.0, 30.0, 1200.0, b, h), rel=1e-9)


def test_the_narrow_bracket_follows_the_crossing_root_and_is_checked_with_all_the_roots():
    from dockhil.contact.stability6 import _bisect_on_crossing_roots

    m, b, h = 750.0, 60.0, 0.016
    loop = MultiAxisLoop([[m]], [[0.0]], [[0.0]], [[1000.0]], [[b]], h, ("x",))
    alpha = exact_k_max(m, b, h) / 1000.0

    def grows(a):
        return rightmost(loop.scaled(a)).s.real > 0.0

    lo, hi = _bisect_on_crossing_roots(loop, 0.99 * alpha, 1.01 * alpha, 1e-9, grows)
    assert lo < hi <= lo * (1 + 1e-9) and lo == pytest.approx(alpha, rel=1e-8)
    # Should all the roots say the loop grows below where the followed root crosses (another root
    # crossed first), the bisection is redone with them: here a stand-in that grows from 0.995 alpha.
    lo, hi = _bisect_on_crossing_roots(loop, 0.99 * alpha, 1.01 * alpha, 1e-9, lambda a: a > 0.995 * alpha)
    assert lo <= 0.995 * alpha < hi <= lo * (1 + 1e-9)


def test_decoupled_axes_take_the_smallest_bound_and_name_its_axis():
    h = 0.016
    masses, dampers, k = [750.0, 300.0, 120.0], [20.0, 60.0, 10.0], [1000.0, 1000.0, 1000.0]
    loop = MultiAxisLoop(
        np.diag(masses), np.zeros((3, 3)), np.zeros((3, 3)), np.diag(k), np.diag(dampers), h, ("x", "y", "rz")
    )
    per_axis = [exact_k_max(m, b, h) / kk for m, b, kk in zip(masses, dampers, k)]
    margin = stiffness_margin(loop)
    assert margin.alpha == pytest.approx(min(per_axis), rel=1e-6)
    assert margin.root.axis == ("x", "y", "rz")[int(np.argmin(per_axis))]
    modes = modal_loops(loop)
    assert modes is not None and sorted(mode["axis"] for mode in modes) == ["rz", "x", "y"]


def simulated_growth(loop: MultiAxisLoop, t_end: float, steps_per_delay: int = 32) -> float:
    """Growth rate [1/s] of the sampled loop: accelerations held over each tick, the delayed
    terms read `steps_per_delay` ticks back; the slope of log max|q| between the two halves
    of the second half of the run."""
    dt = loop.h / steps_per_delay
    minv = np.linalg.inv(loop.mass)
    n = loop.n
    hist_q = [np.zeros(n)] * steps_per_delay
    hist_v = [np.zeros(n)] * steps_per_delay
    q, v = np.full(n, 1e-3), np.zeros(n)
    steps = int(t_end / dt)
    peaks = np.zeros(steps)
    for i in range(steps):
        qd, vd = hist_q[i % steps_per_delay], hist_v[i % steps_per_delay]
        hist_q[i % steps_per_delay], hist_v[i % steps_per_delay] = q, v
        a = -minv @ (loop.k_direct @ q + loop.b_direct @ v + loop.k_delayed @ qd + loop.b_delayed @ vd)
        q, v = q + dt * v + 0.5 * dt * dt * a, v + dt * a
        peaks[i] = np.max(np.abs(q))
    half, quarter = steps // 2, steps // 4
    early = np.max(peaks[half : half + quarter])
    late = np.max(peaks[half + quarter :])
    return math.log(late / early) / (quarter * dt)


def test_coupled_planar_bound_separates_growth_from_decay():
    # Normal translation and rotation coupled through a 0.3 m lever arm. (With damping
    # proportional to stiffness, b_rot = 1, the loop would split into modes.)
    loop = planar_loop(20.0, 5.0, 0.3, 2000.0, 10.0, 0.016, k_rot=200.0, b_rot=3.0)
    assert modal_loops(loop) is None  # the axes couple
    assert modal_loops(planar_loop(20.0, 5.0, 0.3, 2000.0, 10.0, 0.016, k_rot=200.0, b_rot=1.0)) is not None
    margin = stiffness_margin(loop)
    assert margin.alpha is not None and 0.0 < margin.alpha < 1.0
    for factor in (0.85, 1.15):
        scaled = loop.scaled(factor * margin.alpha)
        predicted = rightmost(scaled).s.real
        measured = simulated_growth(scaled, 20.0, steps_per_delay=16)  # within 7 % and 16 % (30 s: 10 %, 20 %)
        assert np.sign(measured) == np.sign(predicted) == (1 if factor > 1 else -1)
        assert measured == pytest.approx(predicted, rel=0.3)


def test_hybrid_loop_of_one_axis_is_the_1dof_hybrid_loop():
    from dockhil.contact.contact6 import Contact6

    m1, m2, h = 750.0, 1e6, 0.032
    g1, g2 = np.diag([1 / m1] * 3 + [1 / 500.0] * 3), np.diag([1 / m2] * 3 + [1 / 5e5] * 3)
    loop = hybrid_loop6(
        Contact6([3000.0, 0, 0, 0, 0, 0], [40.0, 0, 0, 0, 0, 0]), Contact6([1000.0, 0, 0, 0, 0, 0]), g1, g2, h
    )
    m = m1 * m2 / (m1 + m2)
    x_only = MultiAxisLoop(
        loop.mass[:1, :1],
        loop.k_direct[:1, :1],
        loop.b_direct[:1, :1],
        loop.k_delayed[:1, :1],
        loop.b_delayed[:1, :1],
        h,
        ("x",),
    )
    assert rightmost(x_only).s == pytest.approx(hybrid_rightmost(m, 2000.0, 40.0, 1000.0, 0.0, h), rel=1e-9)


def test_bad_loops_are_refused_with_one_line():
    with pytest.raises(ContactModelError, match="mass must be positive definite"):
        MultiAxisLoop(np.diag([1.0, -1.0]), np.zeros((2, 2)), np.zeros((2, 2)), np.eye(2), np.eye(2), 0.01)
    with pytest.raises(ContactModelError, match="k_delayed must be a finite 2x2 matrix"):
        MultiAxisLoop(np.eye(2), np.zeros((2, 2)), np.zeros((2, 2)), np.eye(3), np.eye(2), 0.01)
    with pytest.raises(ContactModelError, match="h must be >= 0"):
        MultiAxisLoop(np.eye(2), np.zeros((2, 2)), np.zeros((2, 2)), np.eye(2), np.eye(2), -0.01)


def test_the_6dof_scene_check_warns_of_an_unstable_delayed_loop_as_the_1dof_one_does():
    # hil6.yaml at its 32 ms is (just) stable; at 64 ms the linearised loop grows, led by the normal
    # axis: the launch says so in its warnings, as hil.yaml's check does for its loop.
    from dockhil.analysis.scenecheck import scene_check
    from dockhil.scene import graph as graphmod
    from dockhil.scene import launchfile
    from tests.conftest import ROOT

    def check(args):
        return scene_check(graphmod.build(launchfile.load(ROOT / "launch" / "hil6.yaml", args)))

    calm, growing = check({}), check({"delay": "0.064"})
    assert calm["loop"]["rightmost_root_1_s"][0] < 0.0
    assert not [w for w in calm["warnings"] if "unstable" in w]
    root = growing["loop"]["rightmost_root_1_s"]
    assert root[0] > 0.0 and growing["loop"]["rightmost_axis"] == "z"
    assert [w for w in growing["warnings"] if w.startswith("the loop is unstable")] == [
        f"the loop is unstable: linearised at the start, the delayed loop grows at {root[0]:+.4g} 1/s (rightmost root "
        f"{root[0]:+.4g} {root[1]:+.4g}j, led by axis z); `dockhil stability multi --scene` on it gives the stable "
        "stiffness"
    ]
