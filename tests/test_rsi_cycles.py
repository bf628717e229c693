"""The RSI link's record of the controller's cycles (/robot/cycles): one entry per datagram answered, its
cycle count, the setpoint the controller took (start pose + RKorr) and the actual pose (RIst) in BASE, m
and quaternion; against a controller played here over a socket, one datagram at a time, on a clock the
test moves. The poses are computed independently with scipy (KUKA A B C: intrinsic Z-Y'-X'')."""

from __future__ import annotations

import math
import socket
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dockhil.devices.kuka_rsi.driver import SceneFrame
from dockhil.devices.kuka_rsi.link import RsiLink, open_socket
from dockhil.msgs import Header, RobotCycles
from dockhil.node import ManualClock, Tick
from dockhil.testing import wrench
from tests import test_hardware_rsi as hw

driven = hw.driven  # the driver against a controller played here (a fixture)

CYCLE = 0.004
START = (500.0, 0.0, 900.0, 180.0, 0.0, 180.0)
DEVICE = "robot controller (KUKA RSI 127.0.0.1 -> UDP port 0)"


def rob(ipoc: int, rist, delay: int) -> bytes:
    x, y, z, a, b, c = rist
    return (
        f'<Rob Type="KUKA"><RIst X="{x}" Y="{y}" Z="{z}" A="{a}" B="{b}" C="{c}"/>'
        f'<Delay D="{delay}"/><IPOC>{ipoc}</IPOC></Rob>'
    ).encode()


def quat(abc) -> np.ndarray:
    return Rotation.from_euler("ZYX", abc, degrees=True).as_quat()


def logged(link: RsiLink, answered: int) -> None:
    """Wait until the link has logged its `answered`-th answer (it logs after sending it, so an answer
    read here may come before its log)."""
    deadline = time.monotonic() + 5.0
    while link.answered < answered:
        assert time.monotonic() < deadline, f"the link answered {link.answered} datagrams, not {answered}"
        time.sleep(0.001)


def same_rotation(q, expected, atol: float = 1e-9) -> bool:
    return bool(np.allclose(q, expected, atol=atol) or np.allclose(q, -np.asarray(expected), atol=atol))


class Controller:
    """A KUKA controller, played: sends a <Rob> datagram, reads the <Sen> answer (IPOC, RKorr)."""

    def __init__(self, port: int, address: str = "127.0.0.1"):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((address, 0))
        self.sock.settimeout(5.0)
        self.port = port

    def send(self, ipoc: int, rist, delay: int = 0) -> None:
        self.sock.sendto(rob(ipoc, rist, delay), ("127.0.0.1", self.port))

    def answer(self) -> tuple[int, tuple[float, ...]]:
        root = ET.fromstring(self.sock.recv(4096))
        korr = root.find("RKorr")
        return int(root.find("IPOC").text), tuple(float(korr.get(n)) for n in ("X", "Y", "Z", "A", "B", "C"))


