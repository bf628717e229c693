"""What a launch costs before its first tick and after its last: a one-tick launch of
launch/hil.yaml (sim time), multi-process and composed, a one-tick launch of two small
nodes (tests/support/graphnodes.py, as most runtime tests launch), and what one node process
costs on its own, from interpreter start to exit.

Each figure is the median of --repeat runs: wall time, and CPU time (user + system
of the process and everything it waited for, from getrusage), which a loaded
machine inflates much less than wall time. A node process here is
`python -m dockhil.process SPEC` for one tick with its outputs bound (so its CURVE
authentication starts, as in a graph) and no inputs connected; "interpreter" is a
bare `python -c pass`, what any process pays. Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
HIL = os.path.join(ROOT, "launch", "hil.yaml")
SIMULATED = ("satellite_dynamics", "virtual_impedance", "delay_injector", "robot_sim", "ft_sim")


def timed(argv: list[str], repeat: int, env: dict | None = None) -> dict:
    """Median wall and CPU seconds of running argv `repeat` times (it must exit 0)."""
    walls, cpus = [], []
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return {"wall_s": round(statistics.median(walls), 3), "cpu_s": round(statistics.median(cpus), 3)}


SMALL = """rate: 1000
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator"}
  - {name: gain, node: "tests.support.graphnodes:Gain"}
"""


def launch(repeat: int, scene: str = HIL, *extra: str) -> dict:
    return timed(
        [sys.executable, "-m", "dockhil.cli", "launch", scene, "--duration", "0.001", "--quiet", *extra], repeat
    )


def small_graph(repeat: int) -> dict:
    with tempfile.TemporaryDirectory(prefix="dockhil-startup-") as folder:
        scene = os.path.join(folder, "small.yaml")
        with open(scene, "w") as f:
            f.write(SMALL)
        return launch(repeat, scene)


def node_spec(type_name: str, folder: str, key_file: str) -> str:
    """A one-tick RunSpec for a node alone: its outputs bound in `folder`, its inputs unconnected."""
    import msgspec

    from dockhil import msgs, nodes
    from dockhil.runtime.executor import PortWire, RunSpec
    from dockhil.runtime.transport import ipc_endpoint

    cls = nodes.load(type_name)
    params = cls.resolve_params(type_name, {})
    _ins, outs = cls.ports(params)
    outputs = {
        port: PortWire(o.topic, ipc_endpoint(folder, f"{type_name}{o.topic}"), msgs.type_name(o.type))
        for port, o in outs.items()
    }
    spec = RunSpec(type_name, type_name, params, 1e-3, "sim", 1, {}, outputs, key_file=key_file, run_id="bench-startup")
    return msgspec.json.encode(spec).decode()


def node_processes(repeat: int) -> dict:
    from dockhil.runtime.transport import GraphKeys

    out = {}
    with tempfile.TemporaryDirectory(prefix="dockhil-startup-") as folder:
        os.chmod(folder, 0o700)
        key_file = str(GraphKeys.make().write(os.path.join(folder, "graph.keys")))
        env = dict(os.environ, DOCKHIL_RUNTIME_DIR=folder)  # device claims stay in here
        for type_name in SIMULATED:
            argv = [sys.executable, "-m", "dockhil.process", node_spec(type_name, folder, key_file)]
            out[type_name] = timed(argv, repeat, env)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="runs of each; medians are reported")
    args = ap.parse_args()
    load_before = os.getloadavg()
    out = {
        "scene": "launch/hil.yaml, one tick, sim time",
        "bytecode_cache_written": not sys.dont_write_bytecode,
        "interpreter": timed([sys.executable, "-c", "pass"], args.repeat),
        "multiprocess_one_tick": launch(args.repeat),
        "composed_one_tick": launch(args.repeat, HIL, "--composed"),
        "small_graph_one_tick": small_graph(args.repeat),
        "node_process": node_processes(args.repeat),
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
