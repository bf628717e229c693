"""dockhil calibrate: the identification profile, the fits against hidden truths, the loop file, bad input,
and one run against the emulators."""

from __future__ import annotations

import json
import math
import random
import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest

from dockhil.analysis.calibration import loop as cal
from dockhil.cli import main
from dockhil.contact.stability import exact_bound
from dockhil.errors import DeviceError, LaunchError
from dockhil.msgs import Header, Pose, RobotState, Twist, Vector3, Wrench, WrenchStamped
from dockhil.node import NodeContext, Tick
from dockhil.nodes.identification import Identification
from dockhil.scene import launchfile

M_HIL = 750.0 * 1e6 / (750.0 + 1e6)  # hil.yaml's reduced mass


@dataclass
class Truth:
    delay: float = 0.032
    lag: float = 0.0
    k: float = 1000.0
    b: float = 0.0
    surface: float = 0.0
    bias: tuple = (0.0, 0.0, 0.0)
    noise: float = 0.0
    ft_delay: float = 0.0


def draw(seed: int) -> Truth:
    """Hidden truths from the ranges calibrate is specified over."""
    r = random.Random(seed)
    return Truth(
        delay=r.uniform(0.016, 0.120),
        lag=r.uniform(0.0, 0.020),
        k=1000.0 * r.uniform(0.7, 1.3),
        b=r.uniform(0.0, 50.0),
        surface=r.uniform(0.0, 0.02),
        bias=tuple(r.uniform(-5.0, 5.0) / math.sqrt(3) for _ in range(3)),
        noise=r.uniform(0.0, 0.5),
    )


