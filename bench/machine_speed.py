"""How fast this machine runs plain Python right now: the CPU time of a fixed loop of float
additions (median of 5). This shared machine's speed moves by about 2x over a day, so each
bench prints it beside its figures: compare figures taken at similar speeds, or scale by it."""

from __future__ import annotations

import json
import statistics
import time


def python_loop_s(n: int = 3_000_000, repeat: int = 5) -> float:
    """Median CPU seconds of n float additions in a Python loop."""
    runs = []
    for _ in range(repeat):
        t = time.process_time()
        s = 0.0
        for i in range(n):
            s += i * 0.5
        runs.append(time.process_time() - t)
    return round(statistics.median(runs), 3)


if __name__ == "__main__":
    print(json.dumps({"python_loop_3M_s": python_loop_s()}))
