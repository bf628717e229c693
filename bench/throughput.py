"""Sim-time ticks per second of a small loop graph, multi-process and composed.

Run from the repository root. Times only the ticking: the multi-process
figure subtracts a run of one tick (start-up and shutdown). Prints one JSON
object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def multiprocess_seconds(duration: float) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "dockhil.cli", "launch", os.path.join(HERE, "loop.yaml"),
                    "--duration", str(duration), "--quiet"], check=True, cwd=ROOT,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def composed_seconds(n_ticks: int) -> float:
    sys.path.insert(0, ROOT)
    from dockhil import launchfile
    from dockhil.composed import ComposedGraph
    from dockhil.graph import build

    g = ComposedGraph(build(launchfile.load(os.path.join(HERE, "loop.yaml"))))
    g.setup()
    t0 = time.perf_counter()
    g.run(n_ticks)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per run (default 5)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode; the median is reported")
    args = ap.parse_args()
    n = int(args.seconds * 1000)
    base = statistics.median(multiprocess_seconds(0.001) for _ in range(args.repeat))
    mp = statistics.median(multiprocess_seconds(args.seconds) for _ in range(args.repeat)) - base
    comp = statistics.median(composed_seconds(n) for _ in range(args.repeat))
    print(json.dumps({
        "graph": "bench/loop.yaml (2 nodes, 1 kHz)",
        "ticks": n,
        "multiprocess_ticks_per_s": round(n / mp),
        "composed_ticks_per_s": round(n / comp),
        "multiprocess_startup_s": round(base, 3),
        "composed_over_multiprocess": round(mp / comp, 1),
    }))


if __name__ == "__main__":
    main()
