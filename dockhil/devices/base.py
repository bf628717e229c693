"""The seams between a driver and its device, as the driver bases use them: a robot's link thread
(`RobotLink`) and a device emulator (`Emulator`). The bases themselves are robot_base.py (the robot
drivers' safety sequence) and ft_base.py (the F/T drivers' life); a new device is one folder
(protocol, link, driver, emulator) and one line in dockhil/node_types.py.

Checked by mypy where a driver hands its link to a base, and by tests/test_device_contract.py,
which runs every driver against its emulator."""

from __future__ import annotations

from typing import Protocol

from dockhil.devices.cycle_log import CycleLog


class RobotLink(Protocol):
    """The thread that talks to a robot controller on the device's own clock. The robot base holds
    the robot through it (`hold`), logs its notes, stops the graph on its fatal error, and publishes
    its record of the device cycles (`cycles`)."""

    connected: bool  # a hold can be answered now
    fatal: str | None  # why the link cannot go on (one line), or None
    cycles: CycleLog  # every exchange with the controller, collected on the link's thread
    longest_gap_s: float  # the longest the device went without taking a command while moving (validity)

    def hold(self, timeout: float) -> bool:
        """Command a hold; True once the device has it within `timeout` [s] (0: do not wait)."""
        ...

    def take_notes(self) -> list[str]:
        """The lines the link has to say since the last call (warnings, counts)."""
        ...

    def stop(self) -> None:
        """End the thread (after a hold)."""
        ...


class Emulator(Protocol):
    """A device emulator: the device's protocol byte for byte on this host, on its own clock in a
    thread of its own, with faults to inject. Emulator nodes start it at setup and stop it at close."""

    def start_thread(self) -> object:
        """Start serving (returns what a client needs, e.g. the port, or the emulator itself)."""
        ...

    def stop_thread(self) -> None:
        """Stop serving and release the device's port."""
        ...
