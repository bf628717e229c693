"""Real-hardware protocols: the F/T sensor's CAN frames, the robot
controller's Modbus registers, slcan adapters on pseudo-terminals, and the
robot-controller emulator.

The modules import python-can, pyserial or pymodbus only where they use
them; importing this package loads none of them.
"""

from __future__ import annotations

from dockhil.errors import DockhilError


class SafetyStop(DockhilError):
    """A safety limit tripped: the robot was told to hold and commanding stopped.

    The message is one line naming the limit and the value; `limit` and
    `value` carry them for programs.
    """

    def __init__(self, message: str, limit: str, value: float | str | None = None):
        super().__init__(message)
        self.limit = limit
        self.value = value
