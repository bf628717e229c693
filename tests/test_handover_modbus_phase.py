"""The Modbus link places its writes between two of the controller's cycles (ControllerPhase), known from
the cycle count it reads back: on a clock the test gives."""

from __future__ import annotations

import random

import pytest

from dockhil.devices.modbus_robot.link import ControllerPhase

PERIOD = 0.001
START = 12.0003  # s: the controller's cycle 0


def reads(phase: ControllerPhase, n: int, late: float, seed: int = 0, first: int = 65_000) -> None:
    """n reads, one every 2 ms of the host's clock, each `late` at most after the cycle it reports."""
    rng = random.Random(seed)
    for i in range(n):
        at = START + 2 * i * PERIOD + rng.uniform(0.0, late)
        k = int((at - START) / PERIOD)  # the last cycle that ran before the read
        phase.read(at, (first + k) & 0xFFFF)


def test_a_write_is_placed_in_the_middle_between_two_controller_cycles_whatever_the_reads_lateness():
    phase = ControllerPhase()
    reads(phase, 300, late=0.0009, seed=1)  # reads up to 0.9 ms after their cycle; the count wraps at 65536
    for t in (12.6001, 12.60049, 12.6009):
        got = phase.mid(t)
        assert ((got - START) / PERIOD) % 1.0 == pytest.approx(0.5, abs=0.05)
        assert abs(got - t) <= PERIOD / 2 + 1e-9


def test_before_enough_reads_or_on_a_count_that_is_no_cycle_a_write_keeps_its_time():
    phase = ControllerPhase()
    reads(phase, ControllerPhase.LEAST - 1, late=0.0002)
    assert phase.mid(12.5) == 12.5
    phase.clear()
    for i in range(ControllerPhase.LEAST):  # a count that moves once a second: no controller's cycle
        phase.read(START + i, i)
    assert phase.mid(40.0) == 40.0
