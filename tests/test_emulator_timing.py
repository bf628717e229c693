"""The emulated controllers' two timings: `ours` takes a correction the cycle after it arrives and acts on
whole cycles, the pose read after the servo's step; `immediate` takes it as it arrives, follows it `delay`
later in continuous time (a delay that is not whole cycles), the pose sampled at its cycle. On the test's
clock, then over UDP against a sensor written here."""

from __future__ import annotations

import math
import threading
import time

import pytest

from dockhil.devices.kuka_rsi.emulator import RsiControllerEmulator, RsiServo
from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.emulator import FOLLOW, ServoModel
from tests.test_hardware_rsi import RawSensor

DELAY = 0.0103  # s: not a whole number of cycles
RSI_CYCLE = 0.004


def rsi_poses(timing: str, tau: float, cycles: int = 12) -> list[float]:
    """x [mm] of the datagrams of cycles 0.. of a controller whose cycle 0 is answered with a 1 mm correction
    1.5 ms after its datagram: `ours` takes it at cycle 1, `immediate` at 1.5 ms."""
    servo = RsiServo((0.0,) * 6, delay=DELAY, tau=tau, timing=timing)
    xs = []
    for k in range(cycles):
        servo.advance(k * RSI_CYCLE)
        xs.append(servo.position[0])
        if k == 0:
            servo.correct((1.0, 0, 0, 0, 0, 0), 0.0015 if timing == "immediate" else RSI_CYCLE)
    return xs


def test_rsi_ours_acts_on_whole_cycles_after_the_next_cycle_and_shows_the_step_a_cycle_later():
    xs = rsi_poses("ours", 0.0)
    # taken at 4 ms, due at 14.3 ms: the target of the cycle at 16 ms, the pose moved by the one at 20 ms
    assert xs[:5] == [0.0] * 5 and xs[5] == 1.0


def test_rsi_immediate_follows_the_correction_its_delay_after_it_arrived_in_continuous_time():
    xs = rsi_poses("immediate", 0.0)
    # arrived at 1.5 ms, due at 11.8 ms: the datagram of the cycle at 12 ms carries it
    assert xs[:3] == [0.0] * 3 and xs[3] == 1.0
    tau = 0.005
    xs = rsi_poses("immediate", tau)
    for k in (3, 6, 11):
        assert xs[k] == pytest.approx(1.0 - math.exp(-(k * RSI_CYCLE - 0.0015 - DELAY) / tau), rel=1e-9)


def test_an_unknown_timing_is_refused():
    with pytest.raises(ValueError, match="timing 'later'"):
        RsiServo(timing="later")
    with pytest.raises(ValueError, match="timing 'later'"):
        ServoModel(timing="later")


def modbus_poses(timing: str, tau: float, cycles: int = 20) -> list[float]:
    """x [m] a read returns after each 1 ms cycle of a controller following 0 from cycle 0, written a 4 mm
    setpoint at 0.5 ms."""
    model = ServoModel(delay=DELAY, tau=tau, heartbeat_timeout=1.0, timing=timing)
    assert model.host_wrote(mm.HR_SESSION, mm.encode_owner(1, "test"))
    at_zero = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0) + (0.0,) * 6
    assert model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, 1, at_zero), now=0.0)
    xs = []
    for k in range(cycles):
        model.cycle(k * 0.001)
        assert model.mode == FOLLOW
        xs.append(mm.decode_inputs(model.inputs).actual[0])
        if k == 0:
            setpoint = (0.004, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0) + (0.0,) * 6
            assert model.host_wrote(0, mm.encode_write(mm.CONTROL_ENABLE, 2, setpoint), now=0.0005)
    return xs


def test_modbus_the_two_timings_differ_by_where_the_cycles_are_spent():
    ours = modbus_poses("ours", 0.0)
    # taken by the cycle at 1 ms, the target at the cycle at 12 ms (11.3 ms later), moved at 13 ms
    assert ours[12] == 0.0 and ours[13] == pytest.approx(0.004, abs=1e-6)
    now = modbus_poses("immediate", 0.0)
    # written at 0.5 ms, due at 10.8 ms: the read after the cycle at 11 ms has it
    assert now[10] == 0.0 and now[11] == pytest.approx(0.004, abs=1e-6)
    tau = 0.004
    now = modbus_poses("immediate", tau)
    for k in (11, 15, 19):
        assert now[k] == pytest.approx(0.004 * (1.0 - math.exp(-(k * 0.001 - 0.0005 - DELAY) / tau)), abs=1e-6)


@pytest.mark.parametrize("timing, first", [("ours", 2), ("immediate", 1)])
def test_rsi_over_udp_immediate_shows_a_correction_one_cycle_sooner(timing, first):
    """A sensor answering every datagram at once with a 1 mm correction (the emulator without delay or lag):
    `ours` shows it in the datagram two cycles after the first answered, `immediate` in the next one."""
    sensor = RawSensor()
    cycle = 0.05  # long enough that the sensor here answers within it on a busy machine
    emulator = RsiControllerEmulator(port=sensor.port, cycle=cycle, start=(0.0,) * 6, timing=timing)
    seen: list[float] = []

    def answer():
        for _ in range(4):
            ipoc, rist, _delay, addr = sensor.receive()
            seen.append(rist[0])
            sensor.answer(ipoc, (1.0, 0.0, 0.0, 0.0, 0.0, 0.0), addr)

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        t0 = time.monotonic()
        for k in range(4):
            emulator.cycle_once(t0 + k * cycle)
        thread.join(timeout=5.0)
    finally:
        emulator.sock.close()
        sensor.sock.close()
    assert emulator.stats["answered"] == 4
    assert seen == pytest.approx([0.0] * first + [1.0] * (4 - first), abs=1e-3)
