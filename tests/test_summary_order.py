"""A summary read from a bag is the live run's whatever order the bag holds its topics in: the
recorder writes each topic as it came, and on a busy machine one topic can run hundreds of ticks
behind another (dockhil/analysis/summary/common.py TickMatcher)."""

import json

import pytest

from dockhil.analysis.summary import SummaryCollector
from dockhil.scene import graph as graphmod
from dockhil.scene import launchfile
from tests.conftest import ROOT
from tests.test_sixdof_graph import run_taps

LAG = 700  # ticks a force topic runs behind the states: more than the matcher's window of 256


def messages_of(scene: str, n_ticks: int):
    graph = graphmod.build(launchfile.load(ROOT / "launch" / scene))
    seen = []
    run_taps(graph, [lambda topic, msg: seen.append((topic, msg))], n_ticks)
    return graph, seen


def lagged(seen, late: set[str]):
    """The same messages, those of `late` topics each LAG states later than they were published."""
    out, held, states = [], [], 0
    for topic, msg in seen:
        if topic in late:
            held.append((states + LAG, topic, msg))
        else:
            out.append((topic, msg))
            if topic == "/satellite/state":
                states += 1
                while held and held[0][0] <= states:
                    out.append(held.pop(0)[1:])
    return out + [m[1:] for m in held]


def summary(graph, seen) -> str:
    collector = SummaryCollector(graph)
    for topic, msg in seen:
        collector(topic, msg)
    out = collector.summary(1.0)
    return json.dumps(out, sort_keys=True)


@pytest.mark.parametrize("scene", ["hil.yaml", "hil6.yaml"])
def test_a_force_topic_far_behind_the_states_gives_the_same_summary(scene):
    graph, seen = messages_of(scene, 1800)
    live = summary(graph, seen)
    for late in ({"/ft/wrench"}, {"/impedance/wrench"}, {"/ft/wrench", "/impedance/wrench"}):
        assert summary(graph, lagged(seen, late)) == live, late
