"""The machine's own real-time floor: how late a SCHED_FIFO thread that does nothing but sleep
1 ms wakes (gc off, priority 80, above every dockhil thread), optionally beside N busy loops.

What it measures no code of ours can do better than: a wake-up later than the RSI cycle here is a
stall of the machine (a virtual machine's vCPU taken by its host, a non-preemptible kernel path),
and an RSI answer caught in it is late whatever the driver does. Prints one JSON object.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import subprocess
import sys
import time


def steal_ms() -> float | None:
    """CPU time this machine's host took from its vCPUs since boot, all CPUs [ms] (Linux /proc/stat's
    steal column; None elsewhere): the stalls no priority inside the machine can avoid."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) * 1000.0 / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def first_touch_us(pages: int = 4096) -> dict:
    """What a page fault costs here: fresh anonymous pages touched one by one [us per page] (a virtual
    machine's host may back each on first touch: ~9 us a page on this development VM, 0.1-0.5 us on bare
    metal). A loop thread that grows its memory pays this while it holds the interpreter."""
    import mmap

    size = pages * mmap.PAGESIZE
    region = mmap.mmap(-1, size)
    took = []
    try:
        for offset in range(0, size, mmap.PAGESIZE):
            t = time.perf_counter()
            region[offset] = 1
            took.append(time.perf_counter() - t)
    finally:
        region.close()
    took.sort()
    return {"p50": round(took[len(took) // 2] * 1e6, 2), "max": round(took[-1] * 1e6, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0, help="seconds to run")
    ap.add_argument("--busy", type=int, default=0, help="start this many busy loops for the run")
    args = ap.parse_args()
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    late: list[float] = []
    try:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(80))
            realtime = True
        except (PermissionError, OSError):
            realtime = False
        gc.disable()
        stolen = steal_ms()
        t0 = deadline = time.monotonic()
        while deadline - t0 < args.duration:
            deadline += 0.001
            pause = deadline - time.monotonic()
            if pause > 0:
                time.sleep(pause)
            behind = time.monotonic() - deadline
            late.append(behind)
            if behind > 0.001:  # re-base: one stall is one count
                deadline = time.monotonic()
        stolen = None if stolen is None else steal_ms() - stolen
    finally:
        for p in busy:
            p.kill()
            p.wait()
    late.sort()
    n = len(late)
    print(
        json.dumps(
            {
                "bench": "SCHED_FIFO 80 wake-up lateness, 1 ms period",
                "realtime": realtime,
                "busy_loops": args.busy,
                "load": os.getloadavg()[0],
                "wakeups": n,
                "p50_ms": round(late[n // 2] * 1e3, 3),
                "p99_ms": round(late[int(n * 0.99)] * 1e3, 3),
                "max_ms": round(late[-1] * 1e3, 3),
                "over_1ms": sum(v > 0.001 for v in late),
                "over_4ms": sum(v > 0.004 for v in late),
                "steal_ms": stolen,  # the host's share of the vCPUs over the run, all CPUs
                "first_touch_us": first_touch_us(),  # a page fault's cost, measured after the run
            }
        )
    )


if __name__ == "__main__":
    main()