def test_each_datagram_answered_logs_its_cycle_the_setpoint_taken_and_the_pose_read_and_no_other_does():
    clock = ManualClock(100.0)
    sock, controller = open_socket("127.0.0.1", "127.0.0.1", 0, DEVICE)
    link = RsiLink(sock, controller, CYCLE, 10.0, 1.0, 10.0, "ImFree", clock)
    ctl, stranger = Controller(sock.getsockname()[1]), Controller(sock.getsockname()[1], "127.0.0.2")
    # toward 10 mm, -5 mm, 2 mm and 1 degree about z: the correction turns 0.23 degrees a cycle
    link.submit((10.0, -5.0, 2.0), (0.0, 0.0, math.sin(math.radians(0.5)), math.cos(math.radians(0.5))))
    link.start()
    base = 4 * 65534  # the 16-bit cycle count wraps after the second datagram
    poses = [START, (501.5, -0.25, 899.0, 179.0, 1.0, -179.5), (502.0, -1.0, 899.5, -179.0, 0.5, 179.0)]
    poses += [(503.25, -2.0, 900.75, -178.5, -0.5, 178.0), (504.0, -3.0, 901.0, -178.0, -1.0, 177.0)]
    # (IPOC, Delay): e1's answer is counted late (D rises by 1 with no gap); e3 comes after one datagram that
    # never came, and D rises by that one: e2's answer was in time
    plan = [(base, 0), (base + 4, 0), (base + 8, 1), (base + 16, 2), (base + 20, 2)]
    answers = []
    try:
        for k, ((ipoc, delay), rist) in enumerate(zip(plan, poses)):
            clock.advance(CYCLE)
            if k == 2:  # a repeated datagram and one from another address: neither answered nor logged
                ctl.send(base + 4, poses[1], 0)
                stranger.send(ipoc, rist, delay)
            ctl.send(ipoc, rist, delay)
            got_ipoc, korr = ctl.answer()
            assert got_ipoc == ipoc  # the answer to this datagram, no other before it
            answers.append(korr)
        logged(link, len(plan))
        entries = link.cycles.take()
    finally:
        link.stop()
        ctl.sock.close()
        stranger.sock.close()
    assert link.counted["repeated"] == 1 and link.counted["foreign"] == 1 and link.missing == 1
    # the last datagram's entry waits for the next datagram's Delay
    assert len(entries) == 4
    sent, read, setpoints, written, actuals, cycles, taken = zip(*entries)
    assert list(cycles) == [65534, 65535, 0, 2]
    assert written == (True, False, True, True) and taken == (False,) * 4
    assert all(s >= r for s, r in zip(sent, read)) and list(read) == sorted(read)

    def absolute(korr) -> np.ndarray:  # start + RKorr: position in m, R(A B C of RKorr) R(start)
        position = (np.array(START[:3]) + np.array(korr[:3])) / 1000.0
        return np.concatenate([position, (Rotation.from_euler("ZYX", korr[3:], degrees=True) * rot(START)).as_quat()])

    def rot(pose):
        return Rotation.from_euler("ZYX", pose[3:], degrees=True)

    # e1 was late: the controller kept e0's correction
    for entry, korr in zip(setpoints, (answers[0], answers[0], answers[2], answers[3])):
        want = absolute(korr)
        assert entry[:3] == pytest.approx(tuple(want[:3]), abs=1e-9)
        assert same_rotation(entry[3:], want[3:], atol=1e-5)  # the answer's angles carry 4 decimals
    assert answers[1] != answers[0] and answers[0][0] == pytest.approx(10.0) and answers[0][3] > 0.0
    for entry, rist in zip(actuals, poses):
        assert entry[:3] == pytest.approx(tuple(np.array(rist[:3]) / 1000.0), abs=1e-12)
        assert same_rotation(entry[3:], quat(rist[3:]), atol=1e-12)


def test_the_scene_frame_maps_a_logged_pose_as_it_maps_rist_and_the_setpoint_back_to_the_command():
    frame = SceneFrame((30.0, -10.0, 5.0), START)
    frame.anchor((0.02, 0.0, 0.01), (0.0, 0.0, 0.0, 1.0))
    rist = (503.0, -2.0, 901.5, 178.0, 1.5, -179.0)
    logged = (*(np.array(rist[:3]) / 1000.0), *quat(rist[3:]))
    position, q = frame.scene_pose(rist)
    values = frame.scene_values(logged)
    assert values[:3] == pytest.approx(position, abs=1e-12) and same_rotation(values[3:], q)
    # a command -> its correction -> the absolute setpoint the link logs -> the command again
    command = ((0.025, -0.003, 0.012), tuple(Rotation.from_rotvec([0.0, 0.01, 0.02]).as_quat()))
    korr_mm, korr_q = frame.correction(*command)
    setpoint = (
        *((np.array(START[:3]) + np.array(korr_mm)) / 1000.0),
        *(Rotation.from_quat(korr_q) * Rotation.from_euler("ZYX", START[3:], degrees=True)).as_quat(),
    )
    back = frame.scene_values(setpoint)
    assert back[:3] == pytest.approx(command[0], abs=1e-12) and same_rotation(back[3:], command[1])


