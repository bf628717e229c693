"""A node that fails (raises in setup or step, returns something other than a dict) stops the
graph with one line naming the node and the tick, the same line whether it runs composed, as a
process of its own, or in a container with others; never as the runtime's own internal error."""

from __future__ import annotations

import pytest

from dockhil.msgs import BodyWrenches, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Param
from dockhil.runtime.executor import check_outputs
from tests.conftest import dockhil_cmd
from tests.support.inprocess import run_main

HERE = "tests.test_node_failures"


class RaisesAtTick2(Node):
    """raises in step at tick 2"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def step(self, tick, inputs):
        if tick.index == 2:
            raise ValueError("boom")
        return {}


class ReturnsNone(Node):
    """returns None from step"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def step(self, tick, inputs):
        return None


class FailsAtSetup(Node):
    """raises in setup"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def setup(self):
        raise KeyError("calibration")

    def step(self, tick, inputs):
        return {}


class ExitsAtTick2(Node):
    """calls sys.exit(0) in step: as processes, the graph waited for its ticks forever"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def step(self, tick, inputs):
        if tick.index == 2:
            import sys

            sys.exit(0)
        return {}


class InterruptsAtTick2(Node):
    """raises KeyboardInterrupt in step at tick 2: as a process of its own, a traceback and 'killed by SIGINT'"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def step(self, tick, inputs):
        if tick.index == 2:
            raise KeyboardInterrupt
        return {}


class InterruptsAtSetup(Node):
    """raises KeyboardInterrupt in setup"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def setup(self):
        raise KeyboardInterrupt

    def step(self, tick, inputs):
        return {}


class InterruptsAtClose(Node):
    """raises KeyboardInterrupt in close"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def step(self, tick, inputs):
        return {}

    def close(self):
        raise KeyboardInterrupt


class ExitsAtClose(Node):
    """calls sys.exit(0) in close: the run exited 0, valid, with the close not done"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def step(self, tick, inputs):
        return {}

    def close(self):
        import sys

        sys.exit(0)


class CtrlCAtTick2(Node):
    """at tick 2 sends SIGINT where a user's Ctrl-C arrives: the dockhil command's process (with
    `parent`, the launcher of this node's process; else this process, a composed run)"""

    outputs = {"w": Output(WrenchStamped, "/w")}
    params = {"parent": Param(bool, False, help="signal the parent process")}

    def step(self, tick, inputs):
        if tick.index == 2:
            import os
            import signal

            os.kill(os.getppid() if self.p.parent else os.getpid(), signal.SIGINT)
        return {"w": WrenchStamped(header=tick.header())}


class FailsAtClose(Node):
    """raises in close, where a driver holds the robot"""

    outputs = {"w": Output(WrenchStamped, "/w")}

    def step(self, tick, inputs):
        return {}

    def close(self):
        raise RuntimeError("could not hold")


def scene(tmp_path, cls: str, container: bool = False, duration: float = 0.05, params: str = "{}") -> str:
    """The failing node, after a node that runs fine (in one container with it if asked)."""
    box = "\n    container: box" if container else ""
    path = tmp_path / "scene.yaml"
    path.write_text(f"""rate: 100
duration: {duration}
nodes:
  - name: good
    node: delay_injector{box}
    params: {{delay: 0.0, input: /w, output: /w2, type: dockhil/WrenchStamped}}
  - name: bad
    node: {HERE}:{cls}{box}
    params: {params}
""")
    return str(path)


@pytest.mark.parametrize(
    "cls, line",
    [
        ("RaisesAtTick2", "node 'bad' failed at tick 2: ValueError: boom"),
        ("ReturnsNone", "node 'bad' returned NoneType from step at tick 0; step returns a dict of its outputs"),
        ("FailsAtSetup", "node 'bad' failed at setup: KeyError: 'calibration'"),
        ("ExitsAtTick2", "node 'bad' called sys.exit(0) at tick 2; a node ends with its graph"),
        ("FailsAtClose", "node 'bad' failed at close: RuntimeError: could not hold"),
        ("InterruptsAtTick2", "node 'bad' raised KeyboardInterrupt at tick 2 (not a Ctrl-C"),
        ("InterruptsAtSetup", "node 'bad' raised KeyboardInterrupt at setup (not a Ctrl-C"),
        ("InterruptsAtClose", "node 'bad' raised KeyboardInterrupt at close (not a Ctrl-C"),
        ("ExitsAtClose", "node 'bad' called sys.exit(0) at close; a node ends with its graph"),
    ],
)
def test_a_composed_run_names_the_failing_node_and_tick(tmp_path, cls, line):
    code, out, err = run_main("launch", scene(tmp_path, cls), "--composed")
    assert code == 1
    assert f"[launch] error: {line}" in err
    assert "internal error" not in err and "Traceback" not in err


def test_a_node_process_says_the_same_of_a_step_that_returns_no_dict():
    declared = ReturnsNone.outputs
    for returned in (None, [1], "w"):
        with pytest.raises(
            Exception,
            match=rf"node 'bad' returned {type(returned).__name__} from step at tick 7; "
            r"step returns a dict of its outputs \(port -> message\), \{\} for none",
        ):
            check_outputs("bad", declared, 7, returned, sim=True)


