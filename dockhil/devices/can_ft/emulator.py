"""F/T sensor emulator: the sensor's CAN frames from a passive compliance against the robot pose.

It stands in for the sensor on the far side of the CAN bus, so the real
driver (dockhil/devices/can_ft/driver.py) runs unchanged. With interface "pty" (the default)
the emulator is itself an slcan adapter on a pseudo-terminal, symlinked at
`channel`; the driver opens that path with python-can's slcan interface.
Any other interface sends through python-can (udp_multicast on loopback, which
hil.yaml's emulators:=true uses, virtual, socketcan on vcan, a second slcan adapter, ...).
"""

from __future__ import annotations

import json
import math
import random
from typing import Any

from dockhil.devices.can_ft import frames as ff
from dockhil.errors import DeviceError
from dockhil.msgs import RobotState
from dockhil.node import Input, Node, Param, Tick


class FtSensorEmulator(Node):
    """Emulated F/T sensor on CAN: force = -(k * penetration + b * velocity), unilateral, with noise and bias."""

    free_running = True  # a device: it runs from power-on, the drivers' setup needs it

    inputs = {"state": Input(RobotState, "/robot/state", help="robot pose: probe relative to the target interface")}
    params = {
        "interface": Param(
            str,
            "pty",
            help="pty: be an slcan adapter on a pseudo-terminal; else a python-can interface to send through",
        ),
        "channel": Param(
            str,
            "",
            help="pty: symlink to create (empty: ft.slcan in the graph's private run "
            "directory, the driver's default); else the python-can channel",
        ),
        "loopback": Param(
            bool,
            True,
            help="udp_multicast: the group on this host's loopback (false: python-can's choice, the routed interface)",
        ),
        "bitrate": Param(int, 1_000_000, unit="bit/s", help="CAN bitrate (python-can interfaces)", gt=0, le=1_000_000),
        **ff.frame_params(),
        "k": Param(float, 1000.0, unit="N/m", help="stiffness of the passive compliance", ge=0.0, le=1e8),
        "b": Param(
            float,
            0.0,
            unit="N s/m",
            help="damping of the passive compliance, on the robot's actual velocity (the contact still only pushes)",
            ge=0.0,
            le=1e6,
        ),
        "surface": Param(
            float, 0.0, unit="m", help="x of the compliance's surface: the penetration is x - surface", ge=-1.0, le=1.0
        ),
        "noise": Param(float, 0.0, unit="N", help="standard deviation of force noise, each axis", ge=0.0, le=1_000.0),
        "torque_noise": Param(
            float, 0.0, unit="N m", help="standard deviation of torque noise, each axis", ge=0.0, le=100.0
        ),
        "bias": Param(
            float, 0.0, unit="N", help="constant offset on Fx (the driver's tare removes it)", ge=-1_000.0, le=1_000.0
        ),
        **{
            f"bias_{axis}": Param(float, 0.0, unit="N", help=f"constant offset on F{axis}", ge=-1_000.0, le=1_000.0)
            for axis in "yz"
        },
        **{
            f"torque_bias_{axis}": Param(
                float, 0.0, unit="N m", help=f"constant offset on T{axis}", ge=-100.0, le=100.0
            )
            for axis in "xyz"
        },
        "maxima": Param(
            str,
            "",
            help="JSON file to write at close with the largest force |F| reported and the "
            "largest penetration (empty: none)",
        ),
        "seed": Param(int, 0, help="noise seed", ge=0, le=2**63 - 1),
    }

    @classmethod
    def resolve_params(cls, node_name: str, given: dict) -> dict:
        from dockhil.devices.can_ft import multicast as can_multicast

        values = super().resolve_params(node_name, given)
        can_multicast.check_params(node_name, values)
        return values

    def setup(self) -> None:
        p = self.p
        self.scaling = ff.FtScaling(p.force_resolution, p.torque_resolution)
        self.rng = random.Random(p.seed)
        self.seq = 0
        self.sent = 0
        self.max_force = 0.0  # N: the largest |F| reported
        self.max_penetration = 0.0  # m
        self._pty_bus = None
        self._can_bus = None
        if p.interface == "pty":
            from dockhil.devices.can_ft.slcan_pty import CanFrame, PtyCanBus
            from dockhil.devices.device_path import private_link

            p.channel = p.channel or private_link("ft.slcan")
            self._frame = CanFrame
            try:  # PtyCanBus claims the link: one graph per adapter path
                self._pty_bus = PtyCanBus([p.channel]).start()
            except OSError as exc:
                raise DeviceError(f"F/T sensor emulator: cannot create slcan adapter at {p.channel}: {exc}") from None
            self.log(f"F/T sensor emulator: slcan adapter at {p.channel} -> {self._pty_bus.ports[0].path}")
        else:
            import can

            from dockhil.devices.can_ft import multicast as can_multicast
            from dockhil.devices.can_ft.driver import one_line
            from dockhil.runtime import ownership

            # One emulated sensor per channel: two would stream the same CAN IDs.
            # The bus is its graph's: a driver of another graph reading it would take our frames for
            # its sensor's. Claimed first, so a refused emulator never holds the emulator claim.
            bus_claim = ownership.claim_for_graph(
                f"can-bus-{p.interface}-{p.channel}", f"CAN bus {p.interface} {p.channel}"
            )
            try:
                self._lock = ownership.claim(
                    f"can-emulator-{p.interface}-{p.channel}", f"F/T sensor emulator on {p.interface} {p.channel}"
                )
            except BaseException:
                bus_claim.release()
                raise
            self._bus_claim = bus_claim
            multicast = p.interface == "udp_multicast" and p.loopback
            device = f"F/T sensor emulator ({p.interface} {p.channel})"
            try:
                self._can_bus = can.Bus(interface=p.interface, channel=p.channel, bitrate=p.bitrate)
                if multicast:
                    can_multicast.on_loopback(self._can_bus, p.channel)
            except (can.CanError, OSError, ValueError) as exc:
                if self._can_bus is not None:
                    self._can_bus.shutdown()
                    self._can_bus = None
                self._release_claims()
                if multicast:
                    raise DeviceError(can_multicast.join_failure(device, p.channel, exc)) from None
                raise DeviceError(f"{device}: {one_line(exc)}") from None
            self._message = can.Message

    def wrench(self, state: RobotState | None) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Force on the chaser [N] and torque [N m] for a robot pose (None: no contact)."""
        p = self.p
        depth = state.pose.position.x - p.surface if state is not None else 0.0
        fx = 0.0
        if depth > 0.0 and state is not None:  # unilateral: the sheet pushes, never pulls
            fx = min(-p.k * depth - p.b * state.twist.linear.x, 0.0)
            self.max_penetration = max(self.max_penetration, depth)
        force = (fx + p.bias + self._noise(p.noise), p.bias_y + self._noise(p.noise), p.bias_z + self._noise(p.noise))
        torque = (
            p.torque_bias_x + self._noise(p.torque_noise),
            p.torque_bias_y + self._noise(p.torque_noise),
            p.torque_bias_z + self._noise(p.torque_noise),
        )
        self.max_force = max(self.max_force, math.sqrt(sum(f * f for f in force)))
        return force, torque

    def _noise(self, sd: float) -> float:
        return self.rng.gauss(0.0, sd) if sd else 0.0

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        force, torque = self.wrench(inputs.get("state"))
        frames = ff.encode_sample(force, torque, self.seq, self.scaling, self.p.can_id)
        self.seq = (self.seq + 1) & 0xFF
        if self._pty_bus is not None:
            port = self._pty_bus.ports[0]
            for arbitration_id, data in frames:
                port.deliver(self._frame(arbitration_id, data))
        else:
            for arbitration_id, data in frames:
                try:
                    self._can_bus.send(  # type: ignore[union-attr]  # open whenever the pty bus is not
                        self._message(arbitration_id=arbitration_id, data=data, is_extended_id=False)
                    )
                except Exception:  # nobody acknowledging on a real bus; a sensor keeps streaming
                    pass
        self.sent += 1
        return {}

    def close(self) -> None:
        if self.p.maxima and hasattr(self, "max_force"):
            with open(self.p.maxima, "w") as f:
                json.dump({"max_force_N": self.max_force, "max_penetration_m": self.max_penetration}, f)
        if self._pty_bus is not None:
            self._pty_bus.stop()
            self._pty_bus = None
        if self._can_bus is not None:
            self._can_bus.shutdown()
            self._can_bus = None
            self._release_claims()

    def _release_claims(self) -> None:
        self._lock.release()
        self._bus_claim.release()
