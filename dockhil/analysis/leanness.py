"""What each node type costs a scene: start-up time, resident memory, heavy imports.

Each node type is measured in a fresh interpreter of its own, as the launcher
would start it: import the node class (`node_types.load`), construct it, set it up
and step it once with no inputs. Hardware drivers are set up against devices
that are not there (a python-can `virtual` bus, a closed TCP port): their
setup fails with a one-line DeviceError after loading what it needs, which is
what is measured. The child reports, after import and after setup, which of
the heavy packages are in `sys.modules`.

    from dockhil.analysis.leanness import measure_all
    for row in measure_all(): print(row["node"], row["startup_s"], row["after_setup"])
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the repository (a source checkout)

# Packages reported per node: numpy and zmq for what they cost, the rest
# because a scene should load them only where a node uses them.
HEAVY = ("numpy", "zmq", "msgspec", "mcap", "can", "serial", "pymodbus", "scipy", "matplotlib", "cyclonedds")
# The packages the rules below are about.
RULED = ("can", "pymodbus", "scipy", "matplotlib", "cyclonedds")
# What each node type may load, and when: a node never imports these at module
# import time; in setup only what it talks to.
ALLOWED_AT_SETUP = {
    "ft_can": {"can"},  # python-can: the sensor's bus
    "robot_modbus": {"pymodbus"},  # the robot controller's Modbus TCP
    "robot_emulator": {"pymodbus"},  # it is a Modbus TCP server
    "ft_emulator": set(),  # with interface "pty" it is its own slcan adapter; other interfaces load python-can
    "ros2_bridge": {"cyclonedds"},  # the DDS participant it writes ROS 2 topics with
}

_CHILD = r"""
import json, os, resource, sys, time
t0 = time.perf_counter()
heavy = set(json.loads(sys.argv[2]))
def loaded():
    return sorted({m.split(".")[0] for m in list(sys.modules)} & heavy)
type_name, spec = sys.argv[1], json.loads(sys.argv[3])
out = {"node": type_name}
sys.path.insert(0, spec["root"])
try:
    if type_name.startswith("module:"):
        for module in type_name[len("module:"):].split(","):
            __import__(module)
        out["import_s"] = time.perf_counter() - t0
        out["after_import"] = loaded()
        out["setup"] = "no node"
    elif type_name.startswith("scene:"):
        from dockhil.scene import launchfile
        from dockhil.runtime.composed import ComposedGraph
        from dockhil.scene.graph import build
        graph = build(launchfile.load(type_name[len("scene:"):]))
        out["import_s"] = time.perf_counter() - t0
        out["after_import"] = loaded()
        t1 = time.perf_counter()
        g = ComposedGraph(graph, log=lambda name, msg: None)
        g.setup()
        g.run(10)
        g.close()
        out["setup"] = "ok: " + ", ".join(n.type_name for n in graph.nodes.values())
        out["setup_s"] = time.perf_counter() - t1
    else:
        from dockhil import node_types
        from dockhil.node import NodeContext, Tick
        cls = node_types.load(type_name)
        out["import_s"] = time.perf_counter() - t0
        out["after_import"] = loaded()
        t1 = time.perf_counter()
        node = None
        try:
            ctx = NodeContext(type_name, 1e-3, spec["sim_time"], log=lambda msg: None)
            node = cls(ctx, **spec["params"])
            node.setup()
            node.step(Tick(0, 0.0, 1e-3), {name: None for name in cls.ports(vars(node.p))[0]})
            out["setup"] = "ok"
        except Exception as exc:
            out["setup"] = f"{type(exc).__name__}: " + " ".join(str(exc).split())
        finally:
            if node is not None:
                try:
                    node.close()
                except Exception:
                    pass
        out["setup_s"] = time.perf_counter() - t1
except Exception as exc:
    out["setup"] = f"import failed: {type(exc).__name__}: {exc}"
out["after_setup"] = loaded()
# VmHWM is this program's own peak; ru_maxrss would also count the parent's
# pages that the child held between fork and exec.
try:
    with open("/proc/self/status") as status:
        out["rss_mb"] = next(int(l.split()[1]) for l in status if l.startswith("VmHWM:")) / 1024.0
