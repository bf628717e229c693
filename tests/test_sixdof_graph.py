"""The 6-DOF HIL graph (launch/hil6.yaml): composed and multi-process runs equal the library's
6-DOF hybrid loop bit for bit; along the axis it is the 1-DOF hil.yaml run; bad 6-DOF parameters
in a launch file stop the launch with one line."""

import subprocess

import numpy as np
import pytest

from dockhil.bags.reader import BagReader
from dockhil.contact.contact6 import Contact6
from dockhil.contact.hybrid6 import simulate_hybrid6
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.rotations import quat_from_rotvec
from dockhil.msgs import SatelliteState, WrenchStamped
from dockhil.runtime.composed import ComposedGraph
from dockhil.scene import graph as graphmod
from dockhil.scene import launchfile
from tests.conftest import ROOT, dockhil_cmd

HIL6 = ROOT / "launch" / "hil6.yaml"
DT = 1e-3


def run_taps(graph, taps: list, n_ticks: int) -> None:
    """A composed sim-time run of `graph` for n_ticks; every message goes to `taps`."""
    g = ComposedGraph(graph, taps=taps, log=lambda name, msg: None)
    g.setup()
    try:
        g.run(n_ticks)
    finally:
        g.close()


def run_composed(path, args: dict, n_ticks: int) -> dict:
    """Messages by topic, in tick order, of a composed sim-time run."""
    scene = launchfile.load(path, {k: str(v) for k, v in args.items()})
    seen: dict = {}
    run_taps(graphmod.build(scene), [lambda topic, msg: seen.setdefault(topic, []).append(msg)], n_ticks)
    return seen


def library_run(offset, tilt, spin, delay, n_ticks, mu=0.0, order=2):
    """launch/hil6.yaml's defaults, written out for the library: the same bodies, contact, start and
    integrator order."""
    chaser = RigidBody(750.0, np.diag([300.0, 400.0, 500.0]), interface_position=[1.0, 0.0, 0.0])
    target = RigidBody(1e6, np.diag([4e6, 5e6, 6e6]), interface_position=[-2.0, 0.0, 0.0])
    s1 = BodyState([-1.0, offset, 0.0], quat_from_rotvec([0.0, 0.0, tilt]), [0.03, 0.0, 0.0], [spin, 0.0, 0.0])
    s2 = BodyState([2.0, 0.0, 0.0], (0.0, 0.0, 0.0, 1.0), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    ideal = Contact6([3000.0, 3000.0, 3000.0, 300.0, 300.0, 300.0], [40.0, 40.0, 40.0, 4.0, 4.0, 4.0])
    passive = Contact6([1000.0, 1000.0, 1000.0, 100.0, 100.0, 100.0], mu=mu)
    return simulate_hybrid6(
        chaser,
        target,
        s1,
        s2,
        ideal,
        passive,
        dt=DT,
        t_end=(n_ticks - 1) * DT,
        delay_ticks=int(round(delay / DT)),
        order=order,
    )


def states(msgs_list):
    """positions, velocities, world angular velocities: (n, 2, 3) each."""

    def arr(get):
        return np.array([[[getattr(get(b), c) for c in "xyz"] for b in m.bodies] for m in msgs_list])

    return arr(lambda b: b.pose.position), arr(lambda b: b.twist.linear), arr(lambda b: b.twist.angular)


def assert_equals_library(state_msgs, run):
    pos, vel, omega = states(state_msgs)
    assert len(state_msgs) == run.t.size
    assert np.array_equal(pos, run.positions)
    assert np.array_equal(vel, run.velocities)
    assert np.array_equal(omega, run.omegas)


def test_composed_off_axis_graph_equals_the_library_loop_bit_for_bit():
    args = dict(offset=0.05, tilt=0.02, spin=0.01, delay=0.016)
    n = 400
    seen = run_composed(HIL6, args, n)
    run = library_run(0.05, 0.02, 0.01, 0.016, n)
    assert run.onset < 0.01 and run.in_contact[-1]  # the tilt leaves a gap of 0.2 mm: touch after 7 ms
    assert np.max(np.abs(run.torque)) > 0.1  # off-axis: torques act, rotations move
    assert np.max(np.abs(run.omegas[:, 0, 1:])) > 1e-5
    assert_equals_library(seen["/satellite/state"], run)


def test_composed_order_4_equals_the_library_loop_bit_for_bit():
    args = dict(offset=0.05, tilt=0.02, spin=0.01, delay=0.016, order=4)
    n = 200
    assert_equals_library(
        run_composed(HIL6, args, n)["/satellite/state"], library_run(0.05, 0.02, 0.01, 0.016, n, order=4)
    )


def test_the_scenes_order_2_is_order_4_to_far_below_the_sampled_loops_error():
    # Why hil6.yaml integrates at order 2: with the wrench held over each tick the two orders agree to
    # ~1e-11 through the whole contact, while the hybrid loop itself is 0.1-5 % off the ideal contact.
    two, four = (library_run(0.05, 0.02, 0.01, 0.032, 1700, order=k) for k in (2, 4))
    assert four.onset is not None and four.exit is not None  # the whole contact is inside
    for name in ("force", "torque", "velocities", "omegas"):
        a, b = getattr(two, name), getattr(four, name)
        assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(b)), name
    assert not np.array_equal(two.omegas, four.omegas)  # two different integrations


