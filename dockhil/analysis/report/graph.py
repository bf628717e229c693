"""The report's runs of the graph and the command: hil.yaml as the model library's loop, composed in
one process, and as separate processes (subprocesses, read back from their bags), and what they cost;
the `dockhil` command run in this process."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from dockhil.analysis.report.precision import HIL_DELAY, LAUNCH_DIR, ROOT, ReportConfig, best_time, hybrid_impedance
from dockhil.contact.hilloop import simulate_hil
from dockhil.contact.scenario import (
    TABLE1,
)
from dockhil.errors import DockhilError
from dockhil.progress import TaskProgress

if TYPE_CHECKING:
    from os import PathLike

    from dockhil.analysis.summary.common import Samples

# -- the graph's cost ----------------------------------------------------------------------------------


def _hil_library(duration: float, dt: float = 1e-3) -> Samples:
    from dockhil.analysis.summary import Samples

    imp = hybrid_impedance(TABLE1)
    n = int(round(duration / dt)) + 1
    r = simulate_hil(
        m1=TABLE1.m1,
        m2=TABLE1.m2,
        k=TABLE1.k,
        impedance=imp,
        dt=dt,
        n_ticks=n,
        v1=TABLE1.v1,
        v2=TABLE1.v2,
        delay=HIL_DELAY,
    )
    return Samples(r.t, r.x1 - r.x2, r.v1 - r.v2, r.force)


def composed_samples(
    scene_file: str, duration: float, args: dict | None = None, ideal_force: tuple[float, float] | None = None
) -> Samples:
    """A shipped scene composed in this process (what `dockhil launch --composed` runs), its
    per-tick series collected by a tap; `args` as `name:=value` on the command line."""
    from dockhil.analysis.summary import Collector
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    overrides = launchfile.parse_overrides([f"{k}:={v}" for k, v in (args or {}).items()])
    scene = launchfile.load(LAUNCH_DIR / scene_file, overrides)
    n = int(round(duration / scene.dt)) + 1
    collect = Collector(ideal_force)
    g = ComposedGraph(build(scene), log=lambda name, msg: None, taps=[collect])
    g.setup()
    try:
        g.run(n)
    finally:
        g.close()
    return collect.samples()


def launch_subprocess(
    scene: str | PathLike[str],
    duration: float,
    args: dict | None = None,
    bag: str | None = None,
    timeout: float = 300.0,
) -> dict:
    """`dockhil launch SCENE --duration S` as its own process tree; returns exit
    code, output and wall time (process start-up included)."""
    argv = [sys.executable, "-m", "dockhil.cli", "launch", str(scene), "--duration", repr(duration), "--quiet"]
    argv += [f"{k}:={v}" for k, v in (args or {}).items()]
    if bag:
        argv += ["--bag", bag]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    t0 = time.perf_counter()
    try:
        done = subprocess.run(argv, cwd=str(ROOT), capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        raise DockhilError(f"dockhil launch {scene} did not finish within {timeout:g} s") from None
    return {
        "code": done.returncode,
        "stdout": done.stdout,
        "stderr": done.stderr,
        "run_time_s": time.perf_counter() - t0,
    }


def bag_samples(path: str, ideal_force: tuple[float, float] | None = None) -> Samples:
    from dockhil.analysis.plots.runplot import load_samples

    return load_samples(path, ideal_force)


def graph_cost(cfg: ReportConfig, progress: TaskProgress | None = None) -> dict:
    """hil.yaml run three ways: the model library's loop, composed in one process,
    separate processes. Run times side by side; trajectories compared bit for bit."""
    from dockhil.analysis.summary import ideal_reference, summarize

    say = progress.step if progress else (lambda label: None)
    duration = cfg.graph_duration
    runs: dict[str, tuple[Samples, float, str]] = {}
    say("graph cost: model library loop")
    lib, t_lib = best_time(lambda: _hil_library(duration), cfg.min_timing_s)
    runs["library"] = (lib, t_lib, "dockhil.contact.hilloop.simulate_hil")
    say("graph cost: composed graph")
    comp, t_comp = best_time(lambda: composed_samples("hil.yaml", duration), cfg.min_timing_s)
    runs["composed"] = (comp, t_comp, "ComposedGraph(hil.yaml), one process, a tap collecting the series")
    say("graph cost: multi-process graph")
    multi = None
    recorded: dict | None
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "hil.mcap")
        if cfg.quick:  # one run, timed while it records (the recorder is one more process)
            timed = recorded = launch_subprocess(LAUNCH_DIR / "hil.yaml", duration, bag=path)
            when = "in the timed run (its time includes the recorder)"
        else:
            timed = launch_subprocess(LAUNCH_DIR / "hil.yaml", duration)
            recorded = None if timed["code"] != 0 else launch_subprocess(LAUNCH_DIR / "hil.yaml", duration, bag=path)
            when = "in a second run"
        if timed["code"] != 0:
            raise DockhilError(f"dockhil launch launch/hil.yaml failed: {last_line(timed)}")
        recorded = cast(dict, recorded)  # the timed run passed: the recording ran
        if recorded["code"] == 0 and os.path.exists(path):
            multi = bag_samples(path)
            how = f"recorded with --bag {when} and read back through the same Collector"
        else:
            how = f"not compared: the --bag run failed ({last_line(recorded)})"
    startup = launch_subprocess(LAUNCH_DIR / "hil.yaml", 0.001)
    ideal = ideal_reference(
        m1=TABLE1.m1, m2=TABLE1.m2, kcs=TABLE1.kcs, bcs=TABLE1.bcs, v1=TABLE1.v1, v2=TABLE1.v2, t=lib.t
    )
    out: dict[str, Any] = {
        "scene": "launch/hil.yaml (Table 1, delay 32 ms, 1 kHz, sim time)",
        "sim_time_s": duration,
        "modes": [],
    }
    for name, (s, elapsed, what) in runs.items():
        summary = summarize(s, run_time_s=elapsed, ideal=ideal)
        out["modes"].append(
            {
                "mode": name,
                "what": what,
                "run_time_s": elapsed,
                "real_time_factor": duration / elapsed,
                "error_vs_ideal": summary["error"],
                "peak_force_N": summary["peak_force_N"],
            }
        )
    mp = {
        "mode": "multiprocess",
        "what": "python -m dockhil.cli launch launch/hil.yaml (one process per node)",
        "run_time_s": timed["run_time_s"],
        "real_time_factor": duration / timed["run_time_s"],
        "startup_s": startup["run_time_s"] if startup["code"] == 0 else None,
        "trajectory": how,
    }
    if multi is not None:
        summary = summarize(multi, run_time_s=timed["run_time_s"], ideal=ideal)
        mp["error_vs_ideal"] = summary["error"]
        mp["peak_force_N"] = summary["peak_force_N"]
    out["modes"].append(mp)
    out["composed_equals_library"] = _same(comp, lib)
    out["multiprocess_equals_library"] = None if multi is None else _same(multi, lib)
    out["max_abs_difference_N"] = {
        "composed_vs_library": _max_diff(comp.force, lib.force),
        "multiprocess_vs_library": None if multi is None else _max_diff(multi.force, lib.force),
    }
    return out


def _same(a: Samples, b: Samples) -> bool:
    """Bit-identical per-tick series (time, penetration, rate, force)."""
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("t", "p", "pd", "force"))


def _max_diff(a: np.ndarray, b: np.ndarray) -> float | None:
    if len(a) != len(b):
        return None
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) if len(a) else 0.0


def last_line(result: dict) -> str:
    lines = [ln for ln in (result["stderr"] + result["stdout"]).splitlines() if ln.strip()]
    return lines[-1] if lines else f"exit code {result['code']}"


def run_cli(argv: list[str], timeout: float = 120.0) -> tuple[int, str]:
    """Run the dockhil command as a user would, in a process of its own (the analyses sit below the
    command line and never import it); exit code and stderr."""
    done = subprocess.run([sys.executable, "-m", "dockhil.cli", *argv], capture_output=True, text=True, timeout=timeout)
    return done.returncode, done.stderr
