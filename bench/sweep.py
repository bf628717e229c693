"""Campaign throughput: runs per second for N short runs of stability.yaml on a local
pool of 1 and 2 workers and on a 2-worker Dask LocalCluster, and each executor's
per-run overhead.

Prints one JSON object. Per executor: `wall_s` (the whole sweep: a local pool's
start-up included, a Dask cluster's not: it is `dask_cluster_start_s`), `runs_per_s`, `run_s_mean` (a run's own time,
measured inside the worker) and `overhead_s_per_run` = (wall_s x workers - sum of run
times) / runs: what batching, pickling, scheduling and idle workers cost each run.
`speedup_2_vs_1` and `dask_vs_local_2` are the ratios of runs per second (goals: >= 1.7
and >= 0.8). On a machine busy with other work the ratios come out lower.

    python bench/sweep.py [--runs 200] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from dockhil.analysis import sweep  # noqa: E402


def campaign_file(folder: str, runs: int, duration: float) -> str:
    path = os.path.join(folder, "bench.yaml")
    with open(path, "w") as f:
        f.write(
            f"scene: stability.yaml\nargs: {{m: 20.0, delay: 0.016, b: 150.0}}\nduration: {duration}\n"
            f"grid:\n  k: {{range: [6000, 12000], num: {runs}}}\n"
        )
    return path


def measure(campaign, executor, folder: str, label: str) -> dict:
    out = os.path.join(folder, f"{label}.parquet")
    started = time.perf_counter()
    result = sweep.sweep(campaign, out, executor, progress=False)
    wall = time.perf_counter() - started
    import pyarrow.parquet as pq

    run_times = [t for t in pq.read_table(out).column("run_time_s").to_pylist() if t is not None]
    n = result["executed"]
    return {
        "workers": executor.workers,
        "runs": n,
        "ok": result["ok"],
        "wall_s": round(wall, 3),
        "runs_per_s": round(n / wall, 2),
        "run_s_mean": round(sum(run_times) / len(run_times), 4),
        "overhead_s_per_run": round((wall * executor.workers - sum(run_times)) / n, 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--duration", type=float, default=1.0, help="simulated seconds per run")
    args = ap.parse_args()
    out: dict = {
        "runs": args.runs,
        "duration_s": args.duration,
        "cpus": sweep.usable_cpus(),
        "loadavg_1min": round(os.getloadavg()[0], 2),
    }
    with tempfile.TemporaryDirectory(prefix="dockhil-bench-sweep-") as folder:
        campaign = sweep.load_campaign(campaign_file(folder, args.runs, args.duration))
        out["local_1"] = measure(campaign, sweep.LocalPool(1), folder, "local1")
        out["local_2"] = measure(campaign, sweep.LocalPool(2), folder, "local2")
        t0 = time.perf_counter()
        dask = sweep.DaskExecutor("local", 2)
        out["dask_cluster_start_s"] = round(time.perf_counter() - t0, 2)
        try:
            out["dask_local_2"] = measure(campaign, dask, folder, "dask2")
        finally:
            dask.close()
    out["speedup_2_vs_1"] = round(out["local_2"]["runs_per_s"] / out["local_1"]["runs_per_s"], 2)
    out["dask_vs_local_2"] = round(out["dask_local_2"]["runs_per_s"] / out["local_2"]["runs_per_s"], 2)
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
