"""Wall-time runs on a busy machine: drivers stop before their devices' emulators, --realtime
reaches every thread on the delivery path (or says in one line why not), and a respawned node
makes the run invalid."""

import os
import re
import signal
import subprocess
from pathlib import Path

import pytest

from dockhil.node import Param
from dockhil.runtime import validity
from dockhil.runtime.launcher import Launcher
from dockhil.scene import launchfile
from dockhil.scene.graph import build
from tests.conftest import dockhil_cmd
from tests.support.graphnodes import Gain

HIL = Path(__file__).resolve().parent.parent / "launch" / "hil.yaml"


def emulated_graph(ft: str = "can", robot: str = "modbus"):
    return build(launchfile.load(HIL, {"ft": ft, "robot": robot, "emulators": True}))


class FakeProc:
    """A child that records when it was told to stop, and stops at once."""

    def __init__(self, name: str, stopped: list[str]):
        self.name, self.stopped, self.returncode, self.pid = name, stopped, None, 0

    def poll(self):
        return self.returncode

    def send_signal(self, sig):
        assert sig == signal.SIGTERM
        self.stopped.append(self.name)
        self.returncode = 0

    def wait(self, timeout=None):
        if self.returncode is None:
            raise subprocess.TimeoutExpired("fake", timeout)
        return self.returncode


def test_drivers_stop_before_the_emulators_of_their_devices():
    launcher = Launcher(emulated_graph(), clock="wall", duration=1.0)
    stopped: list[str] = []
    for child in launcher.children:
        child.proc = FakeProc(child.name, stopped)
    launcher.stop_all(grace=0.1)
    emulators = {n for n, emulated in launcher.devices().items() if emulated}
    assert emulators == {"ft_emulator", "robot_emulator"}
    assert set(stopped[-2:]) == emulators and not emulators & set(stopped[:-2])
    assert {"ft", "robot"} <= set(stopped[:-2])


def test_with_realtime_the_launcher_signals_every_node_above_their_priorities_then_returns(monkeypatch):
    """A launcher preempted between two nodes' stops would leave a reader ticking on a stopped
    publisher: it sends every stop at a priority above the nodes', and is back at its own after."""
    from dockhil.runtime import realtime

    policy = {"now": (os.SCHED_OTHER, 0)}
    seen: list[tuple[str, tuple]] = []

    def set_policy(pid, kind, param):
        assert pid == 0
        policy["now"] = (kind, param.sched_priority)

    monkeypatch.setattr(os, "sched_setscheduler", set_policy)
    monkeypatch.setattr(os, "sched_getscheduler", lambda pid: policy["now"][0])
    monkeypatch.setattr(os, "sched_getparam", lambda pid: os.sched_param(policy["now"][1]))

    class Seen(FakeProc):
        def send_signal(self, sig):
            seen.append((self.name, policy["now"]))
            super().send_signal(sig)

    for realtime_run, during in ((True, (os.SCHED_FIFO, realtime.SIGNAL_PRIORITY)), (False, (os.SCHED_OTHER, 0))):
        seen.clear()
        launcher = Launcher(emulated_graph(), clock="wall", duration=1.0, realtime=realtime_run)
        stopped: list[str] = []
        for child in launcher.children:
            child.proc = Seen(child.name, stopped)
        launcher.stop_all(grace=0.1)
        assert len(seen) == len(launcher.children) and all(at == during for _, at in seen)
        assert policy["now"] == (os.SCHED_OTHER, 0)
    assert realtime.SIGNAL_PRIORITY > max(realtime.IO_PRIORITY, realtime.LOOP_PRIORITY)


def test_composed_drivers_close_before_their_emulators():
    from dockhil.node import Node
    from dockhil.runtime.composed import ComposedGraph

    closed: list[str] = []

    class Driver(Node):
        def close(self):
            closed.append("driver")

    class Device(Node):
        free_running = True

        def close(self):
            closed.append("device")

    class Members:
        nodes = {"device": Device.__new__(Device), "driver": Driver.__new__(Driver)}

    ComposedGraph.close(Members())
    assert closed == ["driver", "device"]


