"""dockhil calibrate against emulators with hidden truths: prints one JSON line.

    python3 bench/calibrate.py [--draws 20] [--seed 0] [--no-realtime] [--robot modbus|rsi] [--rsi-cycle 0.004]
                               [--timing ours|immediate] [--configs rsi:ours,rsi:immediate,modbus:ours,modbus:immediate]
                               [--rows ROWS.jsonl] [--from-rows ROWS.jsonl ...] [--keep DIR]

--configs runs several robot:timing configurations, --draws each, and prints one summary per configuration
(its pass counts and worst margins). A long run is kept row by row in --rows (one JSON line per draw, as it
ends), so it can be run in chunks (--seed, --draws) and summarised later with --from-rows; --keep DIR keeps
each draw's bag and loop file (DIR/ROBOT-TIMING-SEED.mcap, .yaml).

Each draw hides a delay (16-120 ms), a lag (0-20 ms), a stiffness (1000 N/m +-30 %), a damping
(0-50 N s/m), a surface (0-20 mm ahead), a noise (0-0.5 N) and a bias (|F| up to 5 N, and a torque)
in the robot emulator (Modbus, or with --robot rsi the KUKA RSI controller at --rsi-cycle) and the CAN
F/T emulator, runs `dockhil calibrate` on them (wall time, the real drivers in between) and compares,
with medians and worst cases over the draws: the robot's delay as timed at the device (delay_s)
against the emulator's servo delay, in ms and in the emulator's cycles (and against its effective
delay, the hidden one rounded up to its cycle, which is all a cycle's data can show: delay_s + T/2
against it), the lag's error (ms and relative),
k's relative error, the bias's error in noise standard deviations, and the relative error of the
exact stiffness bound (hil.yaml's m, bcs) from the identified delay_s + lag_s against the one from
the emulator's delay + lag, and the bound the verdict also gives, at the cycle's top (delay_s + T/2),
against the one from the emulator's effective delay; the link (link_s) is reported as measured. The emulators' recorded
maxima show the run kept the scene's limits.

The loop's delay (loop_delay_s, the verdict's) is held to the run itself: the bench reads the run's bag and
finds, with code of its own, the delay from the /robot/command ticks to the /robot/state ticks that best
explains the poses through the emulator's hidden lag, over the steps and the chirp (the whole run, and 0.5 s
windows at their 95th percentile; read with no lag where calibrate did not separate the lag from the delay,
which then holds it). loop_delay_s must lie within one device cycle of that and never below the
hidden robot delay, with either emulator timing (--timing: where inside the controller its cycles are spent),
and the stiffness bound of that loop (loop_delay_s + lag_s) within 2 % of the bound of the loop the run had
(its 95th percentile through the hidden lag). The robot's own delay must lie in delay_range_s, which holds it
whatever the controller's inside (delay_s is the device model's point in it).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import shutil
import socket
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from dockhil.contact.stability import exact_bound  # noqa: E402

M1, M2, KCS, BCS = 750.0, 1e6, 3000.0, 40.0
# The robot driver's limits in the rig: its setpoint speed, and the measured speed (the controller's over
# 10 ms, which a setpoint catching up at max_speed after a late device cycle may take to 1.5 max_speed).
MAX_FORCE, MAX_SPEED, MAX_ACTUAL_SPEED = 200.0, 0.1, 0.2


def draw(seed: int) -> dict:
    """Hidden truths from the ranges calibrate is specified over."""
    r = random.Random(seed)
    bias = [r.uniform(-5.0, 5.0) / math.sqrt(3) for _ in range(3)]
    return {
        "delay": r.uniform(0.016, 0.120),
        "lag": r.uniform(0.0, 0.020),
        "k": 1000.0 * r.uniform(0.7, 1.3),
        "b": r.uniform(0.0, 50.0),
        "surface": r.uniform(0.0, 0.02),
        "noise": r.uniform(0.0, 0.5),
        "bias": bias,
        "torque_bias": [r.uniform(-0.5, 0.5) for _ in range(3)],
    }


MODBUS_CYCLE = 0.001  # s: the Modbus emulator's servo cycle (robot_emulator's default)


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def robot_nodes(folder: str, truth: dict, robot: str, cycle: float, timing: str = "ours") -> list[dict]:
    """The robot driver and its emulator hiding the delay and lag; the emulator writes its record (with its
    largest speed) to folder/robot_maxima.json."""
    limits = {"max_force": MAX_FORCE, "max_speed": MAX_SPEED, "ft_timeout": 0.2, "max_actual_speed": MAX_ACTUAL_SPEED}
    record = os.path.join(folder, "robot_maxima.json")
    if robot == "rsi":
        port = free_port(socket.SOCK_DGRAM)
        emulator = {
            "port": port,
            "cycle": cycle,
            "delay": truth["delay"],
            "tau": truth["lag"],
            "record": record,
            "timing": timing,
        }
        return [
            {
                "name": "robot",
                "node": "robot_rsi",
                "params": {"port": port, "listen": "127.0.0.1", "cycle": cycle, **limits},
            },
            {"name": "robot_emulator", "node": "rsi_emulator", "params": emulator},
        ]
    port = free_port()
    emulator = {"port": port, "delay": truth["delay"], "tau": truth["lag"], "maxima": record, "timing": timing}
    return [
        {"name": "robot", "node": "robot_modbus", "params": {"port": port, **limits}},
        {"name": "robot_emulator", "node": "robot_emulator", "params": emulator},
    ]


def rig(folder: str, truth: dict, robot: str = "modbus", cycle: float = 0.004, timing: str = "ours") -> str:
    """A scene of the hardware loop on emulators hiding `truth`; the emulators write their maxima to
    folder/ft_maxima.json and folder/robot_maxima.json."""
    # CAN frames over UDP multicast on loopback (python-can's udp_multicast), one group per run: the
    # driver's code is the one a lab runs, and a pseudo-terminal's bytes, which reach the reader through
    # an ordinary-priority kernel worker, cannot go silent for 0.1 s on a busy machine.
    channel = f"239.74.{random.randrange(1, 255)}.{random.randrange(1, 255)}"
    fb, tb = truth["bias"], truth["torque_bias"]
    ft = {
        "interface": "udp_multicast",
        "channel": channel,
        "k": truth["k"],
        "b": truth["b"],
        "surface": truth["surface"],
        "noise": truth["noise"],
        "bias": fb[0],
        "bias_y": fb[1],
        "bias_z": fb[2],
        "torque_bias_x": tb[0],
        "torque_bias_y": tb[1],
        "torque_bias_z": tb[2],
        "seed": 1,
        "maxima": os.path.join(folder, "ft_maxima.json"),
    }
    nodes = [
        {"name": "dynamics", "node": "satellite_dynamics", "params": {"m1": M1, "m2": M2}},
        {"name": "impedance", "node": "virtual_impedance", "params": {"m1": M1, "m2": M2, "kcs": KCS, "bcs": BCS}},
        *robot_nodes(folder, truth, robot, cycle, timing),
        {"name": "ft", "node": "ft_can", "params": {"interface": "udp_multicast", "channel": channel}},
        {"name": "ft_emulator", "node": "ft_emulator", "params": ft},
    ]
    path = os.path.join(folder, "rig.yaml")
    with open(path, "w") as f:
        json.dump({"description": "emulated hardware with hidden truths", "rate": 1000.0, "nodes": nodes}, f)
    return path


# A busy machine can starve the drivers past their watchdogs: a valid safety stop, not a calibration
# result; such a run is tried again (the attempts are counted). So is one whose F/T emulator, stopped with
# the graph, closed its link before the driver stopped reading it ("while stopping"), and one whose bag
# recorder, starved, lost the run's end (the fits read the bag).
BUSY = (
    "ft_timeout: no F/T data",
    "stale data: no new sample",
    "safety stop: stall:",
    "s old > max_age",
    "INVALID",
    "while stopping",
    "the recorder fell behind",
    "a busy machine?",
)


def run(
    truth: dict,
    realtime: bool = True,
    attempts: int = 3,
    bag_out: str | None = None,
    robot: str = "modbus",
    cycle: float = 0.004,
    timing: str = "ours",
    loop_out: str | None = None,
) -> dict:
    """One calibration against emulators hiding `truth`, tried up to `attempts` times while a busy machine
    stops it (BUSY)."""
    for attempt in range(1, attempts + 1):
        out = run_once(truth, realtime, bag_out=bag_out, robot=robot, cycle=cycle, timing=timing, loop_out=loop_out)
        out["attempts"] = attempt
        if out["exit"] == 0 or not any(b in out.get("stderr_tail", "") for b in BUSY):
            break
    return out


def run_once(
    truth: dict,
    realtime: bool = True,
    timeout: float = 120.0,
    bag_out: str | None = None,
    robot: str = "modbus",
    cycle: float = 0.004,
    timing: str = "ours",
    loop_out: str | None = None,
) -> dict:
    """One calibration against emulators hiding `truth`: its JSON, exit code, wall time, the emulators' maxima
    and the errors (bag_out: keep the run's recording there, replacing an earlier one; loop_out: the loop
    file written, if any)."""
    if bag_out and os.path.exists(bag_out):
        os.remove(bag_out)
    with tempfile.TemporaryDirectory(prefix="dockhil-calibrate-bench-") as folder:
        scene = rig(folder, truth, robot, cycle, timing)
        bag = bag_out or os.path.join(folder, "run.mcap")
        start = time.perf_counter()
        p = subprocess.run(
            [
                sys.executable,
                "-m",
                "dockhil.cli",
                "calibrate",
                scene,
                "--json",
                "--out",
                os.path.join(folder, "loop.yaml"),
                *(["--realtime"] if realtime else []),
                "--bag-out",
                bag,
            ],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        wall = time.perf_counter() - start
        out = {
            "exit": p.returncode,
            "wall_s": wall,
            "truth": truth,
            "written": os.path.exists(os.path.join(folder, "loop.yaml")),
            "stderr_tail": "\n".join(p.stderr.strip().splitlines()[-12:]),
        }
        try:
            out["run_e2e"] = run_end_to_end(bag, truth["lag"])
            # with no lag: the loop's delay where calibrate does not separate the lag (the delay holds it)
            out["run_e2e_no_lag"] = run_end_to_end(bag, 0.0)
        except (OSError, ValueError) as exc:
            out["run_e2e"] = {"error": str(exc)}
        if loop_out and out["written"]:
            shutil.copyfile(os.path.join(folder, "loop.yaml"), loop_out)
        for name in ("ft_maxima", "robot_maxima"):
            try:
                with open(os.path.join(folder, f"{name}.json")) as f:
                    out[name] = json.load(f)
            except OSError:
                out[name] = None
    try:
        found = json.loads(p.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        out["error"] = (p.stderr.strip().splitlines() or ["no output"])[-1]
        return out
    out["found"] = found
    out["errors"] = errors(
        truth, found, cycle if robot == "rsi" else MODBUS_CYCLE, out["run_e2e"], out.get("run_e2e_no_lag")
    )
    return out


def run_end_to_end(bag: str, lag: float) -> dict:
    """The run's own loop delay [s], from its bag, by code independent of calibrate's: the /robot/command
    setpoints held from their ticks, through the hidden first-order lag (exact on a 0.1 ms grid; a lag and a
    delay commute, so it is filtered once), shifted by d on a 0.1 ms grid against the /robot/state poses at
    their ticks over the steps and the chirp; the best d over the whole of them, and over 0.5 s windows
    (where the pose moves) their median and 95th percentile."""
    import numpy as np
    from scipy.signal import lfilter

    from dockhil.bags.reader import BagReader

    cmd, state, phases = [], [], []
    with BagReader(bag) as reader:
        for topic, _t, msg in reader.decoded():
            if topic == "/robot/command":
                cmd.append((msg.header.stamp, msg.pose.position.x))
            elif topic == "/robot/state":
                state.append((msg.header.stamp, msg.pose.position.x))
            elif topic == "/calibration/phase":
                phases.append((msg.header.stamp, msg.state))
    phases.sort()
    names = [p for _t, p in phases]
    begin = next(t for t, p in phases if p == "steps")
    end = next(t for t, p in phases[names.index("chirp") + 1 :])
    c, s = np.array(sorted(cmd)), np.array(sorted(state))
    c = c[(c[:, 0] >= begin) & (c[:, 0] < end)]
    s = s[(s[:, 0] >= begin) & (s[:, 0] < end)]
    grid = np.arange(c[0, 0], s[-1, 0] + 1e-4, 1e-4)
    x0 = s[0, 1]
    u = c[np.clip(np.searchsorted(c[:, 0], grid, side="right") - 1, 0, None), 1] - x0
    if lag > 0:
        a = math.exp(-1e-4 / lag)
        u = lfilter([0.0, 1.0 - a], [1.0, -a], u)
    shifts = np.arange(0.0, 0.3, 1e-4)

    def best(rows) -> float:
        costs = [float(np.sum((np.interp(rows[:, 0] - d, grid, u, left=0.0) + x0 - rows[:, 1]) ** 2)) for d in shifts]
        return float(shifts[int(np.argmin(costs))])

    whole = best(s)
    windows = []
    for start in np.arange(s[0, 0], s[-1, 0], 0.5):
        rows = s[(s[:, 0] >= start) & (s[:, 0] < start + 0.5)]
        if len(rows) >= 20 and np.ptp(rows[:, 1]) >= 2e-4:
            windows.append(best(rows))
    return {
        "whole_s": whole,
        "median_s": float(np.median(windows)) if windows else whole,
        "p95_s": float(np.percentile(windows, 95.0)) if windows else whole,
        "windows": len(windows),
    }


def lag_held(found: dict) -> bool:
    """Whether calibrate separated the lag from the delay (where it did not, lag_s is 0 and the delay holds it)."""
    return "lag_not_identified" not in found.get("fit", {})


def errors(
    truth: dict, found: dict, cycle: float = MODBUS_CYCLE, run_e2e: dict | None = None, no_lag: dict | None = None
) -> dict:
    """Identified minus hidden. The delay is the robot's own, timed at the device (delay_s); the link to
    the device and back (link_s) is measured apart, so the bound here is the robot's: from the identified
    delay_s + lag_s against the hidden delay + lag. The emulator acts on whole cycles of `cycle`: its
    effective delay is the hidden one rounded up to a cycle, which calibrate reports less half a cycle.
    A split calibrate reports as not identified (delay_s None) leaves the robot's delay errors None. Where
    calibrate does not separate the lag (its delay holds it), the run's own delay is read with no lag too
    (`no_lag`): the same quantity by this bench's code."""
    effective = math.ceil(truth["delay"] / cycle - 1e-9) * cycle
    m = M1 * M2 / (M1 + M2)
    split = found["delay_s"] is not None
    true_bound = exact_bound(m, BCS, truth["delay"] + truth["lag"]).k_max
    effective_bound = exact_bound(m, BCS, effective + truth["lag"]).k_max
    bias_sd = [
        abs(f - t) / truth["noise"] if truth["noise"] else math.inf * (abs(f - t) > 0.01)
        for f, t in zip(found["bias_N"], truth["bias"])
    ]
    e2e = run_e2e if run_e2e and "p95_s" in run_e2e else None
    hidden_lag = truth["lag"]
    if not lag_held(found) and no_lag and "p95_s" in no_lag:
        e2e, hidden_lag = no_lag, 0.0
    out = {
        "delay_ms": None,
        "delay_cycles": None,
        "effective_delay_ms": None,
        "bound_rel": None,
        "bound_cycle_top_rel": None,
        "lag_ms": 1e3 * (found["lag_s"] - truth["lag"]),
        "lag_rel": found["lag_s"] / truth["lag"] - 1.0,
        "k_rel": found["k_N_per_m"] / truth["k"] - 1.0,
        "b_Ns_per_m": None if found["b_Ns_per_m"] is None else found["b_Ns_per_m"] - truth["b"],
        "bias_in_noise_sd": max(bias_sd),
        "noise_rel": (found["noise_N"][0] / truth["noise"] - 1.0) if truth["noise"] else found["noise_N"][0],
        "link_ms": 1e3 * found["link_s"] if found.get("link_s") is not None else None,
        # the loop's delay against the run's own (its bag) and against the hidden robot delay
        "loop_vs_run_p95_cycles": (found["loop_delay_s"] - e2e["p95_s"]) / cycle if e2e else None,
        "loop_vs_run_whole_cycles": (found["loop_delay_s"] - e2e["whole_s"]) / cycle if e2e else None,
        # with the lag each fit held (calibrate's, the hidden one): a fit may trade some of one for the other
        "loop_and_lag_vs_run_p95_cycles": (found["loop_delay_s"] + found["lag_s"] - e2e["p95_s"] - hidden_lag) / cycle
        if e2e
        else None,
        "loop_minus_hidden_ms": 1e3 * (found["loop_delay_s"] - truth["delay"]),
        # the bound the verdict's loop gives (loop_delay_s + lag_s) against the one of the loop the run had
        "loop_bound_rel": exact_bound(m, BCS, found["loop_delay_s"] + found["lag_s"]).k_max
        / exact_bound(m, BCS, e2e["p95_s"] + hidden_lag).k_max
        - 1.0
        if e2e
        else None,
        "run_p95_minus_whole_ms": 1e3 * (e2e["p95_s"] - e2e["whole_s"]) if e2e else None,
        # where the split is not identified: the hidden delay's margins inside the range calibrate gives
        "range_low_margin_ms": 1e3 * (truth["delay"] - found["delay_range_s"][0])
        if found.get("delay_range_s")
        else None,
        "range_high_margin_ms": 1e3 * (found["delay_range_s"][1] - truth["delay"])
        if found.get("delay_range_s")
        else None,
    }
    if split:
        found_bound = exact_bound(m, BCS, found["delay_s"] + found["lag_s"]).k_max
        # at the cycle's top, as the verdict also judges it, against the emulator's effective delay
        top_bound = exact_bound(m, BCS, found["delay_s"] + 0.5 * cycle + found["lag_s"]).k_max
        out.update(
            delay_ms=1e3 * (found["delay_s"] - truth["delay"]),
            delay_cycles=(found["delay_s"] - truth["delay"]) / cycle,
            effective_delay_ms=1e3 * (found["delay_s"] + 0.5 * cycle - effective),
            bound_rel=found_bound / true_bound - 1.0,
            bound_cycle_top_rel=top_bound / effective_bound - 1.0,
        )
    return out