def simulate(
    truth: Truth,
    seed: int = 0,
    max_force: float = 200.0,
    x_max: float = 0.1,
    rate: float = 1000.0,
    substeps: int = 10,
    **params,
):
    """The identification node against a plant with `truth`, on the node's own ticks: the servo follows the
    held command through the delay and an exact first-order lag (integrated in substeps), the pose is
    read back at each tick (1 um counts), the force is the unilateral spring-damper, biased and noisy.
    Returns the Recording and the largest |F| and speed the plant saw."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    node = Identification(
        NodeContext("identification", dt, sim_time=True, log=lambda line: None),
        max_force=max_force,
        x_max=x_max,
        **params,
    )
    node.setup()
    h = dt / substeps
    a = 1.0 - math.exp(-h / truth.lag) if truth.lag > 0 else 1.0
    x = v = 0.0
    cmd_t, cmd_x, st, ft, phases = [], [], [], [], []
    state = wrench = None
    history = []  # (t, x, v) for the F/T delay
    max_f = max_v = 0.0
    n = int((Identification.duration(params | {"max_force": max_force, "x_max": x_max}) + 1.0) * rate)
    j = -1  # the last command the servo has seen
    for k in range(n):
        t = k * dt
        out = node.step(Tick(k, t, dt), {"state": state, "wrench": wrench})
        if "command" in out:
            cmd_t.append(t)
            cmd_x.append(out["command"].pose.position.x)
        if "phase" in out:
            phases.append((t, out["phase"].state))
            if out["phase"].state == "done":
                break
        # the plant over the next tick: the command held since its tick, seen `delay` later
        x_tick = x
        for i in range(substeps):
            ts = t + i * h
            while j + 1 < len(cmd_t) and cmd_t[j + 1] <= ts - truth.delay:
                j += 1
            target = cmd_x[j] if j >= 0 else 0.0
            x = x + a * (target - x)
        v = (x - x_tick) / dt  # the tick's mean velocity, as a controller's encoder difference
        tn = t + dt
        xq = round(x * 1e6) / 1e6
        state = RobotState(header=_header(tn), pose=Pose(position=Vector3(x=xq)), twist=Twist(linear=Vector3(x=v)))
        st.append((tn, xq, v))
        history.append((tn, x, v))
        xs, vs = x, v
        if truth.ft_delay:
            j = max(0, len(history) - 1 - int(round(truth.ft_delay / dt)))
            xs, vs = history[j][1], history[j][2]
        depth = xs - truth.surface
        push = max(truth.k * depth + truth.b * vs, 0.0) if depth > 0 else 0.0
        f = [truth.bias[0] - push, truth.bias[1], truth.bias[2]] + rng.normal(0.0, truth.noise, 3) * (truth.noise > 0)
        f = np.round(np.asarray(f) / 0.01) * 0.01  # the CAN frames' 0.01 N counts
        max_f, max_v = max(max_f, float(np.linalg.norm(f))), max(max_v, abs(v))
        wrench = WrenchStamped(header=_header(tn), wrench=Wrench(force=Vector3(*map(float, f))))
        ft.append((tn, *f, 0.0, 0.0, 0.0))
    s, w = np.array(st), np.array(ft)
    rec = cal.Recording(
        np.array(cmd_t), np.array(cmd_x), s[:, 0], s[:, 1], s[:, 2], w[:, 0], w[:, 1:4], w[:, 4:7], phases
    )
    return rec, max_f, max_v


def _header(t):
    return Header(stamp=t)


# -- the pure fits on synthetic runs ----------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_fits_recover_hidden_truths_within_their_tolerances(seed):
    truth = draw(seed)
    rec, max_f, max_v = simulate(truth, seed)
    c = cal.identify(rec)
    cal.check(c)
    assert abs(c.servo.delay_s - truth.delay) < 0.001, (c.servo, truth)
    assert abs(c.servo.lag_s - truth.lag) <= max(0.05 * truth.lag, 2e-4), (c.servo, truth)
    assert abs(c.contact.k_N_per_m - truth.k) <= 0.05 * truth.k, (c.contact, truth)
    for i in range(3):
        assert abs(c.rest.bias_N[i] - truth.bias[i]) <= max(3 * truth.noise, 0.01), (c.rest, truth)
    assert c.rest.noise_N[0] == pytest.approx(truth.noise, abs=max(0.1 * truth.noise, 0.01))
    assert abs(c.contact.surface_m - truth.surface) < 0.0005
    # the loop's delay end to end: the command seen `delay` after its tick, the pose published a tick later
    assert truth.delay + truth.lag <= c.loop_delay_s + c.servo.lag_s <= truth.delay + truth.lag + 0.0015, c.loop
    bound = exact_bound(M_HIL, 40.0, truth.delay + 0.0005 + truth.lag).k_max
    found = cal.verdict(c, M_HIL, 3000.0, 40.0)["kcs_max_N_per_m"]
    assert abs(found - bound) <= 0.04 * bound
    # the profile kept well inside the limits it was given
    assert max_f < 0.5 * 200.0 and max_v < 0.1


def test_a_stiff_surface_stops_the_press_at_its_force_fraction_and_a_soft_one_at_its_depth():
    stiff, _f, _v = simulate(Truth(k=5000.0, delay=0.02), force_fraction=0.3)
    c = cal.identify(stiff)
    assert c.contact.peak_force_N < 0.35 * 200.0 + 3.0  # a delay's worth of travel past 60 N
    assert c.contact.k_N_per_m == pytest.approx(5000.0, rel=0.02)
    soft, _f, _v = simulate(Truth(k=300.0, delay=0.02))
    c = cal.identify(soft)
    assert c.contact.peak_force_N == pytest.approx(300.0 * 0.04, rel=0.15)  # press_depth 40 mm


def test_damping_is_measured_where_the_press_shows_it():
    rec, _f, _v = simulate(Truth(k=1000.0, b=200.0, delay=0.03, lag=0.01, noise=0.1), seed=4)
    c = cal.identify(rec)
    assert c.contact.b_Ns_per_m == pytest.approx(200.0, rel=0.1)
    assert c.contact.b_sigma < 0.5 * c.contact.b_Ns_per_m


def test_the_servo_fit_names_the_second_order_lag_when_it_fits_better():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 6.0, 0.001)
    x = np.where((t % 1.0) < 0.5, 0.0, -0.005)
    from scipy.signal import lfilter

    grid = np.arange(0.0, 6.2, 1e-4)
    u = np.interp(grid - 0.04, t, x, left=0.0)
    a = math.exp(-1e-4 / 0.015)
    y = lfilter([0.0, 1 - a], [1.0, -a], lfilter([0.0, 1 - a], [1.0, -a], u))
    ts = np.arange(0.0, 6.0, 0.002)
    xs = np.interp(ts, grid, y) + rng.normal(0.0, 1e-6, len(ts))
    s = cal.servo(t, x, ts, xs)
    assert s.lag_model == "second-order"


def test_no_contact_within_the_search_stops_with_one_line():
    with pytest.raises(DeviceError, match="no contact within search 0.03 m"):
        simulate(Truth(surface=0.2))


def test_a_press_that_overshoots_past_half_of_max_force_stops_the_run():
    # A very stiff surface behind a long delay: the robot moves on a delay's travel after the force is reached.
    with pytest.raises(DeviceError, match="over half of max_force 200 N"):
        simulate(Truth(k=60000.0, delay=0.12))


def test_a_run_without_phases_or_without_a_press_is_refused():
    with pytest.raises(cal.CalibrationError, match="not a recording of an identification run"):
        cal.recording([("/robot/state", RobotState(header=_header(1.0)))])
    rec, _f, _v = simulate(Truth())
    rec.phases = [(t, p) for t, p in rec.phases if p not in ("approach", "press", "hold", "release")]
    with pytest.raises(cal.CalibrationError, match="no approach or press or hold or release phase"):
        cal.identify(rec)


def test_fits_without_what_they_need_say_what_was_missing():
    t = np.arange(0.0, 2.0, 0.001)
    with pytest.raises(cal.CalibrationError, match="never moved the robot"):
        cal.servo(t, np.zeros_like(t), t, np.zeros_like(t))
    with pytest.raises(cal.CalibrationError, match="too little force"):
        cal.contact(t, np.full_like(t, 0.3), t, np.linspace(0.0, 0.01, len(t)), np.full_like(t, 0.005), noise=0.1)
    with pytest.raises(cal.CalibrationError, match="only 5 F/T samples at rest"):
        cal.rest(np.zeros((5, 3)))


def test_a_fit_whose_uncertainty_exceeds_its_value_is_no_measurement():
    rec, _f, _v = simulate(Truth())
    c = cal.identify(rec)
    shaky = cal.Calibration(c.rest, c.servo, cal.Contact(**{**c.contact.__dict__, "k_sigma": 2 * c.contact.k_N_per_m}))
    with pytest.raises(cal.CalibrationError, match="stiffness k fit is no measurement"):
        cal.check(shaky)


def test_the_verdict_gives_the_exact_bound_the_margin_and_the_largest_stable_kcs():
    rec, _f, _v = simulate(Truth(delay=0.032))
    c = cal.identify(rec)
    v = cal.verdict(c, M_HIL, 3000.0, 40.0)
    h = c.loop_delay_s + c.servo.lag_s + (c.contact.ft_delay_s or 0.0)
    assert v["h_s"] == pytest.approx(h)
    bound = exact_bound(M_HIL, 40.0, h).k_max
    assert v["kcs_max_N_per_m"] == pytest.approx(bound)
    assert v["margin"] == pytest.approx(bound / 3000.0)
    assert v["stable"] is (3000.0 < bound)


def test_the_loop_delay_is_the_end_to_end_one_never_below_the_robots_own():
    """loop_delay_s is the run's end-to-end delay at its high percentile, whatever the robot and link
    add up to; a robot's own delay longer than that (a fit that traded delay for lag) is the floor."""
    import dataclasses

    rec, _f, _v = simulate(Truth(delay=0.032))
    c = cal.identify(rec)
    assert c.loop is not None and c.loop_delay_s == pytest.approx(max(c.loop.delay_s, c.servo.delay_s))
    # the simulated loop: the command seen `delay` after its tick, the pose published at the next tick (the
    # fit on the ticks may read a part of that tick as lag)
    assert 0.032 <= c.loop_delay_s + c.servo.lag_s <= 0.032 + 0.0015
    longer = dataclasses.replace(c.loop, delay_s=0.040)
    assert cal.Calibration(c.rest, c.servo, c.contact, c.link, longer).loop_delay_s == 0.040
    floor = dataclasses.replace(c.servo, delay_s=0.050)
    assert cal.Calibration(c.rest, floor, c.contact, c.link, c.loop).loop_delay_s == 0.050
    assert cal.verdict(cal.Calibration(c.rest, c.servo, c.contact, c.link, longer), M_HIL, 3000.0, 40.0)[
        "h_s"
    ] == pytest.approx(0.040 + c.servo.lag_s + (c.contact.ft_delay_s or 0.0))


