"""The stability verdict proven on the run: prints one JSON line.

    python3 bench/stability_run.py [--robot rsi|modbus] [--timing ours|immediate] [--seconds 30]
                                   [--delay 0.0231] [--lag 0.004] [--noise 0.2] [--factors 0.75 1.35]

On emulated hardware (the robot's hidden delay not a whole number of its cycles, a lag and F/T noise),
`dockhil calibrate launch/stability.yaml` identifies the loop and gives kcs_max_N_per_m, the largest sheet
stiffness that stays stable for the scene's m and virtual damper b (m 50 kg, b 20 N s/m, 250 Hz: Figs.
11-12's loop). Then the scene runs on the same emulated hardware in wall time with the emulated sheet at
`factors` times that bound: below it the contact's oscillation must decay, above it grow. The run's growth
rate (`growth_rate_1_s` of the launch summary: the envelope of the probe's oscillation) is printed with the
bound and the calibration's own predicted growth rate at that stiffness.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile

SCENE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "launch", "stability.yaml")
M, B, RATE = 50.0, 20.0, 250.0
# A thrust that keeps a growing contact inside the robot driver's limits over the run (max_speed 0.1 m/s:
# 10 N, Figs. 11-12's, starts an oscillation of 10 N / K that, grown, is stopped for speed within 30 s)
THRUST = 2.0


def free_ports(kind: int, n: int) -> list[int]:
    """`n` distinct ports free now (each held while the next is chosen)."""
    sockets = [socket.socket(socket.AF_INET, kind) for _ in range(n)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def hardware(robot: str, timing: str, delay: float, lag: float, noise: float) -> list[str]:
    """The launch arguments of the emulated lab, on ports of its own."""
    (rsi, netft), (tcp,) = free_ports(socket.SOCK_DGRAM, 2), free_ports(socket.SOCK_STREAM, 1)
    ft = "netft" if robot == "rsi" else "can"
    return [
        f"robot:={robot}",
        f"ft:={ft}",
        "emulators:=true",
        f"robot_timing:={timing}",
        f"delay:={delay}",
        f"lag:={lag}",
        f"ft_noise:={noise}",
        f"rsi_port:={rsi}",
        f"netft_port:={netft}",
        f"modbus_port:={tcp}",
        f"m:={M}",
        f"b:={B}",
        f"rate:={RATE}",
        f"thrust:={THRUST}",
    ]


def dockhil(*args: str, timeout: float = 240.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dockhil.cli", *args], capture_output=True, text=True, timeout=timeout)


def calibrate(args: list[str], attempts: int = 2, bag_out: str | None = None) -> dict:
    """The calibration's JSON (`bag_out`: keep its identification run there). An identification run that
    stopped (exit 1: a busy machine may stall a device or an input past its limit; the lines say which) is
    tried again, up to `attempts` in all, as a lab would; each stop's reason is kept in `stopped_attempts`."""
    stops: list[str] = []
    keep = ["--bag-out", bag_out] if bag_out else []
    for _ in range(attempts):
        p = dockhil("calibrate", SCENE, *args, *keep, "--json", "--realtime")
        if p.returncode in (0, 3):  # 3: it fell behind real time (a busy machine); its JSON says run_valid
            return {**json.loads(p.stdout.strip().splitlines()[-1]), "stopped_attempts": stops}
        said = [line for line in p.stderr.splitlines() if "error" in line or "INVALID" in line or "stop" in line]
        stops.append(f"exit {p.returncode}: " + " | ".join(said[-3:] or p.stderr.strip().splitlines()[-1:]))
        if p.returncode != 1:
            break
    raise RuntimeError(f"calibrate stopped {len(stops)} time(s): " + " || ".join(stops))