def summary(done: list[dict], key: str) -> dict:
    """Median, worst (largest magnitude, with its sign) and range of one error over the identified draws."""
    values = sorted(r["errors"][key] for r in done if r["errors"][key] is not None)
    if not values:
        return {"median": None, "worst": None, "min": None, "max": None}
    return {
        "median": values[len(values) // 2]
        if len(values) % 2
        else 0.5 * (values[len(values) // 2 - 1] + values[len(values) // 2]),
        "worst": max(values, key=abs),
        "min": values[0],
        "max": values[-1],
    }


def count(done: list[dict], key: str, ok) -> int:
    """How many identified draws have the error `key` and pass `ok` on it."""
    return sum(r["errors"][key] is not None and bool(ok(r["errors"][key])) for r in done)


def summarize(rows: list[dict], robot: str, timing: str, cycle: float, realtime: bool) -> dict:
    """One configuration's pass counts, medians and worst cases over its draws that calibrate identified on a
    valid run (exit 0: a run that fell behind real time, exit 3, prints its fits but writes no loop file)."""
    done = [r for r in rows if "errors" in r and r["exit"] == 0]
    held = [r for r in done if lag_held(r["found"])]  # the lag separated from the delay
    half = 1e3 * 0.5 * cycle
    within = lambda v: abs(v) <= 1.0  # noqa: E731 (one device cycle)
    return {
        "draws": len(rows),
        "identified": len(done),
        "invalid_runs": sum(r["exit"] == 3 for r in rows),
        "seeds": [r.get("seed") for r in rows],
        "exit_codes": [r["exit"] for r in rows],
        "b_not_identified": sum(r["found"]["b_Ns_per_m"] is None for r in done),
        "split_not_identified": sum(r["found"]["delay_s"] is None for r in done),
        "attempts": [r["attempts"] for r in rows],
        "realtime": realtime,
        "robot": robot,
        "emulator_timing": timing,
        "device_cycle_ms": 1e3 * cycle,
        "loop_delay_within_one_cycle_of_run_p95": count(done, "loop_vs_run_p95_cycles", within),
        "loop_delay_within_one_cycle_of_run_whole": count(done, "loop_vs_run_whole_cycles", within),
        "loop_delay_and_lag_within_one_cycle_of_run_p95": count(done, "loop_and_lag_vs_run_p95_cycles", within),
        "loop_delay_not_below_hidden": count(done, "loop_minus_hidden_ms", lambda v: v >= 0.0),
        "timing": sorted({r["found"].get("timing", "") for r in done}),
        "delay_within_1ms": count(done, "delay_ms", lambda v: abs(v) <= 1.0),
        "delay_within_half_cycle": count(done, "delay_ms", lambda v: abs(v) <= half + 1e-6),
        # of the lags calibrate separated from the delay
        "lag_not_identified": len(done) - len(held),
        "lag_within_5pct_or_0.5ms": sum(
            abs(r["errors"]["lag_rel"]) <= 0.05 or abs(r["errors"]["lag_ms"]) <= 0.5 for r in held
        ),
        "lag_within_5pct_or_half_cycle": sum(
            abs(r["errors"]["lag_rel"]) <= 0.05 or abs(r["errors"]["lag_ms"]) <= half for r in held
        ),
        "hidden_delay_within_delay_range": sum(
            r["errors"].get("range_low_margin_ms") is not None
            and r["errors"]["range_low_margin_ms"] >= 0.0
            and r["errors"]["range_high_margin_ms"] >= 0.0
            for r in done
        ),
        "k_within_1pct": count(done, "k_rel", lambda v: abs(v) <= 0.01),
        "bias_within_1_noise_sd": count(done, "bias_in_noise_sd", lambda v: v <= 1.0),
        "bound_within_2pct": count(done, "bound_rel", lambda v: abs(v) <= 0.02),
        "bound_cycle_top_within_2pct": count(done, "bound_cycle_top_rel", lambda v: abs(v) <= 0.02),
        "loop_bound_within_2pct": count(done, "loop_bound_rel", lambda v: abs(v) <= 0.02),
        **{
            name: summary(done, key)
            for name, key in (
                ("delay_error_ms", "delay_ms"),
                ("delay_error_cycles", "delay_cycles"),
                ("effective_delay_error_ms", "effective_delay_ms"),
                ("lag_error_ms", "lag_ms"),
                ("lag_rel_error", "lag_rel"),
                ("k_rel_error", "k_rel"),
                ("bias_error_noise_sd", "bias_in_noise_sd"),
                ("bound_rel_error", "bound_rel"),
                ("bound_cycle_top_rel_error", "bound_cycle_top_rel"),
                ("loop_bound_rel_error", "loop_bound_rel"),
                ("b_error_Ns_per_m", "b_Ns_per_m"),
                ("link_ms", "link_ms"),
                ("loop_delay_vs_run_p95_cycles", "loop_vs_run_p95_cycles"),
                ("loop_delay_vs_run_whole_cycles", "loop_vs_run_whole_cycles"),
                ("loop_delay_and_lag_vs_run_p95_cycles", "loop_and_lag_vs_run_p95_cycles"),
                ("loop_delay_minus_hidden_ms", "loop_minus_hidden_ms"),
                ("run_p95_minus_whole_ms", "run_p95_minus_whole_ms"),
                ("delay_range_low_margin_ms", "range_low_margin_ms"),
                ("delay_range_high_margin_ms", "range_high_margin_ms"),
            )
        },
        "wall_s_max": max((r["wall_s"] for r in rows), default=None),
        "max_force_N": max(((r["ft_maxima"] or {}).get("max_force_N", 0.0) for r in rows), default=None),
        "force_limit_N": MAX_FORCE,
        "max_speed_m_s": max(
            (
                (r["robot_maxima"] or {}).get("max_speed_m_s", (r["robot_maxima"] or {}).get("max_speed", 0.0))
                for r in rows
            ),
            default=None,
        ),
        "actual_speed_limit_m_s": MAX_ACTUAL_SPEED,
        "setpoint_speed_limit_m_s": MAX_SPEED,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-realtime", action="store_true", help="run calibrate without --realtime")
    ap.add_argument("--robot", choices=("modbus", "rsi"), default="modbus", help="the robot driver and its emulator")
    ap.add_argument("--rsi-cycle", type=float, choices=(0.004, 0.012), default=0.004, help="RSI cycle [s]")
    ap.add_argument(
        "--timing",
        choices=("ours", "immediate"),
        default="ours",
        help="the emulated controller's timing: where inside it the cycles are spent",
    )
    ap.add_argument(
        "--configs",
        help="robot:timing,... to run in turn, --draws each (e.g. rsi:ours,rsi:immediate,modbus:ours,modbus:immediate)",
    )
    ap.add_argument("--rows", metavar="ROWS.jsonl", help="append each draw's row here as it ends")
    ap.add_argument("--from-rows", nargs="+", metavar="ROWS.jsonl", help="summarise these rows; run nothing")
    ap.add_argument("--keep", metavar="DIR", help="keep each draw's bag and loop file in DIR")
    args = ap.parse_args()
    realtime = not args.no_realtime
    configs = [tuple(c.split(":")) for c in args.configs.split(",")] if args.configs else [(args.robot, args.timing)]
    for robot, timing in configs:
        if robot not in ("modbus", "rsi") or timing not in ("ours", "immediate"):
            ap.error(f"--configs: {robot}:{timing} is no robot:timing (robots modbus, rsi; timings ours, immediate)")
    if args.keep:
        os.makedirs(args.keep, exist_ok=True)
    rows: list[dict] = []
    if args.from_rows:
        for path in args.from_rows:
            with open(path) as f:
                rows += [json.loads(line) for line in f if line.strip()]
        for r in rows:  # judged again, by this bench's criteria
            if "found" in r:
                r["errors"] = errors(r["truth"], r["found"], r["cycle_s"], r["run_e2e"], r.get("run_e2e_no_lag"))
        configs = sorted({(r["robot"], r["emulator_timing"]) for r in rows}, key=lambda c: (c[0] != "rsi", c))
        realtime = all(r.get("realtime", True) for r in rows)
    else:
        # seed by seed, each configuration in turn: a run stopped early has all of them alike
        for seed in range(args.seed, args.seed + args.draws):
            for robot, timing in configs:
                cycle = args.rsi_cycle if robot == "rsi" else MODBUS_CYCLE
                keep = os.path.join(args.keep, f"{robot}-{timing}-{seed}") if args.keep else None
                row = run(
                    draw(seed),
                    realtime,
                    robot=robot,
                    cycle=cycle,
                    timing=timing,
                    bag_out=keep and keep + ".mcap",
                    loop_out=keep and keep + ".yaml",
                )
                row.update(seed=seed, robot=robot, emulator_timing=timing, cycle_s=cycle, realtime=realtime)
                rows.append(row)
                if args.rows:
                    with open(args.rows, "a") as f:
                        f.write(json.dumps(row) + "\n")
    summaries = {}
    for robot, timing in configs:
        mine = [r for r in rows if r["robot"] == robot and r["emulator_timing"] == timing]
        cycle = mine[0]["cycle_s"] if mine else (args.rsi_cycle if robot == "rsi" else MODBUS_CYCLE)
        summaries[f"{robot}:{timing}"] = summarize(mine, robot, timing, cycle, realtime)
    if len(summaries) == 1 and not args.configs and not args.from_rows:
        print(json.dumps({**next(iter(summaries.values())), "runs": rows}))
    else:
        print(json.dumps({"configs": summaries, "runs": rows}))


if __name__ == "__main__":
    main()
