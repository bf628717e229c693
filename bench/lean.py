"""Per node type: start-up time, peak resident memory and heavy packages loaded,
each measured in a fresh interpreter (see dockhil/analysis/leanness.py). Prints one JSON
object as its last line."""

from __future__ import annotations

import argparse
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per node type; the fastest is reported")
    args = ap.parse_args()
    from dockhil.analysis import leanness

    rows = leanness.measure_all(repeats=args.repeat)
    out = {
        "nodes": {
            r["node"]: {
                "startup_s": round(r["startup_s"], 3) if r.get("startup_s") else None,
                "rss_mb": round(r["rss_mb"], 1) if r.get("rss_mb") else None,
                "loaded_after_setup": r.get("after_setup", []),
                "kind": r["kind"],
            }
            for r in rows
        },
        "violations": leanness.violations(rows),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
