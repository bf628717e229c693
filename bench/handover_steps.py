"""The robot's path against the commanded motion: hil.yaml with the Net F/T emulator and the KUKA RSI or
Modbus controller emulator in wall time (--realtime), beside busy loops; per controller cycle, the step of
the pose the controller took over the commanded motion per cycle where the commanded path passes that pose
(|commanded velocity| x cycle, where it moves at least 15 mm/s, half the approach speed), and the run's
restitution. RSI: each cycle's RSol (the correction the controller holds, from /robot/cycles), on
consecutive cycles. Modbus: the controller (1 ms) takes the setpoint written on each of the link's
exchanges (every 2 ms or so) and holds it between them, so a step is between two consecutive takes, over
the commanded motion in the controller cycles between them; a take is the cycle the controller read back
with its echo of the write's heartbeat (`taken`), else the cycle after the one read. The busy loops are
this script's and ended after each run. Prints one JSON object: per robot and timing, the step ratios'
p50/p90/max over all runs and each run's, the restitution of each run, and the same scene's restitution
in sim time.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOVING = 0.015  # m/s: a cycle counts where the command moves at least this fast (half the approach)
CYCLES = {"rsi": 0.004, "modbus": 0.001}  # s: the emulated controllers' cycles (hil.yaml's defaults)
MAX_TAKE_GAP = 10  # Modbus: consecutive takes farther apart (a stall, a reconnect) are no step of the hand-over


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch(args: list[str], out: str) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": ROOT}
    cmd = [sys.executable, "-m", "dockhil.cli", "launch", os.path.join(ROOT, "launch", "hil.yaml"), *args]
    cmd += ["--summary", os.path.join(out, "summary.json")]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout + p.stderr


def ratios(bag: str, robot: str = "rsi") -> list[float]:
    """Each controller cycle's step over the commanded motion per cycle at the point of the commanded path
    the controller stands at: the command's speed where its path passes the controller's pose, in the same
    direction, the latest such command before the cycle (the path is along x, out and back). Modbus: each
    step between consecutive takes, over the commanded motion in the cycles between them: the controller's
    first cycle after a write takes it (ours) or samples the pose that follows it (immediate), known from
    the read-back (the exchanges whose read came within a cycle of the write, so the count read is that
    cycle's, or the one before it when the controller had not echoed the write yet)."""
    from dockhil.bags.reader import BagReader

    commands, takes = [], {}  # takes: the controller's cycle (a float: immediate) -> (read, setpoint)
    cycle = CYCLES[robot]
    base = None  # Modbus: the 16-bit cycle count unwrapped from the first exchange's
    with BagReader(bag) as b:
        for topic, _t, msg in b.decoded(["/robot/command", "/robot/cycles"]):
            if topic == "/robot/command":
                commands.append((msg.header.stamp, msg.pose.position.x, msg.twist.linear.x))
                continue
            for c in msg.cycles:
                p = c.setpoint.position
                if robot == "rsi":
                    takes[c.device_cycle] = (c.read, (p.x, p.y, p.z))
                    continue
                base = c.device_cycle if base is None else base + ((c.device_cycle - base) & 0xFFFF)
                if not c.written:
                    continue
                if c.read - c.sent <= cycle:
                    # the later write of one cycle is the one the controller took there
                    takes[base + (0 if c.taken else 1)] = (c.read, (p.x, p.y, p.z))
    commands.sort()
    out = []
    keys = sorted(takes)
    for a, b in zip(keys, keys[1:]):
        n = b - a
        if n != 1 if robot == "rsi" else n > MAX_TAKE_GAP:
            continue  # the 16-bit count wrapped, or a datagram never came: no consecutive pair
        (_, pa), (t, pb) = takes[a], takes[b]
        dx = pb[0] - pa[0]
        speed = None
        for (_, x0, _v0), (t1, x1, v1) in zip(commands, commands[1:]):
            if t1 > t:
                break
            if min(x0, x1) <= pb[0] <= max(x0, x1) and (v1 > 0) == (dx > 0):
                speed = abs(v1)
        if speed is None or speed < MOVING:
            continue
        out.append(math.dist(pa, pb) / (speed * cycle * n))
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
    ap.add_argument("--robots", default="rsi,modbus")
    ap.add_argument("args", nargs="*", help="more launch arguments (name:=value)")
    a = ap.parse_args()
    result: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        code, text = launch(list(a.args), tmp)  # the same scene in sim time
        with open(os.path.join(tmp, "summary.json")) as f:
            result["sim_restitution"] = json.load(f).get("restitution")
        for robot, timing in ((r, t) for r in a.robots.split(",") for t in a.timings.split(",")):
            runs, every = [], []
            for r in range(a.runs):
                busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.busy)]
                try:
                    bag = os.path.join(tmp, f"{robot}-{timing}{r}.mcap")
                    code, text = launch(
                        ["ft:=netft", f"robot:={robot}", "emulators:=true", f"robot_timing:={timing}", "rate:=250"]
                        # another graph on this machine may hold the default ports
                        + [f"rsi_port:={free_port()}", f"netft_port:={free_port()}"]
                        + [f"modbus_port:={free_port(socket.SOCK_STREAM)}"]
                        + list(a.args)
                        + ["--wall-time", "--realtime", "--bag", bag],
                        tmp,
                    )
                finally:
                    for p in busy:
                        p.kill()
                        p.wait()
                summary = {}
                if os.path.exists(os.path.join(tmp, "summary.json")):
                    with open(os.path.join(tmp, "summary.json")) as f:
                        summary = json.load(f)
                    os.remove(os.path.join(tmp, "summary.json"))
                got = ratios(bag, robot) if os.path.exists(bag) else []
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
            result[f"{robot}-{timing}"] = {
                "p50": pct(every, 50),
                "p90": pct(every, 90),
                "max": pct(every, 100),
                "runs": runs,
            }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
