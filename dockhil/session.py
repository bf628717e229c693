"""One run of a scene: multi-process or composed, with optional recording and summary.

A sim-time run of a scene with satellite dynamics ends with its summary
(peak force, contact duration, exit velocity, and the ideal model's where
the scene has one). In a multi-process run the summary is read back from
the run's bag: the one asked for with --bag, or a temporary one.

Exit 0 means the result is valid (dockhil/runtime/validity.py): a wall-time run
that fell behind, or any run that lost messages, says INVALID in one line,
carries "valid": false and its reasons in the summary, and exits with
INVALID_EXIT (3).

The summary table is the result (stdout); what the run says about itself is logged (stderr).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Set
from pathlib import Path
from typing import TYPE_CHECKING, cast

from dockhil.errors import DockhilError
from dockhil.files import complete_or_nothing, os_reason, remove_quietly
from dockhil.log import Log
from dockhil.runtime import validity
from dockhil.scene.graph import Graph

if TYPE_CHECKING:
    from dockhil.analysis.summary import SummaryCollector1
    from dockhil.analysis.summary.dof6 import SummaryCollector6
    from dockhil.bags.foxglove import FoxgloveBridge
    from dockhil.bags.tap import TapRecorder


def run_scene(
    graph: Graph,
    *,
    clock: str = "sim",
    duration: float | None = None,
    composed: bool = False,
    transport: str = "ipc",
    bag: str | None = None,
    summary: str | None = None,
    progress: bool = False,
    show_summary: bool = True,
    realtime: bool = False,
    foxglove: tuple[str, int] | None = None,
    end_on: tuple[str, str] | None = None,
) -> int:
    """foxglove: (host, port) to serve a live view of the run on (dockhil.bags.foxglove). end_on: (topic,
    state): a wall-time run ends, as at its duration, once a node says that state there (Launcher)."""
    say = Log("[launch]")

    dt = graph.scene.dt
    n_ticks = None if duration is None else int(round(duration / dt)) + 1
    has_dynamics = "/satellite/state" in graph.publishers
    if summary is not None and not has_dynamics:
        raise DockhilError(f"{graph.scene.path}: --summary needs a scene that publishes /satellite/state")
    # Files that cannot be written fail the launch first, in one line: before the summary's
    # analysis is imported (numpy) and before any node is made, composed or as a process.
    if summary is not None:
        _check_writable(summary, bag)
    if bag is not None:
        from dockhil.bags.live import check_bag_path

        check_bag_path(bag)
    from dockhil.analysis.scenecheck import scene_check

    # A run's validity is in its summary too (it left the physical range, a compensation saturated):
    # a run with dynamics always has one, printed or not.
    want_summary = has_dynamics and n_ticks is not None
    # The loop this scene will run: refused here (one line) when its step does not resolve the contact.
    for line in scene_check(graph)["warnings"]:
        say.warning(line)
    collector = None
    if want_summary:  # numpy and the models: only for a run that has a summary
        from dockhil.analysis import summary as summ

        collector = summ.SummaryCollector(graph)
    tmp = None
    bridge = None
    if foxglove is not None:  # before any node starts: a busy port is refused here
        from dockhil.bags.foxglove import start

        bridge = start(graph, clock=clock, host=foxglove[0], port=foxglove[1])
    started = time.perf_counter()
    reasons: list[str] = []
    judged: dict = {}
    ticking: list[float] = []  # [s] from the first tick to the end of the last: what the real-time factor counts

    def elapsed() -> float:
        """The run's time: the start-up (imports, devices, processes joining) is not the run's, so a
        run that kept up says 1x."""
        if not composed and not ticking:
            devices = launcher.devices()
            # Wall time: an emulated device ticks from its start, before the graph's go.
            span = ticking_span(launcher.timings, {n for n, device in devices.items() if device and clock == "wall"})
            if span is not None:
                ticking.append(span)
        return ticking[0] if ticking else time.perf_counter() - started

    def judge(code: int, timing: list[str]) -> dict:
        """The run's exit code and summary, once: before the recorder closes the bag, which records
        the verdict (dockhil.bags.runinfo)."""
        if not judged:
            reasons.extend(timing if code == 0 else [])
            judged.update(given=code, **_judge(code, reasons, collector, None if composed else bag, elapsed()))
        from dockhil.bags.runinfo import verdict_fields

        return verdict_fields(judged["code"], reasons)

    if composed:
        from dockhil.runtime.plan import check_composable

        check_composable(graph)
        recorder = None
        if bag is not None:
            from dockhil.bags.tap import TapRecorder

            recorder = TapRecorder(bag, graph, sim=clock == "sim", duration=duration, recorded_by="launch --composed")
        try:
            code = _run_composed(graph, clock, n_ticks, progress, recorder, collector, reasons, bridge, ticking)
            verdict = judge(code, [])
        finally:
            if recorder is not None:
                recorder.close(verdict if judged else None)
    else:
        from dockhil.runtime.launcher import Launcher
        from dockhil.runtime.transport import GraphKeys

        if bag is None and want_summary:
            tmp = tempfile.TemporaryDirectory(prefix="dockhil-summary-")
            bag = os.path.join(tmp.name, "run.mcap")
        extra = []
        if bag is not None:  # the recorder runs in a process of its own
            from dockhil.bags import live as bag_live

            # a bag only for the summary records what the summary reads: less for the recorder to keep up with
            topics = summ.SUMMARY_TOPICS if tmp is not None else ()
            extra.append(bag_live.recorder_process(bag, graph, clock, n_ticks, quiet=tmp is not None, topics=topics))

        def timing() -> list[str]:
            if clock == "wall":  # nodes on other hosts report to nobody here; a free-running node is an emulated device
                return validity.wall_time_reasons(launcher.timings, launcher.devices(), dt) + validity.respawn_reasons(
                    launcher.respawns
                )
            return validity.sim_time_reasons(launcher.timings)

        launcher = Launcher(
            graph,
            clock=clock,
            duration=duration,
            transport=transport,
            extra=extra,
            progress=progress,
            realtime=realtime,
            judge=lambda code: judge(code, timing()),
            end_on=end_on,
        )
        if bridge is not None:
            keys = cast(Path, launcher.endpoints.key_file)  # plan() wrote them
            bridge.observe(launcher.endpoints.topics, GraphKeys.read(keys))
        code = launcher.run()
        if not judged:  # no recorder was told: judged here
            judge(code, timing())
    if judged and code == judged["given"]:  # else the recorder failed after the verdict: the run did
        code = judged["code"]
    out = judged.get("out") if code == judged.get("code") else None
    if bridge is not None:
        bridge.close()
    try:
        if out is not None:
            if show_summary:
                print(summ.format_summary(out), flush=True)
            if summary is not None:
                try:
                    with complete_or_nothing(summary) as part, open(part, "w") as f:
                        f.write(json.dumps(out, indent=1))
                    say.info(f"summary written to {summary}")
                except DockhilError as exc:  # the disk filled during the run: the run is not complete
                    say.error(f"--summary: {exc}; the run's summary is lost")
                    code = 1
        elif code == 0 and clock == "sim" and n_ticks:
            run_s, sim_s = elapsed(), (n_ticks - 1) * dt
            say.info(f"done: {sim_s:g} s simulated in {run_s:.2f} s ({sim_s / run_s:.1f}x real time)")
    finally:
        if tmp is not None:
            tmp.cleanup()
    if reasons and code == validity.INVALID_EXIT:  # one line, right under the summary table where there is one
        say.error(f"{validity.invalid_line(reasons)} (exit {validity.INVALID_EXIT})", tag="")  # it says INVALID
    return code


def _judge(
    code: int,
    reasons: list[str],
    collector: SummaryCollector1 | SummaryCollector6 | None,
    bag: str | None,
    elapsed: float,
) -> dict:
    """code: INVALID_EXIT where the run has reasons (its summary's own added to `reasons`); out: the
    summary of a run that completed (read from `bag` in a multi-process run)."""
    if code == 0 and reasons:
        code = validity.INVALID_EXIT
    out = None
    if code in (0, validity.INVALID_EXIT) and collector is not None:
        from dockhil.analysis import summary as summ

        if bag is not None:
            summ.feed_from_bag(bag, collector)
        out = collector.summary(elapsed)
        reasons += out.get("invalid_reasons") or []  # the summary's own (a saturated compensation)
        out["valid"] = not reasons
        out["invalid_reasons"] = list(reasons)
        if reasons and code == 0:
            code = validity.INVALID_EXIT
    return {"code": code, "out": out}


SUMMARY_RESERVE = 64 * 1024  # [bytes] written before the run: a summary takes a few kB


def _check_writable(path: str, bag: str | None) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise DockhilError(f"--summary {path}: folder {folder} does not exist")
    if os.path.isdir(path):
        raise DockhilError(f"--summary {path}: is a directory; name a file, e.g. {os.path.join(path, 'summary.json')}")
    if bag is not None and os.path.realpath(path) == os.path.realpath(bag):
        raise DockhilError(f"--summary {path}: is the file --bag records to; give the summary another name")
    existed = os.path.exists(path)
    if existed and not _is_summary(path):
        raise DockhilError(
            f"--summary {path}: exists and is not the summary of a run (which it would replace); "
            f"choose another name or remove it"
        )
    if existed:  # an earlier run's: from here on the file is this run's summary or nothing
        try:
            os.remove(path)
        except OSError as exc:
            raise DockhilError(f"--summary {path}: cannot replace the earlier summary ({exc.strerror})") from None
    # Writing as much as a summary takes, to the disk, is the one test that holds for every user and
    # file system, and a full disk fails it now rather than after the run.
    try:
        with open(path, "wb") as f:
            f.write(b" " * SUMMARY_RESERVE)
            f.flush()
            os.fsync(f.fileno())
    except OSError as exc:
        raise DockhilError(
            f"--summary {path}: cannot be written ({os_reason(exc)}); free some space or give another path"
        ) from None
    finally:
        remove_quietly(path)


def ticking_span(timings: dict[str, dict], leave_out: Set[str] = frozenset()) -> float | None:
    """[s] from the graph's first tick to the end of its last, from the nodes' loop figures
    (LoopTiming.report), leaving out the nodes in `leave_out` unless no other ticked; None if none ticked."""
    spans = {
        name: (t["first_tick_at_s"], t["last_tick_at_s"])
        for name, t in timings.items()
        if t.get("first_tick_at_s") is not None and t.get("last_tick_at_s") is not None
    }
    kept = [span for name, span in spans.items() if name not in leave_out] or list(spans.values())
    if not kept:
        return None
    return max(end for _, end in kept) - min(start for start, _ in kept)


def _run_composed(
    graph: Graph,
    clock: str,
    n_ticks: int | None,
    progress: bool,
    recorder: TapRecorder | None,
    collector: SummaryCollector1 | SummaryCollector6 | None,
    reasons: list[str],
    bridge: FoxgloveBridge | None = None,
    ticking: list[float] | None = None,
) -> int:
    """recorder: a TapRecorder, left open (all on disk) for the run's verdict; ticking: gets the time
    from the first tick to the end of the last [s]."""
    from dockhil.progress import Progress
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.runtime.executor import Stop
    from dockhil.runtime.registry import register_composed

    stop = Stop()
    stop.install()
    g = ComposedGraph(graph, sim_time=clock == "sim")
    if recorder is not None:
        g.taps.append(recorder)
    if collector is not None:
        g.taps.append(collector)
    if bridge is not None:
        g.taps.append(bridge.tap)
    bar = Progress(n_ticks, graph.scene.dt) if progress and clock == "sim" else None
    failed = False
    entry = register_composed(graph, clock)  # for `dockhil node list` and `node info`
    try:
        g.setup()
        first_tick = time.perf_counter()
        g.run(n_ticks, wall=clock == "wall", stop=stop, progress=bar.update if bar else None)
        if ticking is not None:
            ticking.append(time.perf_counter() - first_tick)
    except DockhilError as exc:
        failed = _said(exc)
    finally:
        if bar is not None:
            bar.done()
        try:
            g.close()
        except DockhilError as exc:  # a driver holds the robot in close: its failure fails the run
            failed = _said(exc)
        finally:
            if recorder is not None:
                recorder.flush()
            if entry is not None:
                entry.unlink(missing_ok=True)
    if failed:
        return 1
    if stop.requested:
        return 130
    if recorder is not None and recorder.lost:
        Log("[launch]").error(
            f"the recorder lost {recorder.lost} message(s) ({recorder.path}); the run is not complete"
        )
        return 1
    if g.timing is not None:
        reasons += validity.node_reasons(g.timing.report("composed"), graph.scene.dt)
    return 0


def _said(exc: DockhilError) -> bool:
    """A composed run's failure, said in its one line (with DOCKHIL_TRACEBACK=1, the node's traceback)."""
    Log("[launch]").error(str(exc))
    if os.environ.get("DOCKHIL_TRACEBACK") and exc.__cause__ is not None:  # a node's own exception
        import traceback

        traceback.print_exception(exc.__cause__)
    return True


def _is_summary(path: str) -> bool:
    """An earlier run's summary (replaced by this run's), or an empty file; anything else is kept."""
    try:
        with open(path, "rb") as f:
            text = f.read(1 << 20)
        if not text:
            return True
        found = json.loads(text)
    except (OSError, ValueError):
        return False
    return isinstance(found, dict) and "sim_time_s" in found and "valid" in found
