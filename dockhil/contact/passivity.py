"""Energy at the HIL port, and a time-domain passivity controller against the energy that the
robot's delay and the sampling generate (after Hannaford and Ryu, IEEE T-RA 2002).

The port is one axis of the interface between hardware and simulation: the measured force f on
the chaser (the target feels -f; F = -f is compressive) and the simulated relative motion of the
interfaces p = x1 - x2. A force is held over a tick (zero-order hold), so the work it does on the
simulated bodies over tick j is exactly f(j) (p(j+1) - p(j)).

A port that is passive and free of delay gives back at most what it holds, so

    generated(k) = S(k) + sum_{j<k} f(j) (p(j+1) - p(j))

is the energy the port made out of nothing, for any store S that is zero when the port is
unloaded: the same total over a contact, different timing. Hannaford and Ryu take S = 0 and learn
of the energy once the contact is over. We take what the delay-free compliance k would hold at
the simulated overlap,

    S = k p^2 / 2 while p > 0 (else 0),

so the generation rate is p' (k p - F): the power of the force error k p - F, which the delay
makes (F = k p(t - h) behind a delay h; k h p'^2 to first order: the delay is a negative damper
-k h). Where p' and k p - F have the same sign the error makes energy, and a damper on p' can
cancel it exactly: the controller dissipates over the next tick what the held force will make
over it (predicted with p + p' dt), so the chaser feels k (p + p' dt / 2) from the port and the
controller together, the delay-free spring at mid-tick: until the bodies first turn, the loop is
the ideal contact, however long the delay. Where they have opposite signs (just past a turn of p,
for about h / 2) the error dissipates by itself and no damper can undo it; the observer keeps
that as credit against later generation, as Hannaford and Ryu's does, so over a contact the loop
gives back what the ideal one does (on Table 1: exit velocity within 1.4e-5 m/s of the ideal's
for any delay up to half the contact).

Other stores see the energy at other times and ask the damper for more. F^2 / (2 k), what the
measured compliance holds (an observer that counts the measured force against the robot's own
motion), makes energy at the rate k p_r (p_r' - p') (p_r = F/k the robot's deflection);
F p - F^2 / (2 k) at k p_r' (p - p_r). Both
are about k h p'^2 too, but both go on where the simulated body turns (p' = 0) while the delayed
robot still moves, so the damping they need grows as 1/p'^2 there, and a bound on it costs force:
on Table 1 at 0.785 s of delay (half the contact) the second, with the energy taken one tick
late, erred -2.8 N on the peak force with a bound of 200 N s/m (more than the loop without
compensation) and +63 N with 1e4 (force spikes). With k p^2 / 2 and the prediction the added force
is the force error itself (measured: never more than 0.05 N above |k p - F| on Table 1), which stays
finite at a turn; only the damping coefficient grows there (as 1/p'), so a high bound costs no
force spike.

The virtual impedance is software, but its forces are held over a tick too: its springs make
k_i (de_i)^2 / 2 per tick (e_i the deflection from its wall). That is counted the same way: work
on the bodies + change of what its springs hold + what its dampers dissipate; the controller
takes it out the tick after.

The controller (per axis) adds a damping force -alpha v on the chaser (+alpha v on the target)
with alpha = E / (v^2 dt), E the net generated energy plus what the port will make over the next
tick, when E is positive. alpha is bounded by `max_damping` and by m_r / dt (m_r the reduced mass):
a damper stronger than that would reverse the relative velocity within a tick, and past 2 m_r / dt
it would make energy. It only dissipates (alpha >= 0) and acts only while the port is loaded (the
bodies touch, or the measured force exceeds `deadband`): it never makes energy, and once a contact
is over no force of it acts. After the bodies part while the delayed robot still pushes, it
cancels that push (the delay-free compliance would carry none). Where v is near 0 no damping can
dissipate: the energy waits and is taken once the bodies move again. Energy still in the loop when
the controller stops (the contact is over, or the run ends) beyond a tolerance means the bound was
too low: the controller saturated and the run is not valid (`saturation`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, cast

from dockhil.contact.scenario import ContactModelError

if TYPE_CHECKING:
    from dockhil.contact.hybrid import VirtualImpedance
    from dockhil.msgs import Energy

RESIDUAL_TOLERANCE = 1e-3  # of the largest energy the port's spring held: more left in the loop = saturated
# [N s/m] the scenes' max_damping. The force added is the delay's force error, so the bound need not
# hold the force down; it only has to clear the damping the error asks for: about k h, k tan(w h) / w
# when the first delayed force arrives (w = sqrt(kcs / m_r): 342 N s/m on Table 1 at 0.3 s), and 1/v
# near each turn. Below 3e4 it clips there and costs peak force on Table 1 at half the contact.
DEFAULT_MAX_DAMPING = 1e5


@dataclass(frozen=True)
class Passivity:
    """Parameters of the passivity controller: the passive stiffness k [N/m] whose store the
    observer credits, the largest damping [N s/m] the controller may add, and the force [N] below
    which a port whose bodies no longer touch counts as unloaded (above the sensor's noise: the
    controller would otherwise keep taking out the noise's positive swings after a contact)."""

    k: float
    max_damping: float
    deadband: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.k) and self.k > 0.0):
            raise ContactModelError(
                f"compensation 'passivity' needs the passive stiffness k > 0 N/m of the "
                f"compliance the sensor measures, got k = {self.k!r}; set k (e.g. k:=2510)"
            )
        if not (math.isfinite(self.max_damping) and self.max_damping > 0.0):
            raise ContactModelError(
                f"compensation 'passivity' needs max_damping > 0 N s/m, got {self.max_damping!r}; "
                f"set max_damping (e.g. max_damping:=200)"
            )
        if not (math.isfinite(self.deadband) and self.deadband >= 0.0):
            raise ContactModelError(f"compensation 'passivity' needs force_deadband >= 0 N, got {self.deadband!r}")


