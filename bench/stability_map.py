"""Time of the Fig. 7 critical-stiffness map (Eq. 12 and the exact bound) on a
200 x 200 (b, h) grid, median of several runs; prints one JSON object.

    python bench/stability_map.py [--n 200] [--runs 7]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from dockhil.contact.stability import critical_stiffness_map  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200, help="grid points per axis (default 200)")
    parser.add_argument("--runs", type=int, default=7, help="timed runs (default 7)")
    args = parser.parse_args()
    m = 750.0
    b = np.linspace(10.0, 200.0, args.n)
    h = np.linspace(0.016, 0.032, args.n)
    critical_stiffness_map(m, b, h, "exact")  # warm-up
    times = {"pade1": [], "exact": [], "both": []}
    for _ in range(args.runs):
        start = time.perf_counter()
        pade = critical_stiffness_map(m, b, h, "pade1")
        mid = time.perf_counter()
        exact = critical_stiffness_map(m, b, h, "exact")
        end = time.perf_counter()
        times["pade1"].append(mid - start)
        times["exact"].append(end - mid)
        times["both"].append(end - start)
    print(
        json.dumps(
            {
                "bench": "stability_map",
                "grid": [args.n, args.n],
                "runs": args.runs,
                "median_seconds": statistics.median(times["both"]),
                "median_seconds_pade1": statistics.median(times["pade1"]),
                "median_seconds_exact": statistics.median(times["exact"]),
                "max_seconds": max(times["both"]),
                "pade1_range_N_per_m": [float(np.nanmin(pade)), float(np.nanmax(pade))],
                "exact_range_N_per_m": [float(np.nanmin(exact)), float(np.nanmax(exact))],
            }
        )
    )


if __name__ == "__main__":
    main()
