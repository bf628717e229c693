"""The end of a wall-time recording: a recorder that fell behind the graph still held the end of the
run when the graph stopped. Nothing follows that loss, so no gap shows it; the publishers' counts,
reported as the nodes exit and told to the recorder by the launcher, do (dockhil.bags.tail)."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import zmq

from dockhil.bags.reader import BagReader
from dockhil.bags.tail import Told, missing, tail_lines
from dockhil.runtime import transport
from dockhil.runtime.executor import TIMING
from dockhil.runtime.launcher import SENT, Launcher
from dockhil.runtime.transport import GraphKeys, Publisher
from dockhil.scene import launchfile
from dockhil.scene.graph import build
from tests.conftest import dockhil_cmd, registered


@pytest.fixture
def small_queues(monkeypatch):
    """Queues of 1000 messages, so that one the recorder does not read fills in a moment."""
    monkeypatch.setattr(transport, "HWM", 1000)


class Steps:
    """A clock the test controls: each reading is `step` seconds after the one before."""

    def __init__(self, step: float):
        self.now, self.step = 0.0, step

    def __call__(self) -> float:
        self.now += self.step
        return self.now


def wrench(k: int) -> bytes:
    from dockhil.msgs import Header, WrenchStamped
    from dockhil.msgs.codec import encode

    return encode(WrenchStamped(header=Header(stamp=1.0 + k * 0.001, tick=k, seq=k)))


def recorder_of(tmp_path, linger_s: float = 2.0):
    """A wall-time publisher of /ft/wrench in this process and the launch's Recorder of it (a graph
    member, as the recorder process is), the recorder's subscription in."""
    from dockhil.bags.live import Recorder, Source

    keys = GraphKeys.make()
    key_file = keys.write(tmp_path / "graph.keys")
    endpoint = f"ipc://{tmp_path}/ft.wrench"
    pub = Publisher(zmq.Context.instance(), "/ft/wrench", endpoint, linger_s, keys=keys, lossy=True)
    lines: list[str] = []
    source = Source("/ft/wrench", endpoint, "dockhil/WrenchStamped", False, os.getpid(), "r", str(key_file))
    rec = Recorder(str(tmp_path / "rec.mcap"), {"/ft/wrench": source}, log=lines.append)
    pub.wait_subscribers(1, 20.0)
    return pub, rec, lines


def test_a_recorder_that_fell_behind_counts_the_end_it_never_got(tmp_path, small_queues):
    """The recorder reads nothing while the publisher fills every queue on the way (its own, the
    kernel's, the recorder's), then the publisher closes at once (a node whose linger ran out): what
    its queue held never arrives. No gap shows it; the count does."""
    pub, rec, lines = recorder_of(tmp_path, linger_s=0.0)
    try:
        k, refused_after_wait = 0, False
        while not refused_after_wait and k < 200_000:  # until every queue on the way is full
            before = pub.dropped
            pub.send(wrench(k))
            k += 1
            if pub.dropped > before:  # the publisher's queue is full: is there room behind it?
                time.sleep(0.2)  # its I/O thread hands on what fits (late, on a busy machine)
                before = pub.dropped
                pub.send(wrench(k))
                k += 1
                refused_after_wait = pub.dropped > before
        taken = pub.taken
        pub.close()  # linger 0: what its queue holds is gone
        rec.drain()
        rec.bag.flush()
        assert rec.lost == 0  # what arrived has no gap: the loss does not show
        rec.await_sent(lambda: {"/ft/wrench": taken}, clock=Steps(0.05))
    finally:
        line = rec.close()
    assert refused_after_wait and taken == k - pub.dropped and 0 < rec.received < taken
    assert rec.tail == {"/ft/wrench": (taken - rec.received, taken)} and rec.lost == taken - rec.received
    assert lines[0] == (
        f"error: the end of the run is missing from the bag: /ft/wrench: {rec.lost} of the {taken} message(s) "
        f"sent never arrived (the recorder fell behind)"
    )
    assert line.endswith(f"; {rec.lost} lost ({rec.lost} at the end of the run, never arrived)"), line
    with BagReader(tmp_path / "rec.mcap") as reader:
        assert sum(1 for _ in reader) == rec.received


