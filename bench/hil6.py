"""Real-time factor of the 6-DOF scene launch/hil6.yaml (off-axis defaults, 1 kHz, sim time):
the composed graph (wall and CPU time, medians; at the scene's order 2 and at order 4), its CPU
time per node and of the runtime alone (nodes replaced by stubs), and the library's sampled loop
(hybrid6.simulate_hybrid6, order 4, recording every tick) for the same scene. The goal is 20x
real time. Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))  # machine_speed
# As the dockhil command does: BLAS worker threads only spin on the models' small problems, and
# process time would count them (before numpy is imported).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from machine_speed import python_loop_s  # noqa: E402

HIL6 = os.path.join(ROOT, "launch", "hil6.yaml")


def composed(n_ticks: int, per_node: bool = False, order: int | None = None) -> tuple[float, float, dict]:
    """(wall [s], CPU [s], CPU per node [us/tick]) of one composed run of n_ticks; order None: the scene's."""
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    args = {} if order is None else {"order": str(order)}
    g = ComposedGraph(build(launchfile.load(HIL6, args)), log=lambda n, m: None)
    g.setup()
    spent: dict[str, float] = {}
    if per_node:  # wrap each node's step with a CPU timer (adds a little overhead of its own)
        for name, node in g.nodes.items():

            def timed(tick, inputs, _step=node.step, _name=name):
                t = time.process_time()
                out = _step(tick, inputs)
                spent[_name] = spent.get(_name, 0.0) + time.process_time() - t
                return out

            node.step = timed
        g.plan = [(name, g.nodes[name], *rest) for name, _node, *rest in g.plan]
    t0, c0 = time.perf_counter(), time.process_time()
    g.run(n_ticks)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    g.close()
    return wall, cpu, {k: v / n_ticks * 1e6 for k, v in spent.items()}


def runtime_only(n_ticks: int) -> float:
    """CPU [us/tick] of the composed runtime alone: every node's step replaced by a stub that returns
    the messages the node sent at tick 300 (in contact) with the tick's header, so what is left is
    the runner (inputs, output checks, histories) and the headers, not the nodes' arithmetic."""
    import msgspec

    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    g = ComposedGraph(build(launchfile.load(HIL6)), log=lambda n, m: None)
    g.setup()
    sent: dict[str, dict] = {}
    for name, node in g.nodes.items():

        def record(tick, inputs, _step=node.step, _name=name):
            sent[_name] = out = _step(tick, inputs)
            return out

        node.step = record
    g.run(301)
    for name, node in g.nodes.items():

        def stub(tick, inputs, _sent=sent[name]):
            return {
                port: msgspec.structs.replace(msg, header=tick.header(msg.header.frame)) for port, msg in _sent.items()
            }

        node.step = stub
    c0 = time.process_time()
    g.run(n_ticks)
    cpu = time.process_time() - c0
    g.close()
    return cpu / n_ticks * 1e6


def library(n_ticks: int) -> float:
    import numpy as np

    from dockhil.contact.contact6 import Contact6
    from dockhil.contact.hybrid6 import simulate_hybrid6
    from dockhil.contact.rigidbody import BodyState, RigidBody
    from dockhil.contact.rotations import quat_from_rotvec

    chaser = RigidBody(750.0, np.diag([300.0, 400.0, 500.0]), interface_position=[1.0, 0.0, 0.0])
    target = RigidBody(1e6, np.diag([4e6, 5e6, 6e6]), interface_position=[-2.0, 0.0, 0.0])
    s1 = BodyState([-1.0, 0.05, 0.0], quat_from_rotvec([0.0, 0.0, 0.02]), [0.03, 0.0, 0.0], [0.01, 0.0, 0.0])
    s2 = BodyState([2.0, 0.0, 0.0], (0.0, 0.0, 0.0, 1.0), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    ideal = Contact6([3000.0, 3000.0, 3000.0, 300.0, 300.0, 300.0], [40.0, 40.0, 40.0, 4.0, 4.0, 4.0])
    passive = Contact6([1000.0, 1000.0, 1000.0, 100.0, 100.0, 100.0])
    t0 = time.perf_counter()
    simulate_hybrid6(chaser, target, s1, s2, ideal, passive, dt=1e-3, t_end=(n_ticks - 1) * 1e-3, delay_ticks=32)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="simulated seconds per run (default 3)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode; medians are reported")
    args = ap.parse_args()
    n = int(round(args.seconds * 1000)) + 1
    sim = (n - 1) * 1e-3

    def medians(runs):
        return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)

    wall, cpu = medians([composed(n) for _ in range(args.repeat)])
    wall4, cpu4 = medians([composed(n, order=4) for _ in range(args.repeat)])
    lib = statistics.median(library(n) for _ in range(args.repeat))
    per_node = composed(n, per_node=True)[2]
    runtime = statistics.median(runtime_only(n) for _ in range(args.repeat))
    print(
        json.dumps(
            {
                "scene": "launch/hil6.yaml (defaults: offset 0.05 m, tilt 0.02 rad, spin 0.01 rad/s, delay 32 ms, order 2)",
                "rate_Hz": 1000.0,
                "sim_seconds": sim,
                "repeat": args.repeat,
                "sixdof_composed_rtf": sim / wall,
                "sixdof_composed_cpu_rtf": sim / cpu,
                "cpu_us_per_tick": cpu / n * 1e6,
                "order4_composed_rtf": sim / wall4,
                "order4_cpu_us_per_tick": cpu4 / n * 1e6,
                "library_loop_order4_rtf": sim / lib,
                "goal_rtf": 20.0,
                "per_node_cpu_us_per_tick": {
                    k: round(v, 1) for k, v in sorted(per_node.items(), key=lambda kv: -kv[1])
                },
                "runtime_only_cpu_us_per_tick": round(runtime, 1),
                "cpus": os.cpu_count(),
                "load_avg_1min": os.getloadavg()[0],
                "python_loop_3M_s": python_loop_s(),  # the machine's speed at the time (bench/machine_speed.py)
            }
        )
    )


if __name__ == "__main__":
    main()
