"""Memory of the run summary against the run's length: the composed hil.yaml scene with the
summary collector as its tap, its allocations traced (tracemalloc) over runs of growing
simulated time. Constant memory per run means the peak stays flat. Prints one JSON object."""

from __future__ import annotations

import argparse
import json
import os
import sys
import tracemalloc

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def peak_bytes(seconds: float) -> tuple[int, dict]:
    from dockhil.analysis.summary import SummaryCollector
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    graph = build(launchfile.load(os.path.join(ROOT, "launch", "hil.yaml"), {"delay": "0.032"}))
    collect = SummaryCollector(graph)
    g = ComposedGraph(graph, log=lambda n, m: None, taps=[collect])
    g.setup()
    try:
        tracemalloc.start()
        g.run(int(round(seconds / graph.scene.dt)) + 1)
        out = collect.summary()
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    finally:
        g.close()
    return peak, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, nargs="+", default=[20.0, 200.0], help="simulated run lengths [s]")
    args = ap.parse_args()
    rows = []
    for s in args.seconds:
        peak, out = peak_bytes(s)
        rows.append(
            {
                "sim_time_s": s,
                "peak_traced_kb": round(peak / 1024, 1),
                "peak_force_N": out["peak_force_N"],
                "exit_velocity_mps": out["exit_velocity_mps"],
            }
        )
    print(json.dumps({"bench": "summary_memory", "runs": rows}))


if __name__ == "__main__":
    main()