def test_a_recorder_behind_reads_on_until_it_has_what_was_sent(tmp_path):
    """The normal end: the messages are still in flight when the counts come; the recorder reads
    them all, and stops as soon as it has them (no quiet time waited out)."""
    pub, rec, lines = recorder_of(tmp_path)
    clock = Steps(0.001)
    try:
        for k in range(500):
            pub.send(wrench(k))
        rec.await_sent(lambda: {"/ft/wrench": 500}, clock=clock, quiet_s=1.0)
    finally:
        line = rec.close()
        pub.close()
    assert rec.received == 500 and rec.tail == {} and rec.lost == 0 and lines == [line]
    assert clock.now < 1.0  # it stopped once all was in
    assert line.endswith("; 0 lost"), line


def test_a_recorder_not_told_the_counts_stops_waiting_and_says_so(tmp_path):
    """A launcher that never tells (it was killed): the wait is bounded; the end is not counted,
    and the recorder says that it is not known."""
    pub, rec, lines = recorder_of(tmp_path)
    clock = Steps(1.0)
    try:
        rec.await_sent(lambda: None, clock=clock, wait_s=15.0)
    finally:
        rec.close()
        pub.close()
    assert 15.0 <= clock.now < 20.0 and rec.lost == 0
    assert lines[0] == (
        "warning: not told within 15 s what the publishers sent; whether the bag misses the end of the run is not known"
    )


def test_a_topic_without_a_count_is_not_waited_for_and_said(tmp_path):
    pub, rec, lines = recorder_of(tmp_path)
    clock = Steps(0.001)
    try:
        rec.await_sent(lambda: {}, clock=clock, quiet_s=100.0)
    finally:
        rec.close()
        pub.close()
    assert clock.now < 1.0 and rec.lost == 0
    assert lines[0] == (
        "note: not known what was sent on /ft/wrench (its node ended without its report: killed, or "
        "crashed; or it runs on another host): whether the bag misses their end is not known"
    )


def test_the_counts_and_the_verdict_come_in_their_order_and_an_end_is_an_end():
    told = Told(io.StringIO(SENT + json.dumps({"/a": 3, "/b": 0}) + "\n" + '{"verdict": "valid"}\n'))
    deadline = time.monotonic() + 10
    while (sent := told.sent()) is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert sent == {"/a": 3, "/b": 0}
    assert told.verdict_line() == '{"verdict": "valid"}\n' and told.verdict_line() == ""

    told = Told(io.StringIO('{"verdict": "valid"}\n'))  # no counts: a sim-time run's recorder
    assert told.verdict_line() == '{"verdict": "valid"}\n' and told.sent() == {} and told.verdict_line() == ""
    told = Told(io.StringIO(SENT + "not json\n"))
    time.sleep(0.1)
    assert told.sent() == {} and told.verdict_line() == ""


def test_what_is_missing_and_how_it_is_said():
    assert missing({"/a": 10, "/b": 5, "/c": 7}, {"/a": 4, "/b": 5, "/c": 9}) == {"/a": (6, 10)}
    assert missing({"/x": 3}, {"/a": 0}) == {}  # a topic not recorded
    assert tail_lines({}, []) == []
    assert tail_lines({"/a": (6, 10), "/b": (1, 2)}, ["/c"]) == [
        "error: the end of the run is missing from the bag: /a: 6 of the 10 message(s) sent, "
        "/b: 1 of the 2 message(s) sent never arrived (the recorder fell behind)",
        "note: not known what was sent on /c (its node ended without its report: killed, or crashed; or "
        "it runs on another host): whether the bag misses their end is not known",
    ]


# -- the launcher: the counts from the nodes' exit reports ----------------------------------------


