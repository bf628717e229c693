"""Rigid bodies in 6-DOF: quaternion algebra, torque-free motion against closed
forms and an independent integration, the conservation bounds of the
integrator, and the refusals of bad bodies and states."""

import math

import numpy as np
import pytest

from dockhil.contact.rigid import Motion, free_step
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.rotations import matrix_to_quat, quat_from_rotvec, quat_multiply, quat_to_matrix, quat_to_rotvec
from dockhil.contact.scenario import ContactModelError


def rodrigues(axis_angle):
    """Rotation matrix by Rodrigues' formula (independent of the quaternion code)."""
    v = np.asarray(axis_angle, float)
    angle = np.linalg.norm(v)
    k = v / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def test_quaternion_algebra_matches_rotation_matrices():
    a, b = np.array([0.3, -1.1, 0.4]), np.array([-2.0, 0.2, 0.9])
    qa, qb = quat_from_rotvec(a), quat_from_rotvec(b)
    assert np.allclose(quat_to_matrix(qa), rodrigues(a), atol=1e-15)
    # The product composes the rotations (scalar-last Hamilton convention).
    assert np.allclose(quat_to_matrix(quat_multiply(qa, qb)), rodrigues(a) @ rodrigues(b), atol=1e-14)
    assert np.allclose(quat_to_rotvec(qa), a, atol=1e-14)
    back = matrix_to_quat(rodrigues(b))
    assert np.allclose(quat_to_matrix(back), rodrigues(b), atol=1e-14)
    # Scalar last: a rotation by pi/2 about z is (0, 0, sin(pi/4), cos(pi/4)).
    assert np.allclose(quat_from_rotvec([0, 0, math.pi / 2]), [0, 0, math.sqrt(0.5), math.sqrt(0.5)])


def test_the_plain_float_helpers_are_the_matrix_algebra():
    # The per-tick path works on tuples of floats: each helper against the matrices it stands for.
    from dockhil.contact.contact6 import MatVec6
    from dockhil.contact.interface6 import left_jacobian_inverse3
    from dockhil.contact.rotations import cross3, rotate, rotate_back

    a, v = np.array([0.3, -1.1, 0.4]), (0.7, -0.2, 1.5)
    q, r = quat_from_rotvec(a), rodrigues(a)
    assert np.allclose(rotate(q, v), r @ v, rtol=0, atol=1e-15)
    assert np.allclose(rotate_back(q, v), r.T @ v, rtol=0, atol=1e-15)
    assert np.allclose(cross3(a, v), np.cross(a, v), rtol=0, atol=1e-15)
    m = np.arange(36.0).reshape(6, 6) - 17.0
    x = (0.1, -0.2, 0.3, 0.5, -0.7, 1.1)
    assert np.allclose(MatVec6(m)(x), m @ x, rtol=1e-15) and MatVec6(np.diag(x))(x) == tuple(c * c for c in x)
    assert MatVec6(np.zeros((6, 6)))(x) == (0.0,) * 6
    # J_l(theta)^-1 maps a small spatial turn d psi (R -> exp(d psi) R) to d theta, by finite differences.
    for theta in (np.array([0.4, -0.3, 0.9]), np.array([1e-7, 2e-7, -1e-7])):
        jinv = np.array(left_jacobian_inverse3(theta))
        eps = 1e-6
        for k in range(3):
            dpsi = np.zeros(3)
            dpsi[k] = eps
            turned = quat_to_rotvec(quat_multiply(quat_from_rotvec(dpsi), quat_from_rotvec(theta)))
            back = quat_to_rotvec(quat_multiply(quat_from_rotvec(-dpsi), quat_from_rotvec(theta)))
            assert np.allclose((turned - back) / (2 * eps), jinv[:, k], rtol=0, atol=1e-9)


INERTIA = np.array([[1200.0, 30.0, -10.0], [30.0, 900.0, 20.0], [-10.0, 20.0, 1500.0]])


def spinning_body(omega=(0.05, 0.3, -0.02)):
    body = RigidBody(750.0, INERTIA, com=[0.1, 0.0, 0.05], interface_position=[1.0, 0.0, 0.0])
    state = BodyState([0.0, 0.0, 0.0], quat_from_rotvec([0.3, -0.2, 0.1]), [0.01, 0.0, 0.0], list(omega))
    return body, state


