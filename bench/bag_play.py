"""Live bags: recording a 1 kHz graph in wall time, and `bag play --rate 10` of a 60 s bag.

Prints one JSON object:

- record: `dockhil launch launch/hil.yaml --wall-time --bag` for a few
  seconds. `lost` is what the recorder reports (received but not on disk);
  `seq_gaps` counts header.seq numbers absent from the bag between the first
  and the last message of each topic (seq = tick, and once a node of this
  scene starts sending it sends every tick), which also catches messages
  that never reached the recorder. `first_seq` shows where each topic
  starts: the robot answers only once the delayed command arrives.
- play: a 60 s bag of the docking graph's topic mix (written directly with
  BagWriter, as bench/bag_write.py builds it) played at --rate 10 to a
  `dockhil bag record` subscriber. `wall_s` is the play process from start
  to exit; `publish_s` the publishing itself; the goal is about 6 s.

    python bench/bag_play.py [--record-seconds 4] [--bag-seconds 60] [--rate 10]
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))


def dockhil(*args: str) -> list[str]:
    return [sys.executable, "-m", "dockhil.cli", *args]


def record_graph(tmp: str, seconds: float) -> dict:
    from dockhil.bags.reader import BagReader
    from dockhil.bags.tools import info

    path = os.path.join(tmp, "hil.mcap")
    r = subprocess.run(
        dockhil("launch", "launch/hil.yaml", "--wall-time", "--duration", str(seconds), "--bag", path),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if r.returncode != 0:
        raise SystemExit(f"launch failed: {r.stdout}{r.stderr}")
    report = next(line for line in r.stdout.splitlines() if "[bag-recorder] recorded" in line)
    lost = int(re.search(r"; (\d+) lost", report).group(1))
    seqs: dict[str, list[int]] = {}
    with BagReader(path) as reader:
        for m in reader:
            seqs.setdefault(m.topic, []).append(m.decode().header.seq)
    gaps = sum(max(s) - min(s) + 1 - len(set(s)) for s in seqs.values())
    found = info(path)
    return {
        "scene": "launch/hil.yaml (1 kHz)",
        "clock": "wall",
        "seconds": seconds,
        "topics": len(found["topics"]),
        "messages": found["messages"],
        "messages_per_s": round(found["messages"] / found["duration_s"]),
        "lost": lost,
        "seq_gaps": gaps,
        "first_seq": {topic: min(s) for topic, s in sorted(seqs.items())},
        "bytes_per_message": round(found["size_bytes"] / found["messages"], 1),
    }


def play_bag(tmp: str, seconds: float, rate: float) -> dict:
    from bag_write import graph_messages

    from dockhil.bags.tools import info
    from dockhil.bags.writer import BagWriter

    path = os.path.join(tmp, "long.mcap")
    messages, topics = graph_messages(seconds)
    with BagWriter(path) as bag:
        for topic, type_name in topics.items():
            bag.add_topic(topic, type_name)
        for topic, ns, data in messages:
            bag.write(topic, ns, ns, data)
    copy = os.path.join(tmp, "played.mcap")
    graphs = os.path.join(os.environ["DOCKHIL_RUNTIME_DIR"], "graphs")
    started = time.monotonic()
    play = subprocess.Popen(
        dockhil("bag", "play", path, "--rate", str(rate), "--subscribers", "1"),
        cwd=ROOT,
        stderr=subprocess.PIPE,
        text=True,
    )
    while not glob.glob(os.path.join(graphs, "play-*.json")):
        if play.poll() is not None:
            raise SystemExit(f"bag play failed: {play.stderr.read()}")
        time.sleep(0.01)
    rec = subprocess.Popen(dockhil("bag", "record", copy), cwd=ROOT, stderr=subprocess.PIPE, text=True)
    _, err = play.communicate(timeout=600)
    wall = time.monotonic() - started
    rec.communicate(timeout=60)
    publish = float(re.search(r" in ([0-9.]+) s", err).group(1))
    # What the subscriber got, and the time it spans (receive times).
    got = info(copy)
    return {
        "bag_seconds": seconds,
        "messages": len(messages),
        "rate": rate,
        "wall_s": round(wall, 3),
        "publish_s": publish,
        "goal_s": round(seconds / rate, 3),
        "subscriber_received": got["messages"],
        "subscriber_span_s": round(got["duration_s"], 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--record-seconds", type=float, default=4.0)
    ap.add_argument("--bag-seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=10.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["DOCKHIL_RUNTIME_DIR"] = os.path.join(tmp, "rt")  # no clash with running graphs
        result = {
            "benchmark": "bag_play",
            "record": record_graph(tmp, args.record_seconds),
            "play": play_bag(tmp, args.bag_seconds, args.rate),
        }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
