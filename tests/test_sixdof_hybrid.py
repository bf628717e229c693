"""The hybrid 6-DOF model: the closed form per axis (NOTES' k1 = (kcs - k)(1 + m1/m2),
its rotational twin, the lever-arm coupling), the two-time fit, and the sampled
hybrid loop against the ideal contact."""

import numpy as np
import pytest

from dockhil.contact import TABLE1
from dockhil.contact.contact6 import Contact6, simulate_contact6
from dockhil.contact.hybrid6 import simulate_hybrid6
from dockhil.contact.impedance6 import fit_impedance6, impedance_closed_form6, interface_mobilities
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.rotations import quat_from_rotvec
from dockhil.contact.scenario import ContactModelError, FitError
from tests.test_sixdof_contact import off_axis_pair

AT_REST = (0.0, 0.0, 0.0, 1.0)


def table1_bodies():
    scn = TABLE1
    chaser = RigidBody(scn.m1, np.diag([500.0, 600.0, 700.0]), interface_position=[1.0, 0, 0])
    target = RigidBody(scn.m2, np.diag([5e5, 6e5, 7e5]), interface_position=[-2.0, 0, 0])
    s1 = BodyState([-1.0, 0, 0], AT_REST, [scn.v1, 0, 0], [0, 0, 0])
    s2 = BodyState([2.0, 0, 0], AT_REST, [scn.v2, 0, 0], [0, 0, 0])
    return chaser, target, s1, s2


def test_closed_form_per_axis_when_the_axes_decouple():
    scn = TABLE1
    m1, m2 = scn.m1, scn.m2
    i1, i2 = np.array([500.0, 600.0, 700.0]), np.array([5e5, 6e5, 7e5])
    # Interfaces at the CoMs on principal axes: every axis is its own 1-DOF problem.
    chaser, target = RigidBody(m1, np.diag(i1)), RigidBody(m2, np.diag(i2))
    s = BodyState([0, 0, 0], AT_REST, [0, 0, 0], [0, 0, 0])
    g1, g2 = interface_mobilities(chaser, target, s, s)
    ideal = Contact6([scn.kcs, 2000, 2000, 300, 300, 300], [scn.bcs, 10, 10, 2, 2, 2])
    passive = Contact6([scn.k, 500, 500, 100, 100, 100])
    imp = impedance_closed_form6(ideal, passive, g1, g2)
    # NOTES / Table 1: k1 = (kcs - k)(1 + m1/m2) = 2001.5, b1 = 40.03, k2 = 2668700 (rounded), b2 = 53373.
    assert imp.k1[0, 0] == pytest.approx(2001.5, rel=1e-12)
    assert imp.c1[0, 0] == pytest.approx(40.03, rel=1e-12)
    assert imp.k2[0, 0] == pytest.approx((3000 - 1000) * (1 + m2 / m1), rel=1e-12)
    assert imp.c2[0, 0] == pytest.approx(40 * (1 + m2 / m1), rel=1e-12)
    for j, (k, kp, _c) in enumerate([(2000, 500, 10), (2000, 500, 10)], start=1):
        assert imp.k1[j, j] == pytest.approx((k - kp) * (1 + m1 / m2), rel=1e-12)
    for j in range(3):  # rotations: inertias instead of masses
        assert imp.k1[3 + j, 3 + j] == pytest.approx((300 - 100) * (1 + i1[j] / i2[j]), rel=1e-12)
        assert imp.c2[3 + j, 3 + j] == pytest.approx(2 * (1 + i2[j] / i1[j]), rel=1e-12)
    for mat in (imp.k1, imp.c1, imp.k2, imp.c2):
        assert np.max(np.abs(mat - np.diag(np.diag(mat)))) < 1e-9 * np.max(np.abs(mat))


