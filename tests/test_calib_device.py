"""calibrate at the device boundary: the servo fit on the driver's device cycles (/robot/cycles) finds the
robot's own delay within a fraction of the device's cycle and the link apart; a recording without them
falls back to the graph's ticks and says so in one line; RobotCycles survive a bag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dockhil.analysis import calibration as cal
from dockhil.bags.reader import BagReader
from dockhil.bags.writer import BagWriter
from dockhil.hardware.cycle_log import CycleLog
from dockhil.msgs import Header, NodeStatus, RobotCommand, RobotCycles, Pose, Vector3, type_name
from dockhil.msgs.codec import encode
from tests.test_calibrate import Truth, simulate

T = 0.001  # the device's cycle [s]


def command(t: float) -> float:
    """Steps and a sweep, as the identification profile moves: a setpoint [m] at tick time t."""
    steps = 0.004 * (int(t / 0.25) % 2)
    return steps + 0.002 * math.sin(2 * math.pi * (0.5 + 3.0 * t) * t) * (t > 1.0)


def device_run(cycles_delay: int, tau: float, seed: int = 0, length: float = 2.0):
    """A controller on its own 1 kHz cycle (jittered) behind a Modbus-like link that writes the latest
    command and reads the pose back in exchanges of 0.3-0.8 ms, every 0.8-1.6 ms. The controller takes
    the setpoint written before its cycle, moves toward it `cycles_delay` cycles later through a lag
    `tau` (exact per cycle), and echoes the exchange it last took. Returns the DeviceCycles, the command
    ticks, the state ticks, and the true forward and back latencies."""
    rng = np.random.default_rng(seed)
    n_cycles = int(length / T)
    c_t = np.arange(n_cycles) * T + rng.uniform(0.0, 0.2 * T, n_cycles)  # the device's cycles
    t_cmd = np.arange(0.0, length, T)  # command ticks
    # the link's exchanges: sent, write handled, read handled, read
    sent, s = [], 0.01
    while s < length - 0.01:
        sent.append(s)
        s += rng.uniform(0.8e-3, 1.6e-3)
    sent = np.array(sent)
    span = rng.uniform(0.3e-3, 0.8e-3, len(sent))
    wrote, handled, read = sent + 0.1 * span, sent + 0.9 * span, sent + span
    value = np.array([command(t_cmd[np.searchsorted(t_cmd, s, side="right") - 1]) for s in sent])
    used = t_cmd[np.searchsorted(t_cmd, sent, side="right") - 1]
    # the controller, cycle by cycle
    a = 1.0 - math.exp(-T / tau) if tau > 0 else 1.0
    taken_by = np.searchsorted(wrote, c_t, side="right") - 1  # the last exchange written before each cycle
    pose, target, x = np.zeros(n_cycles), 0.0, 0.0
    line = []
    for n in range(n_cycles):
        x += a * (target - x)
        pose[n] = x
        line.append(value[taken_by[n]] if taken_by[n] >= 0 else 0.0)
        if n >= cycles_delay:
            target = line[n - cycles_delay]
    seen = np.searchsorted(c_t, handled, side="right") - 1  # the cycle each read sees
    ok = seen >= 0
    dc = cal.DeviceCycles(
        sent[ok],
        read[ok],
        value[ok],
        np.ones(ok.sum(), dtype=bool),
        pose[seen[ok]],
        (seen[ok] % 65536).astype(np.int64),
        (taken_by[seen[ok]] == np.arange(len(sent))[ok]),
    )
    # the truths of the link: each setpoint from its command's tick to the first cycle after its write
    first = np.searchsorted(c_t, wrote[ok], side="right")
    forward = c_t[np.clip(first, 0, n_cycles - 1)] - used[ok]
    t_state = t_cmd + 0.5 * T  # the driver's ticks publish the latest pose read
    j = np.searchsorted(read[ok], t_state, side="right") - 1
    back = (t_state - c_t[seen[ok]][np.clip(j, 0, None)])[j >= 0]
    return dc, t_cmd, t_state[j >= 0], float(np.median(forward)), float(np.median(back))


@pytest.mark.parametrize(("cycles_delay", "tau", "seed"), [(16, 0.0, 1), (43, 0.01, 2), (120, 0.02, 3), (30, 0.004, 4)])
def test_the_device_cycles_give_the_robots_own_delay_within_a_fraction_of_a_cycle(cycles_delay, tau, seed):
    dc, t_cmd, t_state, forward, back = device_run(cycles_delay, tau, seed)
    s = cal.servo(*cal.device_timing(dc))
    # within half a cycle: a step lands on a cycle, and the pose read there is still the old one
    assert abs(s.delay_s - cycles_delay * T) < 0.5 * T, s
    assert abs(s.lag_s - tau) <= max(0.05 * tau, 0.2 * T), s
    ln = cal.link(dc, t_cmd, t_state)
    assert ln.forward_s == pytest.approx(forward, abs=0.3 * T)
    assert ln.back_s == pytest.approx(back, abs=0.3 * T)
    # timed on the link's sends and reads instead, the fit would take the link's latency for the robot's
    late = cal.servo(dc.sent, dc.x_set, dc.read, dc.x_actual)
    assert late.delay_s + late.lag_s > s.delay_s + s.lag_s + 0.5 * T


def test_a_16_bit_cycle_count_is_unwrapped():
    count = np.array([65534, 65535, 65535, 0, 2, 3])
    assert cal._unwrap(count).tolist() == [65534, 65535, 65535, 65536, 65538, 65539]


def _identification_messages(rec: cal.Recording):
    """The simulated run as the bag's (topic, message) pairs, without device cycles: an older bag."""
    from dockhil.msgs import RobotState, Twist, Wrench, WrenchStamped

    floats = lambda *arrays: zip(*(map(float, a) for a in arrays))  # noqa: E731 - msgspec wants floats
    for t, x in floats(rec.t_cmd, rec.x_cmd):
        yield "/robot/command", RobotCommand(header=Header(stamp=t), pose=Pose(position=Vector3(x=x)))
    for t, x, v in floats(rec.t_state, rec.x_state, rec.v_state):
        yield (
            "/robot/state",
            RobotState(header=Header(stamp=t), pose=Pose(position=Vector3(x=x)), twist=Twist(linear=Vector3(x=v))),
        )
    for t, f, m in zip(rec.t_ft, rec.force, rec.torque):
        wrench = Wrench(Vector3(*map(float, f)), Vector3(*map(float, m)))
        yield "/ft/wrench", WrenchStamped(header=Header(stamp=float(t)), wrench=wrench)
    for t, phase in rec.phases:
        yield "/calibration/phase", NodeStatus(header=Header(stamp=t), node="identification", state=phase)


