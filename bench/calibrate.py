"""dockhil calibrate against emulators with hidden truths: prints one JSON line.

    python3 bench/calibrate.py [--draws 20] [--seed 0] [--no-realtime]

Each draw hides a delay (16-120 ms), a lag (0-20 ms), a stiffness (1000 N/m +-30 %), a damping
(0-50 N s/m), a surface (0-20 mm ahead), a noise (0-0.5 N) and a bias (|F| up to 5 N, and a torque)
in the Modbus robot and CAN F/T emulators, runs `dockhil calibrate` on them (wall time, the real
drivers in between) and compares: the delay's error (identified minus the emulator's servo delay:
the link's own latency is part of the loop's delay, so this is positive by that much), the lag's,
k's relative error, the bias's error in noise standard deviations, and the relative error of the
exact stiffness bound (hil.yaml's m, bcs) computed from the identified loop against the one from
the emulator's delay + lag. The emulators' recorded maxima show the run kept the scene's limits.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rig(folder: str, truth: dict, port: int) -> str:
    """A scene of the hardware loop on emulators hiding `truth`; the emulators write their maxima to
    folder/ft_maxima.json and folder/robot_maxima.json."""
    channel = os.path.join(folder, "ft.slcan")
    fb, tb = truth["bias"], truth["torque_bias"]
    ft = {
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
    robot = {
        "port": port,
        "delay": truth["delay"],
        "tau": truth["lag"],
        "maxima": os.path.join(folder, "robot_maxima.json"),
    }
    nodes = [
        {"name": "dynamics", "node": "satellite_dynamics", "params": {"m1": M1, "m2": M2}},
        {"name": "impedance", "node": "virtual_impedance", "params": {"m1": M1, "m2": M2, "kcs": KCS, "bcs": BCS}},
        {
            "name": "robot",
            "node": "robot_modbus",
            "params": {
                "port": port,
                "max_force": MAX_FORCE,
                "max_speed": MAX_SPEED,
                "ft_timeout": 0.2,
                "max_actual_speed": MAX_ACTUAL_SPEED,
            },
        },
        {"name": "ft", "node": "ft_can", "params": {"channel": channel}},
        {"name": "ft_emulator", "node": "ft_emulator", "params": ft},
        {"name": "robot_emulator", "node": "robot_emulator", "params": robot},
    ]
    path = os.path.join(folder, "rig.yaml")
    with open(path, "w") as f:
        json.dump({"description": "emulated hardware with hidden truths", "rate": 1000.0, "nodes": nodes}, f)
    return path


# A busy machine can starve the drivers past their watchdogs: a valid safety stop, not a calibration
# result; such a run is tried again (the attempts are counted). So is one whose F/T emulator, stopped with
# the graph, closed its link before the driver stopped reading it ("while stopping").
BUSY = (
    "ft_timeout: no F/T data",
    "stale data: no new sample",
    "safety stop: stall:",
    "s old > max_age",
    "INVALID",
    "while stopping",
)


def run(truth: dict, realtime: bool = True, attempts: int = 3, bag_out: str | None = None) -> dict:
    """One calibration against emulators hiding `truth`, tried up to `attempts` times while a busy machine
    stops it (BUSY)."""
    for attempt in range(1, attempts + 1):
        out = run_once(truth, realtime, bag_out=bag_out)
        out["attempts"] = attempt
        if out["exit"] == 0 or not any(b in out.get("stderr_tail", "") for b in BUSY):
            break
    return out


def run_once(truth: dict, realtime: bool = True, timeout: float = 120.0, bag_out: str | None = None) -> dict:
    """One calibration against emulators hiding `truth`: its JSON, exit code, wall time, the emulators' maxima
    and the errors (bag_out: keep the run's recording there, replacing an earlier one)."""
    if bag_out and os.path.exists(bag_out):
        os.remove(bag_out)
    with tempfile.TemporaryDirectory(prefix="dockhil-calibrate-bench-") as folder:
        scene = rig(folder, truth, free_port())
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
                *(["--bag-out", bag_out] if bag_out else []),
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
    out["errors"] = errors(truth, found)
    return out


def errors(truth: dict, found: dict, link: float = 0.0) -> dict:
    """Identified minus hidden; `link` [s]: the link's own latency (a zero-delay controller's identified
    delay), which the *_link errors count as part of the true loop's delay."""
    m = M1 * M2 / (M1 + M2)
    true_bound = exact_bound(m, BCS, truth["delay"] + truth["lag"]).k_max
    link_bound = exact_bound(m, BCS, truth["delay"] + link + truth["lag"]).k_max
    bias_sd = [
        abs(f - t) / truth["noise"] if truth["noise"] else math.inf * (abs(f - t) > 0.01)
        for f, t in zip(found["bias_N"], truth["bias"])
    ]
    return {
        "delay_ms": 1e3 * (found["delay_s"] - truth["delay"]),
        "lag_ms": 1e3 * (found["lag_s"] - truth["lag"]),
        "delay_plus_lag_ms": 1e3 * (found["delay_s"] + found["lag_s"] - truth["delay"] - truth["lag"]),
        "k_rel": found["k_N_per_m"] / truth["k"] - 1.0,
        "b_Ns_per_m": found["b_Ns_per_m"] - truth["b"],
        "bias_in_noise_sd": max(bias_sd),
        "noise_rel": (found["noise_N"][0] / truth["noise"] - 1.0) if truth["noise"] else found["noise_N"][0],
        "bound_rel": found["kcs_max_N_per_m"] / true_bound - 1.0,
        "delay_link_ms": 1e3 * (found["delay_s"] - truth["delay"] - link),
        "bound_rel_link": found["kcs_max_N_per_m"] / link_bound - 1.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-realtime", action="store_true", help="run calibrate without --realtime")
    args = ap.parse_args()
    realtime = not args.no_realtime
    # The link's own latency: a controller without delay or lag, identified the same way.
    zero = run(
        {
            "delay": 0.0,
            "lag": 0.0,
            "k": 1000.0,
            "b": 0.0,
            "surface": 0.01,
            "noise": 0.1,
            "bias": [0.0] * 3,
            "torque_bias": [0.0] * 3,
        },
        realtime,
    )
    link = zero["found"]["delay_s"] if "found" in zero else 0.0
    rows = [run(draw(args.seed + i), realtime) for i in range(args.draws)]
    done = [r for r in rows if "errors" in r]
    for r in done:
        r["errors"] = errors(r["truth"], r["found"], link)

    def worst(key):
        return max((abs(r["errors"][key]) for r in done), default=None)

    def mean(key):
        return sum(r["errors"][key] for r in done) / len(done) if done else None

    def around_median(key):
        values = sorted(r["errors"][key] for r in done)
        median = values[len(values) // 2] if values else None
        return {"median": median, "max_abs_from_median": max((abs(v - median) for v in values), default=None)}

    # The loop's true delay + lag taken as the emulator's plus the link's (the median offset over the draws).
    offset = around_median("delay_plus_lag_ms")["median"]
    m = M1 * M2 / (M1 + M2)
    for r in done:
        t, f = r["truth"], r["found"]
        r["errors"]["bound_rel_median_link"] = (
            f["kcs_max_N_per_m"] / exact_bound(m, BCS, t["delay"] + t["lag"] + 1e-3 * offset).k_max - 1.0
        )

    print(
        json.dumps(
            {
                "draws": len(rows),
                "identified": len(done),
                "exit_codes": [r["exit"] for r in rows],
                "attempts": [r["attempts"] for r in rows],
                "realtime": realtime,
                "link_latency_ms": 1e3 * link,
                "link_lag_ms": 1e3 * zero["found"]["lag_s"] if "found" in zero else None,
                "delay_offset_ms": around_median("delay_ms"),
                "delay_plus_lag_offset_ms": around_median("delay_plus_lag_ms"),
                "delay_error_after_link_ms": {"mean": mean("delay_link_ms"), "max_abs": worst("delay_link_ms")},
                "bound_rel_error_after_link": {"mean": mean("bound_rel_link"), "max_abs": worst("bound_rel_link")},
                "bound_rel_error_after_median_link": {
                    "mean": mean("bound_rel_median_link"),
                    "max_abs": worst("bound_rel_median_link"),
                },
                "delay_error_ms": {
                    "mean": mean("delay_ms"),
                    "max_abs": worst("delay_ms"),
                    "min": min((r["errors"]["delay_ms"] for r in done), default=None),
                },
                "lag_error_ms": {"mean": mean("lag_ms"), "max_abs": worst("lag_ms")},
                "delay_plus_lag_error_ms": {"mean": mean("delay_plus_lag_ms"), "max_abs": worst("delay_plus_lag_ms")},
                "k_rel_error_max_abs": worst("k_rel"),
                "bias_error_max_noise_sd": worst("bias_in_noise_sd"),
                "bound_rel_error": {"mean": mean("bound_rel"), "max_abs": worst("bound_rel")},
                "b_error_Ns_per_m_max_abs": worst("b_Ns_per_m"),
                "wall_s_max": max(r["wall_s"] for r in rows),
                "max_force_N": max((r["ft_maxima"] or {}).get("max_force_N", 0.0) for r in rows),
                "force_limit_N": MAX_FORCE,
                "max_speed_m_s": max((r["robot_maxima"] or {}).get("max_speed_m_s", 0.0) for r in rows),
                "actual_speed_limit_m_s": MAX_ACTUAL_SPEED,
                "setpoint_speed_limit_m_s": MAX_SPEED,
                "runs": rows,
            }
        )
    )


if __name__ == "__main__":
    main()
