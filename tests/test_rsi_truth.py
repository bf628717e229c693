"""The controller's record is the truth: the RSI link answers each datagram within one cycle's travel of
every correction the controller may hold, as the controller reports it (RSol where it sends one, Delay and
the IPOC sequence otherwise), so whatever is skipped, lost, late or taken late, two corrections the
controller takes in consecutive cycles differ by at most max_speed x cycle. A controller is played here, on
a clock the test controls: it skips slots (no datagram, not counted), loses datagrams (counted late),
gets answers late (counted; dropped, or taken in the cycle they arrive), and holds what it took."""

from __future__ import annotations

import math
import random
import socket

import pytest

from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.kuka_rsi.link import RsiLink, open_socket
from dockhil.devices.limits import angle_between
from dockhil.node import ManualClock
from tests.test_hardware_rsi import START, read_sen, rob_text

CYCLE = 0.004
MAX_SPEED, MAX_ANGULAR_SPEED = 0.1, 0.5
STEP_MM, STEP_RAD = MAX_SPEED * CYCLE * 1000.0, MAX_ANGULAR_SPEED * CYCLE


class PlayedController:
    """A KUKA controller's RSI cycle, played: what it holds at each interpolation cycle is `trace`."""

    def __init__(self, lk: RsiLink, clock: ManualClock, rsol: bool, late_take: bool):
        self.lk, self.clock, self.rsol, self.late_take = lk, clock, rsol, late_take
        self.held = (0.0,) * 6  # the correction in force: X Y Z mm, A B C degrees
        self.delay, self.ipoc = 0, 1000
        self.late: tuple | None = None  # an answer that came after its cycle: it arrives in the next one
        self.trace = [self.held]

    def cycle(self, fault: str | None = None) -> None:
        self.clock.advance(CYCLE)
        self.ipoc += 4
        arriving, self.late = self.late, None
        if fault == "skip":  # the controller skipped the slot: no datagram, nothing counted
            self._take_late(arriving)
            return self._interpolate()
        commanded = tuple(s + k for s, k in zip(START, self.held)) if self.rsol else None
        data = rob_text(self.ipoc, delay=self.delay, rsol=commanded)
        if fault == "lose":  # the datagram never reached the sensor: no answer, counted late
            self.delay += 1
            self._take_late(arriving)
            return self._interpolate()
        answer = self.lk.handle(data, "127.0.0.1", self.clock())
        assert answer is not None
        _, ipoc, korr = read_sen(answer)
        assert ipoc == self.ipoc
        self._take_late(arriving)
        if fault == "late":  # counted late; taken where it arrives, if this controller does that
            self.delay += 1
            self.late = korr
        else:
            self.held = korr
        self._interpolate()

    def _take_late(self, arriving) -> None:
        if arriving is not None and self.late_take:
            self.held = arriving

    def _interpolate(self) -> None:
        self.trace.append(self.held)

    def steps(self) -> tuple[float, float]:
        """The largest step (mm, rad) between the corrections of consecutive cycles."""
        mm = rad = 0.0
        for a, b in zip(self.trace, self.trace[1:]):
            mm = max(mm, math.dist(a[:3], b[:3]))
            rad = max(rad, angle_between(rsi.abc_to_quat(*a[3:]), rsi.abc_to_quat(*b[3:])))
        return mm, rad


def link(clock: ManualClock) -> RsiLink:
    return RsiLink(None, "127.0.0.1", CYCLE, MAX_SPEED, MAX_ANGULAR_SPEED, 10.0, "ImFree", clock)


@pytest.mark.parametrize("rsol", [False, True])
def test_a_skipped_slot_with_a_late_answer_is_no_double_step(rsol):
    """The controller skips a slot in the cycle our answer comes late: Delay rises by one and the IPOC gap
    is one, as when a datagram is lost and our answer was taken. The controller kept the correction it had:
    the next answer is one step from it (the driver that took the late answer as taken stepped two)."""
    clock = ManualClock()
    lk = link(clock)
    ctl = PlayedController(lk, clock, rsol=rsol, late_take=False)
    lk.submit((20.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    for fault in (None, None, "late", "skip", None, None, None):
        ctl.cycle(fault)
    xs = [round(h[0], 4) for h in ctl.trace]
    assert max(b - a for a, b in zip(xs, xs[1:])) <= STEP_MM + 1e-9, xs
    assert xs[-1] >= 1.2  # and it goes on


@pytest.mark.parametrize("rsol", [False, True])
@pytest.mark.parametrize("late_take", [False, True])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_whatever_is_skipped_lost_or_late_the_controller_never_takes_more_than_a_step(rsol, late_take, seed):
    rng = random.Random(seed)
    clock = ManualClock(50.0)
    lk = link(clock)
    ctl = PlayedController(lk, clock, rsol=rsol, late_take=late_take)
    faults = (None,) * 7 + ("skip", "lose", "late")
    goal = None
    for k in range(3000):
        if k % 150 == 0:  # a new goal far off, turned about z: the link moves at the limit all the time
            goal = (rng.uniform(-60, 60), rng.uniform(-60, 60), rng.uniform(-20, 20)), rng.uniform(-40, 40)
        if k % 20 == 0:
            a = math.radians(goal[1])
            lk.submit(goal[0], (0.0, 0.0, math.sin(a / 2), math.cos(a / 2)))
        ctl.cycle(rng.choice(faults))
    mm, rad = ctl.steps()
    assert mm <= STEP_MM + 1e-9 and rad <= STEP_RAD + 1e-9, (mm, rad)
    travelled = sum(math.dist(a[:3], b[:3]) for a, b in zip(ctl.trace, ctl.trace[1:]))
    assert travelled > 0.3 * 3000 * STEP_MM  # it moves, at a good part of the limit despite 30 % faults


def test_a_datagram_from_another_port_of_the_controllers_address_never_moves_the_robot():
    clock = ManualClock(100.0)
    sock, controller = open_socket("127.0.0.1", "127.0.0.1", 0, "robot controller")
    lk = RsiLink(sock, controller, CYCLE, MAX_SPEED, MAX_ANGULAR_SPEED, 10.0, "ImFree", clock)
    port = sock.getsockname()[1]
    lk.submit((20.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    lk.start()
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ctl,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other,
    ):
        ctl.bind(("127.0.0.1", 0))
        other.bind(("127.0.0.1", 0))
        for s in (ctl, other):
            s.settimeout(0.3)
        try:
            ctl.sendto(rob_text(1000), ("127.0.0.1", port))
            assert read_sen(ctl.recv(4096))[2][0] == pytest.approx(0.4)
            clock.advance(CYCLE)
            other.sendto(rob_text(1004), ("127.0.0.1", port))  # the controller's address, another port
            with pytest.raises(TimeoutError):
                other.recv(4096)
            ctl.sendto(rob_text(1004), ("127.0.0.1", port))  # the controller's own 1004: answered, one step on
            assert read_sen(ctl.recv(4096))[2][0] == pytest.approx(0.8)
            assert lk.counted["foreign"] == 1 and lk.counted["repeated"] == 0
        finally:
            lk.stop()
