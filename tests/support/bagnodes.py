"""Nodes for bag tests: a driven plant whose drive can come from a bag instead.

drive (source) --/drive--> plant --/x--> gain --/u--+
                             ^                      |
                             +----------------------+
"""

from __future__ import annotations

import math
import random

from dockhil.msgs import Vector3, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Param


def _w(tick, x, y=0.0):
    return WrenchStamped(header=tick.header(), wrench=Wrench(force=Vector3(x=x, y=y)))


class Drive(Node):
    """A seeded noisy sine: what a sensor driver would publish, not reproducible without the seed."""

    outputs = {"drive": Output(WrenchStamped, "/drive")}
    params = {
        "seed": Param(int, 7, help="noise seed"),
        "quiet_every": Param(int, 0, help="send nothing at every Nth tick (0: never)"),
    }

    def setup(self):
        self.rng = random.Random(self.p.seed)

    def step(self, tick, inputs):
        noise = self.rng.gauss(0.0, 0.3)
        if self.p.quiet_every and tick.index % self.p.quiet_every == self.p.quiet_every - 1:
            return {}
        return {"drive": _w(tick, 3.0 * math.sin(0.37 * tick.index) + noise, noise)}


class Plant(Node):
    """x[k] = x[k-1] + dt u[k-1] + 0.01 d[k]: state from the loop, the drive read at the same tick."""

    inputs = {"u": Input(WrenchStamped, "/u", feedthrough=False), "d": Input(WrenchStamped, "/drive", required=False)}
    outputs = {"x": Output(WrenchStamped, "/x")}

    def setup(self):
        self.x = 1.0
        self.d = 0.0

    def step(self, tick, inputs):
        u, d = inputs["u"], inputs["d"]
        if u is not None:
            self.x += tick.dt * u.wrench.force.x
        if d is not None:  # an empty tick holds the last drive
            self.d = d.wrench.force.x
        return {"x": _w(tick, self.x + 0.01 * self.d)}
