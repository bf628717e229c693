"""The robot driver's record of its device cycles: every exchange of a link with the controller (the
setpoint sent, the actual pose read, when, and the device's own cycle count), collected on the link's
thread and published by the driver once per tick as a RobotCycles message (`/robot/cycles`), so none
is lost to the hand-over of latest values. Calibration times the robot's delay on them: at the device
boundary, where the device is the clock.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

from dockhil.msgs import Header, Pose, Quaternion, RobotCycle, RobotCycles, Vector3

MAX_HELD = 10_000  # exchanges kept while no tick takes them (a stalled driver): the newest, ~10 s at 1 kHz

# (sent, read, setpoint, written, actual, device cycle, taken); times on the link's (monotonic) clock,
# poses as (x, y, z, qx, qy, qz, qw)
Entry = tuple[float, float, tuple, bool, tuple, int, bool]


def _pose(values: Sequence[float]) -> Pose:
    return Pose(Vector3(values[0], values[1], values[2]), Quaternion(values[3], values[4], values[5], values[6]))


class CycleLog:
    """Exchanges from the link's thread, taken by the driver's step: add() there, output() here."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._entries: list[Entry] = []
        # Graph time minus the link's clock: a tick's stamp is taken before its step reads the clock,
        # so each step's difference is at most the true offset; the largest seen is the closest.
        self._offset: float | None = None

    def add(
        self,
        sent: float,
        read: float,
        setpoint: Sequence[float],
        written: bool,
        actual: Sequence[float],
        device_cycle: int,
        taken: bool,
    ) -> None:
        entry = (sent, read, tuple(setpoint[:7]), written, tuple(actual[:7]), device_cycle, taken)
        with self._lock:
            self._entries.append(entry)
            if len(self._entries) > MAX_HELD:
                del self._entries[: len(self._entries) - MAX_HELD]

    def take(self) -> list[Entry]:
        with self._lock:
            entries, self._entries = self._entries, []
        return entries

    def output(
        self, header: Header, now: float, convert: Callable[[Sequence[float]], Sequence[float]] | None = None
    ) -> dict:
        """{"cycles": RobotCycles} of the exchanges since the last call (none: {}), their times moved onto
        the graph's clock of `header` (its stamp, read at the link's clock's `now`); convert(pose) -> pose
        maps a device pose (x, y, z, qx, qy, qz, qw) into the scene's frame where they differ."""
        offset = header.stamp - now
        if self._offset is None or offset > self._offset:
            self._offset = offset
        entries = self.take()
        if not entries:
            return {}
        off = self._offset
        cv = convert or (lambda pose: pose)
        cycles = tuple(
            RobotCycle(
                max(sent + off, 0.0),
                max(read + off, 0.0),
                _pose(cv(setpoint)),
                written,
                _pose(cv(actual)),
                device_cycle,
                taken,
            )
            for sent, read, setpoint, written, actual, device_cycle, taken in entries
        )
        return {"cycles": RobotCycles(header=header, cycles=cycles)}