@pytest.mark.parametrize(
    "cls, line",
    [
        ("ExitsAtTick2", "[bad] error: node 'bad' called sys.exit(0) at tick 2; a node ends with its graph"),
        ("FailsAtClose", "[bad] error: node 'bad' failed at close: RuntimeError: could not hold"),
        ("FailsAtSetup", "[bad] error: node 'bad' failed at setup: KeyError: 'calibration'"),
        ("InterruptsAtTick2", "[bad] error: node 'bad' raised KeyboardInterrupt at tick 2 (not a Ctrl-C"),
        ("ExitsAtClose", "[bad] error: node 'bad' called sys.exit(0) at close; a node ends with its graph"),
    ],
)
def test_a_node_process_says_the_same_and_fails_the_run(tmp_path, cls, line):
    import subprocess

    run = subprocess.run(dockhil_cmd("launch", scene(tmp_path, cls)), capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert line in run.stderr
    assert "Traceback" not in run.stderr and "SIGINT" not in run.stderr


@pytest.mark.parametrize(
    "cls, line",
    [
        ("RaisesAtTick2", "[box] error: node 'bad' failed at tick 2: ValueError: boom"),
        ("InterruptsAtTick2", "[box] error: node 'bad' raised KeyboardInterrupt at tick 2 (not a Ctrl-C"),
        ("InterruptsAtClose", "[box] error: node 'bad' raised KeyboardInterrupt at close (not a Ctrl-C"),
        ("FailsAtClose", "[box] error: node 'bad' failed at close: RuntimeError: could not hold"),  # not 'box' failed
    ],
)
def test_a_container_names_the_member_that_failed(tmp_path, cls, line):
    import subprocess

    run = subprocess.run(
        dockhil_cmd("launch", scene(tmp_path, cls, container=True)), capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 1
    assert line in run.stderr
    assert "node 'box'" not in run.stderr.split("[launch]")[0] and "Traceback" not in run.stderr


def test_a_ctrl_c_of_a_composed_run_still_stops_it_cleanly(tmp_path):
    """The user's Ctrl-C is not a node's KeyboardInterrupt: the run stops with 130 and no error line."""
    code, out, err = run_main("launch", scene(tmp_path, "CtrlCAtTick2"), "--composed")
    assert code == 130
    assert "error" not in err and "Traceback" not in err


def test_a_ctrl_c_of_a_launch_still_stops_the_graph_cleanly(tmp_path):
    import subprocess

    path = scene(tmp_path, "CtrlCAtTick2", duration=1000.0, params="{parent: true}")  # stopped long before its end
    run = subprocess.run(dockhil_cmd("launch", path, "--quiet"), capture_output=True, text=True, timeout=120)
    assert run.returncode == 130
    assert "[launch] SIGINT: stopping the graph" in run.stderr
    assert "error" not in run.stderr and "Traceback" not in run.stderr


def test_dockhil_traceback_shows_where_the_node_raised(tmp_path, monkeypatch):
    monkeypatch.setenv("DOCKHIL_TRACEBACK", "1")
    code, out, err = run_main("launch", scene(tmp_path, "RaisesAtTick2"), "--composed")
    assert code == 1
    assert "node 'bad' failed at tick 2: ValueError: boom" in err
    assert 'raise ValueError("boom")' in err and "test_node_failures.py" in err


class BuildsAList(Node):
    """publishes its wrenches as a list, as a node may build them"""

    outputs = {"w": Output(BodyWrenches, "/bw")}

    def step(self, tick, inputs):
        return {"w": BodyWrenches(header=tick.header("world"), wrenches=[Wrench(), Wrench()])}


class ChangesWhatItReads(Node):
    """writes into the message it was given: in one process that would change what every other reader sees"""

    inputs = {"w": Input(BodyWrenches, "/bw")}

    def step(self, tick, inputs):
        inputs["w"].wrenches[0] = Wrench()
        return {}


def mutation_scene(tmp_path) -> str:
    path = tmp_path / "mutation.yaml"
    path.write_text(f"""rate: 100
duration: 0.05
nodes:
  - name: writer
    node: {HERE}:BuildsAList
  - name: reader
    node: {HERE}:ChangesWhatItReads
""")
    return str(path)


LINE = "node 'reader' failed at tick 0: TypeError: 'tuple' object does not support item assignment"


def test_a_reader_cannot_change_a_message_composed_as_it_cannot_across_processes(tmp_path):
    """A message's sequences are tuples when decoded, and a composed run turns a list a node built
    into one before any reader sees it: the same refusal, in one line, either way."""
    import subprocess

    code, out, err = run_main("launch", mutation_scene(tmp_path), "--composed")
    assert code == 1 and f"[launch] error: {LINE}" in err
    run = subprocess.run(dockhil_cmd("launch", mutation_scene(tmp_path)), capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and f"[reader] error: {LINE}" in run.stderr


@pytest.mark.parametrize("bad", ["InterruptsAtClose", "ExitsAtClose", "FailsAtClose"])
def test_a_node_failing_at_close_does_not_keep_the_others_from_closing(bad):
    # A driver holds the robot in its close: the nodes after a failing one close all the same.
    from types import SimpleNamespace

    from dockhil.errors import DockhilError
    from dockhil.runtime.composed import ComposedGraph

    closed = []

    class Driver(Node):
        outputs = {"w": Output(WrenchStamped, "/d")}

        def step(self, tick, inputs):
            return {}

        def close(self):
            closed.append(self.ctx.name)

    nodes = {
        name: SimpleNamespace(cls=cls, params={}, inputs={}, outputs={})
        for name, cls in (("bad", globals()[bad]), ("driver", Driver))
    }
    graph = SimpleNamespace(scene=SimpleNamespace(dt=0.01), nodes=nodes, order=["bad", "driver"], publishers={})
    g = ComposedGraph(graph, log=lambda n, m: None)
    g.setup()
    with pytest.raises(DockhilError, match="node 'bad' .* at close"):
        g.close()
    assert closed == ["driver"]
