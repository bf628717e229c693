"""Sim-time ticks per second of a small loop graph, multi-process and composed.

Run from the repository root. Times only the ticking: the multi-process
figure subtracts a run of one tick (start-up and shutdown). Prints one JSON
object as its last line.

--ring N [N ...]: a ring of N processes (an integrator and N-1 feedthrough
gains) for each N; prints what each added process costs per tick, from a
least-squares line through the ticking time per tick against N, for
multi-process and composed runs.
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


def ring_file(folder: str, n: int) -> str:
    """A loop of n nodes: the integrator reads the last gain; gain i reads node i-1."""
    lines = [
        "description: a ring for throughput",
        "rate: 1000",
        "nodes:",
        f"  - {{name: integ, node: 'tests.support.graphnodes:Integrator', remap: {{x: /r0, u: /r{n - 1}}}}}",
    ]
    for i in range(1, n):
        lines.append(
            f"  - {{name: gain{i}, node: 'tests.support.graphnodes:Gain', params: {{gain: 0.001}}, "
            f"remap: {{x: /r{i - 1}, u: /r{i}}}}}"
        )
    path = os.path.join(folder, f"ring{n}.yaml")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


CPU: list[float] = []  # CPU seconds (user + system) of every process of each multiprocess run


def multiprocess_seconds(duration: float, scene: str = os.path.join(HERE, "loop.yaml")) -> float:
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "dockhil.cli", "launch", scene, "--duration", str(duration), "--quiet"],
        check=True,
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    CPU.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return wall


def composed_seconds(n_ticks: int, scene: str = os.path.join(HERE, "loop.yaml")) -> float:
    sys.path.insert(0, ROOT)
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    g = ComposedGraph(build(launchfile.load(scene)))
    g.setup()
    t0 = time.perf_counter()
    g.run(n_ticks)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per run (default 5)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode; the median is reported")
    ap.add_argument("--ring", type=int, nargs="+", metavar="N", help="ring sizes, e.g. 2 4 8")
    args = ap.parse_args()
    n = int(args.seconds * 1000)
    if args.ring:
        return ring(args.ring, args.seconds, n, args.repeat)
    base = statistics.median(multiprocess_seconds(0.001) for _ in range(args.repeat))
    mp = statistics.median(multiprocess_seconds(args.seconds) for _ in range(args.repeat)) - base
    comp = statistics.median(composed_seconds(n) for _ in range(args.repeat))
    print(
        json.dumps(
            {
                "graph": "bench/loop.yaml (2 nodes, 1 kHz)",
                "ticks": n,
                "multiprocess_ticks_per_s": round(n / mp),
                "composed_ticks_per_s": round(n / comp),
                "multiprocess_startup_s": round(base, 3),
                "composed_over_multiprocess": round(mp / comp, 1),
            }
        )
    )


def _slope(xs: list[float], ys: list[float]) -> float:
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def ring(sizes: list[int], seconds: float, n: int, repeat: int) -> None:
    print(json.dumps(ring_costs(sizes, seconds, n, repeat)))


def ring_costs(sizes: list[int], seconds: float, n: int, repeat: int) -> dict:
    """Per-tick wall and CPU time of rings of each size, and what an added process costs (the slope)."""
    import tempfile

    mp_us, cpu_us, comp_us = {}, {}, {}
    with tempfile.TemporaryDirectory() as folder:
        for size in sizes:
            scene = ring_file(folder, size)
            CPU.clear()
            base = statistics.median(multiprocess_seconds(0.001, scene) for _ in range(repeat))
            base_cpu = statistics.median(CPU)
            CPU.clear()
            mp = statistics.median(multiprocess_seconds(seconds, scene) for _ in range(repeat)) - base
            mp_us[size] = mp / n * 1e6
            cpu_us[size] = (statistics.median(CPU) - base_cpu) / n * 1e6
            comp_us[size] = statistics.median(composed_seconds(n, scene) for _ in range(repeat)) / n * 1e6
    return {
        "graph": "ring of N processes (integrator + N-1 gains, 1 kHz)",
        "ticks": n,
        "multiprocess_us_per_tick": {str(k): round(v, 1) for k, v in mp_us.items()},
        "composed_us_per_tick": {str(k): round(v, 2) for k, v in comp_us.items()},
        "multiprocess_us_per_added_process_per_tick": round(_slope(list(mp_us), list(mp_us.values())), 1),
        # CPU time of all processes: what a shared machine's load does not inflate as much as wall time.
        "multiprocess_cpu_us_per_tick": {str(k): round(v, 1) for k, v in cpu_us.items()},
        "multiprocess_cpu_us_per_added_process_per_tick": round(_slope(list(cpu_us), list(cpu_us.values())), 1),
        "composed_us_per_added_node_per_tick": round(_slope(list(comp_us), list(comp_us.values())), 2),
        "load_average": os.getloadavg()[0],
    }


if __name__ == "__main__":
    main()
