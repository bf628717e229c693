"""delay-injector: delays a topic by a fixed time, optionally with jitter and loss.

Before the delay has passed there is nothing to deliver: the output is empty."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Any, cast

import msgspec

from dockhil import msgs, physical
from dockhil.node import Input, Node, Output, Param, Tick

if TYPE_CHECKING:
    import numpy as np


class DelayInjector(Node):
    """Re-publishes its input `delay` (x `delay_scale`) seconds later (exact in ticks in sim time); jitter and loss optional."""

    params = {
        "delay": Param(
            float, 0.032, unit="s", help="fixed delay (rounded to whole ticks)", ge=0.0, scale=physical.ROBOT_DELAY
        ),
        "delay_scale": Param(
            float,
            1.0,
            help="the hardware's true delay over the told `delay`: the topic is delayed by delay x delay_scale "
            "(what a lab does not know; hw_delay_scale:=)",
            gt=0.0,
            le=100.0,
        ),
        "jitter": Param(
            float,
            0.0,
            unit="s",
            help="extra delay, uniform in [0, jitter], per message",
            ge=0.0,
            scale=physical.ROBOT_DELAY,
        ),
        "loss": Param(float, 0.0, help="probability that a message is lost (the last one is held)", ge=0.0, le=1.0),
        "seed": Param(int, 0, help="seed of jitter and loss: the same seed, the same run"),
        "type": Param(str, "dockhil/RobotCommand", help="message type of the delayed topic", choices=tuple(msgs.TYPES)),
        "input": Param(str, "/robot/command", help="topic to delay"),
        "output": Param(str, "/robot/command/delayed", help="topic to publish"),
    }

    @classmethod
    def ports(cls, params):
        t = msgs.type_by_name(params["type"])
        # The declared delay lets the runtime pipeline: this node at tick k reads tick k - delay/dt.
        delay = params["delay"] * params.get("delay_scale", 1.0)
        return (
            {"input": Input(t, params["input"], delay=delay, help="the topic to delay")},
            {"output": Output(t, params["output"], help="the same messages, later")},
        )

    def setup(self):
        from dockhil.contact.hilloop import delay_ticks

        self.max_jitter = delay_ticks(self.p.jitter, self.ctx.dt)
        self.recent: deque = deque(maxlen=self.max_jitter + 1)  # newest last, already `delay` old
        self.rng = None
        if self.max_jitter or self.p.loss:  # numpy only where it draws (a node process without it starts 0.1 s faster)
            import numpy as np

            self.rng = np.random.default_rng(self.p.seed)
        self.last = None

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        msg = inputs["input"]
        if self.max_jitter == 0 and self.p.loss == 0.0:
            out = msg
        else:
            if msg is not None:
                self.recent.append(msg)
            rng = cast("np.random.Generator", self.rng)  # setup made it: this node draws
            extra = int(rng.integers(0, self.max_jitter + 1)) if self.max_jitter else 0
            lost = self.p.loss > 0.0 and rng.random() < self.p.loss
            out = self.recent[max(0, len(self.recent) - 1 - extra)] if self.recent else None
            # A lost message leaves the last one standing; a late one never overtakes one delivered.
            if self.last is not None and (lost or out is None or out.header.tick < self.last.header.tick):
                out = self.last
        if out is None:
            return {}
        self.last = out
        return {"output": msgspec.structs.replace(out, header=tick.header(out.header.frame))}
