"""Small nodes for runtime tests: a counter loop with a state-holding integrator."""

from __future__ import annotations

import os

from dockhil.msgs import NodeStatus, Vector3, Wrench, WrenchStamped
from dockhil.node import Input, Node, Output, Param


def _w(tick, x):
    return WrenchStamped(header=tick.header(), wrench=Wrench(force=Vector3(x=x)))


class Integrator(Node):
    """x[k] = x[k-1] + dt * u[k-1]: state-holding, its input is not feedthrough."""

    inputs = {"u": Input(WrenchStamped, "/u", feedthrough=False)}
    outputs = {"x": Output(WrenchStamped, "/x")}
    params = {"x0": Param(float, 1.0, unit="m", help="initial state")}

    def setup(self):
        self.x = self.p.x0

    def step(self, tick, inputs):
        u = inputs["u"]
        if u is not None:
            self.x += tick.dt * u.wrench.force.x
        return {"x": _w(tick, self.x)}


class FreeRunningIntegrator(Integrator):
    """An Integrator that stands for a device (as the emulators do): it runs from power-on."""

    free_running = True


class Gain(Node):
    """u[k] = -gain * x[k] + noise-free nonlinearity, feedthrough."""

    inputs = {"x": Input(WrenchStamped, "/x")}
    outputs = {"u": Output(WrenchStamped, "/u")}
    params = {
        "gain": Param(float, 2.0, unit="1/s", help="feedback gain", ge=0.0),
        "die_at": Param(int, -1, help="exit abruptly at this tick (tests)"),
    }

    def step(self, tick, inputs):
        if tick.index == self.p.die_at:
            os._exit(3)
        x = inputs["x"].wrench.force.x if inputs["x"] is not None else 0.0  # None before data, in wall time
        return {"u": _w(tick, -self.p.gain * x + 0.1 * x * x)}


class Source(Node):
    """A source with no inputs: a ramp."""

    outputs = {"x": Output(WrenchStamped, "/x")}

    def step(self, tick, inputs):
        return {"x": _w(tick, 0.5 * tick.index)}


class Sink(Node):
    """Consumes /x (feedthrough) and /u (optional)."""

    inputs = {"x": Input(WrenchStamped, "/x"), "opt": Input(WrenchStamped, "/none", required=False)}

    def step(self, tick, inputs):
        return {}


class Trace(Node):
    """Appends the exact bits (float.hex) of /x and /u per tick to a file at close."""

    inputs = {"x": Input(WrenchStamped, "/x"), "u": Input(WrenchStamped, "/u", required=False)}
    params = {"path": Param(str, "", help="output file")}

    def setup(self):
        self.rows = []

    def step(self, tick, inputs):
        u = inputs["u"]
        self.rows.append(f"{tick.index} {inputs['x'].wrench.force.x.hex()} {u.wrench.force.x.hex() if u else '-'}")
        return {}

    def close(self):
        if self.p.path:
            with open(self.p.path, "w") as f:
                f.write("\n".join(self.rows) + "\n")


class StateSink(Node):
    """Expects a RobotState on /x: wiring it to a WrenchStamped publisher is a type error."""

    from dockhil.msgs import RobotState as _RS

    inputs = {"x": Input(_RS, "/x")}

    def step(self, tick, inputs):
        return {}


class StateTrace(Node):
    """Writes the exact bits of chaser/target positions and velocities per tick, at close."""

    from dockhil.msgs import SatelliteState as _SS

    inputs = {"state": Input(_SS, "/satellite/state")}
    params = {"path": Param(str, "", help="output file")}

    def setup(self):
        self.rows = []

    def step(self, tick, inputs):
        b = inputs["state"].bodies
        self.rows.append(
            " ".join(
                v.hex() for v in (b[0].pose.position.x, b[1].pose.position.x, b[0].twist.linear.x, b[1].twist.linear.x)
            )
        )
        return {}

    def close(self):
        with open(self.p.path, "w") as f:
            f.write("\n".join(self.rows) + "\n")


class Announcer(Node):
    """Says its state on /status when it changes: 'running', then 'done' from tick done_at on (a profile
    that ends, as calibrate's identification does)."""

    outputs = {"status": Output(NodeStatus, "/status")}
    params = {"done_at": Param(int, 10, help="the tick it says 'done' at")}

    def step(self, tick, inputs):
        if tick.index in (0, self.p.done_at):
            state = "done" if tick.index == self.p.done_at else "running"
            return {"status": NodeStatus(header=tick.header(), node=self.ctx.name, state=state)}
        return {}