def test_multiprocess_run_equals_the_library_loop_bit_for_bit(tmp_path):
    bag = tmp_path / "hil6.mcap"
    r = subprocess.run(
        dockhil_cmd("launch", HIL6, "--duration", "0.1", "--bag", bag, "--quiet", "delay:=0.01"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    with BagReader(str(bag)) as reader:
        got = [msg for _topic, _t, msg in reader.decoded(["/satellite/state"])]
    assert all(isinstance(m, SatelliteState) for m in got)
    got.sort(key=lambda m: m.header.tick)
    assert_equals_library(got, library_run(0.05, 0.02, 0.01, 0.01, len(got)))
    assert len(got) == 101


@pytest.mark.parametrize("delay", [0.0, 0.032])
def test_along_the_axis_the_6dof_scene_is_the_1dof_hil_scene(delay):
    n = 1800  # the whole contact (about 1.6 s) and the rebound
    one = run_composed(ROOT / "launch" / "hil.yaml", dict(delay=delay), n)
    six = run_composed(HIL6, dict(delay=delay, offset=0.0, tilt=0.0, spin=0.0), n)
    # The 1-DOF sensor reports the force on the chaser; the 6-DOF one, on the target it sits on.
    f1 = np.array([m.wrench.force.x for m in one["/ft/wrench"]])
    f6 = -np.array([m.wrench.force.x for m in six["/ft/wrench"]])
    assert all(isinstance(m, WrenchStamped) for m in six["/ft/wrench"])
    assert f1.size == f6.size == n and np.max(np.abs(f1)) > 10.0  # the passive force peaks near 15 N
    assert np.max(np.abs(f6 - f1)) <= 1e-9 * np.max(np.abs(f1))
    v1 = np.array([[b.twist.linear.x for b in m.bodies] for m in one["/satellite/state"]])
    _, v6, w6 = states(six["/satellite/state"])
    assert np.max(np.abs(v6[:, :, 0] - v1)) <= 1e-9 * np.max(np.abs(v1))
    assert np.max(np.abs(v1[-1, 0] - v1[0, 0])) > 0.03  # the chaser rebounded
    assert np.all(v6[:, :, 1:] == 0.0) and np.all(w6 == 0.0)  # nothing off the axis moves


K_ASYM = (
    "[[3000, 0, 0, 0, 0, 0], [0, 3000, 0, 0, 0, 0], [0, 0, 3000, 0, 0, 0], [0, 0, 0, 300, 0, 0],"
    " [0, 0, 0, 0, 300, 5], [0, 0, 0, 0, 0, 300]]"
)


@pytest.mark.parametrize(
    "old, new, line",
    [
        (
            "      w1: [$(arg spin), 0.0, 0.0]",
            "      w1: [$(arg spin), 0.0, 0.0]\n      inertia1: [300.0, -400.0, 500.0]",
            "node 'dynamics': chaser.inertia must be positive definite: its smallest eigenvalue is -400.0",
        ),
        (
            "      w1: [$(arg spin), 0.0, 0.0]",
            "      w1: [$(arg spin), 0.0, 0.0]\n      q1: [0.0, 0.0, 0.1, 1.0]",
            "node 'dynamics': q1 must be a unit quaternion (x, y, z, w), got norm 1.00498756211",
        ),
        (
            "      stiffness: [$(arg kcs), $(arg kcs), $(arg kcs), $(arg kr), $(arg kr), $(arg kr)]",
            f"      stiffness: {K_ASYM}",
            "node 'impedance': stiffness must be symmetric: entry [4][5] = 5.0 but [5][4] = 0.0",
        ),
    ],
)
def test_bad_6dof_parameters_stop_the_launch_with_one_line(tmp_path, old, new, line):
    text = HIL6.read_text()
    assert old in text
    path = tmp_path / "bad.yaml"
    path.write_text(text.replace(old, new, 1))
    r = subprocess.run(
        dockhil_cmd("launch", path, "--composed", "--duration", "0.01"), capture_output=True, text=True, timeout=60
    )
    assert r.returncode not in (0, None)
    assert "Traceback" not in r.stderr + r.stdout
    lines = [s for s in (r.stderr + r.stdout).splitlines() if s.strip()]
    assert len(lines) == 1 and line in lines[0], lines


def test_plot_6dof_draws_the_recorded_pose_and_rates(tmp_path):
    from dockhil.analysis.plots.plot6 import series6

    bag, png = tmp_path / "hil6.mcap", tmp_path / "hil6.png"
    for args in (
        ("launch", HIL6, "--composed", "--duration", "0.3", "--bag", bag, "--quiet", "delay:=0.01"),
        ("plot", bag, "--6dof", "--png", png),
    ):
        r = subprocess.run(dockhil_cmd(*args), capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stdout + r.stderr
    assert png.stat().st_size > 10_000
    s = series6(str(bag))
    run = library_run(0.05, 0.02, 0.01, 0.01, 301)
    # The command is A's pose in B of the published state: the library's e to rounding.
    assert np.allclose(s.position, run.e[:, :3], rtol=0, atol=1e-12)
    assert np.allclose(s.rotation, run.e[:, 3:], rtol=0, atol=1e-12)
    assert np.array_equal(s.omega, run.omegas) and np.max(np.abs(s.omega[:, 0, 2])) > 0.0
    assert s.torque.shape == (301, 3) and np.max(np.abs(s.torque)) > 0.05  # off-axis: the sensor feels torque


def _off_axis_pair():
    """Two bodies in contact off the axis, tilted and turning, and their published view."""
    from dockhil.contact.hybrid6 import motion_from_published, published_body, relative_interface
    from dockhil.contact.rigid import Motion

    chaser = RigidBody(
        750.0, [[300.0, 10.0, 0.0], [10.0, 400.0, 5.0], [0.0, 5.0, 500.0]], interface_position=[1.0, 0.1, 0.0]
    )
    target = RigidBody(
        2000.0,
        np.diag([900.0, 1000.0, 1100.0]),
        interface_position=[-2.0, 0.0, 0.05],
        interface_orientation=quat_from_rotvec([0.0, 0.05, 0.0]),
    )
    m1 = Motion.from_state(
        chaser,
        BodyState([-0.99, 0.05, 0.01], quat_from_rotvec([0.01, 0.0, 0.02]), [0.03, 0.004, -0.002], [0.01, 0.02, -0.01]),
    )
    m2 = Motion.from_state(
        target, BodyState([2.0, 0.0, 0.1], quat_from_rotvec([0.0, -0.05, 0.0]), [0.0, 0.001, 0.0], [0.0, 0.0, 0.003])
    )
    pubs = [published_body(m) for m in (m1, m2)]
    s1 = motion_from_published(chaser, *pubs[0])
    s2 = motion_from_published(target, *pubs[1])
    g, rate, pose = relative_interface(s1, s2, pubs[0][3], pubs[1][3])
    return m1, m2, g, rate, pose


def test_sensor_reading_is_the_passive_contact_wrench_on_the_target_with_friction():
    from dockhil.contact.contact6 import contact_wrench
    from dockhil.contact.hybrid6 import PassiveSensor6
    from dockhil.contact.rotations import cross

    m1, m2, g, rate, pose = _off_axis_pair()
    assert g.e[0] > 0.0 and np.linalg.norm(rate[1:3]) > 1e-3  # penetrating and sliding
    passive = Contact6([1000.0, 800.0, 900.0, 100.0, 120.0, 90.0], [5.0, 4.0, 3.0, 0.5, 0.4, 0.3], mu=0.3)
    sensor = PassiveSensor6(passive)
    sensor.anchor = np.array([0.0, 0.01, -0.02, 0.003, -0.004, 0.005])  # springs resting off the axis
    force_s, torque_s, _ = sensor.read(pose)
    f1, mom1, _ = contact_wrench(passive, g, rate, sensor.anchor)  # on the chaser, world, about o_A
    rb = g.rot_b
    # The target gets (-F, -M) at o_A: in B's axes, about B's origin.
    assert np.allclose(force_s, rb.T @ -f1, rtol=0, atol=1e-12)
    assert np.allclose(torque_s, rb.T @ (-mom1 - cross(g.r, f1)), rtol=0, atol=1e-12)
    assert abs(force_s[1]) > 0.1  # friction acts along the sliding


def test_the_sensor_mounting_pose_does_not_change_the_wrench_on_the_bodies():
    from dockhil.contact.hybrid6 import PassiveSensor6, held_wrench, sensor_mount_in_body

    m1, m2, g, rate, pose = _off_axis_pair()
    passive = Contact6([1000.0, 800.0, 900.0, 100.0, 120.0, 90.0])
    zero = (np.zeros(3),) * 4
    out = []
    for position, orientation in (
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        ((0.02, -0.03, 0.1), quat_from_rotvec([0.3, -0.2, 0.5])),
    ):
        force, torque, _ = PassiveSensor6(passive, position, orientation).read(pose)
        w = held_wrench(m1, m2, sensor_mount_in_body(m2.body, position, orientation), force, torque, zero)
        out.append(np.concatenate([w.f1, w.t1, w.f2, w.t2]))
    assert np.max(np.abs(out[0])) > 1.0
    assert np.allclose(out[0], out[1], rtol=0, atol=1e-11)
