"""The Modbus controller's record is the truth: each setpoint written is within reach (max_speed times the
time since it was written, at most max_cycle) of every setpoint the controller may hold, the one whose
heartbeat it echoes and those written since; so a controller that misses writes, echoes late or stalls
never takes a jump. A controller played here on a clock the test controls."""

from __future__ import annotations

import math
import random

import pytest

from dockhil.devices.modbus_robot.link import SetpointLimiter

MAX_SPEED, MAX_CYCLE, POLL = 0.1, 0.005, 0.002
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def pose(x: float, y: float = 0.0) -> tuple:
    return (x, y, 0.0, *IDENTITY, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("echoes", ["guarded", "plain"])
def test_a_controller_that_misses_writes_or_stalls_never_takes_a_jump(seed, echoes):
    rng = random.Random(seed)
    lim = SetpointLimiter(MAX_SPEED, 0.5, MAX_CYCLE)
    now, hb = 0.0, 0
    held = (0.0, pose(0.0))  # (written at, setpoint) the controller holds
    written: dict[int, tuple[float, tuple]] = {}
    takes = [held]
    target = pose(0.05, -0.02)
    for k in range(4000):
        if k % 300 == 0:
            target = pose(rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05))
        dt = POLL * rng.choice((1, 1, 1, 0.3, 2.5))  # the link's cycles scatter
        now += dt
        hb = (hb + 1) & 0xFFFF
        setpoint = lim.next(target, held[1], dt, now if echoes == "guarded" else None)
        lim.wrote(hb, now, setpoint)
        written[hb] = (now, setpoint)
        # the controller takes the newest write, or misses it (30 %), or stalls for 10-60 writes (1 %)
        if rng.random() < 0.01:
            now += rng.uniform(0.02, 0.12)
        if rng.random() > 0.3:
            held = written[hb]
            takes.append(held)
            echo = hb
        else:
            echo = next(h for h, w in written.items() if w is held)
        lim.echoed(echo)
    worst = 0.0
    for (ta, a), (tb, b) in zip(takes, takes[1:]):
        step = math.dist(a[:3], b[:3])
        assert step <= MAX_SPEED * MAX_CYCLE + 1e-12
        worst = max(worst, step / (MAX_SPEED * max(tb - ta, POLL)))
    if echoes == "guarded":  # the speed over the time between the writes it took, a poll at least
        assert worst <= 1.0 + 1e-9, worst
    travelled = sum(math.dist(a[:3], b[:3]) for (_, a), (_, b) in zip(takes, takes[1:]))
    assert travelled > 0.3  # m: and it goes where it is told, at a good part of the limit
