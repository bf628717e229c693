"""calibrate at the device boundary: the servo fit on the driver's device cycles (/robot/cycles) finds the
robot's own delay within a fraction of the device's cycle and the link apart; a recording without them
falls back to the graph's ticks and says so in one line; RobotCycles survive a bag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dockhil.analysis.calibration import loop as cal
from dockhil.analysis.calibration.device_cycles import unwrap
from dockhil.bags.reader import BagReader
from dockhil.bags.writer import BagWriter
from dockhil.devices.cycle_log import CycleLog
from dockhil.msgs import Header, NodeStatus, Pose, RobotCommand, RobotCycles, Vector3, type_name
from dockhil.msgs.codec import encode
from dockhil.nodes.identification import chirp_position
from tests.test_calibrate import Truth, simulate

T = 0.001  # the device's cycle [s]


def command(t: float) -> float:
    """The identification profile's shape, at its speeds: two 5 mm steps as ramps at 0.05 m/s, each held
    0.5 s, then a chirp of 0.5-8 Hz, 2.5 mm at most at 0.04 m/s, from 1.2 s on: a setpoint [m] at tick t."""
    if t < 1.2:
        into = t % 0.6
        ramp = min(into / 0.1, 1.0) * 0.005
        return ramp if t < 0.6 else 0.005 - ramp
    return chirp_position(t - 1.2, 0.0025, 0.04, 0.5, 8.0, 3.8)


def read_back(sent, read, value, pose, seen, echoed):
    """(DeviceCycles, kept): the exchanges whose read saw a cycle (`seen`, the index of the cycle each read
    saw: its pose and count), each written, marked taken where that cycle echoed the exchange (`echoed`, the
    exchange each cycle last took)."""
    ok = seen >= 0
    return cal.DeviceCycles(
        sent[ok],
        read[ok],
        value[ok],
        np.ones(ok.sum(), dtype=bool),
        pose[seen[ok]],
        (seen[ok] % 65536).astype(np.int64),
        echoed[seen[ok]] == np.arange(len(sent))[ok],
    ), ok


def device_run(delay: float, tau: float, seed: int = 0, length: float = 5.0):
    """A controller on its own 1 kHz cycle (each cycle up to 0.2 ms late) behind a Modbus-like link that
    writes the latest command and reads the pose back in exchanges of 0.6-2 ms (one in twenty stretched
    to 3-8 ms by a busy machine), one after another. Each cycle the controller moves the pose over the
    cycle toward the target it held (a first-order lag `tau`, exact over the cycle's length), takes the
    setpoint last written, and makes the target the setpoint it took at the latest cycle at least `delay`
    ago; it echoes the exchange it took. Returns the DeviceCycles, the command ticks, the state ticks, and
    the true forward and back latencies."""
    rng = np.random.default_rng(seed)
    n_cycles = int(length / T)
    c_t = np.arange(n_cycles) * T + rng.uniform(0.0, 0.2 * T, n_cycles)  # the device's cycles
    t_cmd = np.arange(0.0, length, T)  # command ticks
    # the link's exchanges: sent, write handled, read handled, read
    sent, s = [], 0.01
    while s < length - 0.01:
        sent.append(s)
        span = rng.uniform(0.6e-3, 2.0e-3) if rng.random() > 0.05 else rng.uniform(3e-3, 8e-3)
        s += span + rng.uniform(0.05e-3, 0.3e-3)
    sent = np.array(sent)
    span = np.diff(np.append(sent, length)) * rng.uniform(0.75, 0.95, len(sent))
    wrote, handled, read = sent + 0.15 * span, sent + 0.85 * span, sent + span
    value = np.array([command(t_cmd[np.searchsorted(t_cmd, s, side="right") - 1]) for s in sent])
    used = t_cmd[np.searchsorted(t_cmd, sent, side="right") - 1]
    # the controller, cycle by cycle
    taken_by = np.searchsorted(wrote, c_t, side="right") - 1  # the last exchange written before each cycle
    took = np.where(taken_by >= 0, value[np.clip(taken_by, 0, None)], 0.0)
    pose, target, x = np.zeros(n_cycles), 0.0, 0.0
    for n in range(n_cycles):
        if n:
            x += (1.0 - math.exp(-(c_t[n] - c_t[n - 1]) / tau) if tau > 0 else 1.0) * (target - x)
        pose[n] = x
        m = np.searchsorted(c_t, c_t[n] - delay, side="right") - 1  # the latest cycle at least `delay` ago
        if m >= 0:
            target = took[m]
    seen = np.searchsorted(c_t, handled, side="right") - 1  # the cycle each read sees
    dc, ok = read_back(sent, read, value, pose, seen, taken_by)
    # the truths of the link: each setpoint from its command's tick to the first cycle after its write
    first = np.searchsorted(c_t, wrote[ok], side="right")
    forward = c_t[np.clip(first, 0, n_cycles - 1)] - used[ok]
    t_state = t_cmd + 0.5 * T  # the driver's ticks publish the latest pose read
    j = np.searchsorted(read[ok], t_state, side="right") - 1
    back = (t_state - c_t[seen[ok]][np.clip(j, 0, None)])[j >= 0]
    return dc, t_cmd, t_state[j >= 0], float(np.median(forward)), float(np.median(back))


# A lag of ~0 is judged absolutely: within half a cycle. The cycle that took a setpoint is known only to
# within the exchange that echoed it (a stretched one spans several cycles), and that scatter reads as a few
# tenths of a millisecond of lag, or hides one.
LAG_FLOOR = 0.5 * T


def within(s: cal.Servo, delay: float, tau: float) -> bool:
    """The goal: the delay within one cycle, the lag within 5 % (or LAG_FLOOR), each within its uncertainty."""
    d, lag = s.delay_s - delay, s.lag_s - tau
    return abs(d) <= T and abs(d) <= 2.0 * s.delay_sigma_s and abs(lag) <= max(0.05 * tau, LAG_FLOOR)


@pytest.mark.parametrize(
    ("delay", "tau", "seed"),
    [(0.016, 0.0, 1), (0.04337, 0.01, 2), (0.10612, 0.0, 3), (0.1199, 0.02, 4), (0.0305, 0.0004, 5)],
)
def test_the_device_cycles_give_the_robots_own_delay_within_its_cycle_and_the_lag(delay, tau, seed):
    dc, t_cmd, t_state, forward, back = device_run(delay, tau, seed)
    s = cal.device_servo(dc)
    # the controller acts on whole cycles: the delay is known to its cycle, and reported at that cycle's middle
    assert abs(s.delay_s - delay) <= 0.6 * T and T / 4 < s.delay_sigma_s < T, s
    assert within(s, delay, tau), s
    ln = cal.link(dc, t_cmd, t_state)
    assert ln.forward_s == pytest.approx(forward, abs=0.3 * T)
    assert ln.back_s == pytest.approx(back, abs=0.3 * T)
    # timed on the link's sends and reads instead, the fit would take the link's latency for the robot's
    late = cal.servo(dc.sent, dc.x_set, dc.read, dc.x_actual)
    assert late.delay_s + late.lag_s > s.delay_s + s.lag_s + 0.5 * T


def test_twenty_draws_over_the_specified_ranges_are_all_within_the_goal():
    rng = np.random.default_rng(20)
    misses = []
    for seed in range(20):
        delay, tau = rng.uniform(0.016, 0.120), rng.uniform(0.0, 0.020)
        s = cal.device_servo(device_run(delay, tau, 100 + seed)[0])
        if not within(s, delay, tau):
            misses.append((seed, delay, tau, s.delay_s, s.lag_s, s.delay_sigma_s, s.lag_sigma_s))
    assert not misses


def test_a_16_bit_cycle_count_is_unwrapped():
    count = np.array([65534, 65535, 65535, 0, 2, 3])
    assert unwrap(count).tolist() == [65534, 65535, 65535, 65536, 65538, 65539]


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
    # on the ticks, the robot's delay is the loop's: the end-to-end one is its high percentile over the run
    assert found["link_s"] is None and found["delay_s"] <= found["loop_delay_s"] <= found["delay_s"] + 0.001
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


def test_the_loop_delay_end_to_end_takes_the_stretch_a_busy_machine_made():
    """Commands against the poses published, 30 ms apart through a 5 ms lag, except for one second in which
    a busy machine made it 34 ms: the typical delay is 30 ms, the loop's (the 95th percentile of the
    windows) the 34 ms the loop had while stretched; nothing about the controller's cycles is assumed."""
    from scipy.signal import lfilter

    t = np.arange(0.0, 6.0, 0.001)
    x = np.array([command(v) for v in t])
    grid = np.arange(0.0, 6.0, 1e-4)
    a = math.exp(-1e-4 / 0.005)
    held = x[np.searchsorted(t, grid, side="right") - 1]  # each command held from its tick
    lagged = lfilter([0.0, 1.0 - a], [1.0, -a], held)
    ts = np.arange(0.0005, 6.0, 0.001)
    busy = (ts >= 2.0) & (ts < 3.0)
    delay = np.where(busy, 0.034, 0.030)
    xs = np.round(np.interp(ts - delay, grid, lagged, left=0.0), 6)
    e2e = cal.end_to_end(t, x, ts, xs, lag=0.005)
    assert e2e.typical_s == pytest.approx(0.030, abs=2e-4)
    assert e2e.delay_s == pytest.approx(0.034, abs=5e-4)
    assert e2e.windows >= 8
    free = cal.end_to_end(t, x, ts, xs)  # the lag fitted too, from the same data
    assert free.lag_s == pytest.approx(0.005, abs=1e-3) and free.typical_s == pytest.approx(0.030, abs=1e-3)