def test_axisymmetric_body_precesses_as_the_closed_form():
    # I1 = I2: Euler's equations give omega_1' = -Omega omega_2, omega_2' = Omega omega_1 with
    # Omega = (I3 - I1) / I1 omega_3 constant: (omega_1, omega_2) turns at Omega.
    i1, i3 = 800.0, 1400.0
    body = RigidBody(100.0, np.diag([i1, i1, i3]))
    w0 = np.array([0.2, 0.0, 0.5])
    m = Motion.from_state(body, BodyState([0, 0, 0], (0, 0, 0, 1), [0, 0, 0], w0))
    dt, steps = 1e-3, 3000
    for _ in range(steps):
        free_step(m, dt)
    t = dt * steps
    big_omega = (i3 - i1) / i1 * w0[2]
    expected = [0.2 * math.cos(big_omega * t), 0.2 * math.sin(big_omega * t), 0.5]
    assert np.allclose(m.state().angular_velocity, expected, rtol=0, atol=1e-12)


def test_asymmetric_body_matches_an_independent_integration_of_eulers_equations():
    from scipy.integrate import solve_ivp

    body, state = spinning_body()
    inertia = body.inertia

    def rhs(_t, y):
        w = y[:3]
        q = y[3:]  # x, y, z, w: q' = 1/2 q (w, 0)
        dw = np.linalg.solve(inertia, -np.cross(w, inertia @ w))
        dq = 0.5 * np.array(quat_multiply(q, (w[0], w[1], w[2], 0.0)))
        return np.concatenate([dw, dq])

    t_end = 10.0
    ref = solve_ivp(
        rhs,
        (0.0, t_end),
        np.concatenate([state.angular_velocity, state.orientation]),
        method="DOP853",
        rtol=1e-13,
        atol=1e-15,
    )
    m = Motion.from_state(body, state)
    for _ in range(int(round(t_end / 1e-3))):
        free_step(m, 1e-3)
    out = m.state()
    assert np.allclose(out.angular_velocity, ref.y[:3, -1], rtol=0, atol=1e-9)
    q_ref = ref.y[3:, -1] / np.linalg.norm(ref.y[3:, -1])
    assert abs(abs(np.dot(out.orientation, q_ref)) - 1.0) < 1e-12
    assert np.allclose(out.position, state.position + t_end * state.velocity, atol=1e-13)


def test_torque_free_conservation_bounds():
    # 20 s at 1 kHz here; bench/sixdof.py runs the 1000 s case and reports the drift.
    body, state = spinning_body()
    m = Motion.from_state(body, state)
    e0, l0 = m.kinetic_energy(), m.angular_momentum()
    energy_err, spatial_err, norm_err = [], [], []
    for i in range(20000):
        free_step(m, 1e-3)
        if i % 500 == 499:
            energy_err.append(m.kinetic_energy() / e0 - 1.0)
            spatial_err.append(np.linalg.norm(m.angular_momentum() - l0) / np.linalg.norm(l0))
            norm_err.append(abs(math.sqrt(sum(c * c for c in m.q)) - 1.0))
    # Order 4: energy error (omega dt)^4-small; angular momentum and |q| exact to round-off.
    assert max(map(abs, energy_err)) < 1e-12
    assert max(spatial_err) < 1e-12
    assert max(norm_err) < 1e-15
    # No drift: the second half's error is not larger than round-off growth of the first's.
    half = len(energy_err) // 2
    assert max(map(abs, energy_err[half:])) < 10 * max(max(map(abs, energy_err[:half])), 1e-15)


def test_order_two_energy_error_is_bounded_and_second_order():
    body, state = spinning_body()
    peaks = []
    for dt in (2e-3, 1e-3):
        m = Motion.from_state(body, state)
        e0 = m.kinetic_energy()
        worst = 0.0
        for _ in range(int(round(10.0 / dt))):
            free_step(m, dt, order=2)
            worst = max(worst, abs(m.kinetic_energy() / e0 - 1.0))
        peaks.append(worst)
    assert 3.5 < peaks[0] / peaks[1] < 4.5  # halving dt quarters the (bounded) error
    assert peaks[1] < 1e-9


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"inertia": np.diag([1.0, -2.0, 3.0])}, "positive definite"),
        ({"inertia": [[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "symmetric"),
        ({"inertia": np.diag([1.0, 1.0, 5.0])}, "I1 + I2 >= I3"),
        ({"inertia": np.eye(2)}, "3x3"),
        ({"interface_orientation": (0.0, 0.0, 0.0, 2.0)}, "unit quaternion"),
        ({"mass": 0.0}, "> 0"),
    ],
)
def test_bad_bodies_are_refused_with_one_line(kwargs, words):
    args = {"mass": 10.0, "inertia": np.eye(3), **kwargs}
    with pytest.raises(ContactModelError) as info:
        RigidBody(name="chaser", **args)
    message = str(info.value)
    assert words in message and "\n" not in message
    assert "chaser" in message or "mass" in message


def test_non_unit_attitude_is_refused():
    with pytest.raises(ContactModelError, match="orientation must be a unit quaternion"):
        BodyState([0, 0, 0], (0.1, 0.0, 0.0, 1.0), [0, 0, 0], [0, 0, 0])