class Exited:
    """A node process that printed `lines` and exited."""

    def __init__(self, lines: list[str]):
        self.stdout = iter(lines)

    def wait(self, timeout=None):
        return 0


def timing_line(name: str, published: dict) -> str:
    return TIMING + json.dumps({"node": name, "ticks": 10, "published": published}) + "\n"


def test_the_launcher_adds_up_the_counts_and_leaves_out_a_node_that_did_not_report_every_run():
    hil = Path(__file__).resolve().parent.parent / "launch" / "hil.yaml"
    launcher = Launcher(build(launchfile.load(hil)), clock="wall", duration=1.0)
    child = {c.name: c for c in launcher.children}
    dyn, ft, robot = child["dynamics"], child["ft"], child["robot"]
    dyn.starts = ft.starts = 1
    launcher._read(dyn, Exited([timing_line("dynamics", {"/satellite/state": 7, "/robot/command": 7})]))
    ft.starts = 2  # respawned: both runs reported (it exited with an error, not killed)
    launcher._read(ft, Exited([timing_line("ft", {"/ft/wrench": 5})]))
    launcher._read(ft, Exited([timing_line("ft", {"/ft/wrench": 4})]))
    robot.starts = 2  # respawned after SIGKILL: its first run said nothing
    launcher._read(robot, Exited([timing_line("robot", {"/robot/state": 3})]))
    assert launcher.sent_counts() == {"/satellite/state": 7, "/robot/command": 7, "/ft/wrench": 9}


# -- end to end -----------------------------------------------------------------------------------


SMALL_SCENE = """
rate: 1000
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator"}
  - {name: gain, node: "tests.support.graphnodes:Gain"}
"""


_sizes: dict[Path, list[int]] = {}


