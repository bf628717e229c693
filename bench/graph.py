"""Real-time factor of launch/hil.yaml at 1 kHz in sim time: multi-process,
composed, and the model library's bare loop, measured in one run.

multiprocess_rtf counts the whole launch (process start-up included) and
multiprocess_ticking_rtf subtracts a one-tick launch; composed and bare time
the ticking only. Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
HIL = os.path.join(ROOT, "launch", "hil.yaml")


def multiprocess(seconds: float) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "dockhil.cli", "launch", HIL, "--duration", str(seconds), "--quiet"],
                   check=True, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def composed(n_ticks: int) -> float:
    from dockhil import launchfile
    from dockhil.composed import ComposedGraph
    from dockhil.graph import build

    g = ComposedGraph(build(launchfile.load(HIL)), log=lambda n, m: None)
    g.setup()
    t0 = time.perf_counter()
    g.run(n_ticks)
    return time.perf_counter() - t0


def bare(n_ticks: int) -> float:
    from dockhil.contact.hilloop import simulate_hil
    from dockhil.contact.impedance import impedance_closed_form
    from dockhil.contact.scenario import ContactScenario

    imp = impedance_closed_form(ContactScenario(750.0, 1e6, 3000.0, 40.0, 1000.0, 0.03, 0.0))
    t0 = time.perf_counter()
    simulate_hil(m1=750.0, m2=1e6, k=1000.0, impedance=imp, dt=1e-3, n_ticks=n_ticks, v1=0.03, delay=0.032)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per run (default 10)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode; medians are reported")
    args = ap.parse_args()
    n = int(round(args.seconds * 1000)) + 1
    start = statistics.median(multiprocess(0.001) for _ in range(args.repeat))
    mp = statistics.median(multiprocess(args.seconds) for _ in range(args.repeat))
    comp = statistics.median(composed(n) for _ in range(args.repeat))
    bl = statistics.median(bare(n) for _ in range(args.repeat))
    out = {
        "scene": "launch/hil.yaml, 1 kHz, sim time",
        "sim_seconds": args.seconds,
        "multiprocess_rtf": round(args.seconds / mp, 2),
        "multiprocess_ticking_rtf": round(args.seconds / (mp - start), 2),
        "multiprocess_startup_s": round(start, 3),
        "composed_rtf": round(args.seconds / comp, 1),
        "bare_rtf": round(args.seconds / bl, 1),
        "bare_over_composed": round(comp / bl, 2),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