class DiesOnce(Gain):
    """Gain that exits abruptly at tick `die_once_at` of its first life only (a marker file remembers)."""

    params = {
        **Gain.params,
        "die_once_at": Param(int, -1, help="exit abruptly at this tick, once"),
        "marker": Param(str, "", help="file made at the first death"),
    }

    def step(self, tick, inputs):
        if tick.index == self.p.die_once_at and not os.path.exists(self.p.marker):
            open(self.p.marker, "w").close()
            os._exit(3)
        return super().step(tick, inputs)


RESPAWNED = """
rate: 200
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator"}
  - {name: gain, node: "tests.test_busy_machine:DiesOnce", respawn: true, respawn_delay: 0.3,
     params: {die_once_at: 100, marker: MARKER}}
"""


def test_respawn_reasons_name_the_node_and_when():
    reasons = validity.respawn_reasons([("ft", 12.34, 1), ("ft", 20.0, 1), ("robot", 3.0, -9)])
    assert reasons == [
        "node 'ft' exited (code 1) and was respawned 2 time(s), at 12.3 s, 20.0 s into the run: its data has a gap",
        "node 'robot' exited (code -9) and was respawned 1 time(s), at 3.0 s into the run: its data has a gap",
    ]
    assert validity.respawn_reasons([]) == []


@pytest.mark.wall_time
def test_a_run_in_which_a_node_was_respawned_is_invalid(write_launch, tmp_path):
    """The node dies half a second in and is respawned: the run goes on to its end but is INVALID,
    with the line naming the node and when. (The machine's own reasons may join the line.)"""
    scene = write_launch(RESPAWNED.replace("MARKER", str(tmp_path / "died")))
    p = subprocess.run(
        dockhil_cmd("launch", str(scene), "--wall-time", "--duration", "3"), capture_output=True, text=True, timeout=120
    )
    text = p.stdout + p.stderr
    assert "Traceback" not in text, text
    assert p.returncode == validity.INVALID_EXIT, text
    line = next(x for x in text.splitlines() if "INVALID:" in x)
    assert re.search(r"node 'gain' exited \(code 3\) and was respawned 1 time\(s\), at \d+\.\d s into the run", line), (
        line
    )


class RecordingContext:
    def __init__(self):
        self.options = {}

    def set(self, option, value):
        self.options[option] = value


def test_realtime_reaches_zeromq_s_io_threads_only_where_granted(monkeypatch):
    import zmq

    from dockhil.runtime import realtime

    ctx = RecordingContext()
    monkeypatch.setattr(realtime, "granted", lambda: True)
    assert realtime.zmq_options(ctx)
    assert ctx.options == {zmq.THREAD_SCHED_POLICY: os.SCHED_FIFO, zmq.THREAD_PRIORITY: realtime.IO_PRIORITY}
    assert realtime.LOOP_PRIORITY < realtime.IO_PRIORITY < realtime.DEVICE_PRIORITY
    # Not granted: libzmq would abort on the refusal, so nothing is asked of it.
    ctx = RecordingContext()
    monkeypatch.setattr(realtime, "granted", lambda: False)
    assert not realtime.zmq_options(ctx) and ctx.options == {}


def test_a_refused_realtime_request_is_one_line_and_normal_priority(monkeypatch):
    from dockhil.runtime import realtime

    def refuse(pid, policy, param):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    lines = []
    assert not realtime.ask(realtime.LOOP_PRIORITY, "the node loop", lines.append)
    assert len(lines) == 1 and "\n" not in lines[0]
    assert lines[0].startswith("warning: real-time scheduling of the node loop refused")
    assert "running at normal priority" in lines[0] and "docs/time.md" in lines[0]
    # A device thread of a process without the privilege is not asked again (nor said again).
    lines.clear()
    monkeypatch.setattr(realtime, "granted", lambda: False)
    realtime.raise_device_thread(lines.append, "the RSI link")
    assert lines == []


