"""What a log record costs: CPU microseconds per record, the median of 7 rounds.

- `stderr`: a node's line formatted and written to a stream (in memory here), the path of a
  composed run and of the launcher's own records;
- `forwarded`: a node process's record as its FORWARD line, then read back and logged by the
  launcher (both halves, in one process);
- `filtered`: a record below the level, which is dropped before it is formatted;
- `print`: the `print(line, file=stream)` the nodes used before, for comparison.

CPU time (time.process_time), so a busy machine changes little. Prints one JSON object.
"""

from __future__ import annotations

import contextlib
import io
import json
import statistics
import sys
import time

from dockhil import log

N = 20_000
ROUNDS = 7


def per_record(fn) -> float:
    rounds = []
    for _ in range(ROUNDS):
        t = time.process_time()
        for i in range(N):
            fn(i)
        rounds.append((time.process_time() - t) / N * 1e6)
    return statistics.median(rounds)


def main() -> None:
    sink = io.StringIO()
    out: dict[str, float] = {}
    log.setup("info", stream=sink)
    out["stderr_us"] = per_record(lambda i: log.node_line("impedance", f"warning: record {i}"))
    out["filtered_us"] = per_record(lambda i: log.node_line("impedance", f"debug: record {i}"))
    forwarded = io.StringIO()
    log._install(log.logging.INFO, [log.ForwardHandler()])
    with contextlib.redirect_stdout(forwarded):
        out["forward_send_us"] = per_record(lambda i: log.node_line("impedance", f"warning: record {i}"))
    lines = forwarded.getvalue().splitlines()[:N]
    log.setup("info", stream=sink)
    out["forward_replay_us"] = per_record(lambda i: log.replay(lines[i], "[impedance]"))
    out["forwarded_us"] = out["forward_send_us"] + out["forward_replay_us"]
    out["print_us"] = per_record(lambda i: print(f"[impedance] warning: record {i}", file=sink, flush=True))
    out = {k: round(v, 2) for k, v in out.items()}
    out.update(records_per_round=N, rounds=ROUNDS, clock="process_time (CPU)", python=sys.version.split()[0])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
