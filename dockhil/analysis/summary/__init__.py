"""The summary of a docking run: peak contact force, contact duration, entry and exit velocity,
coefficient of restitution, and, where the scene has an ideal reference, the same from the ideal
model and the errors; for a body held against a sheet, the growth rate of its oscillation.

Everything is computed in one pass over the ticks with O(1) memory, so a summary of a run of any
length costs the same memory: the live summary of a composed run (`SummaryCollector`, a tap), a
recorded bag (`feed_from_bag`), or arrays of the model library's own loop (`contact_metrics`,
`summarize`).

Modules: `common` (what both kinds share: the tick matcher, the contact and range meters),
`dof1` (the 1-DOF scenes), `dof6` (the 6-DOF scene: docs/sixdof.md). The kind of a scene picks
its summary here and nowhere else.
"""

from __future__ import annotations

from dockhil.analysis.scenecheck import first_node
from dockhil.analysis.summary.common import (
    SUMMARY_TOPICS,
    ContactMeter,
    RangeMeter,
    Samples,
    TickMatcher,
    feed_from_bag,
)
from dockhil.analysis.summary.dof1 import (
    Collector,
    SummaryCollector1,
    contact_metrics,
    format_summary1,
    ideal_reference,
    ideal_summary,
    samples_from_bag,
    scene_reference,
    scene_summary,
    summarize,
)

__all__ = [
    "SUMMARY_TOPICS",
    "Collector",
    "ContactMeter",
    "RangeMeter",
    "Samples",
    "SummaryCollector",
    "TickMatcher",
    "contact_metrics",
    "feed_from_bag",
    "format_summary",
    "ideal_reference",
    "ideal_summary",
    "samples_from_bag",
    "scene_reference",
    "scene_summary",
    "summarize",
]


def SummaryCollector(graph):
    """The run summary's collector for this scene: a 6-DOF scene's (dof: 6, or the *6 name: the graph
    records the registered one) or the 1-DOF one. It is a tap (topic, msg), and `summary(run_time_s)`
    returns the summary."""
    if first_node(graph, "satellite_dynamics6") is not None:
        from dockhil.analysis.summary.dof6 import SummaryCollector6  # its rigid bodies only for a 6-DOF scene

        return SummaryCollector6(graph)
    return SummaryCollector1(graph)


def format_summary(out: dict) -> str:
    """A few readable lines of a summary, of either kind."""
    if out.get("dof") == 6:
        from dockhil.analysis.summary.dof6 import format_summary6

        return format_summary6(out)
    return format_summary1(out)
