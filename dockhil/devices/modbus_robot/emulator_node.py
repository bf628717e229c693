"""Robot-controller emulator node: a Modbus TCP server on this host with a servo behind it.

The server and the servo run in a thread of their own, on the controller's
own clock, from setup() to close(); step() has nothing to do. The servo and
register map are in dockhil/devices/modbus_robot/emulator.py and modbus_map.py.
"""

from __future__ import annotations

from typing import Any

from dockhil.errors import DeviceError
from dockhil.node import Node, Param, Tick


class RobotControllerEmulatorNode(Node):
    """Emulated robot controller: Modbus TCP server, servo with delay and first-order lag."""

    free_running = True  # a device: it runs from power-on, the drivers' setup needs it

    params = {
        "host": Param(str, "127.0.0.1", help="address to listen on"),
        "port": Param(int, 5020, help="TCP port (0: any free port, logged)", ge=0, le=65535),
        "delay": Param(float, 0.0, unit="s", help="servo delay: setpoints take effect this much later", ge=0.0, le=1.0),
        "tau": Param(float, 0.0, unit="s", help="servo first-order lag time constant (0: none)", ge=0.0, le=10.0),
        "cycle": Param(float, 0.001, unit="s", help="servo period", ge=1e-5, le=0.1),
        "timing": Param(
            str,
            "ours",
            help="ours: a setpoint is taken by the next cycle, on whole cycles, a read gives the pose after the "
            "servo's step; immediate: taken as it is written, followed `delay` later, the pose sampled before "
            "the step",
            choices=("ours", "immediate"),
        ),
        "heartbeat_timeout": Param(
            float,
            0.2,
            unit="s",
            help="hold, and end the host's claim, when its heartbeat stops this long",
            ge=1e-3,
            le=10.0,
        ),
        "maxima": Param(
            str, "", help="JSON file to write at close with the largest actual speed and position (empty: none)"
        ),
    }

    def setup(self) -> None:
        from dockhil.devices.modbus_robot.emulator import RobotControllerEmulator, claim_port, listen_problem

        p = self.p
        self._lock = claim_port(p.host, p.port)  # one graph per emulator port, named when refused
        self.emulator = RobotControllerEmulator(
            p.host,
            p.port,
            p.delay,
            p.tau,
            p.cycle,
            p.heartbeat_timeout,
            log=lambda line: self.log(f"warning: robot controller emulator: {line}"),
            timing=p.timing,
        )
        try:
            self.emulator.start_thread()
        except (OSError, RuntimeError):
            self._release()
            raise DeviceError(
                f"robot controller emulator: cannot listen on {p.host}:{p.port}: {listen_problem(p.host, p.port)}"
            ) from None
        self.log(f"robot controller emulator listening on {p.host}:{self.emulator.port}")

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        emulator = getattr(self, "emulator", None)
        if emulator is not None:
            emulator.stop_thread()
            self.emulator = None
            if self.p.maxima:
                import json

                servo = emulator.servo
                with open(self.p.maxima, "w") as f:
                    json.dump({"max_speed_m_s": servo.max_speed, "max_position_m": servo.max_position}, f)
            if emulator.servo.unclaimed:
                self.log(
                    f"warning: robot controller emulator: refused {emulator.servo.unclaimed} writes without "
                    f"a live claim"
                )
        self._release()

    def _release(self) -> None:
        lock = getattr(self, "_lock", None)
        if lock is not None:
            lock.release()
            self._lock = None
