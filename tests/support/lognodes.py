"""A node that says one line at each level, for the logging tests."""

from __future__ import annotations

from dockhil.msgs import Vector3, Wrench, WrenchStamped
from dockhil.node import Node, Output, Param


class Chatty(Node):
    """Publishes /x; at tick `at` logs one debug, info, warning and error line naming itself."""

    outputs = {"x": Output(WrenchStamped, "/x")}
    params = {"at": Param(int, 1, help="tick at which it speaks")}

    def step(self, tick, inputs):
        if tick.index == self.p.at:
            for word in ("debug", "info", "warning", "error"):
                lead = "" if word == "info" else f"{word}: "
                self.log(f"{lead}{self.ctx.name} says {word}")
        return {"x": WrenchStamped(header=tick.header(), wrench=Wrench(force=Vector3(x=float(tick.index))))}


class Library(Node):
    """At tick 1, a library it uses logs a warning and Python warns."""

    outputs = {"x": Output(WrenchStamped, "/x")}

    def step(self, tick, inputs):
        if tick.index == 1:
            import logging
            import warnings

            logging.getLogger("somelib").warning("somelib says warning")
            logging.getLogger("somelib").info("somelib says info")  # below warning: never shown
            warnings.warn("python says warning", UserWarning, stacklevel=1)
        return {"x": WrenchStamped(header=tick.header())}
