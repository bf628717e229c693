"""The emulated controllers' `immediate` timing, written once: each target of a delay line is followed
from the moment it is due (`delay` after it came), the servo's lag exact in between."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any


def follow_due(
    line: deque, delay: float, t: float, now: float, follow: Callable[[float], None], take: Callable[[Any], None]
) -> None:
    """From time t to now: follow the target held (`follow(dt)`), and take each (time, target) of
    `line` whose delay has passed (`take(target)`) at the moment it is due."""
    while line and line[0][0] + delay <= now + 1e-12:
        due = line[0][0] + delay
        if due > t:
            follow(due - t)
            t = due
        take(line.popleft()[1])
    follow(now - t)
