"""A process's context switches by thread, from /proc: what its loop costs the scheduler. A node
counts them over its ticks (LoopTiming.switches), and bench/graph.py gives them per tick.

Voluntary switches are the wake-ups (a thread blocked, waiting for a message or a deadline);
involuntary ones are preemptions (a busy machine's share). Threads are named as the OS names them
(ZMQbg/IO/0, dockhil-zap), the process's first thread "main"; threads of one name are summed."""

from __future__ import annotations

import os


def by_thread() -> dict[str, list[int]]:
    """Thread name -> [voluntary, involuntary] context switches so far; {} where /proc has none."""
    out: dict[str, list[int]] = {}
    pid = os.getpid()
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:  # not Linux
        return out
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/status") as f:
                status = f.read()
            with open(f"/proc/self/task/{tid}/comm") as f:
                name = "main" if int(tid) == pid else f.read().strip()
        except OSError:  # the thread ended meanwhile
            continue
        counts = out.setdefault(name, [0, 0])
        for line in status.splitlines():
            if line.startswith("voluntary_ctxt_switches:"):
                counts[0] += int(line.split()[1])
            elif line.startswith("nonvoluntary_ctxt_switches:"):
                counts[1] += int(line.split()[1])
    return out


def since(before: dict[str, list[int]], after: dict[str, list[int]]) -> dict[str, list[int]]:
    """The switches of each thread between two `by_thread` readings (a thread made between them
    counts from 0)."""
    return {
        name: [n - b for n, b in zip(counts, before.get(name, [0, 0]), strict=True)] for name, counts in after.items()
    }
