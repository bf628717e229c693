"""KUKA RSI: how fast the driver answers the controller, as the controller sees it.

The controller emulator runs in a process of its own (a controller is another
machine) and times each answer from its datagram's send to the answer's
arrival (the kernel's receive timestamp). The driver runs in this process as
in a graph: its node steps at the scene's rate with a moving command, its link
thread answers. Optionally both ask for SCHED_FIFO (--realtime), and --busy N
starts N busy loops for the run (ended after it).
Prints one JSON object: answer latency p50/p99/max [ms], late answers, lost and
counted datagrams.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import resource
import socket
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0, help="seconds to run (default 600)")
    ap.add_argument("--cycle", type=float, default=0.004, choices=(0.004, 0.012), help="RSI cycle [s]")
    ap.add_argument("--rate", type=float, default=1000.0, help="the driver node's step rate [Hz]")
    ap.add_argument("--realtime", action="store_true", help="SCHED_FIFO for the driver's link and the emulator")
    ap.add_argument("--busy", type=int, default=0, help="start this many busy loops for the run")
    args = ap.parse_args()
    sys.path.insert(0, ROOT)
    from rt_probe import steal_ms  # this folder's

    from dockhil.devices.kuka_rsi.driver import RobotRsiDriver
    from dockhil.msgs import Header, Pose, RobotCommand, Twist, Vector3
    from dockhil.node import NodeContext, Tick

    port = free_udp_port()
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    logs: list[str] = []
    with tempfile.TemporaryDirectory() as folder:
        record = os.path.join(folder, "emulator.json")
        emulator = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "dockhil.devices.kuka_rsi.emulator",
                "--port",
                str(port),
                "--cycle",
                str(args.cycle),
                "--duration",
                str(args.duration + 30.0),
                "--record",
                record,
                "--max-late",
                "1000000000",
                *(["--realtime"] if args.realtime else []),
            ],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
        )
        if args.realtime:  # as `dockhil launch --realtime` does for a node's loop (after the children start)
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
            except (PermissionError, OSError) as exc:
                print(f"warning: real-time scheduling refused ({exc})", file=sys.stderr)
        node = RobotRsiDriver(
            NodeContext("robot", 1.0 / args.rate, sim_time=False, log=logs.append),
            port=port,
            ft_timeout=0.0,
            realtime=args.realtime,
            connect_timeout=10.0,
        )
        try:
            node.setup()
            gc.freeze()  # as a graph's node does after its setup (dockhil.runtime.executor)
            stolen = steal_ms()
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            dt = 1.0 / args.rate
            t0 = next_t = time.monotonic()
            k = 0
            while time.monotonic() - t0 < args.duration:
                t = k * dt
                x = 0.005 * math.sin(2 * math.pi * 0.5 * t)  # 5 mm at 0.5 Hz: 16 mm/s at most
                v = 0.005 * 2 * math.pi * 0.5 * math.cos(2 * math.pi * 0.5 * t)
                cmd = RobotCommand(
                    header=Header(time.time(), k, k, "target"), pose=Pose(Vector3(x)), twist=Twist(Vector3(v))
                )
                node.step(Tick(k, time.monotonic() - t0, dt), {"command": cmd})
                k += 1
                next_t += dt
                pause = next_t - time.monotonic()
                if pause > 0:
                    time.sleep(pause)
                elif pause < -0.1:
                    next_t = time.monotonic()
            counted, missing = dict(node.link.counted), node.link.missing
            stolen = None if stolen is None else steal_ms() - stolen
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
        finally:
            emulator.terminate()  # the controller stops first: no late answers from the driver's closing
            emulator.wait(timeout=30)
            node.close()
            for p in busy:
                p.kill()
                p.wait()
        with open(record) as f:
            rec = json.load(f)
    out = {
        "bench": "KUKA RSI answer latency, controller emulator in its own process",
        "duration_s": args.duration,
        "cycle_ms": args.cycle * 1000,
        "rate_hz": args.rate,
        "realtime": args.realtime,
        "busy_loops": args.busy,
        "cpus": os.cpu_count(),
        "latency_ms": rec["latency_ms"],
        "datagrams": rec["sent"],
        "answered": rec["answered"],
        "late": rec["late"],
        "late_in_a_row_max": rec["late_in_a_row_max"],
        # cycles the emulator itself sent more than half a cycle late: not the driver's to answer for
        "unjudged": rec["unjudged"],
        "lost": rec["lost"],
        "counted_by_driver": counted,
        "stray_answers": rec["stray_answers"],
        # IPOC gaps the emulator did not lose on purpose: cycles it skipped because it stalled itself
        # (its own process, SCHED_FIFO 60 with --realtime): the machine's stalls (bench/rt_probe.py).
        "emulator_stalls": missing - rec["lost"],
        "max_step_mm": round(rec["max_step_mm"], 4),
        "max_speed_m_s": round(rec["max_speed"], 4),
        # the host's share of this virtual machine's vCPUs over the run (all CPUs): stalls no priority avoids
        "steal_ms": stolen,
        # the driver process's page faults while it ran (each one stalls the thread that takes it)
        "driver_page_faults": faults,
        "warnings": [line for line in logs if line.startswith("warning")],
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
