"""The ideal 6-DOF contact: along one axis it is the 1-DOF library; decoupled
axes follow their own 1-DOF closed forms; an off-axis impact conserves
momenta (and, undamped, energy to the integrator's order); the F/T sensor's
wrench moves to the centres of mass; bad matrices are refused."""

import math

import numpy as np
import pytest

from dockhil.contact import TABLE1, ideal_trajectory, relative_motion, simulate_contact
from dockhil.contact.contact6 import Contact6, simulate_contact6
from dockhil.contact.interface6 import sensor_wrench_to_bodies
from dockhil.contact.rigid import Motion
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.rotations import quat_from_rotvec
from dockhil.contact.scenario import ContactModelError

AT_REST = (0.0, 0.0, 0.0, 1.0)


def test_one_axis_run_reproduces_the_1dof_library():
    scn = TABLE1
    # Interfaces 1 m ahead of the chaser's CoM and 2 m behind the target's; contact at x = 0 at t = 0.
    chaser = RigidBody(scn.m1, np.diag([500.0, 600.0, 700.0]), interface_position=[1.0, 0, 0])
    target = RigidBody(scn.m2, np.diag([5e5, 6e5, 7e5]), interface_position=[-2.0, 0, 0])
    model = Contact6([scn.kcs, 1e3, 1e3, 1e3, 1e3, 1e3], [scn.bcs, 0, 0, 0, 0, 0])
    run = simulate_contact6(
        chaser,
        target,
        BodyState([-1.0, 0, 0], AT_REST, [scn.v1, 0, 0], [0, 0, 0]),
        BodyState([2.0, 0, 0], AT_REST, [scn.v2, 0, 0], [0, 0, 0]),
        model,
        dt=1e-3,
        t_end=1.7,
    )
    closed = ideal_trajectory(scn, run.t)
    exact = simulate_contact(scn, dt=1e-3, t_end=1.7)
    v1, v2 = run.velocities[:, 0, 0], run.velocities[:, 1, 0]
    for ref in (closed, exact):
        assert np.max(np.abs(v1 - ref.v1)) < 1e-9 * scn.v1
        assert np.max(np.abs(v2 - ref.v2)) < 1e-9 * scn.v1 * scn.m1 / scn.m2
        assert np.max(np.abs(run.normal_force - ref.force)) < 1e-9 * np.max(ref.force)
        assert np.max(np.abs(run.positions[:, 0, 0] + 1.0 - ref.x1)) < 1e-9 * np.max(np.abs(ref.x1))
    assert run.exit == pytest.approx(closed.exit, rel=1e-9)
    # Nothing but the axis moved.
    assert np.max(np.abs(run.velocities[:, :, 1:])) == 0.0 and np.max(np.abs(run.omegas)) == 0.0


def test_decoupled_axes_follow_their_own_closed_forms():
    # Interfaces at the CoMs, principal axes along the interface axes: the normal axis x and the
    # roll rx about it decouple exactly (forces act along the line of the CoMs, the roll torque
    # about it). Each follows m p'' + b p' + k p = 0 with its own reduced mass or inertia.
    m1, m2 = 400.0, 900.0
    ix1, ix2 = 50.0, 200.0
    k = np.array([5000.0, 0.0, 0.0, 300.0, 0.0, 0.0])
    c = np.array([60.0, 0.0, 0.0, 4.0, 0.0, 0.0])
    chaser = RigidBody(m1, np.diag([ix1, 80.0, 90.0]))
    target = RigidBody(m2, np.diag([ix2, 300.0, 350.0]))
    v_close, w_rel = 0.1, 0.05
    run = simulate_contact6(
        chaser,
        target,
        BodyState([0, 0, 0], AT_REST, [v_close, 0, 0], [w_rel, 0, 0]),
        BodyState([0, 0, 0], AT_REST, [0, 0, 0], [0, 0, 0]),
        Contact6(k, c),
        dt=1e-3,
        t_end=0.5,
    )
    inside = run.in_contact
    t = run.t[inside]
    p, pd = relative_motion(m1 * m2 / (m1 + m2), k[0], c[0], v_close, t)
    assert np.max(np.abs(run.e[inside, 0] - p)) < 1e-9 * np.max(p)
    assert np.max(np.abs(run.rate[inside, 0] - pd)) < 1e-9 * v_close
    # Roll: the relative angle starts at 0 with rate w_rel.
    th, thd = relative_motion(ix1 * ix2 / (ix1 + ix2), k[3], c[3], w_rel, t)
    assert np.max(np.abs(run.e[inside, 3] - th)) < 1e-9 * np.max(np.abs(th))
    assert np.max(np.abs(run.rate[inside, 3] - thd)) < 1e-9 * w_rel


def off_axis_pair() -> tuple[RigidBody, RigidBody]:
    """Two bodies with full inertias, an off-centre CoM and tilted interfaces (the off-axis cases)."""
    i1 = np.array([[40.0, 2, -1], [2, 50, 3], [-1, 3, 60]])
    i2 = np.array([[80.0, -4, 2], [-4, 70, 1], [2, 1, 90]])
    chaser = RigidBody(
        100.0,
        i1,
        com=[0.05, 0.02, 0],
        interface_position=[1.0, 0.1, -0.05],
        interface_orientation=quat_from_rotvec([0, 0, 0.05]),
    )
    target = RigidBody(
        200.0, i2, interface_position=[-1.0, 0.0, 0.0], interface_orientation=quat_from_rotvec([0.02, 0, 0])
    )
    return chaser, target


