"""The summary of a recorded run from its bag alone (`dockhil analyze`).

The bag holds its run (dockhil.bags.runinfo): the scene's launch files and arguments rebuild the graph
the run ran, and the summary is the one the launch printed, computed by the same code from the same
messages (SummaryCollector, feed_from_bag; a 6-DOF scene's by summary6): peak force, duration, entry and
exit velocity and restitution against the scene's ideal contact, the energy account, the sampled loop.
What the bag cannot know is how long the machine took (run_time_s, real_time_factor: left out). The
validity is the one recorded; reasons the messages give besides (a scene changed with name:=value) are
added. A bag of an older dockhil holds no scene: `--scene FILE [name:=value ...]` names it, or the ideal
contact's --kcs, --bcs, --m1, --m2, --v1, --v2 stand on hil.yaml's loop (ideal.yaml's, when the bag
holds no measured or virtual force).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from dockhil.bags import runinfo
from dockhil.errors import DockhilError

if TYPE_CHECKING:
    from dockhil.analysis.summary import SummaryCollector1
    from dockhil.analysis.summary.dof6 import SummaryCollector6
    from dockhil.scene.graph import Graph

IDEAL_ARGS = ("kcs", "bcs", "m1", "m2", "v1", "v2")  # the ideal contact, as launch arguments of hil.yaml
_FORCE_TOPICS = ("/ft/wrench", "/impedance/wrench")


class AnalyzeError(DockhilError):
    """A bag that cannot be analyzed as asked: one line, what is missing and what to pass."""


@dataclass
class Analysis:
    summary: dict  # the launch's summary keys, less run_time_s and real_time_factor; `run`: the bag's run
    info: runinfo.RunInfo
    graph: Graph
    scene: str  # where the scene came from, in a few words

    @property
    def valid(self) -> bool:
        return bool(self.summary.get("valid"))


def scene_graph(
    path: str, info: runinfo.RunInfo, scene_file: str | None = None, overrides: dict | None = None
) -> tuple[Graph, str]:
    """(graph, where its scene came from) of the run a bag recorded."""
    from dockhil.analysis.plots.runplot import bag_graph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    overrides = dict(overrides or {})
    if scene_file is not None:
        return build(launchfile.load(scene_file, overrides)), f"{scene_file} (given)"
    if len(info.runs) > 1:
        raise AnalyzeError(
            f"{path}: the bag holds {len(info.runs)} runs (recorded from outside across graphs); "
            f"name the one to analyze with --scene FILE [name:=value ...]"
        )
    graph = bag_graph(path, overrides, info)
    if graph is not None:
        changed = f", with {' '.join(f'{k}:={v}' for k, v in overrides.items())}" if overrides else ""
        return graph, f"recorded{changed}"
    if any(name in overrides for name in IDEAL_ARGS):
        stand_in = "hil.yaml" if _has_force_topics(path) else "ideal.yaml"
        return (
            build(launchfile.load(stand_in, overrides)),
            f"not recorded: the given ideal contact on {stand_in}'s loop",
        )
    why = info.why if not info.runs else "the bag holds no scene (its graph registered none)"
    raise AnalyzeError(
        f"{path}: {why}, so its scene and ideal contact are not known; pass the scene, "
        f"--scene FILE [name:=value ...] (e.g. --scene hil.yaml delay:=0.016), or the ideal "
        f"contact, --kcs --bcs --m1 --m2 --v1 --v2"
    )


def _has_force_topics(path: str) -> bool:
    from dockhil.bags.reader import BagReader

    with BagReader(path) as reader:
        return any(t["topic"] in _FORCE_TOPICS and t["count"] for t in reader.summary()["topics"])


class _Ticks:
    """Hands each message on to the summary, and holds the bag's tick spacing against the scene's: a
    scene at another rate would put every sample at the wrong time."""

    def __init__(self, collector: SummaryCollector1 | SummaryCollector6, dt: float, path: str):
        self.collector, self.dt, self.path = collector, dt, path
        self.states = 0

    def __call__(self, topic: str, msg: Any) -> None:  # a message of the topic's type
        if topic == "/satellite/state":
            self.states += 1
            h = msg.header
            if self.states <= 3 and h.tick > 0 and h.stamp < 1e6:  # sim time: stamp = tick dt
                spacing = h.stamp / h.tick
                if not math.isclose(spacing, self.dt, rel_tol=1e-6):
                    raise AnalyzeError(
                        f"{self.path}: the bag's ticks are {spacing * 1e3:.6g} ms apart, the scene's "
                        f"{self.dt * 1e3:.6g} ms; give the scene its rate (rate:={1 / spacing:.6g})"
                    )
        self.collector(topic, msg)


def analyze(path: str, scene_file: str | None = None, overrides: dict | None = None) -> Analysis:
    from dockhil.analysis.summary import SummaryCollector, feed_from_bag

    info = runinfo.read_path(path)
    graph, scene = scene_graph(path, info, scene_file, overrides)
    if "/satellite/state" not in graph.publishers:
        raise AnalyzeError(
            f"{path}: its scene ({scene}) publishes no /satellite/state: there is no contact to summarize"
        )
    collector = SummaryCollector(graph)
    ticks = _Ticks(collector, graph.scene.dt, path)
    feed_from_bag(path, ticks)
    if not ticks.states:
        raise AnalyzeError(f"{path}: no /satellite/state messages; record the dynamics' state to analyze a run")
    out = collector.summary(None)
    for key in ("run_time_s", "real_time_factor"):  # the machine's speed: not in the bag
        out.pop(key, None)
    own = list(out.get("invalid_reasons") or [])
    if info.valid is None:  # not recorded, or not told: the messages alone judge
        reasons = own
    else:
        recorded = info.reasons
        reasons = recorded + [r for r in own if r not in recorded]
    out["valid"] = not reasons
    out["invalid_reasons"] = reasons
    out["run"] = dict(info.as_json() or {"verdict": info.state, "why": info.why}, bag=path, analyzed_scene=scene)
    return Analysis(out, info, graph, scene)


def validity_line(a: Analysis) -> str:
    """The run's validity in one line, as recorded (or why it is not known)."""
    from dockhil.runtime.validity import INVALID_EXIT, invalid_line

    state = a.info.state
    if not a.valid:
        return f"{invalid_line(a.summary['invalid_reasons'])} (exit {INVALID_EXIT})"
    if state == "valid":
        return "valid (as recorded: the launch exited 0)"
    if state == "not recorded":
        return f"valid as far as its messages show (no verdict recorded: {a.info.why})"
    return f"valid as far as its messages show (the recorded verdict is {state}: {a.info.why})"


def figures(a: Analysis, path: str, out_dir: str) -> list[str]:
    """The run's figures in out_dir: force and velocity against the ideal (a 1-DOF run, with its energy),
    or the 6-DOF figure; returns the files written."""
    import os

    from dockhil.analysis.plots.runplot import is_sixdof, plot_runs

    try:  # made as `figures --out` makes its own
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise AnalyzeError(f"--png {out_dir}: cannot create the folder ({exc.strerror or exc})") from None
    stem = os.path.splitext(os.path.basename(path))[0]
    if is_sixdof(a.graph):
        from dockhil.analysis.plots.plot6 import plot6

        png = os.path.join(out_dir, f"{stem}-6dof.png")
        plot6([path], png)
    else:
        png = os.path.join(out_dir, f"{stem}-force-velocity.png")
        plot_runs([path], png, graphs=[a.graph])
    return [png]
