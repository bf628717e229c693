"""How fast BagWriter records the topics of a 1 kHz HIL graph; prints one JSON object.

The mix is what the docking graph publishes every 1 ms tick (two wrenches,
the satellite state with two bodies, robot command, delayed command and
robot state) plus one 10 Hz status per node. Values follow a noisy contact
trajectory so that compression sees realistic data. Messages are encoded
beforehand: the recorder receives wire (msgpack) bytes, encoding is the
publisher's cost; transcoding them to the bag's JSON is the writer's.

messages_per_s is over wall time, cpu_messages_per_s over the process's CPU
time (steadier on a loaded machine). read_cpu_messages_per_s: BagReader handing
back every message of the zstd bag as wire bytes (what `bag play` and replay
do), over CPU time.

    python bench/bag_write.py [--seconds 10] [--runs 5]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dockhil.bags.reader import BagReader
from dockhil.bags.writer import BagWriter  # noqa: E402
from dockhil.msgs import (  # noqa: E402
    BodyState,
    Header,
    NodeStatus,
    Pose,
    RobotCommand,
    RobotState,
    SatelliteState,
    Twist,
    Vector3,
    Wrench,
    WrenchStamped,
    type_name,
)
from dockhil.msgs.codec import encode  # noqa: E402

NODES = ("satellite-dynamics", "virtual-impedance", "ft-sensor", "robot-command", "delay-injector")


def graph_messages(seconds: float, rate_hz: float = 1000.0) -> tuple[list[tuple[str, int, bytes]], dict[str, str]]:
    rng = random.Random(1)
    dt = 1.0 / rate_hz
    topics = {
        "/ft/wrench": type_name(WrenchStamped),
        "/impedance/wrench": type_name(WrenchStamped),
        "/dynamics/state": type_name(SatelliteState),
        "/robot/command": type_name(RobotCommand),
        "/robot/command_delayed": type_name(RobotCommand),
        "/robot/state": type_name(RobotState),
        "/status": type_name(NodeStatus),
    }
    out = []
    for k in range(int(seconds * rate_hz)):
        t = k * dt
        ns = 1_700_000_000_000_000_000 + k * 1_000_000
        h = Header(stamp=t, tick=k, seq=k, frame="target")
        x = 0.02 * math.sin(2 * math.pi * 0.5 * t)
        v = 0.02 * math.pi * math.cos(2 * math.pi * 0.5 * t)
        f = max(0.0, 4000.0 * x) + rng.gauss(0.0, 0.5)
        wrench = WrenchStamped(
            header=h,
            wrench=Wrench(
                force=Vector3(x=f, y=rng.gauss(0, 0.2), z=rng.gauss(0, 0.2)),
                torque=Vector3(x=rng.gauss(0, 0.01), y=rng.gauss(0, 0.01)),
            ),
        )
        virtual = WrenchStamped(header=h, wrench=Wrench(force=Vector3(x=-0.8 * f - 30.0 * v)))
        pose = Pose(position=Vector3(x=x))
        twist = Twist(linear=Vector3(x=v))
        state = SatelliteState(
            header=h,
            bodies=[BodyState(name="chaser", mass=120.0, pose=pose, twist=twist), BodyState(name="target", mass=300.0)],
            in_contact=x > 0,
        )
        command = RobotCommand(header=h, pose=pose, twist=twist)
        actual = RobotState(header=h, pose=Pose(position=Vector3(x=x + rng.gauss(0, 1e-5))), twist=twist)
        for topic, msg in (
            ("/ft/wrench", wrench),
            ("/impedance/wrench", virtual),
            ("/dynamics/state", state),
            ("/robot/command", command),
            ("/robot/command_delayed", command),
            ("/robot/state", actual),
        ):
            out.append((topic, ns, encode(msg)))
        if k % 100 == 0:
            for node in NODES:
                out.append(("/status", ns, encode(NodeStatus(header=h, node=node, ticks=k))))
    return out, topics


def one_run(messages, topics, compression: str) -> tuple[float, float, int, float]:
    """(wall s, CPU s, bytes) of writing the bag, and CPU s of reading it back."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "bench.mcap")
        start, cpu = time.perf_counter(), time.process_time()
        with BagWriter(path, compression=compression) as bag:
            for topic, type_ in topics.items():
                bag.add_topic(topic, type_)
            write = bag.write
            for topic, ns, data in messages:
                write(topic, ns, ns, data)
        elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
        start = time.process_time()
        with BagReader(path) as reader:
            count = sum(1 for _ in reader)
        read = time.process_time() - start
        assert count == len(messages)
        return elapsed, cpu, os.path.getsize(path), read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="graph time recorded per run [s]")
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    messages, topics = graph_messages(args.seconds)
    needed = len(messages) / args.seconds
    result = {
        "benchmark": "bag_write",
        "graph": "1 kHz docking graph: 6 topics at 1 kHz + 5 statuses at 10 Hz",
        "messages": len(messages),
        "graph_messages_per_s": round(needed),
        "mean_wire_bytes": round(sum(len(d) for _, _, d in messages) / len(messages), 1),
        "runs": args.runs,
    }
    for compression in ("zstd", "lz4", "none"):
        runs = [one_run(messages, topics, compression) for _ in range(args.runs)]
        elapsed = statistics.median(r[0] for r in runs)
        rate = len(messages) / elapsed
        entry = {
            "messages_per_s": round(rate),
            "cpu_messages_per_s": round(len(messages) / statistics.median(r[1] for r in runs)),
            "realtime_factor": round(rate / needed, 1),
            "bytes_per_message": round(runs[0][2] / len(messages), 1),
        }
        if compression == "zstd":  # the default: headline numbers
            result.update(entry)
            result["read_cpu_messages_per_s"] = round(len(messages) / statistics.median(r[3] for r in runs))
        result.setdefault("by_compression", {})[compression] = entry
    print(json.dumps(result))


if __name__ == "__main__":
    main()