@dataclass
class EnergyTick:
    """The energy account at one tick [J], cumulative from the start (the fields of msgs.Energy)."""

    port_work_J: float = 0.0
    port_spring_J: float = 0.0
    port_stored_J: float = 0.0
    kinetic_J: float = 0.0
    virtual_work_J: float = 0.0
    virtual_stored_J: float = 0.0
    virtual_dissipated_J: float = 0.0
    generated_J: float = 0.0
    compensation_dissipated_J: float = 0.0
    net_generated_J: float = 0.0
    damping_Ns_m: float = 0.0
    at_max_damping: bool = False
    port_loaded: bool = False


ENERGY_FIELDS = tuple(f.name for f in fields(EnergyTick))


def port_store(f: float, p: float, k: float) -> tuple[float, float]:
    """(spring, stored) [J] of a port whose compliance k carries the force f on the chaser
    (F = -f compressive) while the simulated interfaces overlap by p: F^2/(2k), what the measured
    compliance holds, and k p^2/2 (p > 0), what the delay-free compliance would hold."""
    if k <= 0.0:
        return 0.0, 0.0
    return f * f / (2.0 * k), (0.5 * k * p * p if p > 0.0 else 0.0)


def port_generation(f: float, p: float, dp: float, k: float) -> float:
    """[J] the energy the port makes over a tick in which the held force f on the chaser acts while
    the overlap moves from p by dp: its work on the bodies plus the change of the store k p^2/2."""
    q = p + dp
    return f * dp + 0.5 * k * ((q * q if q > 0.0 else 0.0) - (p * p if p > 0.0 else 0.0))


def damping_force(
    passivity: Passivity | None, energy: float, v: float, dt: float, active: bool, ceiling: float = math.inf
) -> tuple[float, float, bool]:
    """One axis of the controller: (force on the chaser [N], damping [N s/m], at the bound) over
    the next tick, so that it dissipates `energy` [J] at velocity v [m/s]; the damping is bounded by
    max_damping and by `ceiling` (m_r / dt: no reversal of the relative velocity within a tick)."""
    if passivity is None or not active or energy <= 0.0:
        return 0.0, 0.0, False
    want = math.inf if v == 0.0 else energy / (v * v * dt)
    bound = min(passivity.max_damping, ceiling)
    alpha = min(want, bound)
    return -alpha * v, alpha, want > bound