def chunks(bag: Path) -> int:
    """How many times the bag has grown since it was made: the recorder puts a chunk on disk
    every half second while messages come."""
    size = bag.stat().st_size if bag.exists() else 0
    seen = _sizes.setdefault(bag, [])
    if size and (not seen or size != seen[-1]):
        seen.append(size)
    return len(seen) - 1


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.wall_time
def test_a_recorder_stalled_over_the_end_of_a_wall_time_run_fails_it_with_the_count(write_launch, tmp_path):
    """The recorder is stopped (SIGSTOP) from early in the run until its nodes have exited:
    the end of the run waited in their queues, which their linger dropped. Before, the recorder
    drained what the kernel held and said "0 lost"; now the count of what was sent says what is
    missing, and the run fails as for any recorder loss."""
    scene = write_launch(SMALL_SCENE)
    bag = tmp_path / "run.mcap"
    launch = subprocess.Popen(
        dockhil_cmd("launch", scene, "--wall-time", "--duration", "4", "--bag", bag),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    recorder = None
    try:
        entry = registered(launch.pid, timeout=60)
        nodes = [entry["nodes"][n]["pid"] for n in ("integ", "gain")]
        recorder = entry["nodes"]["bag-recorder"]["pid"]
        deadline = time.monotonic() + 60
        while chunks(bag) < 2 and time.monotonic() < deadline:  # messages flow: the graph runs, recorded
            time.sleep(0.01)
        os.kill(recorder, signal.SIGSTOP)
        while not all(gone(pid) for pid in nodes) and time.monotonic() < deadline:
            time.sleep(0.05)
        os.kill(recorder, signal.SIGCONT)
        out, _ = launch.communicate(timeout=120)
    finally:
        if recorder is not None and not gone(recorder):
            os.kill(recorder, signal.SIGCONT)
        if launch.poll() is None:
            launch.kill()
            launch.wait()
    assert "Traceback" not in out, out
    missing_line = next(x for x in out.splitlines() if "the end of the run is missing from the bag" in x)
    said = {}
    for part in missing_line.split(": ", 2)[2].split(" never arrived")[0].split(", "):
        topic, rest = part.split(": ")
        said[topic] = (int(rest.split(" of the ")[0]), int(rest.split(" of the ")[1].split(" ")[0]))
    with BagReader(bag) as reader:
        on_disk: dict[str, int] = {}
        for m in reader:
            on_disk[m.topic] = on_disk.get(m.topic, 0) + 1
    assert said and all(m > 0 and on_disk[t] + m == n for t, (m, n) in said.items()), (said, on_disk)
    lost = sum(m for m, _ in said.values())
    assert f"; {lost} lost ({lost} at the end of the run, never arrived)" in out, out
    assert f"[bag-recorder] error: {lost} message(s) lost; the recording of this run is incomplete" in out
    assert "[launch] node 'bag-recorder' exited with code 4 after the run" in out and "stopping the graph" not in out
    assert launch.returncode == 1, out


@pytest.mark.wall_time
def test_a_wall_time_run_recorded_whole_says_0_lost(write_launch, tmp_path):
    """The recorder keeps up (at 200 Hz it would have to stop for a second to fall behind): every
    message sent is in the bag, and it says 0 lost, judged on the counts. (DOCKHIL_TIMING_DIR: each
    node writes there the report it gives the launcher, with what it sent.)"""
    bag = tmp_path / "run.mcap"
    reports = tmp_path / "timing"
    reports.mkdir()
    r = subprocess.run(
        dockhil_cmd(
            "launch", write_launch(SMALL_SCENE.replace("1000", "200")), "--wall-time", "--duration", "1", "--bag", bag
        ),
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ, DOCKHIL_TIMING_DIR=str(reports)),
    )
    assert r.returncode in (0, 3) and "Traceback" not in r.stderr, r.stderr  # 3: a machine too busy to keep up
    assert "[bag-recorder] recorded " in r.stderr and f"to {bag}; 0 lost" in r.stderr, r.stderr
    assert "missing from the bag" not in r.stderr and "not known" not in r.stderr, r.stderr
    sent = {}
    for name in ("integ", "gain"):
        sent.update(json.loads((reports / f"{name}.json").read_text())["published"])
    with BagReader(bag) as reader:
        on_disk: dict[str, int] = {}
        for m in reader:
            on_disk[m.topic] = on_disk.get(m.topic, 0) + 1
    assert sent == on_disk and min(sent.values()) > 100, (sent, on_disk)


@pytest.mark.wall_time
@pytest.mark.parametrize("respawn", [True, False], ids=["respawned", "crashed"])
def test_a_node_that_ends_without_its_report_leaves_its_topic_unjudged_and_the_recorder_finishes(
    write_launch, tmp_path, respawn
):
    """A node that exits abruptly (no exit report): respawned, the run goes on and is INVALID for it;
    crashed, the graph stops (exit 1). Either way the recorder does not wait for its topic's end,
    says that it is not known, and closes the bag with the run's verdict."""
    from tests.test_busy_machine import RESPAWNED

    text = RESPAWNED.replace("MARKER", str(tmp_path / "died"))
    if not respawn:
        text = text.replace("respawn: true, ", "")
    bag = tmp_path / "run.mcap"
    started = time.monotonic()
    r = subprocess.run(
        dockhil_cmd("launch", write_launch(text), "--wall-time", "--duration", "3", "--bag", bag),
        capture_output=True,
        text=True,
        timeout=120,
    )
    took = time.monotonic() - started
    text = r.stderr
    assert "Traceback" not in text and "not told within" not in text, text
    assert "[bag-recorder] note: not known what was sent on /u (its node ended without its report" in text, text
    missing_lines = [x for x in text.splitlines() if "missing from the bag" in x]
    assert not any("/u:" in x for x in missing_lines), text  # never judged on a count that is not known
    if respawn and not missing_lines:  # (a machine so busy that the recorder lost the end of /x fails the run)
        assert r.returncode == 3 and f"to {bag}; 0 lost" in text, text
    else:
        assert r.returncode == 1, text
    print(f"{'respawned' if respawn else 'crashed'}: the launch took {took:.1f} s")