def test_a_lever_arm_couples_translation_and_rotation():
    # Chaser contact point 0.5 m off its CoM along y: a normal force turns it about z.
    m1, iz1, lever = 100.0, 40.0, 0.5
    m2, iz2 = 1e3, 900.0
    chaser = RigidBody(m1, np.diag([30.0, 35.0, iz1]), interface_position=[0.0, lever, 0.0])
    target = RigidBody(m2, np.diag([800.0, 850.0, iz2]))
    g1, g2 = interface_mobilities(
        chaser,
        target,
        BodyState([0, -lever, 0], AT_REST, [0, 0, 0], [0, 0, 0]),
        BodyState([0, 0, 0], AT_REST, [0, 0, 0], [0, 0, 0]),
    )
    # By hand (x at the contact point, rotation rz): a_x = f/m + lever^2 f / I_z,
    # rz'' = -lever f / I_z, a_x per unit moment = -lever / I_z.
    hand1 = np.array([[1 / m1 + lever**2 / iz1, -lever / iz1], [-lever / iz1, 1 / iz1]])
    hand2 = np.diag([1 / m2, 1 / iz2])
    sel = np.ix_([0, 5], [0, 5])
    assert np.allclose(g1[sel], hand1, rtol=1e-13, atol=0)
    assert np.allclose(g2[sel], hand2, rtol=1e-13, atol=0)
    k = np.diag([3000.0, 0, 0, 0, 0, 500.0])
    kp = np.diag([1000.0, 0, 0, 0, 0, 100.0])
    imp = impedance_closed_form6(Contact6(k), Contact6(kp), g1, g2)
    expected = (k - kp)[sel] @ (hand1 + hand2) @ np.linalg.inv(hand1)
    assert np.allclose(imp.k1[sel], expected, rtol=1e-12)
    assert abs(imp.k1[0, 5]) > 50.0  # the coupling is real
    # Passive + virtual is the ideal stiffness on either body: K_i D_i = K - K_p.
    assert np.allclose(imp.k1 @ imp.d1, k - kp, atol=1e-9 * 3000)
    assert np.allclose(imp.k2 @ imp.d2, k - kp, atol=1e-9 * 3000)


def test_two_time_fit_recovers_the_closed_form_along_the_axis():
    scn = TABLE1
    chaser, target, s1, s2 = table1_bodies()
    ideal = Contact6([scn.kcs, 0, 0, 0, 0, 0], [scn.bcs, 0, 0, 0, 0, 0])
    passive = Contact6([scn.k, 0, 0, 0, 0, 0])
    run = simulate_contact6(chaser, target, s1, s2, ideal, dt=1e-3, t_end=1.2)
    g1, g2 = interface_mobilities(chaser, target, s1, s2)
    fit = fit_impedance6(run, [0.5, 1.0], passive, g1, g2, axes=["x"])
    k1, b1, k2, b2 = fit["x"]
    m1, m2 = scn.m1, scn.m2
    assert k1 == pytest.approx((scn.kcs - scn.k) * (1 + m1 / m2), rel=1e-8)
    assert b1 == pytest.approx(scn.bcs * (1 + m1 / m2), rel=1e-8)
    assert k2 == pytest.approx((scn.kcs - scn.k) * (1 + m2 / m1), rel=1e-8)
    assert b2 == pytest.approx(scn.bcs * (1 + m2 / m1), rel=1e-8)
    with pytest.raises(FitError, match="identical rows"):
        fit_impedance6(run, [0.5, 0.5], passive, g1, g2, axes=["x"])
    with pytest.raises(FitError, match="inside the contact"):
        fit_impedance6(run, [0.5, 1.9], passive, g1, g2, axes=["x"])
    with pytest.raises(FitError, match="axis ry: the contact does not move this axis"):
        fit_impedance6(run, [0.5, 1.0], passive, g1, g2, axes=["ry"])


def off_axis_case():
    chaser, target = off_axis_pair()
    s1 = BodyState([-1.951, 0.3, 0.1], quat_from_rotvec([0.01, 0.02, -0.03]), [0.05, 0.01, 0], [0.02, -0.03, 0.05])
    s2 = BodyState([0.0, 0.3, 0.1], AT_REST, [0, 0, 0.0], [0, 0.02, 0])
    k = np.diag([1000.0, 400, 500, 150, 120, 100])
    k[0, 4] = k[4, 0] = 50.0
    k[1, 5] = k[5, 1] = -40.0
    ideal = Contact6(k, np.diag([20.0, 5, 5, 2, 2, 2]))
    passive = Contact6(np.diag([600.0, 200, 200, 80, 60, 50]))
    return chaser, target, s1, s2, ideal, passive


def _errors(ideal_run, hybrid_run):
    out = {
        "peak force": abs(hybrid_run.peak("force") / ideal_run.peak("force") - 1),
        "peak torque": abs(hybrid_run.peak("torque") / ideal_run.peak("torque") - 1),
    }
    # Exit velocities, relative to the change the contact makes to them.
    for j, body in enumerate(("chaser", "target")):
        for name in ("velocities", "omegas"):
            a, b = getattr(ideal_run, name), getattr(hybrid_run, name)
            out[f"{body} {name}"] = np.linalg.norm(a[-1, j] - b[-1, j]) / np.linalg.norm(a[-1, j] - a[0, j])
    return out


