"""One run of a scene: multi-process or composed, with optional recording and summary."""

from __future__ import annotations

import sys
import time

from dockhil.graph import Graph


def run_scene(graph: Graph, *, clock: str = "sim", duration: float | None = None, composed: bool = False,
              transport: str = "ipc", bag: str | None = None, summary: str | None = None,
              progress: bool = False) -> int:
    dt = graph.scene.dt
    n_ticks = None if duration is None else int(round(duration / dt)) + 1
    started = time.perf_counter()
    if composed:
        code = _run_composed(graph, clock, n_ticks, progress, bag)
    else:
        from dockhil.launcher import Launcher

        extra = []
        if bag is not None:
            from dockhil import bag_live

            bag_live.check_bag_path(bag)  # a bag that cannot be written fails the launch before any node runs
            extra.append(bag_live.recorder_process(bag, graph, clock, n_ticks))
        code = Launcher(graph, clock=clock, duration=duration, transport=transport, extra=extra).run()
    elapsed = time.perf_counter() - started
    if code == 0 and clock == "sim" and n_ticks:
        sim_s = (n_ticks - 1) * dt
        print(f"[launch] done: {sim_s:g} s simulated in {elapsed:.2f} s "
              f"({sim_s / elapsed:.1f}x real time)", file=sys.stderr)
    return code


def _run_composed(graph: Graph, clock: str, n_ticks: int | None, progress: bool, bag: str | None = None) -> int:
    from dockhil.composed import ComposedGraph
    from dockhil.errors import DockhilError
    from dockhil.executor import Stop

    stop = Stop()
    stop.install()
    g = ComposedGraph(graph, sim_time=clock == "sim")
    recorder = None
    if bag is not None:
        from dockhil.bag_live import TapRecorder

        recorder = TapRecorder(bag, graph, sim=clock == "sim")
        g.taps.append(recorder)
    try:
        g.setup()
        g.run(n_ticks, wall=clock == "wall", stop=stop)
    except DockhilError as exc:
        print(f"[launch] error: {exc}", file=sys.stderr)
        return 1
    finally:
        try:
            g.close()
        finally:
            if recorder is not None:
                recorder.close()
    return 130 if stop.requested else 0
