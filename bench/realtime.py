"""The real-time loop: launch/hil.yaml at 1 kHz in wall time.

Every node records how late each tick started against its fixed-rate
schedule (jitter), how many ticks overran their period (deadline misses),
and how old each input's newest message was when used. The end-to-end
sensor-to-command latency is the age of /ft/wrench when the dynamics use it
to compute the next command (the command leaves in the same tick).
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="wall seconds to run (default 10)")
    ap.add_argument("--realtime", action="store_true", help="launch with --realtime (SCHED_FIFO node loops)")
    ap.add_argument(
        "--hardware", action="store_true", help="run the real-protocol drivers against the CAN and Modbus emulators"
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        extra = []
        if args.hardware:
            extra = ["ft:=can", "robot:=modbus", "emulators:=true", f"can_channel:={folder}/ft.slcan"]
        env = dict(os.environ, DOCKHIL_TIMING_DIR=folder)
        subprocess.run(
            [
                sys.executable,
                "-m",
                "dockhil.cli",
                "launch",
                os.path.join(ROOT, "launch", "hil.yaml"),
                *extra,
                "--wall-time",
                "--duration",
                str(args.seconds),
                "--quiet",
                *(["--realtime"] if args.realtime else []),
            ],
            check=True,
            cwd=ROOT,
            env=env,
            stdout=subprocess.DEVNULL,
        )
        nodes = {}
        for name in sorted(os.listdir(folder)):
            if name.endswith(".json"):
                with open(os.path.join(folder, name)) as f:
                    nodes[name[:-5]] = json.load(f)
    ticks = sum(n["ticks"] for n in nodes.values())
    misses = sum(n["deadline_misses"] for n in nodes.values())
    worst = lambda key: max(n["jitter_us"].get(key, 0.0) for n in nodes.values())  # noqa: E731
    ft_age = nodes["dynamics"]["input_age_us"].get("ft", {})
    out = {
        "scene": "launch/hil.yaml, 1 kHz, wall time"
        + (", CAN + Modbus emulators" if args.hardware else "")
        + (", SCHED_FIFO" if args.realtime else ""),
        "seconds": args.seconds,
        "nodes": len(nodes),
        "jitter_us_p50": round(worst("p50"), 1),
        "jitter_us_p99": round(worst("p99"), 1),
        "jitter_us_max": round(worst("max"), 1),
        "deadline_miss_ratio": round(misses / ticks, 5) if ticks else None,
        "sensor_to_command_us_p50": round(ft_age.get("p50", float("nan")), 1),
        "sensor_to_command_us_p99": round(ft_age.get("p99", float("nan")), 1),
        "per_node": {
            name: {
                "jitter_us_p99": round(n["jitter_us"].get("p99", 0.0), 1),
                "jitter_us_max": round(n["jitter_us"].get("max", 0.0), 1),
                "worst_tick": n["worst_tick"],
                "deadline_misses": n["deadline_misses"],
                "ticks": n["ticks"],
            }
            for name, n in nodes.items()
        },
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
