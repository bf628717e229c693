"""The sampled HIL loop, piece by piece, and the whole loop as one function.

The simulation nodes (satellite dynamics, virtual impedance, delay injector,
robot servo, F/T sensor) each call one piece below per tick; `simulate_hil`
calls the same pieces in the same order, so the node graph and this bare
loop produce bit-identical trajectories.

Timing of one tick k (step dt): the dynamics integrate from tick k-1 to k
with the forces of tick k-1 held constant (zero-order hold), then publish
the state of tick k; the virtual impedance, the delayed robot and the F/T
sensor answer at the same tick. The sampled loop thus adds one step to the
robot delay h. Until h has passed the robot has no command, reports no
pose, and the sensor reads no force.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, cast

from dockhil.contact.hybrid import VirtualImpedance, passive_force, virtual_forces
from dockhil.contact.passivity import ENERGY_FIELDS, EnergyMonitor, Passivity
from dockhil.contact.scenario import ContactModelError, ContactScenario

if TYPE_CHECKING:
    import numpy as np


class Bodies:
    """Two free-floating bodies on one axis (chaser, target); m2 = 0 fixes the
    target to the ground. `method` is one of the model tool's integrators.
    With `ideal` (kcs, bcs) the ideal spring-dashpot acts inside the step
    while the bodies touch, instead of measured forces."""

    def __init__(
        self,
        m1: float,
        m2: float,
        x1: float,
        x2: float,
        v1: float,
        v2: float,
        method: str = "exact",
        ideal: tuple[float, float] | None = None,
        on_unstable: str = "raise",
    ):
        # numpy and the integrators here, not at the top: the nodes that use only the pieces below
        # (servo, sensor, delay) do not load them.
        import numpy as np

        from dockhil.contact.integrators import RELATIVE, Integrator, LinearSecondOrderSystem, Penetration

        self.fixed_target = m2 == 0.0
        self.m1, self.m2 = m1, m2
        self.x2_fixed = x2
        masses = [m1] if self.fixed_target else [m1, m2]
        self.free = Integrator(LinearSecondOrderSystem.free(masses), method, on_unstable)
        self.contact = None
        if ideal is not None:
            kcs, bcs = ideal
            if self.fixed_target:
                system = LinearSecondOrderSystem([m1], [[kcs]], [[bcs]])  # on x1 - x2: see `state`
            else:
                system = LinearSecondOrderSystem.ideal_contact(ContactScenario(m1, m2, kcs, bcs))
            self.contact = Integrator(system, method, on_unstable)
            self.kcs, self.bcs = kcs, bcs
            reduced = m1 if self.fixed_target else m1 * m2 / (m1 + m2)
            self.omega = math.sqrt(kcs / reduced)
        # A fixed target's state is kept relative to it, so a contact spring pulls toward the sheet.
        self.pen = Penetration([1.0]) if self.fixed_target else RELATIVE
        self.state: np.ndarray | tuple[float, float, float, float] = (
            np.array([x1 - x2, v1]) if self.fixed_target else np.array([x1, x2, v1, v2])
        )
        if ideal is None and not self.fixed_target:  # free flight steps in scalar arithmetic on Python floats: see step
            self.state = cast("tuple[float, float, float, float]", tuple(self.state.tolist()))
        self._rows: dict[float, tuple] = {}  # dt -> the free step's matrices as rows of Python floats
        self.in_contact = self._overlapping()

    def positions(self) -> tuple[float, float, float, float]:
        """(x1, x2, v1, v2) as Python floats."""
        s = self.state
        if self.fixed_target:
            return float(s[0]) + self.x2_fixed, self.x2_fixed, float(s[1]), 0.0
        if type(s) is tuple:  # already Python floats
            return s
        return float(s[0]), float(s[1]), float(s[2]), float(s[3])

    def touching(self) -> bool:
        """In contact: as located by the stepping with the ideal contact inside, else by the positions."""
        return self.in_contact if self.contact is not None else self._overlapping()

    def _overlapping(self) -> bool:
        x1, x2, v1, v2 = self.positions()
        p = x1 - x2
        return p > 0.0 or (p == 0.0 and v1 - v2 > 0.0)

    def step(self, f1: float, f2: float, dt: float) -> None:
        """Advance dt [s] with external forces f1, f2 [N] held constant; with the ideal
        contact inside, contact onsets and separations within the step are located."""
        if self.contact is None and not self.fixed_target:
            # Free flight: phi @ state + gamma @ force in scalar arithmetic (numpy costs more than
            # it saves on four values); each row summed left to right, as the matrix product does.
            rows = self._rows.get(dt)
            if rows is None:
                phi, gamma = self.free.step_matrices(dt)
                rows = self._rows[dt] = (tuple(map(tuple, phi.tolist())), tuple(map(tuple, gamma.tolist())))
            phi, gamma = rows
            (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3), (d0, d1, d2, d3) = phi
            (ga0, ga1), (gb0, gb1), (gc0, gc1), (gd0, gd1) = gamma
            s0, s1, s2, s3 = self.state
            self.state = (
                a0 * s0 + a1 * s1 + a2 * s2 + a3 * s3 + (ga0 * f1 + ga1 * f2),
                b0 * s0 + b1 * s1 + b2 * s2 + b3 * s3 + (gb0 * f1 + gb1 * f2),
                c0 * s0 + c1 * s1 + c2 * s2 + c3 * s3 + (gc0 * f1 + gc1 * f2),
                d0 * s0 + d1 * s1 + d2 * s2 + d3 * s3 + (gd0 * f1 + gd1 * f2),
            )
        elif self.contact is None:  # a fixed target: numpy's product of two values fuses differently
            import numpy as np

            state = cast(np.ndarray, self.state)  # an array: only free flight between free bodies keeps a tuple
            self.state = self.free.step(state, np.array([f1]), dt)
        else:
            import numpy as np

            from dockhil.contact.integrators import step_with_events

            force = np.array([f1]) if self.fixed_target else np.array([f1, f2])
            state = cast(np.ndarray, self.state)  # an array: only free flight between free bodies keeps a tuple
            self.state, self.in_contact, _ = step_with_events(
                self.free, self.contact, state, force, dt, self.in_contact, self.pen, self.omega
            )
        s0, s1, *rest = self.state
        if not (math.isfinite(s0) and math.isfinite(s1) and all(map(math.isfinite, rest))):
            raise ContactModelError(
                f"the bodies' state diverged to {[float(v) for v in self.state]}; the loop is unstable or the "
                f"step too large"
            )

    def ideal_force(self) -> float:
        """Compressive ideal contact force [N] at the current state (0 apart)."""
        if self.contact is None or not self.in_contact:
            return 0.0
        x1, x2, v1, v2 = self.positions()
        return self.kcs * (x1 - x2) + self.bcs * (v1 - v2)


def virtual_wrench(
    x1: float, x2: float, v1: float, v2: float, m1: float, m2: float, impedance: VirtualImpedance
) -> tuple[float, float]:
    """Virtual forces [N] on chaser and target while touching; m2 = 0 is a fixed
    target (infinite mass: the wall is the target itself)."""
    if m2 != 0.0:
        return virtual_forces(x1, x2, v1, v2, m1, m2, impedance)
    p, pd = x1 - x2, v1 - v2
    if p < 0.0 or (p == 0.0 and pd <= 0.0):  # the same contact test as virtual_forces
        return 0.0, 0.0
    return -(impedance.k1 * p + impedance.b1 * pd), 0.0


def sensor_force(robot_x: float | None, k: float) -> float:
    """Force [N] of the passive compliance on the chaser (along +x): -k p while p > 0;
    0 while the robot reports no pose."""
    return 0.0 if robot_x is None else -passive_force(robot_x, k)


class DelayLine:
    """Returns the value pushed `ticks` pushes ago, None before that."""

    def __init__(self, ticks: int):
        if ticks < 0:
            raise ContactModelError(f"delay must be >= 0 ticks, got {ticks}")
        self.buf: deque = deque([None] * (ticks + 1), maxlen=ticks + 1)

    def push(self, value):
        self.buf.append(value)
        return self.buf[0]


class Servo:
    """First-order lag x' = (u - x) / tau, exact for u held over a step; tau = 0 follows u."""

    def __init__(self, tau: float, dt: float):
        self.alpha = 1.0 if tau == 0.0 else -math.expm1(-dt / tau)
        self.x: float | None = None
        self.v = 0.0

    def step(self, target: float, target_v: float) -> tuple[float, float]:
        """Pose and velocity after one step towards the target."""
        if self.x is None or self.alpha == 1.0:
            self.x, self.v = target, target_v
        else:
            self.x += self.alpha * (target - self.x)
            self.v += self.alpha * (target_v - self.v)
        return self.x, self.v


