"""Restitution in wall time against the same scene in sim time with the same loop: hil.yaml with the Net F/T
and KUKA RSI emulators (ft_noise 0.2 N) in wall time, then the simulated robot and sensor in sim time at
the loop that wall-time run had. The loop is one delay from the commanded pose to the measured force
(dockhil/analysis/summary/contact_delay.py), read from each run's own bag: the hardware run's (the robot's
servo delay, the controller's cycle and timing, the link, the sensor's stream and the graph's hops), and
the simulated run's at the told delay, whose difference to its `delay:=` is the simulated hops'. The sim
run's `delay:=` is the wall run's loop delay less those hops, its rate the wall run's; its summary's force
band is the same (the same ft_noise). Prints one JSON object: per run the wall restitution, the sim
restitution at that loop and their relative difference (and the sim at the told delay, for contrast), and
the median and max over the runs.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from dockhil.analysis.summary import contact_delay  # noqa: E402
from dockhil.analysis.summary.common import BAND_SIGMAS  # noqa: E402

HARDWARE = ["ft:=netft", "robot:=rsi", "emulators:=true"]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch(args: list[str], summary: str, bag: str) -> tuple[int, dict, str]:
    env = {**os.environ, "PYTHONPATH": ROOT}
    cmd = [sys.executable, "-m", "dockhil.cli", "launch", os.path.join(ROOT, "launch", "hil.yaml"), *args]
    cmd += ["--summary", summary, "--bag", bag]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    out = {}
    if os.path.exists(summary):
        with open(summary) as f:
            out = json.load(f)
        os.remove(summary)
    lines = (p.stdout + p.stderr).strip().splitlines()
    said = [ln for ln in lines if "INVALID" in ln or "error:" in ln] or lines[-1:]
    return p.returncode, out, said[0] if p.returncode and said else ""


def rel(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else round(abs(a - b) / abs(b), 5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--rate", type=float, default=1000.0, help="the graph's rate in both runs [Hz]")
    ap.add_argument("--delay", type=float, default=0.032, help="the told delay: the emulated robot's servo delay")
    ap.add_argument("--ft-noise", type=float, default=0.2)
    ap.add_argument("--timing", default="ours", choices=("ours", "immediate"))
    ap.add_argument("--busy", type=int, default=0, help="busy loops beside the wall-time graph")
    ap.add_argument("--no-realtime", action="store_true", help="the wall run without --realtime")
    a = ap.parse_args()
    scene = [f"rate:={a.rate:g}", f"ft_noise:={a.ft_noise:g}"]
    sim = [*scene, "allow_coarse:=true"]  # a loop near its edge: the sampled check asks for a finer rate
    band = BAND_SIGMAS * a.ft_noise
    result: dict = {"rate": a.rate, "told_delay_s": a.delay, "ft_noise": a.ft_noise, "timing": a.timing}
    with tempfile.TemporaryDirectory() as tmp:
        s = os.path.join(tmp, "summary.json")
        bag = os.path.join(tmp, "sim_told.mcap")
        _, told, _ = launch([*sim, f"delay:={a.delay:g}"], s, bag)
        hops = contact_delay.from_bag(bag, band).delay_s - a.delay  # the simulated loop's own hops
        result["sim_told_restitution"] = told.get("restitution")
        result["sim_hops_s"] = round(hops, 5)
        runs = []
        for r in range(a.runs):
            busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.busy)]
            try:
                bag = os.path.join(tmp, f"wall{r}.mcap")
                ports = [
                    f"rsi_port:={free_port()}",
                    f"netft_port:={free_port()}",
                ]  # another graph may hold the defaults
                wall_args = [
                    *HARDWARE,
                    *ports,
                    *scene,
                    f"delay:={a.delay:g}",
                    f"robot_timing:={a.timing}",
                    "--wall-time",
                ]
                code, wall, line = launch(wall_args + ([] if a.no_realtime else ["--realtime"]), s, bag)
            finally:
                for p in busy:
                    p.kill()
                    p.wait()
            run: dict = {"exit": code, "valid": wall.get("valid"), "wall_restitution": wall.get("restitution")}
            if line:
                run["last_line"] = line
            try:
                loop = contact_delay.from_bag(bag, band)
            except contact_delay.NoContactError as exc:
                run["no_loop"] = str(exc)
                runs.append(run)
                continue
            sim_delay = round(loop.delay_s - hops, 5)
            sim_bag = os.path.join(tmp, f"sim{r}.mcap")
            _, got, _ = launch([*sim, f"delay:={sim_delay:g}"], s, sim_bag)
            run.update(
                wall_loop_delay_s=round(loop.delay_s, 5),
                sim_delay_arg_s=sim_delay,
                sim_loop_delay_s=round(contact_delay.from_bag(sim_bag, band).delay_s, 5),
                sim_restitution=got.get("restitution"),
                rel_diff=rel(wall.get("restitution"), got.get("restitution")),
                rel_diff_told=rel(wall.get("restitution"), told.get("restitution")),
            )
            runs.append(run)
    diffs = [r["rel_diff"] for r in runs if r.get("rel_diff") is not None]
    valid = [r["rel_diff"] for r in runs if r.get("rel_diff") is not None and r["valid"]]
    result.update(
        runs=runs,
        rel_diff_median=statistics.median(diffs) if diffs else None,
        rel_diff_max=max(diffs) if diffs else None,
        valid_runs=len(valid),
        rel_diff_max_valid=max(valid) if valid else None,
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