def test_hybrid_loop_without_delay_reproduces_the_ideal_off_axis_contact():
    chaser, target, s1, s2, ideal, passive = off_axis_case()
    worst = {}
    for dt in (2e-3, 1e-3):
        ref = simulate_contact6(chaser, target, s1, s2, ideal, dt=dt, t_end=1.0)
        hyb = simulate_hybrid6(chaser, target, s1, s2, ideal, passive, dt=dt, t_end=1.0)
        assert ref.exit is not None and hyb.exit is not None and ref.peak("torque") > 1.0
        errors = _errors(ref, hyb)
        worst[dt] = max(errors.values())
        if dt == 1e-3:
            assert all(e < 5e-3 for e in errors.values()), errors
    assert worst[1e-3] < 0.75 * worst[2e-3]  # tightens with rate (0.64 here; 1 to 2 kHz: 0.39)


def test_hybrid_refuses_an_ideal_contact_with_friction():
    chaser, target, s1, s2, ideal, passive = off_axis_case()
    with pytest.raises(ContactModelError, match="frictionless"):
        simulate_hybrid6(chaser, target, s1, s2, Contact6(ideal.stiffness, mu=0.2), passive)


@pytest.mark.parametrize("delay", [0.0, 0.032])
def test_one_axis_hybrid_loop_is_the_1dof_hil_loop(delay):
    # The graph's 1-DOF loop (hilloop.simulate_hil: passive spring read through the robot delay,
    # virtual impedance on the CoM wall, forces held over each tick) against the 6-DOF loop
    # along one axis: the same ticks, the same numbers to round-off.
    from dockhil.contact import impedance_closed_form
    from dockhil.contact.hilloop import simulate_hil

    scn = TABLE1
    dt, n = 2e-3, 1000
    one = simulate_hil(
        m1=scn.m1,
        m2=scn.m2,
        k=scn.k,
        impedance=impedance_closed_form(scn),
        dt=dt,
        n_ticks=n,
        delay=delay,
        x1=0.0,
        x2=0.0,
        v1=scn.v1,
        v2=scn.v2,
    )
    chaser, target, s1, s2 = table1_bodies()
    six = simulate_hybrid6(
        chaser,
        target,
        s1,
        s2,
        Contact6([scn.kcs, 0, 0, 0, 0, 0], [scn.bcs, 0, 0, 0, 0, 0]),
        Contact6([scn.k, 0, 0, 0, 0, 0]),
        dt=dt,
        t_end=(n - 1) * dt,
        delay_ticks=int(round(delay / dt)),
    )
    assert np.max(np.abs(six.velocities[:, 0, 0] - one.v1)) < 1e-9 * scn.v1
    assert np.max(np.abs(six.velocities[:, 1, 0] - one.v2)) < 1e-9 * scn.v1 * scn.m1 / scn.m2
    assert np.max(np.abs(-six.force[:, 0] - one.force)) < 1e-9 * np.max(np.abs(one.force))
    assert np.max(np.abs(six.positions[:, 0, 0] + 1.0 - one.x1)) < 1e-9 * np.max(np.abs(one.x1))


def test_published_interface_answers_equal_questions_alike_and_never_another_bodys():
    # It remembers its last answer (the dynamics and the virtual impedance ask the same each tick):
    # an equal body built anew gets the numbers of a fresh computation, a body that differs in
    # any value the geometry or the mobilities read gets its own.
    from dockhil.contact import hybrid6
    from dockhil.contact.hybrid6 import published_body, published_interface
    from dockhil.contact.rigid import Motion

    chaser, target, s1, s2 = table1_bodies()
    s1 = BodyState([-1.0, 0.05, 0.0], quat_from_rotvec([0.0, 0.0, 0.02]), [0.03, 0.0, 0.0], [0.01, 0.0, 0.0])
    p1, p2 = published_body(Motion.from_state(chaser, s1)), published_body(Motion.from_state(target, s2))

    def fresh(b1, b2):
        hybrid6._LAST_INTERFACE[0] = None
        g, velocity, spin = published_interface(b1, p1, b2, p2)
        return g.d, g.q_rel, g.point, g.e, velocity, spin, g.pose1[0].mass, g.pose2[0].mass

    def asked(b1, b2):
        g, velocity, spin = published_interface(b1, p1, b2, p2)
        return g.d, g.q_rel, g.point, g.e, velocity, spin, g.pose1[0].mass, g.pose2[0].mass

    first = fresh(chaser, target)
    again = RigidBody(chaser.mass, np.diag([500.0, 600.0, 700.0]), interface_position=[1.0, 0, 0])
    assert asked(again, target) == first
    heavier = RigidBody(2.0 * chaser.mass, np.diag([500.0, 600.0, 700.0]), interface_position=[1.0, 0, 0])
    longer = RigidBody(chaser.mass, np.diag([500.0, 600.0, 700.0]), interface_position=[1.5, 0, 0])
    for other in (heavier, longer):
        published_interface(chaser, p1, target, p2)  # remembered for the first body
        assert asked(other, target) == fresh(other, target) != first