def delay_ticks(delay: float, dt: float) -> int:
    return int(round(delay / dt))


@dataclass
class HilRun:
    """Per-tick arrays of a HIL run. force: compressive contact force on the chaser [N]."""

    t: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    v1: np.ndarray
    v2: np.ndarray
    force: np.ndarray
    extra: dict = field(default_factory=dict)


def simulate_hil(
    *,
    m1: float,
    m2: float,
    k: float,
    impedance: VirtualImpedance,
    dt: float,
    n_ticks: int,
    delay: float = 0.0,
    x1: float = 0.0,
    x2: float = 0.0,
    v1: float = 0.0,
    v2: float = 0.0,
    thrust: float = 0.0,
    method: str = "exact",
    lag: float = 0.0,
    passivity: Passivity | None = None,
    energy: bool = False,
) -> HilRun:
    """The HIL loop of the graph in hil.yaml/stability.yaml, without the graph. With `passivity`
    the virtual impedance adds the passivity controller's force (as the node does). With
    `energy` or `passivity`, `extra` holds the energy account per tick (the fields of
    `EnergyTick`, as the node publishes on /energy); without, the loop runs at full speed."""
    import numpy as np

    bodies = Bodies(m1, m2, x1, x2, v1, v2, method)
    line = DelayLine(delay_ticks(delay, dt))
    servo = Servo(lag, dt)
    monitor = EnergyMonitor(m1, m2, k, impedance, passivity) if energy or passivity is not None else None
    out = np.empty((6, n_ticks))
    account = {name: np.empty(n_ticks) for name in ENERGY_FIELDS} if monitor is not None else {}
    f1 = f2 = 0.0
    for tick in range(n_ticks):
        if tick > 0:
            bodies.step(f1, f2, dt)
        a1, a2, b1, b2 = bodies.positions()
        fv1, fv2 = virtual_wrench(a1, a2, b1, b2, m1, m2, impedance)
        cmd = line.push((a1 - a2, b1 - b2))
        rx = None if cmd is None else servo.step(*cmd)[0]
        fs = sensor_force(rx, k)
        if monitor is not None:
            fc, e = monitor.step(a1, a2, b1, b2, fs, fv1, fv2, dt)
            if passivity is not None:  # the same sums as the virtual-impedance node publishes
                fv1, fv2 = fv1 + fc, fv2 - fc
            for name, series in account.items():
                series[tick] = getattr(e, name)
        f1 = fs + fv1 + thrust
        f2 = -fs + fv2
        out[:, tick] = (tick * dt, a1, a2, b1, b2, -(fs + fv1))
    return HilRun(out[0], out[1], out[2], out[3], out[4], out[5], extra=account)


def simulate_ideal(
    *,
    m1: float,
    m2: float,
    kcs: float,
    bcs: float,
    dt: float,
    n_ticks: int,
    x1: float = 0.0,
    x2: float = 0.0,
    v1: float = 0.0,
    v2: float = 0.0,
    thrust: float = 0.0,
    method: str = "exact",
) -> HilRun:
    """The ideal model (Eq. 1) sampled as the satellite-dynamics node runs it in ideal.yaml."""
    import numpy as np

    bodies = Bodies(m1, m2, x1, x2, v1, v2, method, ideal=(kcs, bcs))
    out = np.empty((6, n_ticks))
    for tick in range(n_ticks):
        if tick > 0:
            bodies.step(thrust, 0.0, dt)
        a1, a2, b1, b2 = bodies.positions()
        out[:, tick] = (tick * dt, a1, a2, b1, b2, bodies.ideal_force())
    return HilRun(*out)
