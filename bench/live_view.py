"""The live view: what the Foxglove bridge costs and how fast it forwards.

Prints one JSON object:

- forward: `FoxgloveBridge.serve` of the docking graph's message mix (one
  SatelliteState, one WrenchStamped per tick) to a connected viewer that
  subscribed to both: messages per second through msgpack -> JSON -> the
  server, and how many the viewer received.
- run: `dockhil launch launch/hil.yaml --quiet` in sim time, multi-process,
  without the bridge and with `--foxglove` and a viewer subscribed to every
  topic: wall seconds of each run (best of --repeats) and messages the viewer
  received. The difference is the CPU the bridge takes from the nodes on this
  machine; the runs' results are the same bit for bit (tests/test_foxglove.py).

    python bench/live_view.py [--ticks 20000] [--duration 3] [--repeats 2]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Viewer(threading.Thread):
    """A Foxglove WebSocket client that subscribes to every advertised channel and counts message data."""

    def __init__(self, port: int):
        super().__init__(daemon=True)
        self.port = port
        self.received = 0
        self.subscribed = threading.Event()
        self.stop = False

    def run(self) -> None:
        asyncio.run(self._view())

    async def _view(self) -> None:
        import websockets

        while True:
            try:
                ws = await websockets.connect(
                    f"ws://127.0.0.1:{self.port}",
                    max_size=None,
                    close_timeout=0.5,
                    subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                )
                break
            except OSError:
                await asyncio.sleep(0.05)
        try:
            async for msg in ws:
                if isinstance(msg, str):
                    op = json.loads(msg)
                    if op["op"] == "advertise":
                        subs = [{"id": c["id"], "channelId": c["id"]} for c in op["channels"]]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        self.subscribed.set()
                else:
                    self.received += 1
                if self.stop:
                    break
        except websockets.exceptions.ConnectionClosed:
            pass


def forward(ticks: int) -> dict:
    import msgspec

    from dockhil.bags.foxglove import FoxgloveBridge
    from dockhil.msgs import BodyState, Header, SatelliteState, Vector3, Wrench, WrenchStamped

    port = free_port()
    bridge = FoxgloveBridge(
        {"/satellite/state": "dockhil/SatelliteState", "/ft/wrench": "dockhil/WrenchStamped"},
        sim=True,
        port=port,
        log=lambda line: None,
        burst=10**9,
    )
    viewer = Viewer(port)
    viewer.start()
    viewer.subscribed.wait(30)
    while not all(ch.has_sinks() for ch in bridge.channels.values()):
        time.sleep(0.01)
    frames = []
    for k in range(ticks):
        h = Header(stamp=k * 0.001, tick=k, seq=k)
        frames.append(
            [
                b"/satellite/state",
                msgspec.msgpack.encode(
                    SatelliteState(header=h, bodies=[BodyState("chaser", 750.0), BodyState("target", 1e6)])
                ),
            ]
        )
        frames.append([b"/ft/wrench", msgspec.msgpack.encode(WrenchStamped(header=h, wrench=Wrench(Vector3(k))))])
    t = time.perf_counter()
    for i in range(0, len(frames), 1000):
        bridge.serve(frames[i : i + 1000])
    elapsed = time.perf_counter() - t
    time.sleep(0.5)  # what the server still holds reaches the viewer
    received = viewer.received
    viewer.stop = True
    bridge.close()
    return {
        "messages": len(frames),
        "seconds": round(elapsed, 3),
        "messages_per_s": round(len(frames) / elapsed),
        "viewer_received": received,
    }


def run(duration: float, watched: bool) -> dict:
    args = [sys.executable, "-m", "dockhil.cli", "launch", "launch/hil.yaml", "--quiet", "--duration", str(duration)]
    viewer = None
    if watched:
        port = free_port()
        args += ["--foxglove", str(port)]
        viewer = Viewer(port)
    t = time.perf_counter()
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if viewer is not None:
        viewer.start()
    code = proc.wait()
    wall = time.perf_counter() - t
    out = {"exit": code, "wall_s": round(wall, 2)}
    if viewer is not None:
        viewer.join(5)
        out["viewer_received"] = viewer.received
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=20000)
    ap.add_argument("--duration", type=float, default=3.0)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    result = {"forward": forward(a.ticks)}
    runs = {}
    for watched in (False, True):
        tries = [run(a.duration, watched) for _ in range(a.repeats)]
        runs["watched" if watched else "plain"] = min(tries, key=lambda r: r["wall_s"])
    result["run"] = {"sim_s": a.duration, **runs}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