except (OSError, StopIteration, ValueError):
    out["rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
out["in_process_s"] = time.perf_counter() - t0
print("@dockhil-lean@ " + json.dumps(out), flush=True)
"""


def _closed_port() -> int:
    """A TCP port on 127.0.0.1 with nothing listening (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _sample_bag(directory: str) -> str:
    """A one-message bag for the bag_source node to open."""
    from dockhil import msgs
    from dockhil.bags.writer import BagWriter
    from dockhil.msgs.codec import encode

    path = os.path.join(directory, "sample.mcap")
    msg = msgs.WrenchStamped(header=msgs.Header(stamp=0.0, tick=0, seq=0, frame=""), wrench=msgs.Wrench())
    with BagWriter(path, overwrite=True) as bag:
        bag.add_topic("/ft/wrench", msgs.type_name(msgs.WrenchStamped))
        bag.write("/ft/wrench", 0, 0, encode(msg))
    return path


def setup_specs(directory: str) -> dict[str, dict]:
    """How each node type is constructed for the measurement: sim or wall time
    and the parameters that keep it off real hardware."""
    from dockhil.nodes import ros2_bridge

    specs = {
        "ft_can": {
            "sim_time": False,
            "params": {"interface": "virtual", "channel": "dockhil-lean", "open_timeout": 0.05, "tare_samples": 0},
        },
        "robot_modbus": {
            "sim_time": False,
            "params": {"port": _closed_port(), "connect_timeout": 0.05, "reconnect_min": 0.01},
        },
        "ft_emulator": {"sim_time": False, "params": {"channel": os.path.join(directory, "ft.slcan")}},
        "robot_emulator": {"sim_time": False, "params": {"port": 0}},
        "ft_netft": {
            "sim_time": False,
            "params": {
                "host": "127.0.0.1",
                "port": _closed_port(),
                "open_timeout": 0.05,
                "counts_per_force": 1e6,
                "counts_per_torque": 1e6,
                "force_unit": "N",
                "torque_unit": "Nm",
                "tare_samples": 0,
            },
        },
        "netft_emulator": {"sim_time": False, "params": {"port": 0, "http_port": 0}},
        # DDS on the loopback interface only, in a domain of its own
        "ros2_bridge": {
            "sim_time": True,
            "params": {"domain_id": 200 + os.getpid() % 30},
            "env": {"CYCLONEDDS_URI": ros2_bridge.LOOPBACK_URI},
        },
    }
    try:
        specs["bag_source"] = {"sim_time": True, "params": {"path": _sample_bag(directory)}}
    except Exception:  # no bag support: the node is measured as far as it goes
        pass
    return specs


def measure(type_name: str, spec: dict | None = None, timeout: float = 60.0, repeats: int = 1) -> dict:
    """Start-up time [s], peak resident memory [MB] and heavy imports of one node
    type ("module:A,B" for plain imports, "scene:FILE" for a whole scene composed
    in one process), in a fresh interpreter; the fastest of `repeats` runs."""
    rows = [_measure_once(type_name, spec, timeout) for _ in range(max(1, repeats))]
    timed = [r for r in rows if r.get("startup_s") is not None and "rss_mb" in r]
    return min(timed, key=lambda r: r["startup_s"]) if timed else rows[-1]


def _measure_once(type_name: str, spec: dict | None, timeout: float) -> dict:
    spec = {"sim_time": True, "params": {}, **(spec or {}), "root": str(ROOT)}
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", **spec.pop("env", {}))
    argv = [sys.executable, "-c", _CHILD, type_name, json.dumps(HEAVY), json.dumps(spec)]
    t0 = time.perf_counter()
    try:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, cwd=str(ROOT), env=env)
    except subprocess.TimeoutExpired:
        return {"node": type_name, "setup": f"did not finish within {timeout:g} s", "startup_s": None}
    wall = time.perf_counter() - t0
    for line in done.stdout.splitlines():
        if line.startswith("@dockhil-lean@ "):
            row = json.loads(line.split(" ", 1)[1])
            row["startup_s"] = wall
            row["interpreter_s"] = max(0.0, wall - row.pop("in_process_s"))
            return row
    tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
    return {"node": type_name, "setup": f"measurement failed: {tail}", "startup_s": wall}


RUNTIME = (
    "module:dockhil.msgs,dockhil.node,dockhil.runtime.executor,dockhil.runtime.transport,"
    "dockhil.runtime.process,dockhil.node_types"
)
BASELINES = {
    "module:json": "python, nothing of dockhil",
    RUNTIME: "node process runtime (transport, executor)",
    "module:dockhil.contact": "import dockhil.contact",
    "module:dockhil.cli": "import dockhil.cli",
}
SCENES = ("launch/ideal.yaml", "launch/hil.yaml")


def measure_all(
    types: list[str] | None = None, workers: int = 2, baselines: bool = True, repeats: int = 2
) -> list[dict]:
    """Every registered node type (or `types`), plus baselines (a bare interpreter,
    the runtime every node process loads, `import dockhil.contact`, `import
    dockhil.cli`) and the simulated scenes composed in one process."""
    from dockhil import node_types

    types = sorted(node_types.REGISTRY) if types is None else list(types)
    with tempfile.TemporaryDirectory() as tmp:
        specs = setup_specs(tmp)
        jobs = [(t, specs.get(t)) for t in types]
        if baselines:
            jobs = [(b, None) for b in BASELINES] + jobs
            from dockhil.scene.launchfile import SHIPPED_SCENES  # launch/ of a checkout, or of the wheel

            jobs += [(f"scene:{s}", None) for s in SCENES if (SHIPPED_SCENES / Path(s).name).exists()]
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            rows = list(pool.map(lambda job: measure(job[0], job[1], repeats=repeats), jobs))
    for row in rows:
        name = row["node"]
        row["kind"] = "node" if name in types else "scene" if name.startswith("scene:") else "baseline"
        row["node"] = BASELINES.get(name, name.replace("scene:", "scene "))
    return rows


def violations(rows: list[dict]) -> list[str]:
    """Heavy imports that break the rules above, one line each."""
    out = []
    for row in rows:
        name = row["node"]
        if row.get("kind") != "node":
            continue
        early = set(row.get("after_import", [])) & set(RULED)
        if early:
            out.append(f"{name}: imports {', '.join(sorted(early))} at module import (move it into setup)")
        allowed = ALLOWED_AT_SETUP.get(name, set())
        late = set(row.get("after_setup", [])) & set(RULED)
        extra = late - allowed
        if extra:
            out.append(f"{name}: loads {', '.join(sorted(extra))} in setup or step without using it")
    return out
