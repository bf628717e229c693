"""What the F/T sensor drivers (ft_can over CAN, ft_netft on an ATI Net F/T box) share, written once:
the wrench they publish, the tare and mounting parameters, and the sequence of a sensor's life.

Setup refuses sim time, opens the device (the driver's `_open`: claim it, connect, start the
stream) and tares it at the graph's first start (dockhil/devices/tare.py: a restart keeps that tare,
a given bias is only checked); if the tare fails, the device is shut again. Each step takes what the
device measured since the last step (the driver's `_read`: a raw force and torque, or None when
nothing new came); nothing new for stale_timeout on the runtime's clock stops the graph with one
line (the robot driver holds), and nothing is published rather than an old value repeated. Close
shuts the device and logs what the driver counted (`_report`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from dockhil.devices import tare
from dockhil.errors import DeviceError, LaunchError
from dockhil.msgs import Vector3, Wrench, WrenchStamped
from dockhil.node import Node, Output, Param, Tick

Raw = tuple[Sequence[float], Sequence[float]]  # force [N], torque [N m], before the tare and the sign


def tare_params(stale_help: str, open_help: str, frame: str) -> dict[str, Param]:
    """The mounting, tare and watchdog parameters of an F/T driver (`tare_samples` counts the
    device's own samples or records)."""
    return {
        "sign": Param(float, 1.0, help="-1 if the sensor reports the force on the target side", choices=(1.0, -1.0)),
        "tare_samples": Param(
            int,
            100,
            help="samples averaged into the bias at the graph's first start (0: raw readings, no "
            "tare and no given bias); nothing may touch the probe meanwhile. A restart keeps the first tare",
            ge=0,
            le=100_000,
        ),
        "bias": Param(
            list,
            [],
            unit="N, N m",
            help="[fx, fy, fz, tx, ty, tz] the unloaded probe reads untared (the loop file's tare): "
            "subtracted instead of a tare at start, whose samples only check it (tare.mismatch); [] tares",
        ),
        "bias_from": Param(str, "", help="where the bias comes from (the loop file), named when it is refused"),
        # A tare takes whatever loads the probe at start for the sensor's offset, and every force limit downstream
        # would then miss it: a large bias means the probe is pressed, a large spread that it moved while taring.
        "max_bias": Param(
            float,
            50.0,
            unit="N",
            help="largest tare bias |F| accepted; more means something "
            "loads the probe at start (raise it for a heavy tool; 0: off)",
            ge=0.0,
            le=10_000.0,
        ),
        "max_bias_torque": Param(
            float, 5.0, unit="N m", help="largest tare bias |T| accepted (0: off)", ge=0.0, le=1_000.0
        ),
        "max_tare_spread": Param(
            float,
            2.0,
            unit="N",
            help="largest standard deviation of a force axis over the "
            "tare samples (the noise band); more means the probe moved or was touched while "
            "taring (0: off)",
            ge=0.0,
            le=1_000.0,
        ),
        "max_tare_spread_torque": Param(
            float,
            0.2,
            unit="N m",
            help="largest standard deviation of a torque axis over the tare samples (0: off)",
            ge=0.0,
            le=100.0,
        ),
        "stale_timeout": Param(float, 0.1, unit="s", help=stale_help, gt=0.0, le=10.0),
        "max_gap": Param(
            float,
            0.05,
            unit="s",
            help="validity: longest time between two fresh readings in the run; longer (a stalled sensor or "
            "emulator), the run is INVALID",
            gt=0.0,
            le=10.0,
        ),
        "open_timeout": Param(float, 2.0, unit="s", help=open_help, gt=0.0, le=120.0),
        "frame": Param(str, frame, help="header frame id of the published wrench"),
    }


class FtDriver(Node):
    """An F/T sensor driver's port and life: a driver fills in `_is_open`, `_open`, `_first_samples`,
    `_read`, `_shutdown` and `_report`, and names its device and what it streams (`sample`)."""

    outputs = {"wrench": Output(WrenchStamped, "/ft/wrench", help="wrench the contact exerts on the chaser")}
    device: str
    sample = "sample"  # what the device streams, in the lines that count them ("record" for the Net F/T)

    @classmethod
    def resolve_params(cls, node_name: str, given: dict) -> dict:
        values = super().resolve_params(node_name, given)
        tare.check_bias_param(node_name, values)
        return values

    # -- the device's part ------------------------------------------------------------
    def _open(self) -> None:
        """Claim the device, connect and start its stream; undo what was done if it fails."""
        raise NotImplementedError

    def _first_samples(self, want: int) -> Sequence[Raw]:
        """The first `want` raw (force, torque) samples the device streams, within open_timeout."""
        raise NotImplementedError

    def _read(self) -> Raw | None:
        """The raw (force, torque) the device measured since the last step; None: nothing new."""
        raise NotImplementedError

    def _shutdown(self) -> None:
        """Stop the stream and let go of the device (safe to call twice, and after a failed open)."""
        raise NotImplementedError

    def _report(self) -> list[str]:
        """The lines close logs of what the driver counted (taken before the device is shut)."""
        return []

    def _is_open(self) -> bool:
        """Whether the device is open (close has something to shut)."""
        raise NotImplementedError

    # -- the sequence -----------------------------------------------------------------
    def setup(self) -> None:
        if self.ctx.sim_time:
            raise LaunchError(
                f"node {self.ctx.name!r} reads a real F/T sensor and runs only in wall time (launch with --wall-time)"
            )
        self.bias_force: Sequence[float] = (0.0, 0.0, 0.0)
        self.bias_torque: Sequence[float] = (0.0, 0.0, 0.0)
        self._last_fresh_t: float | None = None
        self._longest_gap = 0.0
        self._fresh_before = False
        self._open()
        try:
            self._tare()
        except BaseException:
            self._shutdown()
            raise

    def _tare(self) -> None:
        """Tare at the graph's first start; a restart keeps that tare (it may come back in contact)."""
        p = self.p
        limits = tare.TareLimits(p.max_bias, p.max_bias_torque, p.max_tare_spread, p.max_tare_spread_torque)
        bias = tare.graph_tare(
            self.ctx.name,
            self.device,
            p.tare_samples,
            limits,
            self._first_samples,
            self.log,
            unit=f"{self.sample}s",
            given=tare.given_bias(p.bias, p.sign),
            given_from=p.bias_from,
        )
        if bias is not None:
            self.bias_force, self.bias_torque = bias.force, bias.torque

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        raw = self._read()
        t = tick.t  # the runtime's clock (a test chooses it), so "stale after 0.1 s" is decided exactly
        if self._last_fresh_t is None:
            self._last_fresh_t = t  # the stale clock starts with the first tick
        if raw is None:
            age = t - self._last_fresh_t
            if age > self.p.stale_timeout:
                raise DeviceError(
                    f"{self.device}: stale data: no new {self.sample} for {age:.3f} s "
                    f"(stale_timeout {self.p.stale_timeout:g} s)"
                )
            return {}  # nothing new: publish nothing rather than repeat an old value
        if self._fresh_before:  # from the first reading on (the first tick waits for no stream)
            self._longest_gap = max(self._longest_gap, t - self._last_fresh_t)
        self._fresh_before = True
        self._last_fresh_t = t
        (f, tq), sign, bf, bt = raw, self.p.sign, self.bias_force, self.bias_torque
        force = Vector3(*(sign * (f[i] - bf[i]) for i in range(3)))
        torque = Vector3(*(sign * (tq[i] - bt[i]) for i in range(3)))
        return {"wrench": WrenchStamped(header=tick.header(self.p.frame), wrench=Wrench(force=force, torque=torque))}

    def device_figures(self) -> dict:
        """The sensor's stream as validity judges it (dockhil/runtime/validity.py: device_reasons)."""
        return {
            "what": getattr(self, "device", "the F/T sensor"),
            "gap_is": f"a fresh {self.sample}",
            "longest_gap_s": getattr(self, "_longest_gap", 0.0),
            "gap_limit_s": self.p.max_gap,
        }

    def close(self) -> None:
        if not self._is_open():
            return
        lines = self._report()
        self._shutdown()
        for line in lines:
            self.log(line)


def problems_line(device: str, counted: Sequence[tuple[int, str]]) -> list[str]:
    """One warning naming what went wrong how often ('3 samples lost, 1 bad frames'), or none."""
    problems = [f"{n} {what}" for n, what in counted if n]
    return [f"warning: {device}: {', '.join(problems)}"] if problems else []
