"""KUKA RSI: the datagrams against texts written here from the protocol, KUKA's A B C against
independent rotations, the controller emulator driven by a raw socket, the driver's answering
path on a clock the test controls, the driver against an independent fake controller and against
the emulator, and one end-to-end launch."""

from __future__ import annotations

import json
import math
import os
import random
import socket
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from scipy.spatial.transform import Rotation

from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.kuka_rsi.driver import RobotRsiDriver, RsiLink, SceneFrame
from dockhil.devices.kuka_rsi.emulator import RsiControllerEmulator, RsiServo
from dockhil.errors import DeviceError, LaunchError, SafetyStop
from dockhil.msgs import Header, Pose, RobotCommand, Twist, Vector3
from dockhil.node import ManualClock, NodeContext, Tick
from dockhil.runtime import ownership
from dockhil.testing import wrench
from tests.conftest import dockhil_cmd, udp_port

ROOT = Path(__file__).resolve().parents[1]
CYCLE = 0.004
START = (512.5, -20.25, 803.0, 170.0, 10.0, -175.0)  # mm, degrees: a pose off every axis


def rob_text(ipoc: int, rist=START, delay: int = 0, attribute: str = "Type", extra: str = "", rsol=None) -> bytes:
    """A controller datagram as the protocol describes it, with elements a driver must skip (RSol, the
    commanded pose, where given)."""
    x, y, z, a, b, c = rist
    commanded = "" if rsol is None else '  <RSol X="{}" Y="{}" Z="{}" A="{}" B="{}" C="{}" />\r\n'.format(*rsol)
    return (
        f'<Rob {attribute}="KUKA">\r\n'
        f'  <RIst X="{x}" Y="{y}" Z="{z}" A="{a}" B="{b}" C="{c}" />\r\n'
        f"{commanded}"
        f'  <AIPos A1="0.0" A2="-90.0" A3="90.0" A4="0.0" A5="45.0" A6="0.0" />\r\n'
        f'  <ASPos A1="0.0" A2="-90.0" A3="90.0" A4="0.0" A5="45.0" A6="0.0" />\r\n'
        f'  <Delay D="{delay}" />\r\n{extra}'
        f"  <IPOC>{ipoc}</IPOC>\r\n</Rob>"
    ).encode()


def read_sen(data: bytes) -> tuple[str, int, tuple[float, ...]]:
    """The answer as any XML reader sees it: (Type, IPOC, RKorr X Y Z A B C)."""
    root = ET.fromstring(data)
    assert root.tag == "Sen"
    korr = root.find("RKorr").attrib
    return root.get("Type"), int(root.find("IPOC").text), tuple(float(korr[k]) for k in "XYZABC")


def rotation_deg(abc_from, abc_to) -> float:
    """Angle [degrees] between two KUKA orientations, by scipy (intrinsic Z-Y'-X'')."""
    r0 = Rotation.from_euler("ZYX", abc_from, degrees=True)
    r1 = Rotation.from_euler("ZYX", abc_to, degrees=True)
    return math.degrees((r1 * r0.inv()).magnitude())


# -- the datagrams ------------------------------------------------------------------------------


def test_a_controller_datagram_is_read_with_the_elements_it_needs_and_the_rest_skipped():
    frame = rsi.parse_rob(
        rob_text(4711, delay=3, extra='  <Tech C11="0.0" C12="1.5" />\r\n  <DiL>0</DiL>\r\n', rsol=START)
    )
    assert frame.ipoc == 4711 and frame.delay == 3
    assert frame.rist == START and frame.rsol == START
    # Open simulators write TYPE; RSol and Delay are optional in the Ethernet configuration.
    bare = b'<Rob TYPE="KUKA"><RIst X="1" Y="2" Z="3" A="4" B="5" C="6"/><IPOC>9</IPOC></Rob>'
    frame = rsi.parse_rob(bare)
    assert frame == rsi.RobFrame(9, (1.0, 2.0, 3.0, 4.0, 5.0, 6.0), None, None)


@pytest.mark.parametrize(
    "data, why",
    [
        (b'<Rob Type="KUKA"><RIst X="1" Y="2" Z="3" A="4" B="5" C="6"/>', "malformed XML"),
        (b'<Rob Type="KUKA"><AIPos A1="0"/><IPOC>1</IPOC></Rob>', "no RIst"),
        (b'<Rob Type="KUKA"><RIst X="1" Y="2" Z="3" A="4" B="5" C="6"/></Rob>', "no IPOC"),
        (b'<Rob Type="KUKA"><RIst X="1" Y="2" Z="3" A="4" B="5"/><IPOC>1</IPOC></Rob>', "no attribute C"),
        (b'<Rob Type="KUKA"><RIst X="nan" Y="2" Z="3" A="4" B="5" C="6"/><IPOC>1</IPOC></Rob>', "not finite"),
        (b'<Rob Type="KUKA"><RIst X="1mm" Y="2" Z="3" A="4" B="5" C="6"/><IPOC>1</IPOC></Rob>', "not a number"),
        (b'<Rob Type="KUKA"><RIst X="1" Y="2" Z="3" A="4" B="5" C="6"/><IPOC>-4</IPOC></Rob>', "IPOC"),
        (b'<Sen Type="ImFree"><RKorr X="0" Y="0" Z="0" A="0" B="0" C="0"/><IPOC>1</IPOC></Sen>', "not <Rob>"),
        (b'<!DOCTYPE r [<!ENTITY e "xxxxxxxx">]><Rob Type="KUKA"><IPOC>&e;</IPOC></Rob>', "declaration"),
        (b'<Rob Type="KUKA"><?pi x?><IPOC>1</IPOC></Rob>', "processing instruction"),
        (b'<Rob Type="KUKA">' + b" " * rsi.MAX_DATAGRAM + b"</Rob>", "oversized"),
    ],
)
def test_what_is_not_a_controller_datagram_is_refused_in_a_few_words(data, why):
    with pytest.raises(rsi.RsiError, match=why):
        rsi.parse_rob(data)