def test_a_recording_without_device_cycles_is_fitted_on_the_ticks_and_says_so_in_one_line(tmp_path, capsys):
    from dockhil.cli import main

    rec, _f, _v = simulate(Truth(delay=0.03, lag=0.005, noise=0.05), 1)
    bag = tmp_path / "old.mcap"
    with BagWriter(bag) as writer:
        topics = set()
        for topic, msg in _identification_messages(rec):
            if topic not in topics:
                writer.add_topic(topic, type_name(type(msg)))
                topics.add(topic)
            ns = round(msg.header.stamp * 1e9)
            writer.write(topic, ns, ns, encode(msg))
    assert main(["calibrate", "--bag", str(bag), "--json"]) == 0
    out, err = capsys.readouterr()
    import json

    found = json.loads(out.strip().splitlines()[-1])
    assert found["link_s"] is None and found["loop_delay_s"] == found["delay_s"]
    assert found["timing"] == cal.NO_CYCLES
    assert abs(found["delay_s"] - 0.03) < 0.001
    lines = [line for line in err.splitlines() if "no device cycles" in line]
    assert len(lines) == 1 and lines[0].startswith("dockhil calibrate: warning:"), err


def test_robot_cycles_survive_a_bag_and_become_the_recordings_device_cycles(tmp_path):
    log = CycleLog()
    for i in range(5):
        at = 10.0 + i * 0.001
        setpoint = (0.001 * i, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
        log.add(at, at + 0.0004, setpoint, i % 2 == 0, (0.0005 * i, 0, 0, 0, 0, 0, 1), 65534 + i, i == 3)
    # the link's clock is 1000 s behind the graph's: the message carries the graph's times
    msg = log.output(Header(stamp=1010.01, tick=3), now=10.01)["cycles"]
    assert log.output(Header(stamp=1010.02), now=10.02) == {}  # taken once: nothing twice
    assert [c.sent for c in msg.cycles] == pytest.approx([1010.0 + i * 0.001 for i in range(5)])
    path = tmp_path / "cycles.mcap"
    with BagWriter(path) as writer:
        writer.add_topic("/robot/cycles", type_name(RobotCycles))
        writer.write("/robot/cycles", 1, 1, encode(msg))
    with BagReader(path) as reader:
        ((topic, _t, back),) = list(reader.decoded())
    assert topic == "/robot/cycles" and back == msg
    phases = [(1009.0, "steps"), (1011.0, "approach")]
    base = [("/calibration/phase", NodeStatus(header=Header(stamp=t), state=p)) for t, p in phases]
    from dockhil.msgs import RobotState, WrenchStamped

    extra = [
        ("/robot/command", RobotCommand(header=Header(stamp=1010.0))),
        ("/robot/state", RobotState(header=Header(stamp=1010.0))),
        ("/ft/wrench", WrenchStamped(header=Header(stamp=1010.0))),
    ]
    rec = cal.recording([*base, *extra, ("/robot/cycles", back)])
    c = rec.cycles
    assert c is not None and c.cycle.tolist() == [65534, 65535, 65536, 65537, 65538]
    assert c.written.tolist() == [True, False, True, False, True] and c.taken.tolist() == [False] * 3 + [True, False]
    assert c.x_set.tolist() == pytest.approx([0.001 * i for i in range(5)])
    assert c.read - c.sent == pytest.approx([0.0004] * 5)
