"""Memory of a publisher whose subscriber connects and never reads (a stuck process).

A wall-time (lossy) publisher sends N messages of SIZE bytes to a subscriber in another
process that never reads; its resident memory grows by at most the high-water mark's worth,
and the rest is dropped and counted. Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

IDLE = """
import sys, time, zmq
s = zmq.Context().socket(zmq.SUB)
s.setsockopt(zmq.SUBSCRIBE, b"")
s.connect(sys.argv[1])
print("connected", flush=True)
time.sleep(600)
"""


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=200_000)
    ap.add_argument("--size", type=int, default=1000, help="payload bytes")
    args = ap.parse_args()
    sys.path.insert(0, ROOT)
    import zmq

    from dockhil.runtime.transport import HWM, Publisher

    with tempfile.TemporaryDirectory() as tmp:
        endpoint = f"ipc://{tmp}/q"
        ctx = zmq.Context()
        pub = Publisher(ctx, "/q", endpoint, linger_s=0, lossy=True)
        idle = subprocess.Popen([sys.executable, "-c", IDLE, endpoint], stdout=subprocess.PIPE, text=True)
        try:
            idle.stdout.readline()
            pub.wait_subscribers(1, 10.0)
            before = rss_mb()
            payload = b"x" * args.size
            t0 = time.perf_counter()
            for _ in range(args.messages):
                pub.send(payload)
            seconds = time.perf_counter() - t0
            time.sleep(0.5)  # let the I/O thread settle its queues
            grown = rss_mb() - before
        finally:
            idle.kill()
            idle.wait()
            pub.close()
            ctx.term()
    print(
        json.dumps(
            {
                "messages": args.messages,
                "payload_bytes": args.size,
                "hwm": HWM,
                "dropped": pub.dropped,
                "publisher_rss_growth_mb": round(grown, 1),
                "unbounded_would_be_mb": round(args.messages * args.size / 1e6, 1),
                "send_rate_per_s": round(args.messages / seconds),
            }
        )
    )


if __name__ == "__main__":
    main()