def off_axis_bodies():
    chaser, target = off_axis_pair()
    s1 = BodyState([-1.97, 0.3, 0.1], quat_from_rotvec([0.01, 0.02, -0.03]), [0.2, 0.01, 0], [0.05, -0.1, 0.2])
    s2 = BodyState([0.0, 0.3, 0.1], AT_REST, [0, 0, 0.0], [0, 0.02, 0])
    return chaser, target, s1, s2


def coupled_stiffness():
    k = np.diag([4000.0, 1000, 1200, 300, 250, 200])
    k[0, 4] = k[4, 0] = 100.0
    k[1, 5] = k[5, 1] = -80.0
    return k


def _rel(arr):
    return np.max(np.linalg.norm(arr - arr[0], axis=1)) / np.linalg.norm(arr[0])


def test_off_axis_impact_conserves_momenta_with_damping_and_friction():
    chaser, target, s1, s2 = off_axis_bodies()
    model = Contact6(coupled_stiffness(), np.diag([40.0, 10, 10, 2, 2, 2]), mu=0.3, slip_velocity=1e-3)
    run = simulate_contact6(chaser, target, s1, s2, model, dt=1e-3, t_end=0.5)
    assert run.in_contact.sum() > 100 and run.peak("torque") > 1.0  # a real off-axis contact
    assert _rel(run.momentum) < 1e-10
    assert _rel(run.angular_momentum) < 1e-10


def test_undamped_off_axis_energy_is_conserved_to_the_integrators_order():
    chaser, target, s1, s2 = off_axis_bodies()
    errors = {}
    for order in (2, 4):
        for dt in (1e-3, 5e-4):
            run = simulate_contact6(
                chaser, target, s1, s2, Contact6(coupled_stiffness()), dt=dt, t_end=0.45, order=order
            )
            inside = run.in_contact
            assert inside.sum() > 100
            errors[order, dt] = np.max(np.abs(run.energy[inside] - run.energy[0])) / run.energy[0]
            assert _rel(run.momentum) < 1e-10 and _rel(run.angular_momentum) < 1e-10
    assert 3.5 < errors[2, 1e-3] / errors[2, 5e-4] < 4.5
    assert 12.0 < errors[4, 1e-3] / errors[4, 5e-4] < 20.0
    assert errors[4, 1e-3] < 1e-9


def test_normal_only_contact_keeps_energy_through_separation():
    # With only the normal axis stiff nothing is stored off-normal when the contact lets go.
    chaser, target, s1, s2 = off_axis_bodies()
    run = simulate_contact6(chaser, target, s1, s2, Contact6([3000.0, 0, 0, 0, 0, 0]), dt=1e-3, t_end=1.2)
    assert run.exit is not None and not run.in_contact[-1]
    assert abs(run.energy[-1] / run.energy[0] - 1.0) < 1e-9


def test_sensor_wrench_moves_to_both_centres_of_mass():
    body = RigidBody(10.0, np.eye(3), com=[0.2, 0.0, 0.0])
    rot = quat_from_rotvec([0, 0, math.pi / 2])  # body x -> world y
    carrier = Motion.from_state(body, BodyState([1.0, 2.0, 3.0], rot, [0, 0, 0], [0, 0, 0]))
    other = Motion.from_state(body, BodyState([1.0, 4.0, 3.0], AT_REST, [0, 0, 0], [0, 0, 0]))
    # Sensor 0.5 m ahead of the body origin along body y, its own x along body z (rotation -pi/2 about y).
    sensor_q = quat_from_rotvec([0, -math.pi / 2, 0])
    f_c, t_c, f_o, t_o = sensor_wrench_to_bodies(
        carrier, other, [0.0, 0.5, 0.0], sensor_q, [2.0, 0.0, 0.0], [0.0, 0.0, 0.1]
    )
    # By hand: sensor x = body z = world z; sensor z = -(body x) = -(world y); body origin at the
    # CoM minus R (0.2, 0, 0) = (1, 1.8, 3); sensor origin = (1, 1.8, 3) + R (0, 0.5, 0) = (0.5, 1.8, 3).
    f_world = np.array([0.0, 0.0, 2.0])
    m_world = np.array([0.0, -0.1, 0.0])
    origin = np.array([0.5, 1.8, 3.0])
    assert np.allclose(f_c, f_world, atol=1e-15) and np.allclose(f_o, -f_world, atol=1e-15)
    assert np.allclose(t_c, m_world + np.cross(origin - [1.0, 2.0, 3.0], f_world), atol=1e-15)
    # Equal and opposite: zero net force and zero net moment about any point.
    ref = np.array([7.0, -3.0, 2.0])
    net = (t_c + np.cross([1.0, 2.0, 3.0] - ref, f_c)) + (t_o + np.cross([1.0, 4.0, 3.0] - ref, f_o))
    assert np.allclose(net, 0.0, atol=1e-14)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"stiffness": np.diag([1.0, 2, 3, 4, 5, 6]) + np.eye(6, k=1)}, "must be symmetric"),
        ({"stiffness": [1.0, -2, 3, 4, 5, 6]}, ">= 0"),
        ({"stiffness": np.ones(6), "damping": -np.eye(6)}, "positive semi-definite"),
        ({"stiffness": np.ones(5)}, "6x6"),
        ({"stiffness": np.ones(6), "mu": -0.1}, "mu must be >= 0"),
    ],
)
def test_bad_contact_matrices_are_refused_with_one_line(kwargs, words):
    with pytest.raises(ContactModelError) as info:
        Contact6(**kwargs)
    assert words in str(info.value) and "\n" not in str(info.value)
