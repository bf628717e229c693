"""Net F/T box emulator node: the box of dockhil/devices/ati_netft/emulator.py on this host, its
contact driven by the robot pose.

The box streams on its own clock from setup() to close() (a device runs from power-on); step()
only hands it the latest robot pose. The box's address belongs to this graph (the driver of the
same graph claims it too), so another graph's driver cannot read this graph's contact.
"""

from __future__ import annotations

from typing import Any

from dockhil.devices.ati_netft import protocol as rdt
from dockhil.errors import DeviceError
from dockhil.msgs import RobotState
from dockhil.node import Input, Node, Param, Tick


class NetFtEmulator(Node):
    """Emulated ATI Net F/T box: RDT over UDP and netftapi2.xml over HTTP; passive compliance contact."""

    free_running = True

    inputs = {"state": Input(RobotState, "/robot/state", help="robot pose: probe relative to the target interface")}
    params = {
        "host": Param(str, "127.0.0.1", help="address to listen on"),
        "port": Param(int, rdt.RDT_PORT, help="UDP port of RDT (0: any free port, logged)", ge=0, le=65535),
        "http_port": Param(
            int, 8080, help="TCP port serving netftapi2.xml (the real box: 80; 0: any free port)", ge=0, le=65535
        ),
        "rate": Param(
            float,
            1000.0,
            unit="Hz",
            help="RDT records a second (the box's setting, at most 7000)",
            gt=0.0,
            le=rdt.MAX_RDT_RATE,
        ),
        "counts_per_force": Param(float, 1_000_000.0, help="cfgcpf: counts per force unit", gt=0.0, scale=(1e-3, 1e12)),
        "counts_per_torque": Param(
            float, 1_000_000.0, help="cfgcpt: counts per torque unit", gt=0.0, scale=(1e-3, 1e12)
        ),
        "force_unit": Param(
            str, "N", help="scfgfu: N, lbf, klbf, kN, kgf, gf", choices=tuple(rdt.FORCE_CODES.values())
        ),
        "torque_unit": Param(
            str, "Nm", help="scfgtu: Nm, Nmm, lbf-in, lbf-ft, kgf-cm, kNm", choices=tuple(rdt.TORQUE_CODES.values())
        ),
        "k": Param(float, 1000.0, unit="N/m", help="passive stiffness of the compliance", ge=0.0),
        "b": Param(float, 0.0, unit="N s/m", help="passive damping of the compliance, while in contact", ge=0.0),
        "bias": Param(float, 0.0, unit="N", help="constant offset on Fx (the driver's tare removes it)"),
        "noise": Param(float, 0.0, unit="N", help="standard deviation of force noise, each axis", ge=0.0),
        "torque_noise": Param(float, 0.0, unit="N m", help="standard deviation of torque noise, each axis", ge=0.0),
        "seed": Param(int, 0, help="seed of the noise and of the faults"),
        "loss": Param(float, 0.0, unit="%", help="records never sent", ge=0.0, le=100.0),
        "duplicate": Param(float, 0.0, unit="%", help="records sent twice", ge=0.0, le=100.0),
        "reorder": Param(float, 0.0, unit="%", help="records sent after the next one", ge=0.0, le=100.0),
        "late": Param(float, 0.0, unit="%", help="records held back late_delay", ge=0.0, le=100.0),
        "late_delay": Param(float, 0.05, unit="s", help="how late a late record is", ge=0.0, le=10.0),
        "jitter": Param(float, 0.0, unit="s", help="each send up to this late (in order)", ge=0.0, le=1.0),
        "fault_after": Param(
            float, -1.0, unit="s", help="the status word turns non-zero this long into a stream (< 0: never)"
        ),
        "fault_status": Param(
            int, 0x80020000, help="the status word of the fault (default: error, saturation)", gt=0, lt=2**32
        ),
        "maxima": Param(str, "", help="JSON file for the box's counts and largest reported force, written at close"),
    }

    def setup(self) -> None:
        import socket

        from dockhil.devices.ati_netft.emulator import ContactModel, NetFtBox
        from dockhil.runtime import ownership

        p = self.p
        self.model = ContactModel(p.k, p.b, p.bias, p.noise, p.torque_noise, p.seed)
        self.box: NetFtBox | None = NetFtBox(
            self.model,
            p.host,
            p.port,
            p.http_port,
            p.rate,
            p.counts_per_force,
            p.counts_per_torque,
            p.force_unit,
            p.torque_unit,
            p.seed,
            p.loss,
            p.duplicate,
            p.reorder,
            p.late,
            p.late_delay,
            p.jitter,
            p.fault_after,
            p.fault_status,
            p.maxima,
        )
        self._claim = None
        if p.port:
            try:
                address = socket.gethostbyname(p.host)
            except OSError:
                address = p.host
            self._claim = ownership.claim_for_graph(f"netft-{address}-{p.port}", f"Net F/T box {p.host}:{p.port}")
        try:
            self.box.start_thread()
        except OSError as exc:
            self._release()
            raise DeviceError(
                f"Net F/T emulator: cannot listen on {p.host} (udp {p.port}, http {p.http_port}): {exc.strerror or exc}"
            ) from None
        self.log(
            f"Net F/T emulator: RDT on udp {p.host}:{self.box.port}, netftapi2.xml on "
            f"http://{p.host}:{self.box.http_port}, {p.rate:g} records/s"
        )

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        state = inputs.get("state")
        if state is not None:
            self.model.set_pose(state.pose.position.x, state.twist.linear.x)
        return {}

    def close(self) -> None:
        box = getattr(self, "box", None)
        if box is not None:
            box.stop_thread()
            self.box = None
            s = box.stats()
            self.log(
                f"Net F/T emulator: {s['records']} records, {s['sent']} datagrams sent, largest |Fx| "
                f"{s['max_abs_force_N'][0]:.3f} N"
            )
        self._release()

    def _release(self) -> None:
        claim = getattr(self, "_claim", None)
        if claim is not None:
            claim.release()
            self._claim = None
