"""A wall-time run that ends when a node says so: `dockhil calibrate` ends its identification run once
the profile says 'done' (the robot back and holding), not at the longest the profile could take. The
launcher stops the graph as at its duration, a second later (END_AFTER_S), and the run is judged as
any other; a state not said leaves the duration to end it."""

from __future__ import annotations

import logging
import signal
import time

import pytest

SCENE = """
rate: 100
nodes:
  - {name: announcer, node: "tests.support.graphnodes:Announcer", params: {done_at: DONE}}
"""


class Said(logging.Handler):
    """The dockhil logger's records, whatever handlers an earlier test left on it."""

    def __init__(self):
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def run(write_launch, done_at: int, duration: float, state: str) -> tuple[int, float, str]:
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build
    from dockhil.session import run_scene

    graph = build(launchfile.load(write_launch(SCENE.replace("DONE", str(done_at)))))
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    said, logger = Said(), logging.getLogger("dockhil")
    level = logger.level
    logger.addHandler(said)
    logger.setLevel(logging.INFO)
    start = time.monotonic()
    try:
        code = run_scene(graph, clock="wall", duration=duration, show_summary=False, end_on=("/status", state))
    finally:  # the launcher's stop handlers are this test process's no longer
        logger.removeHandler(said)
        logger.setLevel(level)
        for s, h in handlers.items():
            signal.signal(s, h)
    return code, time.monotonic() - start, "\n".join(said.lines)


@pytest.mark.wall_time
def test_a_run_ends_a_second_after_its_node_says_done_and_not_before(write_launch):
    from dockhil.runtime.launcher import END_AFTER_S

    code, took, said = run(write_launch, done_at=50, duration=60.0, state="done")  # 'done' 0.5 s in
    assert code == 0, said
    assert "/status says 'done': the run ends in 1 s" in said
    assert END_AFTER_S <= took < 30.0, took  # not the 60 s duration (start-up and a busy machine aside)


@pytest.mark.wall_time
def test_a_state_never_said_leaves_the_duration_to_end_the_run(write_launch):
    code, took, said = run(write_launch, done_at=50, duration=2.0, state="finished")
    assert code == 0 and "says" not in said, said
    assert took >= 2.0