class EnergyMonitor:
    """The energy account of the 1-DOF HIL loop, fed each tick with the state and the forces that
    will act over the next tick; with `passivity`, also the controller's force.

    m2 = 0 is a fixed target (the virtual wall is the target). The virtual impedance is that of
    `dockhil.contact.hybrid.virtual_forces`: springs and dampers to the centre of mass, so body
    i's deflection is e1 = (m2/M) p, e2 = -(m1/M) p while the bodies touch. k: the passive
    compliance [N/m] (0: unknown, the port's store is not credited)."""

    def __init__(self, m1: float, m2: float, k: float, impedance: VirtualImpedance, passivity: Passivity | None = None):
        self.m1, self.m2, self.k = m1, m2, k
        self.imp = impedance
        self.s1, self.s2 = (1.0, 0.0) if m2 == 0.0 else (m2 / (m1 + m2), -m1 / (m1 + m2))
        self.reduced = m1 if m2 == 0.0 else m1 * m2 / (m1 + m2)  # [kg] of the relative motion p
        self.passivity = passivity
        self.prev: tuple[float, float, float, float, float, float, float, float, bool] | None = (
            None  # (x1, x2, p, pd, f, fc, fv1, fv2, touching) of the previous tick
        )
        self.e = EnergyTick()
        self.initial = 0.0  # [J] what the port and the virtual springs hold at the first tick

    def step(
        self,
        x1: float,
        x2: float,
        v1: float,
        v2: float,
        f: float,
        fv1: float,
        fv2: float,
        dt: float,
        external: float = 0.0,
    ) -> tuple[float, EnergyTick]:
        """Account for the tick that just ended (the previous tick's forces over the motion since),
        then return the controller's force on the chaser for the next tick (0 without it; the
        target gets its opposite) and the account. f: measured force on the chaser [N]; fv1, fv2:
        virtual forces [N] on chaser and target; external: another compensation's force on the chaser
        over the next tick [N] (dockhil.contact.compensation), counted with the controller's."""
        e, imp = self.e, self.imp
        p, pd = x1 - x2, v1 - v2
        touching = p > 0.0 or (p == 0.0 and pd > 0.0)  # as hybrid.virtual_forces
        if self.prev is not None:
            px1, px2, pp, ppd, pf, pfc, pfv1, pfv2, ptouch = self.prev
            dp = p - pp
            e.port_work_J += pf * dp
            e.compensation_dissipated_J -= pfc * dp
            e.virtual_work_J += pfv1 * (x1 - px1) + pfv2 * (x2 - px2)
            if ptouch:  # the dampers pulled with the deflection rates of the tick's start
                e.virtual_dissipated_J += (imp.b1 * self.s1 * self.s1 + imp.b2 * self.s2 * self.s2) * ppd * dp
        e.kinetic_J = 0.5 * (self.m1 * v1 * v1 + self.m2 * v2 * v2)
        e.port_spring_J, e.port_stored_J = port_store(f, p, self.k)
        if touching:
            e1, e2 = self.s1 * p, self.s2 * p
            e.virtual_stored_J = 0.5 * (imp.k1 * e1 * e1 + imp.k2 * e2 * e2)
        else:
            e.virtual_stored_J = 0.0
        if self.prev is None:
            # A run may start in contact: what the stores hold then was not made by the loop (the
            # delay-free port holds k p^2 / 2 from the start; the delayed robot reports it later).
            self.initial = e.port_stored_J + e.virtual_stored_J
        e.generated_J = (
            e.port_work_J
            + e.port_stored_J
            + e.virtual_work_J
            + e.virtual_stored_J
            + e.virtual_dissipated_J
            - self.initial
        )
        e.net_generated_J = e.generated_J - e.compensation_dissipated_J
        e.port_loaded = touching or abs(f) > (self.passivity.deadband if self.passivity is not None else 0.0)
        if self.passivity is not None and e.port_loaded:
            # What is left, and what the held force will make over the next tick (p moving at pd).
            energy = e.net_generated_J + port_generation(f, p, pd * dt, self.k)
            fc, e.damping_Ns_m, e.at_max_damping = damping_force(
                self.passivity, energy, pd, dt, True, self.reduced / dt
            )
        else:
            fc, e.damping_Ns_m, e.at_max_damping = 0.0, 0.0, False
        self.prev = (x1, x2, p, pd, f, fc + external, fv1, fv2, touching)
        return fc, e


class EnergyMeter:
    """What a run's energy account says, fed one account per tick (O(1) memory): the last
    account, the largest spring energy, the ticks at the bound, and the most energy left in
    the loop when the controller stopped (each time the port was unloaded, and at the end)."""

    def __init__(self):
        self.last: EnergyTick | Energy | None = None
        self.spring_max = 0.0
        self.ticks_at_max = 0
        self.left = -math.inf

    def add(self, account: EnergyTick | Energy) -> None:
        if self.last is not None and self.last.port_loaded and not account.port_loaded:
            self.left = max(self.left, account.net_generated_J)  # after the last loaded tick's force acted
        self.last = account
        self.spring_max = max(self.spring_max, account.port_spring_J)
        self.ticks_at_max += bool(account.at_max_damping)

    def residual(self) -> float:
        """[J] the most net generated energy the loop kept when the controller stopped."""
        last = cast("EnergyTick | Energy", self.last)  # an account was added
        return max(self.left, last.net_generated_J) if last.port_loaded else self.left

    def saturation(self, max_damping: float) -> str | None:
        """One line when the controller left generated energy in the loop, else None."""
        if self.last is None or self.residual() == -math.inf:
            return None
        residual, tol = self.residual(), RESIDUAL_TOLERANCE * self.spring_max
        if residual <= tol:
            return None
        return (
            f"the passivity controller saturated at max_damping {max_damping:g} N s/m: {residual:.3g} J made "
            f"by the delay stayed in the loop (allowed {tol:.3g} J, {RESIDUAL_TOLERANCE:g} of the port's "
            f"peak energy; {self.ticks_at_max} ticks at the bound); raise max_damping"
        )


def left_in_loop(account: dict) -> tuple[float, float]:
    """(left, allowed) [J] of per-tick account arrays (simulate_hil's `extra`): the most net
    generated energy kept when the controller stopped, as EnergyMeter.residual, and the tolerance."""
    import numpy as np

    loaded = np.asarray(account["port_loaded"], bool)
    net = np.asarray(account["net_generated_J"], float)
    stops = np.flatnonzero(loaded[:-1] & ~loaded[1:]) + 1
    candidates = list(net[stops]) + ([net[-1]] if loaded[-1] else [])
    left = max(candidates) if candidates else -math.inf
    return float(left), RESIDUAL_TOLERANCE * float(np.max(account["port_spring_J"]))
