"""The robot's path against the commanded motion: hil.yaml with the Net F/T and KUKA RSI emulators in wall
time (--realtime), beside busy loops; per controller cycle, the step of the pose the controller took (its
RSol, from /robot/cycles) over the commanded motion per cycle where the commanded path passes that pose
(|commanded velocity| x cycle, where it moves at least 15 mm/s, half the approach speed), and the run's
restitution. The busy loops are this script's and ended after each run. Prints one JSON object: per
timing, the step ratios' p50/p90/max over all runs and each run's, the restitution of each run, and the
same scene's restitution in sim time.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOVING = 0.015  # m/s: a cycle counts where the command moves at least this fast (half the approach)
CYCLE = 0.004


def launch(args: list[str], out: str) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": ROOT}
    cmd = [sys.executable, "-m", "dockhil.cli", "launch", os.path.join(ROOT, "launch", "hil.yaml"), *args]
    cmd += ["--summary", os.path.join(out, "summary.json")]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout + p.stderr


def ratios(bag: str) -> list[float]:
    """Each controller cycle's step over the commanded motion per cycle at the point of the commanded path
    the controller stands at: the command's speed where its path passes the controller's pose, in the same
    direction, the latest such command before the cycle (the path is along x, out and back)."""
    from dockhil.bags.reader import BagReader

    commands, cycles = [], {}
    with BagReader(bag) as b:
        for topic, _t, msg in b.decoded(["/robot/command", "/robot/cycles"]):
            if topic == "/robot/command":
                commands.append((msg.header.stamp, msg.pose.position.x, msg.twist.linear.x))
            else:
                for c in msg.cycles:
                    p = c.setpoint.position
                    cycles[c.device_cycle] = (c.read, (p.x, p.y, p.z))
    commands.sort()
    out = []
    keys = sorted(cycles)
    for a, b in zip(keys, keys[1:]):
        if b - a != 1:
            continue  # the 16-bit count wrapped, or a datagram never came: no consecutive pair
        (_, pa), (t, pb) = cycles[a], cycles[b]
        dx = pb[0] - pa[0]
        speed = None
        for (_, x0, _v0), (t1, x1, v1) in zip(commands, commands[1:]):
            if t1 > t:
                break
            if min(x0, x1) <= pb[0] <= max(x0, x1) and (v1 > 0) == (dx > 0):
                speed = abs(v1)
        if speed is None or speed < MOVING:
            continue
        out.append(math.dist(pa, pb) / (speed * CYCLE))
    return out


def pct(values: list[float], q: float) -> float | None:
    if not values:
        return None
    v = sorted(values)
    return round(v[min(len(v) - 1, int(q / 100 * len(v)))], 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--busy", type=int, default=2, help="busy loops beside the graph")
    ap.add_argument("--timings", default="ours,immediate")
    ap.add_argument("args", nargs="*", help="more launch arguments (name:=value)")
    a = ap.parse_args()
    result: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        code, text = launch(list(a.args), tmp)  # the same scene in sim time
        with open(os.path.join(tmp, "summary.json")) as f:
            result["sim_restitution"] = json.load(f).get("restitution")
        for timing in a.timings.split(","):
            runs, every = [], []
            for r in range(a.runs):
                busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.busy)]
                try:
                    bag = os.path.join(tmp, f"{timing}{r}.mcap")
                    code, text = launch(
                        ["ft:=netft", "robot:=rsi", "emulators:=true", f"robot_timing:={timing}", "rate:=250"]
                        + list(a.args)
                        + ["--wall-time", "--realtime", "--bag", bag],
                        tmp,
                    )
                finally:
                    for p in busy:
                        p.kill()
                        p.wait()
                with open(os.path.join(tmp, "summary.json")) as f:
                    summary = json.load(f)
                got = ratios(bag)
                every += got
                runs.append(
                    {
                        "exit": code,
                        "p50": pct(got, 50),
                        "p90": pct(got, 90),
                        "max": pct(got, 100),
                        "cycles": len(got),
                        "restitution": summary.get("restitution"),
                        "valid": summary.get("valid"),
                        "last_line": text.strip().splitlines()[-1] if code else "",
                    }
                )
            result[timing] = {"p50": pct(every, 50), "p90": pct(every, 90), "max": pct(every, 100), "runs": runs}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