def test_an_answer_reads_back_as_any_xml_reader_sees_it():
    write = rsi.SenWriter("ImFree")
    answer = write((1.25, -0.5, 0.0001, 0.1, -179.99, 45.0), 123456789012)
    sen_type, ipoc, korr = read_sen(answer)
    assert sen_type == "ImFree" and ipoc == 123456789012
    assert korr == pytest.approx((1.25, -0.5, 0.0001, 0.1, -179.99, 45.0), abs=5e-5)
    assert b"e-" not in answer and b"e+" not in answer  # fixed point: no exponent for a controller to misread
    assert read_sen(rsi.SenWriter("KukaRsiDriver")((0,) * 6, 1))[0] == "KukaRsiDriver"
    with pytest.raises(ValueError):
        rsi.SenWriter('x" evil="1')
    # the emulator's side reads a sensor's answer written by hand
    text = (
        b'<Sen Type="ImFree">\n<EStr>hello</EStr>\n<RKorr X="1.5" Y="0" Z="-2" A="0" B="0" C="0.25" />\n'
        b"<IPOC>77</IPOC>\n</Sen>"
    )
    assert rsi.parse_sen(text) == (77, (1.5, 0.0, -2.0, 0.0, 0.0, 0.25))


# -- A B C <-> quaternion --------------------------------------------------------------------------


def test_kuka_angles_are_intrinsic_z_y_x_as_scipy_and_hand_matrices_compute_them():
    rng = random.Random(3)
    for _ in range(500):
        abc = (rng.uniform(-180, 180), rng.uniform(-89.9, 89.9), rng.uniform(-180, 180))
        q = rsi.abc_to_quat(*abc)
        expected = Rotation.from_euler("ZYX", abc, degrees=True).as_quat()  # x, y, z, w
        sign = 1.0 if sum(a * b for a, b in zip(q, expected)) >= 0 else -1.0
        assert [sign * c for c in q] == pytest.approx(list(expected), abs=1e-12)
        assert rsi.quat_to_abc(q) == pytest.approx(abc, abs=1e-9)
    # By hand: A = 90 turns x into y; B = 90 (about the new y) turns x into -z; C about the last x.
    r = Rotation.from_quat(rsi.abc_to_quat(90.0, 0.0, 0.0))
    assert r.apply((1, 0, 0)) == pytest.approx((0, 1, 0), abs=1e-12)
    r = Rotation.from_quat(rsi.abc_to_quat(0.0, 90.0, 0.0))
    assert r.apply((1, 0, 0)) == pytest.approx((0, 0, -1), abs=1e-12)
    r = Rotation.from_quat(rsi.abc_to_quat(90.0, 0.0, 90.0))  # Rz(90) Rx(90): Rx first, on the vector
    assert r.apply((0, 1, 0)) == pytest.approx((0, 0, 1), abs=1e-12)  # y -> z -> z
    assert r.apply((0, 0, 1)) == pytest.approx((1, 0, 0), abs=1e-12)  # z -> -y -> x


@pytest.mark.parametrize("b", [90.0, -90.0])
def test_at_gimbal_lock_the_angles_found_give_the_same_rotation(b):
    for a, c in ((30.0, 0.0), (30.0, 20.0), (-170.0, 150.0)):
        q = rsi.abc_to_quat(a, b, c)
        found = rsi.quat_to_abc(q)
        assert found[1] == pytest.approx(b, abs=1e-6) and found[2] == 0.0
        assert rotation_deg((a, b, c), found) < 1e-6


# -- the emulator, driven by a raw socket ------------------------------------------------------------


