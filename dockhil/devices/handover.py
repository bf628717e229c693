"""The time-stamped hand-over: the pose a device takes on its own cycle, for the time of that cycle.

A command carries its time (the tick it was computed for, on the scene's clock) and its velocity. The graph
hands it over whenever its tick ran, late or bunched; the device's cycle beats on its own clock. Handing
the device the latest pose as it stands would make its path out of graph ticks beating against its
cycle: a cycle with no new command stands still, the next takes two ticks' motion at once. Instead each
command is placed on the device's clock: its stamp plus the least delay from stamp to hand-over seen
(a late tick does not shift the timeline), plus a margin, the worst lateness beyond that least of the
last LATE_WINDOW commands, at most a tick (so the command for a cycle's time has usually come). The
device's cycle at time t takes the pose for t: between the two latest commands, or from the latest
ahead along its velocity, at most one tick (it holds there until the next command comes), so a 250 Hz
graph against a 4 ms robot moves the robot at the commanded speed, the margin later. The links keep
their per-cycle limits on top of it. No I/O; the caller gives the times.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

from dockhil.contact.rotations import quat_from_rotvec, quat_multiply
from dockhil.devices.limits import angle_between, turn_toward

# The least delay from stamp to hand-over may grow this much per second (a clock that drifts, a graph that
# fell behind for good): the timeline follows it, 0.1 ms a second, never a tick's jitter.
DELAY_CREEP = 1e-4
MARGIN_SLEW = 0.02  # s/s: how fast the margin moves: the device's speed changes by at most 2 % for it
# A link thread's longest wait for the interpreter while another thread of its process runs (the links
# lower the process's switch interval to it while they run): a device's cycle is timed to a fraction of it.
SWITCH_INTERVAL = 0.0002  # s
LATE_WINDOW = 64  # commands over which the timeline's margin is the latest's worst lateness (a quarter second)


class Handover:
    """Commands placed on the device's clock; `pose(t)` is the pose for the device's cycle at t."""

    def __init__(self) -> None:
        self.delay: float | None = None  # s: the least (hand-over time - stamp), creeping up slowly
        self._at = 0.0
        self._late: deque[float] = deque(maxlen=LATE_WINDOW)  # how much later than the least the last ones came
        self.margin = 0.0  # s: the timeline's lag behind the least delay: the latest commands' lateness
        self.motion: tuple | None = None  # (t0 on the device's clock, tick, p, q, linear, angular) or None
        self._before: tuple | None = None  # the motion before it

    def put(
        self,
        now: float,
        stamp: float,
        tick: float,
        position: Sequence[float],
        orientation: Sequence[float],
        linear: Sequence[float],
        angular: Sequence[float],
    ) -> None:
        """A command for `stamp` [s], handed over at `now` (the device's clock): pose (position, unit
        quaternion x y z w) and velocity (linear per second, angular rad/s as a rotation vector), in the
        device's units; `tick` [s]: how far ahead of it the device may go along the velocity."""
        seen = now - stamp
        first = self.delay is None
        elapsed = now - self._at
        self.delay = seen if self.delay is None else min(seen, self.delay + DELAY_CREEP * elapsed)
        self._at = now
        self._late.append(seen - self.delay)
        # The margin follows the lateness slowly: a shift of the timeline is a change of the device's speed.
        goal = min(max(self._late), tick)
        slew = MARGIN_SLEW * elapsed
        self.margin = goal if first else self.margin + min(max(goal - self.margin, -slew), slew)
        self._before = self.motion
        self.motion = (
            stamp + self.delay + self.margin,
            tick,
            tuple(position),
            tuple(orientation),
            tuple(linear),
            tuple(angular),
        )

    def speed(self) -> float | None:
        """How fast the commands move [units/s]: the latest's velocity, or its pose's change from the one
        before over their times, whichever is more (a command that says no velocity still moves); None
        without a command."""
        motion, before = self.motion, self._before
        if motion is None:
            return None
        v = math.sqrt(sum(c * c for c in motion[4]))
        if before is not None and motion[0] > before[0]:
            v = max(v, math.dist(motion[2], before[2]) / (motion[0] - before[0]))
        return v

    def clear(self) -> None:
        self.motion = self._before = None

    def pose(self, t: float) -> tuple[tuple, tuple] | None:
        """(position, orientation) for the device's cycle at t; None without a command."""
        motion, before = self.motion, self._before
        if motion is None:
            return None
        if before is not None and t < motion[0] and before[0] < motion[0]:
            # between the two latest commands
            f = max(0.0, (t - before[0]) / (motion[0] - before[0]))
            p = tuple(a + f * (b - a) for a, b in zip(before[2], motion[2]))
            return p, tuple(turn_toward(before[3], motion[3], f * angle_between(before[3], motion[3])))
        t0, tick, p, q, v, w = motion
        ahead = min(max(t - t0, 0.0), tick)
        if not ahead:
            return p, q
        position = tuple(a + b * ahead for a, b in zip(p, v))
        if not any(w):
            return position, q
        turn = quat_multiply(quat_from_rotvec(tuple(c * ahead for c in w)), q)
        n = math.sqrt(sum(c * c for c in turn))
        return position, tuple(c / n for c in turn)
