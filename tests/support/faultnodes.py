"""Nodes that misbehave on purpose, for the validity and stall tests."""

from __future__ import annotations

import math
import os
import time

from dockhil.msgs import SatelliteState, Vector3, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Param


def _w(tick, x):
    return WrenchStamped(header=tick.header(), wrench=Wrench(force=Vector3(x=x)))


class NanAt(Node):
    """Publishes a ramp on /x, and NaN from tick `at` on (a loop that diverged)."""

    outputs = {"x": Output(WrenchStamped, "/x")}
    params = {"at": Param(int, 5, help="first tick with NaN")}

    def step(self, tick, inputs):
        return {"x": _w(tick, math.nan if tick.index >= self.p.at else 0.1 * tick.index)}


class BoolAt(Node):
    """Publishes a ramp on /x, and from tick `at` on a bool where the float belongs (a composed
    run's screen judges only numbers and lets it through; the wire refuses it)."""

    outputs = {"x": Output(WrenchStamped, "/x")}
    params = {"at": Param(int, 5, help="first tick with the bool")}

    def step(self, tick, inputs):
        return {"x": _w(tick, True if tick.index >= self.p.at else 0.1 * tick.index)}


class Follow(Node):
    """Reads /x, publishes /u = -x: a consumer."""

    inputs = {"x": Input(WrenchStamped, "/x")}
    outputs = {"u": Output(WrenchStamped, "/u")}

    def step(self, tick, inputs):
        x = inputs["x"]
        return {"u": _w(tick, 0.0 if x is None else -x.wrench.force.x)}


class Hiccup(Node):
    """Publishes /x; at tick `at` its step takes `seconds` (a process starved or stopped)."""

    outputs = {"x": Output(WrenchStamped, "/x")}
    params = {
        "at": Param(int, 50, help="tick that stalls"),
        "seconds": Param(float, 0.3, unit="s", help="how long it stalls", ge=0.0),
    }

    def setup(self):
        self.clock = self.ctx.clock

    def step(self, tick, inputs):
        if tick.index == self.p.at:
            advance = getattr(self.clock, "advance", None)
            if advance is not None:  # a test's clock: the stall is exact
                advance(self.p.seconds)
            else:
                time.sleep(self.p.seconds)
        return {"x": _w(tick, float(tick.index))}


class Gate(Node):
    """Reads /satellite/state; with `hold`, its step at tick 1 waits until the file `path` exists
    (a run a test can keep in progress for as long as it needs, at no CPU cost)."""

    inputs = {"state": Input(SatelliteState, "/satellite/state", required=False)}
    params = {
        "hold": Param(bool, False, help="wait at tick 1 for the file"),
        "path": Param(str, "", help="the file that opens the gate"),
        "give_up": Param(float, 120.0, unit="s", help="go on after this long (no worker waits forever)", gt=0.0),
    }

    def step(self, tick, inputs):
        if self.p.hold and tick.index == 1:
            deadline = time.monotonic() + self.p.give_up
            while not os.path.exists(self.p.path) and time.monotonic() < deadline:
                time.sleep(0.01)
        return {}