def growth(bag: str, k: float) -> tuple[float | None, int]:
    """The growth rate [1/s] of the body's oscillation about its equilibrium (thrust / k), from the run's
    bag (/satellite/state, the chaser's x): a line through the log of its peaks (contact/envelope.py), and
    the number of states read. None: fewer than 4 peaks."""
    from dockhil.bags.reader import BagReader
    from dockhil.contact.envelope import growth_rate

    t, x = [], []
    with BagReader(bag) as reader:
        for topic, _t, msg in reader.decoded():
            if topic == "/satellite/state":
                t.append(msg.header.stamp)
                x.append(msg.bodies[0].pose.position.x)
    try:  # on times from the first (in wall time the stamps are Unix times: their squares lose the digits)
        return growth_rate([v - t[0] for v in t], x, about=THRUST / k), len(t)
    except ValueError:
        return None, len(t)


def run(args: list[str], k: float, seconds: float) -> dict:
    """The scene on the emulated lab with the sheet at k, in wall time: its exit, growth rate and the
    simulated time it reached (a growing contact may end in a safety stop: the bag still has its growth)."""
    with tempfile.TemporaryDirectory(prefix="dockhil-stability-run-") as folder:
        bag = os.path.join(folder, "run.mcap")
        p = dockhil(
            "launch",
            SCENE,
            *args,
            f"k:={k}",
            "allow_unstable:=true",
            "--wall-time",
            "--realtime",
            "--duration",
            str(seconds),
            "--quiet",
            "--bag",
            bag,
            timeout=seconds + 120.0,
        )
        try:
            rate, states = growth(bag, k)
        except (OSError, ValueError) as exc:
            return {"exit": p.returncode, "error": f"{bag}: {exc}"}
    stopped = [line for line in p.stderr.splitlines() if "error:" in line or "INVALID" in line]
    return {
        "exit": p.returncode,
        "k_N_per_m": k,
        "growth_rate_1_s": rate,
        "states": states,
        **({"stopped": stopped[0]} if stopped else {}),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", choices=("rsi", "modbus"), default="rsi")
    ap.add_argument("--timing", choices=("ours", "immediate"), default="ours")
    ap.add_argument("--seconds", type=float, default=30.0, help="wall time of each run [s]")
    ap.add_argument("--delay", type=float, default=0.0231, help="the emulated robot's hidden delay [s]")
    ap.add_argument("--lag", type=float, default=0.004, help="its hidden lag [s]")
    ap.add_argument("--noise", type=float, default=0.2, help="the emulated F/T noise [N]")
    ap.add_argument("--factors", type=float, nargs="+", default=[0.75, 1.35])
    a = ap.parse_args()
    args = hardware(a.robot, a.timing, a.delay, a.lag, a.noise)
    found = calibrate(args)
    bound = found["kcs_max_N_per_m"]
    out = {
        "robot": a.robot,
        "emulator_timing": a.timing,
        "hidden_delay_s": a.delay,
        "hidden_lag_s": a.lag,
        "m_kg": M,
        "b_Ns_per_m": B,
        "rate_hz": RATE,
        "seconds": a.seconds,
        "thrust_N": THRUST,
        "calibration_run_valid": found["run_valid"],
        "calibration_stopped_attempts": found["stopped_attempts"],
        "loop_delay_s": found["loop_delay_s"],
        "lag_s": found["lag_s"],
        "verdict_h_s": found["verdict"]["h_s"],
        "kcs_max_N_per_m": bound,
        "runs": [],
    }
    from dockhil.contact.stability import growth_rate

    for factor in a.factors:
        r = run(args, factor * bound, a.seconds)
        r["factor"] = factor
        r["predicted_growth_rate_1_s"] = growth_rate(M, factor * bound, B, found["verdict"]["h_s"], "undelayed")
        out["runs"].append(r)
    out["decays_below_grows_above"] = all(
        r.get("growth_rate_1_s") is not None and (r["growth_rate_1_s"] < 0.0) == (r["factor"] < 1.0)
        for r in out["runs"]
    )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