def test_a_negative_damping_beyond_its_uncertainty_is_not_identified():
    rec, _f, _v = simulate(Truth())
    c = cal.identify(rec)
    leading = cal.Contact(**{**c.contact.__dict__, "b_Ns_per_m": -1.06, "b_sigma": 0.02})
    d = cal.Calibration(c.rest, c.servo, leading, c.link, c.loop).as_dict()
    assert d["b_Ns_per_m"] is None and d["uncertainty"]["b_Ns_per_m"] is None
    assert "not identified" in d["fit"]["b_not_identified"] and "-1.06" in d["fit"]["b_not_identified"]
    within = cal.Contact(**{**c.contact.__dict__, "b_Ns_per_m": -0.01, "b_sigma": 0.02})
    assert cal.Calibration(c.rest, c.servo, within, c.link, c.loop).as_dict()["b_Ns_per_m"] == -0.01


# -- the command: bad input, the loop file ----------------------------------------------------------------------


def test_a_scene_without_hardware_is_refused_naming_the_arguments_to_give(tmp_path, capsys):
    out = tmp_path / "loop.yaml"
    assert main(["calibrate", "hil.yaml", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "robot and F/T sensor are simulated" in err and "robot:=modbus ft:=can" in err and "emulators:=true" in err
    assert main(["calibrate", "hil.yaml", "robot:=modbus", "--out", str(out)]) == 2
    assert "give ft:=can" in capsys.readouterr().err
    assert not out.exists()


def test_a_bag_without_an_identification_run_is_refused_and_nothing_written(tmp_path, capsys):
    bag, out = tmp_path / "run.mcap", tmp_path / "loop.yaml"
    assert main(["launch", "hil.yaml", "--duration", "0.05", "--quiet", "--composed", "--bag", str(bag)]) == 0
    capsys.readouterr()
    assert main(["calibrate", "--bag", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not a recording of an identification run" in err, err
    assert not out.exists()
    assert main(["calibrate", "--bag", str(tmp_path / "none.mcap")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_a_loop_file_with_max_force_is_refused_by_the_command_in_one_line(tmp_path, capsys):
    loop = tmp_path / "loop.yaml"
    loop.write_text("args:\n  delay: 0.03\n  max_force: 90000\n")
    assert main(["graph", "hil.yaml", f"loop:={loop}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "max_force" in err and "Traceback" not in err, err


def test_a_loop_file_sets_the_scene_and_the_command_line_wins(tmp_path):
    loop = tmp_path / "loop.yaml"
    loop.write_text(
        "args:\n  delay: 0.0473\n  lag: 0.0081\n  k: 1012.5\n  ft_noise: 0.21\n  ft_delay: 0.002\n"
        'tare: {"force_N": [0.1, 0.2, 0.3], "torque_Nm": [0, 0, 0]}\n'
    )
    scene = launchfile.load("hil.yaml", {"loop": str(loop)})
    assert (scene.values["delay"], scene.values["lag"], scene.values["k"], scene.values["ft_noise"]) == (
        0.0473,
        0.0081,
        1012.5,
        0.21,
    )
    scene = launchfile.load("hil.yaml", launchfile.parse_overrides([f"loop:={loop}", "delay:=0.02"]))
    assert scene.values["delay"] == 0.02 and scene.values["k"] == 1012.5
    six = launchfile.load("hil6.yaml", {"loop": str(loop)})  # the 6-DOF scene declares the same
    assert (six.values["delay"], six.values["ft_noise"], six.values["ft_delay"]) == (0.0473, 0.21, 0.002)
    stability = launchfile.load("stability.yaml", {"loop": str(loop)})
    assert (stability.values["delay"], stability.values["ft_delay"]) == (0.0473, 0.002)
    lean = tmp_path / "lean.yaml"  # a scene that declares only some: those are set, the rest left aside
    lean.write_text(
        "args:\n  loop: {default: ''}\n  delay: {default: 0.016}\n"
        "nodes:\n  - {name: delay, node: delay_injector, params: {delay: $(arg delay)}}\n"
    )
    only = launchfile.load(str(lean), {"loop": str(loop)})
    assert only.values["delay"] == 0.0473 and "ft_delay" not in only.values and "k" not in only.values


@pytest.mark.parametrize(
    "text, why",
    [
        ("delay: 0.03\n", "not a loop file"),
        ("args:\n  delay: fast\n", "not a number"),
        ("args: [1, 2]\n", "not a loop file"),
        ("args:\n  delay: 0.03\n  max_force: 90000\n", "args.max_force is not what calibration identifies"),
        ("args:\n  m1: 1000000.0\n", "args.m1 is not what calibration identifies"),
        ("args:\n  delay: 0.03\nrsi_port: 80\n", "'rsi_port' is not what calibration identifies"),
    ],
)
def test_a_bad_loop_file_is_one_line(tmp_path, text, why):
    loop = tmp_path / "loop.yaml"
    loop.write_text(text)
    with pytest.raises(LaunchError, match=why) as refused:
        launchfile.load("hil.yaml", {"loop": str(loop)})
    assert "\n" not in str(refused.value) and str(loop) in str(refused.value)
    with pytest.raises(LaunchError, match="cannot read"):
        launchfile.load("hil.yaml", {"loop": str(tmp_path / "missing.yaml")})


# -- against the emulators ---------------------------------------------------------------------------------------


@pytest.mark.wall_time
def test_calibrate_on_emulators_finds_their_hidden_truths_within_the_limits(tmp_path):
    """One live run (wall time, real drivers, --realtime) on emulators hiding a draw: the delay, timed at the
    device, within the emulator's 1 ms cycle of its hidden one, the rest within its tolerance; the emulators'
    maxima show the scene's force and speed limits were kept, and the run took under 60 s."""
    from bench.calibrate import MAX_ACTUAL_SPEED, MAX_FORCE, run
    from bench.calibrate import draw as bench_draw

    truth = bench_draw(7)
    bag = tmp_path / "run.mcap"
    r = run(truth, bag_out=str(bag))
    assert r["exit"] == 0, r["stderr_tail"]
    assert r["wall_s"] < 60.0 and r["written"]
    e = r["errors"]
    assert abs(e["delay_ms"]) <= 1.0, e
    # One live draw on a machine that may be busy: the lag within 5 % or two device cycles (1.6 ms was
    # seen with both cores busy); bench/calibrate.py holds the 20-draw statistics against the goal.
    assert abs(e["lag_ms"]) <= max(0.05 * 1e3 * truth["lag"], 2.0), e
    assert abs(e["k_rel"]) < 0.05 and e["bias_in_noise_sd"] < 3.0, e
    assert 0.0 < r["ft_maxima"]["max_force_N"] < 0.5 * MAX_FORCE
    assert r["robot_maxima"]["max_speed_m_s"] < MAX_ACTUAL_SPEED
    # the recording gives the same loop offline
    offline = subprocess.run(
        [sys.executable, "-m", "dockhil.cli", "calibrate", "--bag", str(bag), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert offline.returncode == 0, offline.stderr
    found = json.loads(offline.stdout)
    for key in ("delay_s", "lag_s", "k_N_per_m", "b_Ns_per_m", "bias_N", "noise_N"):
        assert found[key] == r["found"][key], key


@pytest.mark.wall_time
def test_calibrate_holds_the_loops_delay_on_a_controller_that_takes_corrections_as_they_come():
    """The other plausible controller (the emulators' `timing: immediate`) on Modbus at 1 kHz: the loop's
    delay is the run's own, end to end, within a device cycle of what its bag shows and never below the
    hidden delay, where the device model's split into robot and link does not hold. (The KUKA RSI emulator,
    with either timing: tests/test_stability_run.py, whose scene is calibrated on it.)"""
    from bench.calibrate import draw as bench_draw
    from bench.calibrate import run

    truth = bench_draw(3)
    r = run(truth, robot="modbus", cycle=0.001, timing="immediate")
    assert r["exit"] == 0, r["stderr_tail"]
    e = r["errors"]
    assert abs(e["loop_and_lag_vs_run_p95_cycles"]) <= 1.0 and e["loop_minus_hidden_ms"] >= 0.0, e
