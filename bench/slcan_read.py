"""CPU time to receive a frame from an slcan adapter: python-can's slcan recv against the bulk reader.

An emulated adapter (dockhil.devices.can_ft.slcan_pty.SlcanPort, a pseudo-terminal) holds N frames of the
F/T sensor's layout; each reader takes them all, three times, on the same process's CPU clock.
Prints one JSON object: microseconds of CPU per frame (median of the three), and the ratio.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import can

from dockhil.devices.can_ft.slcan_pty import CanFrame, SlcanPort
from dockhil.devices.can_ft.slcan_reader import SlcanReader


def fill(port: SlcanPort, n: int) -> None:
    for i in range(n):
        while not port.deliver(CanFrame(0x1A0 + (i & 1), bytes([i & 0xFF] * 8))):
            port.flush()
            time.sleep(0.001)  # the host reads below; the adapter's queue is bounded


def cpu_per_frame(bus, port: SlcanPort, recv, n: int) -> float:
    got = 0
    start = time.process_time()
    pending = n
    while got < n:
        if pending:
            chunk = min(pending, 200)  # what the pty holds without the adapter dropping
            fill(port, chunk)
            pending -= chunk
        while recv(0.0) is not None:
            got += 1
    return (time.process_time() - start) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000, help="frames per measurement (default 20000)")
    args = ap.parse_args()
    port = SlcanPort()
    bus = can.Bus(interface="slcan", channel=port.path, bitrate=1_000_000, timeout=0.0, sleep_after_open=0.0)
    try:
        port.read_host()  # the open commands python-can sent
        reader = SlcanReader(bus.serialPortOrig)
        runs = {"python_can_us": [], "bulk_us": []}
        for _ in range(3):
            runs["python_can_us"].append(cpu_per_frame(bus, port, bus.recv, args.frames))
            runs["bulk_us"].append(cpu_per_frame(bus, port, reader.recv, args.frames))
    finally:
        bus.shutdown()
        port.close()
    out = {k: round(statistics.median(v), 2) for k, v in runs.items()}
    out["ratio"] = round(out["python_can_us"] / out["bulk_us"], 1)
    out["frames"] = args.frames
    out["note"] = "CPU time per received frame (the sending adapter's work included in both)"
    print(json.dumps(out))


if __name__ == "__main__":
    main()