class RawSensor:
    """A sensor written here: receives the controller's datagrams, answers by hand."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(2.0)
        self.port = self.sock.getsockname()[1]

    def receive(self):
        data, addr = self.sock.recvfrom(8192)
        root = ET.fromstring(data)
        rist = root.find("RIst").attrib
        return (
            int(root.find("IPOC").text),
            tuple(float(rist[k]) for k in "XYZABC"),
            int(root.find("Delay").get("D")),
            addr,
        )

    def answer(self, ipoc: int, korr, addr) -> None:
        x, y, z, a, b, c = korr
        self.sock.sendto(
            f'<Sen Type="ImFree"><RKorr X="{x}" Y="{y}" Z="{z}" A="{a}" B="{b}" C="{c}"/>'
            f"<IPOC>{ipoc}</IPOC></Sen>".encode(),
            addr,
        )


def test_the_emulator_sends_each_cycle_applies_answers_counts_late_ones_and_stops_rsi():
    sensor = RawSensor()
    emulator = RsiControllerEmulator(port=sensor.port, cycle=CYCLE, max_late=5, start=START)
    emulator.start_thread()
    try:
        ipoc, rist, delay, addr = sensor.receive()
        assert rist == pytest.approx(START, abs=1e-3) and delay == 0
        # not answered yet: the late count starts with the first answer
        ipoc2, *_ = sensor.receive()
        assert ipoc2 - ipoc == 4 * round((ipoc2 - ipoc) / 4) and ipoc2 > ipoc  # a millisecond timestamp
        # answered (each cycle, in case a loaded machine makes an answer late), the correction (absolute, no
        # delay, no lag) shows in the next datagram
        ipoc3 = ipoc2
        for _ in range(100):
            sensor.answer(ipoc3, (1.0, -2.0, 0.5, 0.0, 0.0, 1.0), addr)
            ipoc3, rist, delay, _ = sensor.receive()
            if rist[0] != pytest.approx(START[0], abs=1e-3):
                break
        assert rist[:3] == pytest.approx((START[0] + 1.0, START[1] - 2.0, START[2] + 0.5), abs=1e-3)
        assert rotation_deg(START[3:], rist[3:]) == pytest.approx(1.0, abs=1e-3)
        # silence from here: Delay counts the late answers, and RSI stops after max_late of them
        seen = []
        with pytest.raises(TimeoutError):
            while True:
                seen.append(sensor.receive()[2])
        # the datagram that showed the correction went unanswered: late 1; then D counts up each cycle, and
        # the 5th late answer in a row stopped RSI before its datagram went out. D counts every answer not
        # taken: also a cycle the emulator, descheduled on a busy machine, sent too late to judge (unjudged,
        # not a late answer of the sensor's) or skipped (a late answer: D may then skip a value).
        s = emulator.stats
        assert seen and all(b > a for a, b in zip(seen, seen[1:])) and emulator.stopped
        assert seen[-1] == s["late"] - 1 + s["unjudged"], (seen, s)
    finally:
        emulator.stop_thread()
        sensor.sock.close()
    record = emulator.record()
    assert record["answered"] >= 1 and record["late_in_a_row_max"] == 5 and record["stopped"]
    answered, late_before = record["answered"], record["late"] - 5  # a busy machine may make one late
    assert emulator.account() == (
        f"{record['cycles']} cycles: {answered} answered in time, {late_before} late, then 5 unanswered at the "
        f"end; {record['unjudged']} sent too late by this emulator to judge"
    )
    assert record["max_step_mm"] == pytest.approx(math.dist((0, 0, 0), (1.0, -2.0, 0.5)), abs=1e-9)


def test_an_answer_that_came_in_time_is_on_time_though_the_emulator_woke_after_its_cycle():
    """The kernel's arrival time judges an answer: a controller thread woken late (a busy machine) finds
    the answer waiting and counts it answered; an answer that itself came after the cycle is late; a
    cycle the emulator sent too late for the sensor to answer in is not the sensor's late answer."""
    sensor = RawSensor()
    cycle = 0.05  # long enough that the sensor here answers within it on a busy machine
    emulator = RsiControllerEmulator(port=sensor.port, cycle=cycle, max_late=5, start=START)
    real_receive = emulator._receive
    answer_after: list[float | None] = [0.0]  # how long the sensor takes to answer, this cycle (None: never)
    waited: set[int] = set()
    sent_delays: list[int] = []

    def answer_then_wake_late(deadline):
        if emulator.stats["cycles"] not in waited:
            waited.add(emulator.stats["cycles"])
            ipoc, _rist, delay, addr = sensor.receive()
            sent_delays.append(delay)
            if answer_after[0] is not None:
                time.sleep(answer_after[0])
                sensor.answer(ipoc, (0.5, 0.0, 0.0, 0.0, 0.0, 0.0), addr)
            time.sleep(max(0.0, deadline - time.monotonic()) + 2 * cycle)  # the thread wakes after its cycle
        return real_receive(deadline)

    emulator._receive = answer_then_wake_late
    try:
        emulator.cycle_once(time.monotonic())
        assert emulator.stats["answered"] == 1 and emulator.stats["late"] == 0
        answer_after[0] = 2 * cycle  # now the answer itself comes after the cycle
        emulator.cycle_once(time.monotonic())
        assert emulator.stats["answered"] == 1 and emulator.stats["late"] == 1
        assert emulator.stats["stray_answers"] == 1
        answer_after[0] = None  # no answer, to a datagram the emulator sent 0.8 cycle into its slot
        emulator.cycle_once(time.monotonic() - 0.8 * cycle)
        assert emulator.stats["late"] == 1 and emulator.stats["unjudged"] == 1
        # a controller counts every answer it did not take in Delay: the sensor then steps from what it has
        answer_after[0] = 0.0
        emulator.cycle_once(time.monotonic())
        assert sent_delays == [0, 0, 1, 2]
    finally:
        emulator.sock.close()
        sensor.sock.close()
    assert emulator.latencies.count == 3 and emulator.latencies.min < cycle < emulator.latencies.max  # one came late


