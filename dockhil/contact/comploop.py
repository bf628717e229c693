"""The HIL loop with a target contact (linear or Hunt-Crossley), a delay compensation and simulated
hardware that differs from what the loop is told, without the graph.

`ImpedanceStep` is what the virtual-impedance node computes each tick (the target's force less the
passive compliance's, the energy account, the compensation's force); `simulate_compensated` runs it
with the pieces of dockhil.contact.hilloop in the graph's order, so the graph and this loop give
the same trajectory. The hardware's truth (`Hardware`): its compliance is k_scale times the told k,
its robot delay delay_scale times the told delay, its sensor reports ft_delay later than the robot
moved, with white noise of `noise` N (drawn as the simulated sensor draws it), behind a servo lag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

from dockhil.contact import hunt_crossley
from dockhil.contact.compensation import CompensationSettings, Compensator, hold_damping
from dockhil.contact.hilloop import Bodies, DelayLine, HilRun, Servo, delay_ticks, sensor_force, virtual_wrench
from dockhil.contact.hunt_crossley import TargetContact, hunt_crossley_omega
from dockhil.contact.hybrid import VirtualImpedance, passive_force
from dockhil.contact.passivity import ENERGY_FIELDS, EnergyMonitor, Passivity
from dockhil.contact.scenario import ContactModelError

if TYPE_CHECKING:
    import numpy as np

ZERO = VirtualImpedance(0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Hardware:
    """The simulated hardware's truth, against what the loop is told (1, 1, 0, 0, 0: as told)."""

    k_scale: float = 1.0
    delay_scale: float = 1.0
    ft_delay: float = 0.0
    noise: float = 0.0
    lag: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name, lo in (("k_scale", 0.0), ("delay_scale", 0.0)):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > lo):
                raise ContactModelError(f"hw_{name} must be > 0, got {value!r}")
        for name in ("ft_delay", "noise", "lag"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ContactModelError(f"{name} must be >= 0, got {value!r}")


def target_frequency(contact: TargetContact, m: float, v: float = 0.03) -> float:
    """[rad/s] the contact's frequency: sqrt(kcs / m) (linear), or hunt_crossley_omega."""
    if contact.kind == "linear":
        return math.sqrt(contact.kcs / m)
    return hunt_crossley_omega(contact, m, v)


def linear_equivalent(params: dict, m: float) -> tuple[float, float]:
    """(kcs, bcs) of the linear contact with a Hunt-Crossley target's frequency (hunt_crossley_omega at
    the closing velocity v_close) and restitution: what the scene check judges the loop with."""
    contact = TargetContact("hunt_crossley", params["kcs"], n=params["hc_n"], alpha=params["hc_alpha"])
    return hunt_crossley.linear_equivalent(contact, m, params["v_close"])


class ImpedanceStep:
    """One tick of the virtual impedance: the virtual forces (the linear impedance, or the target's force
    less the told passive k p for a Hunt-Crossley target, on top of a given impedance), the energy
    account (the port, the linear impedance) and the compensation's force.

    step(x1, x2, v1, v2, f, robot, dt) -> (f1, f2, account): forces on chaser and target for the next
    tick; f the measured force on the chaser; robot the robot's reported (pose, velocity) or None."""

    def __init__(
        self,
        m1: float,
        m2: float,
        k: float,
        impedance: VirtualImpedance,
        contact: TargetContact | None,
        settings: CompensationSettings,
        dt: float,
        passivity: Passivity | None = None,
    ):
        self.m1, self.m2, self.k = m1, m2, k
        self.impedance = impedance
        self.contact = contact if contact is not None and contact.kind == "hunt_crossley" else None
        self.method = settings.method
        if "passivity" in self.method and passivity is None:
            raise ContactModelError(f"compensation {self.method!r} needs the passivity controller's settings")
        self.passivity = passivity if "passivity" in self.method else None
        self.monitor = EnergyMonitor(m1, m2, k, impedance, self.passivity)
        self.target = contact
        self.given_stiffness = k + impedance.k1  # without a target: the passive compliance and the given spring
        self.compensator = Compensator(settings, dt)
        self.hold = self.passivity is None and self.method != "none"

    def step(self, x1, x2, v1, v2, f, robot, dt):
        fv1, fv2 = virtual_wrench(x1, x2, v1, v2, self.m1, self.m2, self.impedance)
        if self.method == "none" or self.method == "passivity":
            fc, account = self.monitor.step(x1, x2, v1, v2, f, fv1, fv2, dt)
            extra = 0.0
        else:
            p, pd = x1 - x2, v1 - v2
            touching = p > 0.0 or (p == 0.0 and pd > 0.0)
            port, extra = self.compensator.step(p, pd, f, robot, touching)
            if self.hold and touching:
                stiffness = self.given_stiffness if self.target is None else self.target.stiffness(p)
                extra -= hold_damping(stiffness, dt) * pd
            if self.passivity is not None:  # phase lead + passivity: the observer watches the led port
                fc, account = self.monitor.step(x1, x2, v1, v2, port, fv1, fv2, dt)
                extra += fc
            else:
                fc, account = self.monitor.step(x1, x2, v1, v2, f, fv1, fv2, dt, external=extra)
        if self.method == "passivity":
            fv1, fv2 = fv1 + fc, fv2 - fc
        elif self.method != "none":
            fv1, fv2 = fv1 + extra, fv2 - (extra if self.m2 != 0.0 else 0.0)
        if self.contact is not None:
            fh = self.target_force(x1 - x2, v1 - v2)
            fv1, fv2 = fv1 + fh, fv2 - (fh if self.m2 != 0.0 else 0.0)
        return fv1, fv2, account

    def target_force(self, p: float, pd: float) -> float:
        """[N] on the chaser from a Hunt-Crossley target at penetration p, rate pd: its force less the told
        passive k p while touching (0 apart, or without one)."""
        if self.contact is None or not (p > 0.0 or (p == 0.0 and pd > 0.0)):
            return 0.0
        return -(self.contact.force(p, pd) - passive_force(p, self.k))


class SensorSim:
    """The simulated F/T sensor: the true compliance against the robot's pose, white noise, and a delay of
    its own (the force it reads now is reported `delay_ticks` ticks later; 0 N before)."""

    def __init__(self, k: float, noise: float, seed: int, delay_ticks_: int):
        self.k, self.noise = k, noise
        self.rng = None
        if noise:
            import numpy as np

            self.rng = np.random.default_rng(seed)
        self.line = DelayLine(delay_ticks_) if delay_ticks_ else None

    def read(self, robot_x: float | None) -> float:
        force = sensor_force(robot_x, self.k)
        if self.noise:
            rng = cast("np.random.Generator", self.rng)  # made with the noise
            force += float(rng.normal(0.0, self.noise))
        if self.line is not None:
            late = self.line.push(force)
            force = 0.0 if late is None else late
        return force


def simulate_compensated(
    *,
    m1: float,
    m2: float,
    k: float,
    impedance: VirtualImpedance,
    dt: float,
    n_ticks: int,
    delay: float,
    settings: CompensationSettings,
    contact: TargetContact | None = None,
    hardware: Hardware = Hardware(),
    passivity: Passivity | None = None,
    x1: float = 0.0,
    x2: float = 0.0,
    v1: float = 0.0,
    v2: float = 0.0,
    thrust: float = 0.0,
    method: str = "exact",
    energy: bool = False,
) -> HilRun:
    """The loop of hil.yaml/stability.yaml with `compensation:=`, `contact:=` and the hardware's truth:
    as simulate_hil (bit for bit with method none and the hardware as told), `extra` the account."""
    import numpy as np

    bodies = Bodies(m1, m2, x1, x2, v1, v2, method)
    line = DelayLine(delay_ticks(delay * hardware.delay_scale, dt))
    servo = Servo(hardware.lag, dt)
    sensor = SensorSim(k * hardware.k_scale, hardware.noise, hardware.seed, delay_ticks(hardware.ft_delay, dt))
    imp = ImpedanceStep(m1, m2, k, impedance, contact, settings, dt, passivity)
    out = np.empty((6, n_ticks))
    account = {name: np.empty(n_ticks) for name in ENERGY_FIELDS} if energy else {}
    f1 = f2 = 0.0
    for tick in range(n_ticks):
        if tick > 0:
            bodies.step(f1, f2, dt)
        a1, a2, b1, b2 = bodies.positions()
        cmd = line.push((a1 - a2, b1 - b2))
        robot = None if cmd is None else servo.step(*cmd)
        fs = sensor.read(None if robot is None else robot[0])
        fv1, fv2, e = imp.step(a1, a2, b1, b2, fs, robot, dt)
        for name, series in account.items():
            series[tick] = getattr(e, name)
        f1 = fs + fv1 + thrust
        f2 = -fs + fv2
        out[:, tick] = (tick * dt, a1, a2, b1, b2, -(fs + fv1))
    return HilRun(out[0], out[1], out[2], out[3], out[4], out[5], extra=account)
