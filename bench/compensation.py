"""The compensation benchmark's quick grid, measured: prints one JSON object.

    python3 bench/compensation.py [--full]

Per scene and target (the hardware 30 % softer, its delay 20 % longer, 0.2 N noise, 2 ms F/T delay;
omega h up to 0.5): the best method, whether it meets every goal, its worst errors, and none's restitution
error over the best's at omega h = 0.16; per method, in how many scenes it meets every goal (mismatched
and as told); the grid's run count, wall and CPU seconds.
"""

from __future__ import annotations

import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from dockhil.contact import compensation_grid as grid  # noqa: E402
from dockhil.contact.compensation import METHODS  # noqa: E402


def main() -> None:
    full = "--full" in sys.argv[1:]
    start, cpu = time.perf_counter(), time.process_time()
    rows = grid.grid(full)
    out: dict = {
        "grid": "full" if full else "quick",
        "runs": len(rows),
        "wall_seconds": round(time.perf_counter() - start, 1),
        "cpu_seconds": round(time.process_time() - cpu, 1),
        "failed_runs": sum(r["error"] is not None for r in rows),
    }
    for hw in ("mismatch", "as_told"):
        goals = grid.goals(rows, hw)
        out[hw] = {
            "scenes": {
                scene: {
                    "best": g["best"],
                    "best_meets_all": g["best_meets_all"],
                    "best_worst": g["methods"][g["best"]]["worst"],
                    "ratio_none_over_best_at_0.16": g["restitution_error_ratio_none_over_best_at_0.16"],
                }
                for scene, g in goals.items()
            },
            "scenes_meeting_every_goal_per_method": {
                m: sum(bool(g["methods"].get(m, {}).get("all_met")) for g in goals.values()) for m in METHODS
            },
        }
    print(json.dumps(out, default=lambda v: None))


if __name__ == "__main__":
    main()