def test_the_emulator_servo_follows_after_its_delay_with_a_first_order_lag():
    servo = RsiServo(START, delay=0.012, tau=0.02)
    servo.correct((4.0, 0, 0, 0, 0, 0), 0.0)
    xs = []
    for k in range(60):
        servo.advance(k * CYCLE)
        xs.append(servo.position[0] - START[0])
    assert xs[3] == 0.0  # nothing before the delay
    for k in (10, 30, 59):  # the target arrived at 12 ms and is followed from the next cycle on
        assert xs[k] == pytest.approx(4.0 * (1 - math.exp(-(k - 3) * CYCLE / 0.02)), rel=1e-9)


def test_the_emulator_faults_lose_duplicate_and_reorder_datagrams_from_a_seed():
    counts = []
    for _ in range(2):
        sensor = RawSensor()
        emulator = RsiControllerEmulator(port=sensor.port, cycle=CYCLE, loss=20, duplicate=20, reorder=20, seed=5)
        ipocs = []
        sensor.sock.settimeout(0.0)
        for _ in range(200):  # a cycle at a time, no waiting: the faults, not the timing, are under test
            emulator.cycle_once(time.monotonic() - CYCLE)
            try:
                while True:
                    ipocs.append(sensor.receive()[0])
            except (BlockingIOError, TimeoutError):
                pass
        emulator.sock.close()
        sensor.sock.close()
        s = emulator.stats
        assert 0 < s["lost"] < 80 and 0 < s["duplicated"] and 0 < s["reordered"]
        assert len(ipocs) == 200 - s["lost"] + s["duplicated"] - (1 if emulator._held_back else 0)
        assert any(b < a for a, b in zip(ipocs, ipocs[1:])) and len(set(ipocs)) < len(ipocs)
        counts.append((s["lost"], s["duplicated"], s["reordered"], ipocs))
    assert counts[0] == counts[1]  # the same seed, the same faults


# -- the answering path, on a clock the test controls ----------------------------------------------


def link(clock, max_speed=0.1, max_angular_speed=0.5, stale_after=0.2) -> RsiLink:
    return RsiLink(None, "127.0.0.1", CYCLE, max_speed, max_angular_speed, stale_after, "ImFree", clock)


def test_each_answer_echoes_the_ipoc_and_moves_the_correction_at_most_the_limit_per_cycle():
    clock = ManualClock(10.0)
    lk = link(clock)
    frame = SceneFrame((0.0, 0.0, 0.0), START)
    lk.submit(*frame.correction((0.05, -0.02, 0.01), rsi.abc_to_quat(0.0, 0.0, 30.0)))  # far: 55 mm, 30 deg
    korrs = []
    for k in range(400):
        clock.advance(CYCLE)
        if k % 50 == 0:  # the graph keeps handing the same setpoint over: never stale
            lk.submit(*lk.target[1:])
        answer = lk.handle(rob_text(1000 + 4 * k), "127.0.0.1", clock())
        _, ipoc, korr = read_sen(answer)
        assert ipoc == 1000 + 4 * k
        korrs.append(korr)
    steps = [math.dist(a[:3], b[:3]) for a, b in zip([(0,) * 6] + korrs, korrs)]
    turns = [rotation_deg(a[3:], b[3:]) for a, b in zip([(0,) * 6] + korrs, korrs)]
    assert max(steps) <= 0.1 * CYCLE * 1000 + 1e-3  # mm (the answer's 4 decimals)
    assert max(turns) <= math.degrees(0.5 * CYCLE) + 1e-3
    assert korrs[-1][:3] == pytest.approx((50.0, -20.0, 10.0), abs=1e-4)  # reached in the end
    assert rotation_deg((0, 0, 0), korrs[-1][3:]) == pytest.approx(30.0, abs=1e-3)


