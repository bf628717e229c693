"""dockhil/contact/_rigid.c, rigid.py's per-tick arithmetic compiled, gives the bits of its Python
twins: on random inputs, function by function, and for whole 6-DOF runs (the digests of
tests/test_sixdof_reference.py, checked here with the twins alone)."""

import math
import os
import random
import subprocess
import sys

import numpy as np
import pytest

from dockhil.contact import rigid, rotations
from dockhil.contact.rigid import Motion
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.rotations import quat_from_rotvec
from tests.conftest import ROOT

compiled = pytest.mark.skipif(rigid.COMPILED is None, reason="dockhil.contact._rigid is not built here")


def test_the_compiled_twins_are_built_where_ci_runs():
    # CI installs with a C compiler: there the fast path must be the one the suite holds.
    if os.environ.get("CI") == "true":
        assert rigid.COMPILED is not None, "dockhil.contact._rigid did not build (pip install -e . compiles it)"


def _quat(rng):
    q = [rng.gauss(0.0, 1.0) for _ in range(4)]
    n = math.sqrt(sum(c * c for c in q))
    return tuple(c / n for c in q)


def _vec(rng, scale=1.0):
    return tuple(rng.gauss(0.0, scale) * 10.0 ** rng.uniform(-8, 3) for _ in range(3))


@compiled
def test_rotations_and_products_equal_their_twins_bit_for_bit():
    rng = random.Random(7)
    for _ in range(2000):
        q, a, v = _quat(rng), _quat(rng), _vec(rng)
        assert rigid.COMPILED.rotate(q, v) == rotations.rotate_python(q, v)
        assert rigid.COMPILED.rotate_back(q, v) == rotations.rotate_back_python(q, v)
        assert rigid.COMPILED.quat_multiply(q, a) == rotations.quat_multiply_python(q, a)
    # Any sequence, as the twins unpack it; floats out.
    q, v = [0.0, 0.0, math.sin(0.1), math.cos(0.1)], np.array([1.0, 2.0, 3.0])
    assert rigid.COMPILED.rotate(q, v) == tuple(float(c) for c in rotations.rotate_python(q, v))


def _pair(rng):
    inertia = np.diag([rng.uniform(300, 500) for _ in range(3)])  # I1 + I2 >= I3
    inertia[0, 1] = inertia[1, 0] = rng.uniform(-20, 20)
    body = RigidBody(rng.uniform(10, 1e4), inertia, interface_position=[1.0, 0.2, -0.1])
    state = BodyState(
        list(_vec(rng)), quat_from_rotvec(_vec(rng)), list(_vec(rng)), [rng.gauss(0, 0.5) for _ in range(3)]
    )
    return Motion.from_state(body, state), Motion.from_state(body, state)


@compiled
def test_free_flights_and_kicks_equal_their_twins_bit_for_bit():
    rng = random.Random(11)
    for _ in range(300):
        (a1, b1), (a2, b2) = _pair(rng), _pair(rng)
        for _ in range(20):
            t = rng.choice([1e-3, 5e-4, -1.7e-3, 0.2])
            rigid.COMPILED.drift(a1, t)
            rigid.drift_python(b1, t)
            f1, t1, f2, t2 = _vec(rng), _vec(rng), _vec(rng), _vec(rng)
            rigid.COMPILED.kick(a1, a2, f1, t1, f2, t2, t)
            rigid.kick_python(b1, b2, f1, t1, f2, t2, t)
        for a, b in ((a1, b1), (a2, b2)):
            assert (a.x, a.v, a.q, a.L) == (b.x, b.v, b.q, b.L)
            assert all(type(c) is float for c in a.x + a.v + a.q + a.L)


@compiled
def test_bad_input_gets_a_clear_error_not_a_crash():
    with pytest.raises(ValueError, match="expected 3 values, got 2"):
        rigid.COMPILED.rotate((0.0, 0.0, 0.0, 1.0), (1.0, 2.0))
    with pytest.raises(TypeError):
        rigid.COMPILED.rotate((0.0, 0.0, 0.0, 1.0), ("a", 2.0, 3.0))
    with pytest.raises(AttributeError):  # as the twin: not a Motion
        rigid.COMPILED.drift(object(), 1e-3)


def test_the_python_twins_alone_give_the_recorded_6dof_runs():
    # The suite runs the compiled path (where built); this holds the twins to the same digests.
    env = {**os.environ, "DOCKHIL_PURE_PYTHON": "1"}
    code = (
        "from dockhil.contact import rigid; assert rigid.COMPILED is None;"
        "from tests.test_sixdof_reference import CASES, digest;"
        "[print(name, digest(a, p) == (n, d)) for name, (a, p, n, d) in CASES.items()]"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.split("\n")
    assert [line.rsplit(" ", 1)[1] for line in lines if line] == ["True"] * 3, r.stdout


@compiled
def test_the_interface_geometry_equals_its_twin_bit_for_bit():
    from dockhil.contact import hybrid6
    from dockhil.contact.interface6 import InterfaceGeometry

    rng = random.Random(5)
    inertia = [[300.0, 20.0, 0.0], [20.0, 400.0, 10.0], [0.0, 10.0, 500.0]]  # principal axes off the body's
    tilted = quat_from_rotvec([0.0, 0.0, 0.02])
    for frames in ((np.diag([300.0, 400.0, 500.0]), (0.0, 0.0, 0.0, 1.0)), (inertia, tilted)):
        b1 = RigidBody(750.0, frames[0], interface_position=[1.0, 0.1, 0.0], interface_orientation=frames[1])
        b2 = RigidBody(
            1e6, np.diag([4e6, 5e6, 6e6]), interface_position=[-2.0, 0.0, 0.3], interface_orientation=frames[1]
        )
        for _ in range(500):
            p1 = (_vec(rng), _quat(rng), _vec(rng), _vec(rng))
            p2 = (_vec(rng), _quat(rng), _vec(rng), _vec(rng))
            q1, q2 = hybrid6.principal_attitude(b1, p1[1]), hybrid6.principal_attitude(b2, p2[1])
            want = InterfaceGeometry.between(b1, p1[0], q1, b2, p2[0], q2)
            velocity, spin = want.rates3(p1[2], p1[3], p2[2], p2[3])
            got = rigid.COMPILED.interface(b1._frames, b2._frames, *p1, *p2)
            assert got == (
                q1,
                q2,
                want.arm1,
                want.arm2,
                want.point,
                want.r,
                want.q_b,
                want.q_rel,
                want.d,
                velocity,
                spin,
            )


@compiled
def test_rotation_vectors_and_jacobians_equal_their_twins_bit_for_bit():
    from dockhil.contact import interface6

    rng = random.Random(13)
    quats = [_quat(rng) for _ in range(2000)] + [(0.0, 0.0, 0.0, 1.0), (1e-9, 0.0, 0.0, -1.0), (0.0, 0.0, 1.0, 0.0)]
    for q in quats:
        theta = rigid.COMPILED.rotvec3(q)
        assert theta == rotations.rotvec3_python(q)
        small = tuple(c * 1e-6 for c in theta)  # the series branch of J_l^-1 too
        for t in (theta, small):
            assert rigid.COMPILED.left_jacobian_inverse3(t) == interface6.left_jacobian_inverse3_python(t)