def test_a_refused_node_loop_runs_at_normal_priority(monkeypatch):
    """run_node with --realtime where the OS refuses: the one line, then the node runs."""
    from dockhil.runtime import process
    from dockhil.runtime.executor import RunSpec

    def refuse(pid, policy, param):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    lines = []
    spec = RunSpec(
        name="src",
        type_name="tests.support.graphnodes:Integrator",
        params={},
        dt=0.01,
        clock="wall",
        n_ticks=3,
        inputs={},
        outputs={},
        realtime=True,
    )
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        assert process.run_node(spec, log=lines.append) == 0
    finally:  # the node's stop handlers are this test process's no longer
        for s, h in handlers.items():
            signal.signal(s, h)
    assert sum("real-time scheduling of the node loop refused" in line for line in lines) == 1, lines


@pytest.mark.parametrize("type_name, asked", [("Integrator", [50]), ("FreeRunningIntegrator", [50, 60])])
def test_an_emulated_device_s_loop_runs_above_the_node_loops(monkeypatch, type_name, asked):
    """--realtime: a free-running node (an emulator standing for a device) asks for the devices'
    priority after the loops', so after a stall of the whole machine the device delivers before
    the drivers judge it stale, as a real device, which no host stall stops, would have."""
    from dockhil.runtime import process, realtime
    from dockhil.runtime.executor import RunSpec

    priorities = []
    monkeypatch.setattr(os, "sched_setscheduler", lambda pid, policy, param: priorities.append(param.sched_priority))
    monkeypatch.setattr(realtime, "granted", lambda: bool(priorities))
    monkeypatch.setattr(realtime, "zmq_options", lambda ctx: False)
    spec = RunSpec(
        name="dev",
        type_name=f"tests.support.graphnodes:{type_name}",
        params={},
        dt=0.01,
        clock="wall",
        n_ticks=2,
        inputs={},
        outputs={},
        realtime=True,
    )
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        assert process.run_node(spec, log=lambda line: None) == 0
    finally:
        for s, h in handlers.items():
            signal.signal(s, h)
    assert priorities == asked
    assert asked == [realtime.LOOP_PRIORITY, realtime.DEVICE_PRIORITY][: len(asked)]


def test_a_real_time_loop_sleeps_without_spinning(monkeypatch):
    """Spun time under SCHED_FIFO counts against the kernel's real-time budget; a graph of loops
    that spend it gets every real-time thread stopped for the rest of the second."""
    from dockhil.runtime import looptime, realtime

    monkeypatch.setattr(realtime, "granted", lambda: True)
    assert looptime.loop_spin() == 0.0
    monkeypatch.setattr(realtime, "granted", lambda: False)
    assert looptime.loop_spin() == looptime.SPIN_S > 0.0


def test_an_emulated_device_without_topics_ticks_its_loop_slowly_and_one_with_topics_at_the_graph_s_rate():
    """An emulated device whose own thread is the device (RSI, Modbus) has nothing to step: its loop at
    the graph's 1 kHz only took the interpreter from the device's thread. On a clock the test moves."""
    from dockhil.node import ManualClock, Node
    from dockhil.runtime.executor import IDLE_DEVICE_PERIOD_S, NodeExecutor, RunSpec, Stop

    class Device(Node):
        free_running = True

        def step(self, tick, inputs):
            return {}

    class Loop(Device):
        free_running = False

    period = 1 / 1024
    for cls, ticks in ((Device, round(1.0 / IDLE_DEVICE_PERIOD_S)), (Loop, 1024)):
        clock = ManualClock()
        ex = NodeExecutor(RunSpec("n", "x:Device", {}, period, "wall"), cls, Stop(), log=lambda line: None, clock=clock)
        ex.start()
        try:
            report = ex.run_wall(1.0)
        finally:
            ex.close()
        assert report["ticks"] == ticks and report["deadline_misses"] == 0


def test_a_refused_nice_for_a_recorder_is_one_line_and_normal_priority(monkeypatch):
    from dockhil.runtime import realtime

    asked = []

    def refuse(which, pid, value):
        asked.append((which, pid, value))
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "setpriority", refuse)
    lines: list[str] = []
    assert not realtime.favour(4242, "'bag-recorder'", lines.append)
    assert asked == [(os.PRIO_PROCESS, 4242, realtime.RECORD_NICE)] and realtime.RECORD_NICE < 0
    assert len(lines) == 1 and lines[0].startswith("warning: a nice of -10 for 'bag-recorder' refused")
    assert "docs/time.md" in lines[0]
