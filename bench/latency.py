"""One-hop publish-to-receive latency between two processes: the runtime's
transport and codec against raw pyzmq + msgpack, measured in one run; the
runtime path twice: with the graph's CURVE security (as every graph runs)
and without it ("plain"), which shows what the encryption costs.

Both paths use ipc sockets and the same pacing (1 kHz); runs alternate in
blocks so that machine noise hits both alike. CLOCK_MONOTONIC is shared by
processes on one host, so the receiver subtracts the sender's stamp.
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np


def _keys(kind: str, endpoint: str):
    """CURVE keys shared through a key file beside the socket (as a graph's run directory holds it)."""
    if kind != "runtime":
        return None
    from pathlib import Path

    from dockhil.runtime.transport import GraphKeys

    path = Path(endpoint[len("ipc://") :] + ".keys")
    if not path.exists():
        GraphKeys.make().write(path)
    return GraphKeys.read(path)


def sender(kind: str, endpoint: str, n: int, period: float) -> None:
    import zmq

    from dockhil import msgs
    from dockhil.msgs.codec import encode

    ctx = zmq.Context.instance()
    if kind in ("runtime", "plain"):
        from dockhil.runtime.transport import Publisher

        pub = Publisher(ctx, "/ft/wrench", endpoint, keys=_keys(kind, endpoint))
        pub.wait_subscribers(1, 10)
        wrench = msgs.Wrench(force=msgs.Vector3(x=1.0, y=2.0, z=3.0), torque=msgs.Vector3(x=0.1))
        send = lambda i: pub.send(  # noqa: E731
            encode(msgs.WrenchStamped(header=msgs.Header(stamp=time.perf_counter(), tick=i, seq=i), wrench=wrench))
        )
    else:
        import msgpack

        sock = ctx.socket(zmq.PUB)
        sock.bind(endpoint)
        time.sleep(0.5)  # raw PUB/SUB has no join barrier
        payload = {"force": [1.0, 2.0, 3.0], "torque": [0.1, 0.0, 0.0]}
        send = lambda i: sock.send(msgpack.packb({"stamp": time.perf_counter(), "tick": i, **payload}))  # noqa: E731
    next_t = time.perf_counter()
    for i in range(n):
        send(i)
        next_t += period
        while time.perf_counter() < next_t:
            pass
    time.sleep(0.2)


def receiver(kind: str, endpoint: str, n: int) -> list[float]:
    import zmq

    ctx = zmq.Context.instance()
    out = []
    if kind in ("runtime", "plain"):
        from dockhil import msgs
        from dockhil.msgs.codec import decode
        from dockhil.runtime.transport import Subscriber

        sub = Subscriber(ctx)
        sub.connect(endpoint, keys=_keys(kind, endpoint))
        while len(out) < n:
            frames = sub.recv(5.0)
            if frames is None:
                break
            msg = decode(frames[1], msgs.WrenchStamped)
            out.append(time.perf_counter() - msg.header.stamp)
    else:
        import msgpack

        sock = ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.SUBSCRIBE, b"")
        sock.connect(endpoint)
        while len(out) < n:
            if not sock.poll(5000):
                break
            msg = msgpack.unpackb(sock.recv())
            out.append(time.perf_counter() - msg["stamp"])
    return out


def one_block(kind: str, n: int, period: float, tmp: str) -> list[float]:
    endpoint = f"ipc://{tmp}/{kind}-{time.monotonic_ns()}"
    _keys(kind, endpoint)  # written before either side reads it
    proc = subprocess.Popen([sys.executable, __file__, "--send", kind, endpoint, str(n), str(period)])
    try:
        return receiver(kind, endpoint, n)
    finally:
        proc.wait(30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=2000, help="messages per block (default 2000)")
    ap.add_argument("--blocks", type=int, default=3, help="blocks per path, alternating (default 3)")
    ap.add_argument("--rate", type=float, default=1000.0, help="send rate [Hz] (default 1000)")
    ap.add_argument("--send", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.send:
        kind, endpoint, n, period = args.send
        sender(kind, endpoint, int(n), float(period))
        return
    period = 1.0 / args.rate
    lat = {"runtime": [], "plain": [], "raw": []}
    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR", "/tmp")) as tmp:
        for b in range(args.blocks):
            for kind in ("runtime", "plain", "raw") if b % 2 == 0 else ("raw", "plain", "runtime"):
                got = one_block(kind, args.messages, period, tmp)
                lat[kind].extend(got[len(got) // 10 :])  # drop the warm-up tenth
                print(f"{kind} block {b + 1}: {len(got)} messages", file=sys.stderr)
    r = np.array(lat["runtime"]) * 1e6
    w = np.array(lat["raw"]) * 1e6
    c = np.array(lat["plain"]) * 1e6
    result = {
        "messages_per_path": int(len(r)),
        "runtime_hop_us_p50": round(float(np.percentile(r, 50)), 1),
        "runtime_hop_us_p99": round(float(np.percentile(r, 99)), 1),
        "plain_hop_us_p50": round(float(np.percentile(c, 50)), 1),
        "plain_hop_us_p99": round(float(np.percentile(c, 99)), 1),
        "raw_hop_us_p50": round(float(np.percentile(w, 50)), 1),
        "raw_hop_us_p99": round(float(np.percentile(w, 99)), 1),
    }
    result["ratio_p50"] = round(result["runtime_hop_us_p50"] / result["raw_hop_us_p50"], 2)
    result["curve_cost_us_p50"] = round(result["runtime_hop_us_p50"] - result["plain_hop_us_p50"], 1)
    # The runtime's hop (CURVE, the codec, the screen) within 15 % of raw pyzmq + msgpack.
    result["goals"] = {"ratio_p50": {"goal": "<= 1.15", "met": result["ratio_p50"] <= 1.15}}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