def test_an_answer_the_controller_did_not_take_is_not_stepped_from():
    """A controller that skips an answer (it came late, or the controller was late itself) keeps the
    correction it had and counts the answer in Delay; the next answer is within one step of the correction
    in force and of the answer it skipped (which a controller may still take), so the robot never moves
    more than the limit in a cycle. Where Delay rose with a datagram that never came, which of the two the
    controller counted is not known: the next answer is within a step of either."""
    clock = ManualClock()
    lk = link(clock)
    lk.submit((20.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    in_force, taken = 0.0, []
    exchanges = [  # (IPOC, Delay, taken by the controller)
        (4, 0, True),
        (8, 0, True),
        (12, 0, False),
        (16, 1, False),
        (20, 2, True),
        (24, 2, True),
        (32, 3, True),  # 28 never came: counted late (or skipped, and the answer to 24 came late)
        (36, 3, True),  # Delay unchanged: the answer to 32 was taken
    ]
    for ipoc, delay, took in exchanges:
        clock.advance(CYCLE)
        x = read_sen(lk.handle(rob_text(ipoc, delay=delay), "127.0.0.1", clock()))[2][0]
        assert abs(x - in_force) <= 0.4 + 1e-4  # one cycle's travel at most, from what the robot has
        if took:
            in_force = x
        taken.append(round(x, 4))
    assert taken == [0.4, 0.8, 1.2, 1.2, 1.2, 1.6, 1.6, 2.0]


def test_a_stalled_graph_holds_the_correction_where_it_is():
    clock = ManualClock()
    lk = link(clock, stale_after=0.098)
    lk.submit((20.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    xs = []
    for k in range(100):
        clock.advance(CYCLE)
        xs.append(read_sen(lk.handle(rob_text(k + 1), "127.0.0.1", clock()))[2][0])
    # moved 0.4 mm a cycle for 0.096 s (24 cycles), then held: the setpoint is older than the timeout
    assert xs[22] == pytest.approx(9.2, abs=1e-4) and xs[23] == pytest.approx(9.6, abs=1e-4)
    assert set(xs[24:]) == {xs[23]}
    assert lk.stale_holds == 76 and any("holding" in n for n in lk.take_notes())


def test_bunched_graph_steps_still_move_one_bounded_step_per_datagram():
    clock = ManualClock()
    lk = link(clock)
    for i in range(40):  # forty steps handed over at one instant (a late graph catching up)
        lk.submit((0.1 * i, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    clock.advance(CYCLE)
    _, _, korr = read_sen(lk.handle(rob_text(1), "127.0.0.1", clock()))
    assert korr[0] == pytest.approx(0.4, abs=1e-4)  # toward the latest (3.9 mm), one step of 0.4 mm


def test_foreign_malformed_repeated_and_oversized_datagrams_are_counted_and_never_move_the_robot():
    clock = ManualClock()
    lk = link(clock)
    lk.submit((10.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    first = read_sen(lk.handle(rob_text(100), "127.0.0.1", clock()))[2]
    bad = [
        (rob_text(104), "10.0.0.7"),  # another sender
        (b'<Rob Type="KUKA"><RIst X="1" Y="2"', "127.0.0.1"),
        (rob_text(100), "127.0.0.1"),  # the same IPOC again
        (rob_text(96), "127.0.0.1"),  # an older one
        (rob_text(108, extra=" " * rsi.MAX_DATAGRAM), "127.0.0.1"),
    ]
    for data, host in bad:
        assert lk.handle(data, host, clock()) is None
    assert lk.counted == {"foreign": 1, "malformed": 1, "repeated": 2, "oversized": 1}
    assert lk.korr[0] == (0.4, 0.0, 0.0)  # the correction moved only for the valid datagram
    notes = lk.take_notes()
    assert len(notes) == 4 and all(n.startswith("warning: datagram ") for n in notes)
    assert read_sen(lk.handle(rob_text(104), "127.0.0.1", clock()))[2][0] == pytest.approx(first[0] + 0.4)


def test_a_hold_or_a_non_finite_setpoint_keeps_the_last_correction():
    clock = ManualClock()
    lk = link(clock)
    lk.submit((10.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    for k in range(3):
        lk.handle(rob_text(k + 1), "127.0.0.1", clock())
    assert lk.korr[0][0] == pytest.approx(1.2)
    lk.submit((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert read_sen(lk.handle(rob_text(10), "127.0.0.1", clock()))[2][0] == pytest.approx(1.2)
    lk.submit((10.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    lk.hold_latched = True
    assert read_sen(lk.handle(rob_text(11), "127.0.0.1", clock()))[2][0] == pytest.approx(1.2)
    lk.hold_latched = False
    lk.submit(None, None)  # no fresh F/T data, or enable off: hold
    assert read_sen(lk.handle(rob_text(12), "127.0.0.1", clock()))[2][0] == pytest.approx(1.2)


def test_the_scene_frame_maps_the_docking_axis_and_rist_both_ways():
    # The scene's +x (docking axis) along BASE -Y: A = -90.
    frame = SceneFrame((-90.0, 0.0, 0.0), START)
    turn = Rotation.from_rotvec((0.1, 0.0, 0.0))  # 0.1 rad about the docking axis
    p, q = frame.correction((0.01, 0.0, 0.002), tuple(turn.as_quat()))
    assert p == pytest.approx((0.0, -10.0, 2.0), abs=1e-9)
    assert Rotation.from_quat(q).as_rotvec() == pytest.approx((0.0, -0.1, 0.0), abs=1e-12)
    # the robot at start + that correction reads back as that scene pose
    moved_abc = (Rotation.from_quat(q) * Rotation.from_euler("ZYX", START[3:], degrees=True)).as_euler(
        "ZYX", degrees=True
    )
    rist = (START[0] + p[0], START[1] + p[1], START[2] + p[2], *moved_abc)
    position, orientation = frame.scene_pose(rist)
    assert position == pytest.approx((0.01, 0.0, 0.002), abs=1e-12)
    assert Rotation.from_quat(orientation).as_rotvec() == pytest.approx((0.1, 0.0, 0.0), abs=1e-9)
    # Anchored at a scene pose (the first command): the correction is the change from it, and RIst reads
    # back as that pose plus the robot's change.
    start = Rotation.from_rotvec((0.0, 0.0, 0.02))
    frame.anchor((-0.01, 0.05, 0.0), tuple(start.as_quat()))
    assert frame.correction((-0.01, 0.05, 0.0), tuple(start.as_quat()))[0] == pytest.approx((0, 0, 0), abs=1e-12)
    p2, q2 = frame.correction((0.0, 0.05, 0.002), tuple((turn * start).as_quat()))
    assert p2 == pytest.approx(p, abs=1e-9) and Rotation.from_quat(q2).as_rotvec() == pytest.approx((0, -0.1, 0))
    position, orientation = frame.scene_pose(rist)
    assert position == pytest.approx((0.0, 0.05, 0.002), abs=1e-12)
    assert (Rotation.from_quat(orientation) * (turn * start).inv()).magnitude() < 1e-9


# -- the driver node against an independent fake controller ----------------------------------------


class FakeController:
    """A controller written here: hand-written <Rob> datagrams from 127.0.0.1, answers read by ET."""

    def __init__(self, port: int, bind: str = "127.0.0.1"):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((bind, 0))
        self.sock.settimeout(2.0)
        self.port = port
        self.ipoc = 5000

    def exchange(self, rist=START, data: bytes | None = None):
        self.ipoc += 4
        self.sock.sendto(data or rob_text(self.ipoc, rist), ("127.0.0.1", self.port))
        return read_sen(self.sock.recvfrom(8192)[0])

    def send_only(self, data: bytes) -> None:
        self.sock.sendto(data, ("127.0.0.1", self.port))

    def until_answered(self, ready: threading.Event) -> None:
        """Cycle until the driver has set up (its setup waits for our first datagram)."""
        self.sock.settimeout(0.05)
        while not ready.is_set():
            try:
                self.exchange()
            except TimeoutError:
                pass
        self.sock.settimeout(2.0)


def ft(k: int, fx: float = 0.0):
    """A fresh F/T sample (the driver tells samples apart by their headers)."""
    w = wrench(fx)
    return type(w)(header=Header(k * 0.001, k, k, ""), wrench=w.wrench)


def command(k: int, x: float, v: float = 0.0) -> RobotCommand:
    return RobotCommand(header=Header(k * 0.001, k, k, "target"), pose=Pose(Vector3(x)), twist=Twist(Vector3(v)))


@pytest.fixture
def driven():
    """A driver on a free port, set up against FakeController on a ManualClock; both closed after."""
    made = []

    def make(**params):
        port = udp_port()
        clock = ManualClock(100.0)
        logs: list[str] = []
        node = RobotRsiDriver(
            NodeContext("robot", 0.001, sim_time=False, log=logs.append, clock=clock),
            port=port,
            host="127.0.0.1",
            **params,
        )
        controller = FakeController(port)
        ready = threading.Event()
        feeder = threading.Thread(target=controller.until_answered, args=(ready,), daemon=True)
        feeder.start()
        try:
            node.setup()
        finally:
            ready.set()
            feeder.join()
        made.append((node, controller))
        return node, controller, clock, logs

    yield make
    for node, controller in made:
        node.close()
        controller.sock.close()


def test_the_driver_answers_a_fake_controller_and_publishes_the_pose_in_the_scene_frame(driven):
    node, ctl, clock, logs = driven(ft_timeout=0)
    assert any("RSI running" in line for line in logs)
    for k in range(30):
        clock.advance(0.001)
        node.step(Tick(k, k * 0.001, 0.001), {"command": command(k, 0.00005 * k), "wrench": wrench()})
        if k % 4 == 3:
            sen_type, ipoc, korr = ctl.exchange((START[0] + 0.5, *START[1:]))
            assert sen_type == "ImFree" and ipoc == ctl.ipoc
            assert korr[0] == pytest.approx(0.05 * k, abs=1e-4) and korr[1:] == (0.0,) * 5
    ctl.exchange((START[0] + 0.5, *START[1:]))  # the link stores a datagram before it answers it
    state = node.step(Tick(30, 0.03, 0.001), {"command": command(30, 0.0015), "wrench": wrench()})["state"]
    assert state.pose.position.x == pytest.approx(0.0005, abs=1e-9)  # RIst 0.5 mm along BASE X = scene x
    assert state.pose.orientation.w == pytest.approx(1.0)
    # a datagram from another address on this host: counted, never answered
    stranger = FakeController(ctl.port, bind="127.0.0.2")
    stranger.sock.settimeout(0.2)
    with pytest.raises(TimeoutError):
        stranger.exchange()
    stranger.sock.close()
    _, _, before = ctl.exchange()
    ctl.send_only(rob_text(1))  # an old IPOC
    ctl.send_only(b"<Rob><oops")
    _, _, after = ctl.exchange()
    assert after[0] - before[0] <= 0.4 + 1e-4  # one cycle's step, nothing more
    time.sleep(0.05)
    node.step(Tick(31, 0.031, 0.001), {"command": command(31, 0.00155), "wrench": wrench()})
    warnings = [line for line in logs if line.startswith("warning: datagram")]
    assert len(warnings) == 3 and all("\n" not in w for w in warnings)


def test_the_driver_holds_on_a_safety_stop_and_at_close(driven):
    node, ctl, clock, logs = driven(max_force=50.0)
    for k in range(8):
        clock.advance(0.001)
        node.step(Tick(k, k * 0.001, 0.001), {"command": command(k, 0.00005 * k), "wrench": ft(k)})
        if k % 4 == 3:
            ctl.exchange()
    held = ctl.exchange()[2]
    # the force limit trips: the driver holds (the controller's next answers carry the same correction)
    cycling = threading.Event()
    cycling.set()

    def controller():  # keeps its cycle while the driver trips
        while cycling.is_set():
            ctl.exchange()
            time.sleep(0.002)

    feeder = threading.Thread(target=controller, daemon=True)
    feeder.start()
    try:
        with pytest.raises(SafetyStop) as err:
            clock.advance(0.001)
            node.step(Tick(8, 0.008, 0.001), {"command": command(8, 0.0004), "wrench": ft(8, fx=80.0)})
    finally:
        cycling.clear()
        feeder.join()
    assert "max_force" in str(err.value) and "robot held" in str(err.value) and "\n" not in str(err.value)
    assert {ctl.exchange()[2] for _ in range(5)} == {held}


def test_a_command_that_runs_ahead_of_the_correction_faster_than_the_limit_stops(driven):
    node, ctl, clock, logs = driven(ft_timeout=0, max_following_error=0.0)
    # 1 mm a tick (1 m/s), its twist claiming less: the correction follows at 0.4 mm a cycle, the command
    # pulls away and is stopped once it is more than stall_timeout's travel (0.02 m) ahead (with the
    # following error on, that stops it first: the fake robot here does not move).
    with pytest.raises(SafetyStop) as err:
        for k in range(200):
            clock.advance(0.001)
            node.step(Tick(k, k * 0.001, 0.001), {"command": command(k, 0.001 * k, 0.05), "wrench": wrench()})
            if k % 4 == 3:
                ctl.exchange()
    text = str(err.value)
    assert "max_speed: the command ran 0.02" in text and "ahead of the correction sent" in text, text
    assert 20 <= k <= 40 and "\n" not in text
    # held from here: the controller's answers carry the last correction
    assert len({ctl.exchange()[2] for _ in range(3)}) == 1


def test_a_controller_that_stops_sending_stops_the_graph_in_one_line(driven):
    node, ctl, clock, logs = driven(ft_timeout=0, controller_timeout=0.05)
    node.step(Tick(0, 0.0, 0.001), {"command": command(0, 0.0), "wrench": wrench()})
    clock.advance(0.06)
    with pytest.raises(DeviceError) as err:
        node.step(Tick(1, 0.06, 0.001), {"command": command(1, 0.0), "wrench": wrench()})
    text = str(err.value)
    assert "no datagram for 0.06" in text and "stopped RSI" in text and "\n" not in text


def test_setup_without_a_controller_fails_in_one_line_and_refuses_sim_time():
    port = udp_port()
    node = RobotRsiDriver(
        NodeContext("robot", 0.001, sim_time=False, log=lambda line: None), port=port, connect_timeout=0.1
    )
    with pytest.raises(DeviceError) as err:
        node.setup()
    assert "no RSI datagram from 127.0.0.1 within 0.1 s" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(LaunchError, match="wall time"):
        RobotRsiDriver(NodeContext("robot", 0.001, sim_time=True)).setup()
    # the port is free again after the failed setup: a second try binds it
    with pytest.raises(DeviceError, match="no RSI datagram"):
        node.setup()


def test_a_second_graph_naming_the_same_rsi_port_is_refused_naming_the_owner(driven):
    node, ctl, clock, logs = driven(ft_timeout=0)
    ownership.set_graph("graph-two")
    try:
        other = RobotRsiDriver(
            NodeContext("robot", 0.001, sim_time=False, log=lambda line: None), port=node.p.port, connect_timeout=0.1
        )
        with pytest.raises(DeviceError) as err:
            other.setup()
    finally:
        ownership.set_graph("")
    text = str(err.value)
    assert text.startswith(f"KUKA RSI port {node.p.port} is in use by process pid {os.getpid()}"), text
    assert "\n" not in text


# -- the driver against the emulator -------------------------------------------------------------------


def test_the_driver_against_the_emulator_tracks_the_command_within_the_per_cycle_limit(tmp_path):
    port = udp_port()
    # The emulator is a thread of this process here: a loaded machine may stall it, or the driver, for a
    # while; it does not stop RSI for that, and the driver waits for it.
    emulator = RsiControllerEmulator(port=port, cycle=CYCLE, delay=0.008, tau=0.01, max_late=10**9)
    emulator.start_thread()
    logs: list[str] = []
    node = RobotRsiDriver(
        NodeContext("robot", 0.001, sim_time=False, log=logs.append),
        port=port,
        ft_timeout=0,
        max_speed=0.05,
        controller_timeout=2.0,
        stall_timeout=1.0,
    )
    try:
        node.setup()
        last, bunch = None, 0
        for k in range(900):
            x = 0.02 * min(k * 0.001, 0.5)  # 20 mm/s for 0.5 s of the scene's time, then still
            out = node.step(
                Tick(k, k * 0.001, 0.001), {"command": command(k, x, 0.02 if x < 0.01 else 0.0), "wrench": wrench()}
            )
            last = out.get("state", last)
            if k == 300:  # the graph stalls for 60 ms, then catches up: sixty ticks at once
                time.sleep(0.06)
                bunch = 60
            if bunch:
                bunch -= 1
            else:
                time.sleep(0.001)
    finally:
        node.close()
        emulator.stop_thread()
    record = emulator.record()
    assert record["answered"] > 50 and not record["stopped"]
    assert record["max_step_mm"] <= 0.05 * CYCLE * 1000 + 1e-3
    assert last.pose.position.x == pytest.approx(0.01, abs=5e-4)  # 10 mm, tracked through delay and lag


def test_an_emulator_whose_driver_reads_another_controller_is_refused_in_one_line():
    from dockhil.devices.kuka_rsi.emulator_node import RsiControllerEmulatorNode

    node = RsiControllerEmulatorNode(
        NodeContext("rsi_emulator", 0.001, sim_time=False), port=udp_port(), controller="192.0.2.7"
    )
    with pytest.raises(LaunchError) as err:
        node.setup()
    text = str(err.value)
    assert "reads the controller at 192.0.2.7" in text and "would move a real robot" in text and "\n" not in text


@pytest.mark.wall_time
def test_launch_hil_with_the_rsi_driver_and_its_emulator_is_valid(tmp_path):
    """As a lab runs it on a busy machine (--realtime, which says so in one line where it is refused). A
    run the machine stopped (a node behind real time, or an input stale for 0.1 s) is tried once more."""
    for _attempt in range(2):
        proc = subprocess.run(
            dockhil_cmd(
                "launch",
                ROOT / "launch" / "hil.yaml",
                "robot:=rsi",
                "emulators:=true",
                f"rsi_port:={udp_port()}",
                "--wall-time",
                "--realtime",
                "--duration",
                "5",
                "--quiet",
            ),
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
        )
        text = proc.stdout + proc.stderr
        behind = proc.returncode == 3 and "fell behind real time" in text
        stale = proc.returncode == 1 and "s old > max_age" in text
        if not (behind or stale):
            break
    # Valid, or stopped only because a loaded machine kept a node from keeping real time.
    assert proc.returncode == 0 or behind or stale, text[-3000:]
    assert "RSI running" in text and "Traceback" not in text, text[-3000:]
    assert not [line for line in text.splitlines() if line.startswith(("[robot] error", "[rsi_emulator] error"))]


def test_the_emulator_runs_alone_and_refuses_an_unphysical_fault_in_one_line(tmp_path):
    run = lambda *a: subprocess.run(  # noqa: E731
        [sys.executable, "-m", "dockhil.devices.kuka_rsi.emulator", *a],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert run("--help").returncode == 0
    bad = run("--loss", "150")
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "--loss 150" in bad.stderr
    sensor = RawSensor()
    record = tmp_path / "record.json"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dockhil.devices.kuka_rsi.emulator",
            "--port",
            str(sensor.port),
            "--duration",
            "5",
            "--max-late",
            "10",
            "--record",
            str(record),
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        ipoc, rist, delay, addr = sensor.receive()  # the emulator has started
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.3:  # answer for a while (some in time, whatever the machine's load)
            sensor.answer(ipoc, (0.5, 0, 0, 0, 0, 0), addr)
            try:
                ipoc, rist, delay, addr = sensor.receive()
            except TimeoutError:  # so loaded that ten answers in a row came late: RSI stopped already
                break
        assert proc.wait(timeout=30) == 1  # then silence: RSI stopped after ten late answers in a row
    finally:
        proc.kill()
        sensor.sock.close()
    assert proc.stderr.read().strip() == "rsi emulator: error: RSI stopped: 10 late answers in a row"
    done = json.loads(record.read_text())
    assert done["answered"] >= 1 and done["late_in_a_row_max"] == 10 and done["stopped"]
    assert done["max_step_mm"] == 0.5  # the one correction, applied once