def test_the_driver_with_anchor_origin_publishes_state_and_cycles_in_the_scene_frame_before_any_command(driven):
    """The driver against a controller played here: with `anchor: origin` (calibrate's) the state comes from
    the first datagram on, and /robot/cycles carries setpoint and pose in the scene frame, as the state."""
    node, ctl, clock, logs = driven(anchor="origin", ft_timeout=0, scene_a=90.0)  # scene x = BASE Y
    moved = (hw.START[0], hw.START[1] + 0.5, *hw.START[2:])  # 0.5 mm along BASE Y: scene x 0.5 mm
    ctl.exchange(moved)
    logged(node.link, node.link.received)
    clock.advance(0.001)
    out = node.step(Tick(0, 0.0, 0.001), {"wrench": wrench()})
    assert out["state"].pose.position.x == pytest.approx(0.0005, abs=1e-9)  # no command yet
    cycles = list(out["cycles"].cycles)
    for k in range(1, 9):
        clock.advance(0.001)
        _, ipoc, korr = ctl.exchange(moved)
        logged(node.link, node.link.received)
        out = node.step(Tick(k, k * 0.001, 0.001), {"command": hw.command(k, 0.001), "wrench": wrench()})
        cycles += out.get("cycles", RobotCycles(header=Header())).cycles
    assert korr[1] == pytest.approx(1.0, abs=1e-4)  # 1 mm along BASE Y, reached at 0.4 mm a cycle
    # one entry per datagram, each published once the next datagram came: the last is still held
    counts = [c.device_cycle for c in cycles]
    assert counts == list(range(counts[0], ipoc // 4)) and ipoc // 4 - counts[0] >= 9
    assert all(not c.taken and c.written for c in cycles)
    assert cycles[-1].actual.position.x == pytest.approx(0.0005, abs=1e-9)
    assert cycles[-1].actual.orientation.w == pytest.approx(1.0, abs=1e-9)
    # the setpoints the controller took, in the scene frame: 0 until the answer after the first command's
    # step, then 0.4 mm a cycle to the command's 1 mm (the eighth datagram's entry is still held)
    xs = [c.setpoint.position.x for c in cycles[-7:]]
    assert xs == pytest.approx([0.0, 0.0004, 0.0008, 0.001, 0.001, 0.001, 0.001], abs=1e-9)
    assert all(abs(c.setpoint.position.y) < 1e-12 and abs(c.setpoint.position.z) < 1e-12 for c in cycles)


def played_cycles(delay: float, lag: float, cycle: float, seed: int, seconds: float = 6.0):
    """The exchanges of an RSI controller with a hidden delay and lag (the emulator's servo, advanced on the
    test's cycle clock): steps then a chirp, each answer taken the cycle after its datagram, the link's read
    times scattered by up to a few tenths of a millisecond and 1 um of noise on the pose."""
    from dockhil.analysis.calibration.device_cycles import DeviceCycles
    from dockhil.devices.kuka_rsi.emulator import RsiServo

    rng = np.random.default_rng(seed)
    servo = RsiServo((0.0,) * 6, delay, lag)
    n = int(seconds / cycle)
    sent, read, x_set, x_actual = (np.empty(n) for _ in range(4))
    for k in range(n):
        t = k * cycle
        servo.advance(t)
        read[k] = t + 2e-4 + abs(rng.normal(0.0, 2e-4))
        sent[k] = read[k] + 1e-4
        x_actual[k] = round(servo.position[0] / 1000.0 + rng.normal(0.0, 1e-6), 6)
        u = t - 3.0
        x_set[k] = 0.002 * (int(t / 0.5) % 2) if t < 3.0 else 0.001 * math.sin(2 * math.pi * (0.5 + 2.0 * u) * u)
        servo.correct((x_set[k] * 1000.0, 0.0, 0.0, 0.0, 0.0, 0.0), t + cycle)
    counts = (250_000 + np.arange(n)) & 0xFFFF
    return DeviceCycles(sent, read, x_set, np.ones(n, bool), x_actual, counts, np.zeros(n, bool))


def test_a_lag_under_a_cycle_is_not_traded_for_a_delay_between_cycles():
    """A controller acts on whole cycles: the fit keeps the delay at a whole cycle where that explains the
    poses as well for one parameter less, so a lag well under the 4 ms cycle is read as such (the free fit
    read some as none, the delay taking a fraction of a cycle). Lags this small barely show: 0.6 ms of lag
    leaves 0.1 % of a step after one cycle, and its uncertainty says so."""
    from dockhil.analysis.calibration.device_cycles import device_servo

    # (delay, lag, the noise's seed): three the free fit read with no lag (the third also 0.03 ms of delay
    # off), one without a lag and one with a lag of over two cycles
    cases = (
        (0.02579, 0.000607, 5),
        (0.07095, 0.000119, 11),
        (0.09569, 0.000801, 22),
        (0.0497, 0.0, 3),
        (0.0613, 0.0094, 3),
    )
    for delay, lag, seed in cases:
        servo = device_servo(played_cycles(delay, lag, CYCLE, seed=seed))
        effective = math.ceil(delay / CYCLE) * CYCLE  # the controller's delay: whole cycles
        assert servo.delay_s + CYCLE / 2 == pytest.approx(effective, abs=2e-4), (delay, lag, servo)
        assert abs(servo.lag_s - lag) <= max(0.05 * lag, 1e-4), (delay, lag, servo)
        # its uncertainty is the lag's own, as the poses bound it (the free fit's, where delay and lag trade,
        # was tens of seconds), and covers the truth
        assert abs(servo.lag_s - lag) <= 3.0 * servo.lag_sigma_s <= 1.5e-3, (delay, lag, servo)
