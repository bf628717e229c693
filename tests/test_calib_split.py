"""The loop's split into the robot's own delay and the link, where the data cannot make it: a controller that
does not echo the cycle that took a correction (RSI: its answer follows the pose) may take it as it arrives
and sample the pose before the servo's step, and then the device model, which places the take at the next
cycle, reads the robot's delay about a cycle and the link's wait short. Calibrate reports that delay as not
identified (with the range it lies in, which holds the true one), never as the model's number; where the
device echoes its takes (Modbus), the split stands."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from dockhil.analysis.calibration import loop as cal
from tests.test_calib_device import command, device_run
from tests.test_calibrate import Truth, simulate

CYCLE = 0.004  # s: RSI's


def rsi_immediate_run(delay: float, tau: float, seed: int = 0, length: float = 5.0):
    """An RSI-like controller on its 4 ms cycle (each up to 0.2 ms late): each cycle it sends the pose sampled
    at the cycle, before the servo's step; the driver reads it 0.2-0.6 ms later and answers 0.3-1 ms after
    with the latest command. The controller takes the correction as it arrives, and its servo follows it
    `delay` later in continuous time through a first-order lag `tau` (exact). Nothing echoes the take.
    Returns DeviceCycles, the command ticks and the state ticks."""
    rng = np.random.default_rng(seed)
    n = int(length / CYCLE)
    c_t = np.arange(n) * CYCLE + rng.uniform(0.0, 0.2e-3, n)
    t_cmd = np.arange(0.0, length, 0.001)
    read = c_t + rng.uniform(0.2e-3, 0.6e-3, n)
    sent = read + rng.uniform(0.3e-3, 1.0e-3, n)
    value = np.array([command(t_cmd[np.searchsorted(t_cmd, s, side="right") - 1]) for s in sent])
    due = sent + 50e-6 + delay  # arrival, then the robot's own delay
    # the pose at each cycle: the target switches at each `due`, the lag exact in continuous time
    events = sorted([(t, "pose", k) for k, t in enumerate(c_t)] + [(t, "due", k) for k, t in enumerate(due)])
    pose, x, target, last = np.zeros(n), 0.0, 0.0, 0.0
    for t, kind, k in events:
        x += (1.0 - math.exp(-(t - last) / tau) if tau > 0 else 1.0) * (target - x)
        last = t
        if kind == "due":
            target = value[k]
        else:
            pose[k] = x
    dc = cal.DeviceCycles(
        sent,
        read,
        value,
        np.ones(n, dtype=bool),
        pose,
        (np.arange(n) + 1000) % 65536,
        np.zeros(n, dtype=bool),
    )
    return dc, t_cmd, t_cmd + 0.5e-3


def calibration_with(dc, t_cmd, t_state) -> cal.Calibration:
    """A calibration whose servo and link are fitted on these device cycles (the rest from a simulated run)."""
    rec, _f, _v = simulate(Truth(delay=0.03, k=1000.0, noise=0.1), 1)
    base = cal.identify(rec)
    return dataclasses.replace(base, servo=cal.device_servo(dc), link=cal.link(dc, t_cmd, t_state))


@pytest.mark.parametrize("delay, tau, seed", [(0.0429, 0.0102, 1), (0.0231, 0.0, 2), (0.0745, 0.004, 3)])
def test_a_controller_that_does_not_echo_its_takes_leaves_the_robots_delay_not_identified(delay, tau, seed):
    dc, t_cmd, t_state = rsi_immediate_run(delay, tau, seed)
    c = calibration_with(dc, t_cmd, t_state)
    # what the device model would have said: short of the robot's delay by more than half a cycle
    assert c.servo.delay_s < delay - 0.5 * CYCLE, c.servo
    d = c.as_dict()
    assert d["delay_s"] is None and d["link_s"] is None and d["uncertainty"]["delay_s"] is None
    lo, hi = d["delay_range_s"]
    assert lo <= delay <= hi and hi - lo < 2.0 * CYCLE + c.link.forward_s + 1e-9, (lo, delay, hi)
    reason = d["fit"]["split_not_identified"]
    assert "\n" not in reason and "not separated" in reason and "delay_range_s" in reason
    cal.check(c)  # not identified is no failed fit: the loop's delay and the rest stand


def test_a_controller_that_echoes_its_takes_keeps_the_split():
    dc, t_cmd, t_state, _fwd, _back = device_run(0.04337, 0.01, 2)
    c = calibration_with(dc, t_cmd, t_state)
    d = c.as_dict()
    assert d["delay_s"] == pytest.approx(0.04337, abs=0.001) and d["link_s"] > 0.0
    assert d["delay_range_s"] is None and "split_not_identified" not in d["fit"]
