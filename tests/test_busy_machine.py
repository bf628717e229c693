"""Wall-time runs on a busy machine: drivers stop before their devices' emulators, --realtime
reaches every thread on the delivery path (or says in one line why not), and a respawned node
makes the run invalid."""

import signal
import subprocess
from pathlib import Path

from dockhil.runtime.launcher import Launcher
from dockhil.scene import launchfile
from dockhil.scene.graph import build

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
