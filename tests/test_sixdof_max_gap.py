"""max_gap of the 6-DOF dynamics: the robot command follows the pair's pose within max_gap along the
docking axis, waits still beyond it, and comes back continuously (sim time throughout)."""

from __future__ import annotations

import math

import numpy as np

from dockhil import node_types as registry
from dockhil.contact.rotations import quat_conjugate, quat_multiply, rotvec3
from dockhil.msgs import BodyWrenches, Header, Vector3, Wrench
from dockhil.testing import NodeHarness
from tests.test_sixdof_graph import HIL6, run_composed

DT = 1e-3
MAX_GAP = 0.2


def pose(cmd):
    p, o = cmd.pose.position, cmd.pose.orientation
    return (p.x, p.y, p.z), (o.x, o.y, o.z, o.w)


def twist(cmd):
    v = cmd.twist.linear
    return (v.x, v.y, v.z)


def turn(a, b) -> float:
    """The angle [rad] of the rotation from attitude b to attitude a."""
    return math.hypot(*rotvec3(quat_multiply(a, quat_conjugate(b))))


def away_and_back(max_gap: float):
    """Commands and log lines: the chaser leaves B at 0.1 m/s, drifting sideways and spinning (roll 0.3
    rad/s, yaw 0.05 rad/s), for 4 s, then a virtual 60 N along +x brings it back through B's plane."""
    push = {"impedance": BodyWrenches(header=Header(), wrenches=(Wrench(force=Vector3(60.0)), Wrench()))}
    params = dict(dof=6, v1=[-0.1, 0.02, 0.0], w1=[0.3, 0.0, 0.05], max_gap=max_gap)
    with NodeHarness("satellite_dynamics", dt=DT, **params) as h:
        outs = h.run(4000) + h.run(6000, inputs=push)
    return [out["command"] for out in outs], h.logs


def test_the_command_waits_still_beyond_max_gap_and_comes_back_continuously():
    pair, _ = away_and_back(0.0)  # max_gap 0: the pair's own pose, every tick
    got, logs = away_and_back(MAX_GAP)
    gap = np.array([-c.pose.position.x for c in pair])
    park = int(np.argmax(gap > MAX_GAP))
    back = park + int(np.argmax(gap[park:] <= MAX_GAP))
    plane = back + int(np.argmax(gap[back:] <= 0.0))
    assert 0 < park < back < plane < len(pair) - 100
    # Within max_gap, before it ever parked: the command is the pair's, bit for bit.
    assert got[:park] == pair[:park]
    # Beyond it: the pose of the tick it parked, at -max_gap along the axis, held still.
    (_, y, z), q = pose(pair[park])
    held = ((-MAX_GAP, y, z), q)
    for cmd in got[park:back]:
        assert pose(cmd) == held
        assert (cmd.twist.linear.x, cmd.twist.linear.y, cmd.twist.linear.z) == (0.0, 0.0, 0.0)
        assert (cmd.twist.angular.x, cmd.twist.angular.y, cmd.twist.angular.z) == (0.0, 0.0, 0.0)
    # ... while the pair drifted sideways and turned far (what would leave the robot's workspace).
    (_, y_back, z_back), q_back = pose(pair[back])
    assert math.hypot(y_back - y, z_back - z) > 0.25 and turn(q_back, q) > 1.5
    # Coming back it starts at the held pose and moves, each tick, by the pair's own step plus the
    # offset to the pair times at most 1.5 times the gap's step over the gap at the return.
    d_back = pose(pair[back])[0]
    offset = math.dist(held[0], d_back)
    angle = turn(held[1], q_back)
    assert math.dist(pose(got[back])[0], held[0]) < 1e-12 and turn(pose(got[back])[1], held[1]) < 1e-12
    for k in range(back + 1, plane + 1):
        (d0, q0), (d1, q1) = pose(got[k - 1]), pose(got[k])
        (p0, r0), (p1, r1) = pose(pair[k - 1]), pose(pair[k])
        ds = 1.5 * abs(gap[k] - gap[k - 1]) / gap[back]
        assert math.dist(d0, d1) <= math.dist(p0, p1) + ds * offset + 1e-12
        assert turn(q1, q0) <= turn(r1, r0) + ds * angle + 1e-9
        # Its twist is its pose's rate (the midpoint of two ticks' twists, to the step's O(dt^2)).
        rate = [(b - a) / DT for a, b in zip(d0, d1)]
        v0, v1 = got[k - 1].twist.linear, got[k].twist.linear
        mid = [(a + b) / 2 for a, b in zip((v0.x, v0.y, v0.z), (v1.x, v1.y, v1.z))]
        if k < plane:
            assert math.dist(rate, mid) < 1e-4
    # Nor does its velocity step at the plane, where the take-down ends and a contact may begin: it
    # changes there no more than from tick to tick within the take-down (one in proportion to the
    # gap would step by the offset's whole rate there).
    steps = [math.dist(twist(got[k - 1]), twist(got[k])) for k in range(back + 2, plane + 1)]
    assert steps[-1] <= max(steps[:-1])
    # From B's plane on (before any contact) it is the pair's again, bit for bit.
    assert got[plane:] == pair[plane:]
    assert [m for m in logs if "waits at the gap" in m] == [
        f"interfaces {-pair[park].pose.position.x:.3g} m apart along the docking axis: the robot waits at the gap "
        "max_gap = 0.2 m, its pose held"
    ]


def test_the_command_within_max_gap_is_the_same_bit_for_bit():
    # hil6.yaml for 12 s: the contact, then the pair drifts past 0.3 m (the scene's max_gap).
    n = 12000
    off = run_composed(HIL6, {"max_gap": 0.0}, n)["/robot/command"]
    wide = run_composed(HIL6, {"max_gap": 1.0}, n)["/robot/command"]
    assert len(off) == n and max(-c.pose.position.x for c in off) > 0.3
    assert wide == off


def workspace() -> dict:
    """The robot drivers' default workspace box and max_tilt (robot_rsi's, the scene's robot:=rsi)."""
    params = registry.load("robot_rsi").params
    return {name: params[name].default for name in ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max", "max_tilt")}


def commanded(cmds):
    """(position (n, 3), angle of each commanded attitude from the first [rad])."""
    first = pose(cmds[0])[1]
    return np.array([pose(c)[0] for c in cmds]), np.array([turn(pose(c)[1], first) for c in cmds])


def test_a_120_s_hil6_run_commands_the_robot_inside_its_workspace():
    w = workspace()
    xyz, tilt = commanded(run_composed(HIL6, {}, 120_001)["/robot/command"])
    for i, axis in enumerate("xyz"):
        assert np.all(xyz[:, i] >= w[f"{axis}_min"]) and np.all(xyz[:, i] <= w[f"{axis}_max"]), axis
    assert np.max(tilt) <= w["max_tilt"]
    assert np.min(xyz[:, 0]) == -0.3  # it waited at hil6.yaml's max_gap
    # Without max_gap the drift leaves the workspace within 20 s.
    xyz, _ = commanded(run_composed(HIL6, {"max_gap": 0.0}, 20_001)["/robot/command"])
    assert np.min(xyz[:, 0]) < w["x_min"]
