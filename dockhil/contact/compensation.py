"""Delay compensation methods of the HIL loop, one axis, each a small class stepped once a tick.

The port: the F/T sensor measures f, the force of the passive compliance k on the chaser, but the
robot presses it with the command of h seconds ago (and the sensor may report it later still), so
f = -k p(t - h) while the simulation moves p = x1 - x2 now. To first order the late spring is a
negative damper -k h (f = -k p + k h p'), the energy the delay makes. Each method adds a force fc on
the chaser (the target gets -fc) over the next tick, computed from what the virtual impedance sees:
the simulated state, the measured force and (for the predictor) the robot's reported pose.

- phase lead (Qi, Gao, Zhao et al., J. Intell. Robot. Syst. 2016; Wang et al. 2019): the measured
  force through L(s) = (1 + T1 s) / (1 + T2 s), T1 chosen so that L leads by exactly w h at the
  contact's frequency w (tan^-1(w T1) - tan^-1(w T2) = w h), discretised by Tustin prewarped at w
  (the discrete filter has that phase at w exactly). Its gain there is sqrt(1 + w^2 T1^2) /
  sqrt(1 + w^2 T2^2) ~ 1 + (w h)^2 / 2 + w^2 h T2: the lead amplifies (noise by T1 / T2).
- Smith predictor: a model of the hardware (the told k, delay and servo lag) run on the commands;
  fc = model(now) - model(delayed), so the loop feels f - model(delayed) + model(now): exactly the
  delay-free spring when the model matches the hardware.
- predictor with online identification (model-based prediction after He, Shen, Gao and Zhang,
  Chin. J. Mech. Eng. 35:149, 2022): the port's k and b identified from the robot's reported pose r
  and the measured force by recursive least squares (a Kalman filter of constant parameters), and
  the whole target computed at the simulated state, with the hardware's part taken as measured
  less its identified model: the loop feels -F_target(p, p') + (f + k^ r + b^ r'), so neither the
  robot's delay (r is what the robot reports, whatever the delay) nor a wrong k enters; only what
  the model does not explain (noise, an F/T delay the fit cannot absorb) reaches the bodies.
- energy matching: a delay h on a spring k is a damper -k h; an undelayed damper k h cancels it to
  first order. The first order restitution of the uncompensated linear loop is exp(-pi z / sqrt(1 - z^2)) with
  z = (c - k h) / (2 sqrt(K m)).
- passivity (Hannaford and Ryu, IEEE T-RA 2002): dockhil.contact.passivity.
- phase lead + passivity: the led force is the port the passivity observer watches.

Every force of the sampled loop is held over a tick, half a tick late on average: on the whole
contact of stiffness K a damper -K dt / 2 (0.005 of restitution on a 10 rad/s contact at 1 kHz).
The passivity observer sees that energy as it sees the delay's; the other methods are told of it
and add K dt / 2 (`hold_damping`, K the target's local stiffness), so that each is measured on the
delay it compensates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dockhil.contact.hilloop import DelayLine, Servo, delay_ticks, sensor_force
from dockhil.contact.scenario import ContactModelError

METHODS = ("none", "passivity", "phase_lead", "smith", "predictor", "energy", "phase_lead+passivity")


def check_method(method: str) -> str:
    if method not in METHODS:
        raise ContactModelError(f"compensation must be one of {', '.join(METHODS)}, got {method!r}")
    return method


# -- phase lead ------------------------------------------------------------------------------


def lead_time_constants(omega: float, h: float, tau: float) -> tuple[float, float]:
    """(T1, T2) [s] of the lead (1 + T1 s) / (1 + T2 s) with phase w h at w = omega [rad/s], T2 = tau."""
    if not (math.isfinite(omega) and omega > 0.0):
        raise ContactModelError(f"compensation 'phase_lead' needs the contact frequency > 0 rad/s, got {omega!r}")
    lead = omega * h + math.atan(omega * tau)
    if lead >= 0.5 * math.pi:
        raise ContactModelError(
            f"compensation 'phase_lead': a first-order lead cannot advance by w h = {omega * h:.3g} rad with "
            f"lead_tau {tau:g} s at w = {omega:.4g} rad/s (needs w h + atan(w lead_tau) < pi/2); lower lead_tau"
        )
    return math.tan(lead) / omega, tau


class PhaseLead:
    """The measured force through the lead filter, Tustin prewarped at omega; step returns the filtered force."""

    def __init__(self, omega: float, h: float, tau: float, dt: float):
        if not tau > 0.0:  # Tustin puts a pure zero's pole at z = -1: an undamped oscillation at the Nyquist rate
            raise ContactModelError(f"compensation 'phase_lead' needs lead_tau > 0 s, got {tau!r}")
        self.t1, self.t2 = lead_time_constants(omega, h, tau)
        c = omega / math.tan(0.5 * omega * dt)  # s = c (z - 1) / (z + 1): exact at omega
        a0 = 1.0 + self.t2 * c
        self.b0, self.b1 = (1.0 + self.t1 * c) / a0, (1.0 - self.t1 * c) / a0
        self.a1 = (1.0 - self.t2 * c) / a0
        self.x = self.y = 0.0

    def step(self, f: float) -> float:
        y = self.b0 * f + self.b1 * self.x - self.a1 * self.y
        self.x, self.y = f, y
        return y

    def response(self, omega: float, dt: float) -> complex:
        """The discrete filter's frequency response at omega [rad/s]."""
        z = complex(math.cos(omega * dt), math.sin(omega * dt))
        return (self.b0 * z + self.b1) / (z + self.a1)


# -- Smith predictor -------------------------------------------------------------------------


class SmithPredictor:
    """The told hardware (delay, servo lag, compliance k) simulated on the commands: fc = model(now) -
    model(delayed), as the simulated robot and sensor compute it, so it is exact on a matched plant."""

    def __init__(self, k: float, delay: float, lag: float, dt: float):
        self.k = k
        self.line = DelayLine(delay_ticks(delay, dt))
        self.servo = Servo(lag, dt)

    def step(self, p: float, pd: float) -> float:
        cmd = self.line.push((p, pd))
        late = sensor_force(None if cmd is None else self.servo.step(*cmd)[0], self.k)
        return sensor_force(p, self.k) - late


# -- predictor with the port identified online ------------------------------------------------


class PortIdentifier:
    """Recursive least squares of F = k r + b r' (F = -f compressive, r the robot's reported
    penetration) while r > 0: a Kalman filter of constant parameters, prior (k0, 0) with standard
    deviations (k0, k0 * 0.1 s), measurement noise `noise` [N]."""

    def __init__(self, k0: float, noise: float):
        self.k, self.b = k0, 0.0
        self.p11, self.p12, self.p22 = k0 * k0, 0.0, (0.1 * k0) ** 2
        self.r = max(noise, 1e-3) ** 2
        self.updates = 0

    def update(self, r: float, rd: float, force: float) -> None:
        # gain = P phi / (phi' P phi + R); theta += gain * innovation; P -= gain phi' P
        p1 = self.p11 * r + self.p12 * rd
        p2 = self.p12 * r + self.p22 * rd
        s = r * p1 + rd * p2 + self.r
        g1, g2 = p1 / s, p2 / s
        innovation = force - (self.k * r + self.b * rd)
        self.k += g1 * innovation
        self.b += g2 * innovation
        self.p11 -= g1 * p1
        self.p12 -= g1 * p2
        self.p22 -= g2 * p2
        self.updates += 1


class IdentifyingPredictor:
    """fc = k^ r + b^ r' - k p (each while its penetration is positive): with the virtual impedance's
    -(F_target - k p), the loop feels -F_target + (f + k^ r + b^ r'). `ft_delay` [s]: what the sensor
    is told to lag the robot's report (the identification pairs f with r that much older)."""

    def __init__(self, k: float, noise: float, ft_delay: float, dt: float):
        self.k = k
        self.id = PortIdentifier(k, noise)
        self.line = DelayLine(delay_ticks(ft_delay, dt))

    def step(self, p: float, f: float, robot: tuple[float, float] | None) -> float:
        aligned = self.line.push(robot)
        if aligned is not None and aligned[0] > 0.0:
            self.id.update(aligned[0], aligned[1], -f)
        fc = -self.k * p if p > 0.0 else 0.0
        if aligned is not None and aligned[0] > 0.0:
            fc += self.id.k * aligned[0] + self.id.b * aligned[1]
        return fc


# -- energy matching --------------------------------------------------------------------------


def energy_matching_damping(k: float, h: float) -> float:
    """[N s/m] the undelayed damper that cancels, to first order, what the delay h on the compliance k makes."""
    return k * h


def hold_damping(stiffness: float, dt: float) -> float:
    """[N s/m] what the zero-order hold makes on a contact of stiffness K: its forces act on average
    half a tick late, a damper -K dt / 2 (the passivity observer sees it in the energy; the other
    methods are told)."""
    return 0.5 * stiffness * dt


def first_order_restitution(m: float, stiffness: float, damping: float) -> float:
    """exp(-pi z / sqrt(1 - z^2)), z = c / (2 sqrt(K m)): the linear contact's restitution with the
    net damping c (for the delayed loop, c - k h); 0 when z >= 1."""
    z = damping / (2.0 * math.sqrt(stiffness * m))
    return 0.0 if z >= 1.0 else math.exp(-math.pi * z / math.sqrt(1.0 - z * z))


# -- one object for the node and the loop -----------------------------------------------------


@dataclass(frozen=True)
class CompensationSettings:
    """What a method is told (the loop file's or the scene's numbers, not the hardware's truth):
    method, the compliance k [N/m], the robot delay [s] and servo lag [s], the contact's frequency
    omega [rad/s] (phase lead), lead_tau [s] (phase lead's filter, 0: a quarter of the delay), the
    F/T noise [N] and delay [s] behind the robot's report (predictor)."""

    method: str
    k: float
    delay: float
    lag: float = 0.0
    omega: float = 0.0
    lead_tau: float = 0.0
    noise: float = 0.0
    ft_delay: float = 0.0

    def __post_init__(self) -> None:
        check_method(self.method)
        for name in ("delay", "lag", "lead_tau", "noise", "ft_delay"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ContactModelError(f"compensation {self.method!r}: {name} must be >= 0, got {value!r}")
        if self.method != "none" and not (math.isfinite(self.k) and self.k > 0.0):
            raise ContactModelError(
                f"compensation {self.method!r} needs the passive stiffness k > 0 N/m of the compliance "
                f"the sensor measures, got k = {self.k!r}; set k"
            )
        if "phase_lead" in self.method:
            lead_time_constants(self.omega, self.delay, self.tau)

    @property
    def tau(self) -> float:
        return self.lead_tau if self.lead_tau > 0.0 else 0.25 * self.delay


class Compensator:
    """The method's force on the chaser for the next tick; `passivity` methods are the energy
    monitor's (see EnergyMonitor.step: the port force it watches is `port`, the led force with a
    lead). step returns (port force the loop credits to the hardware, extra force fc)."""

    def __init__(self, settings: CompensationSettings, dt: float):
        s = settings
        self.settings, self.dt = s, dt
        ticks = delay_ticks(s.delay, dt)
        # Without a whole tick of delay there is nothing to lead (and a lead_tau of delay / 4 would be 0).
        self.lead = PhaseLead(s.omega, ticks * dt, s.tau, dt) if "phase_lead" in s.method and ticks else None
        self.smith = SmithPredictor(s.k, s.delay, s.lag, dt) if s.method == "smith" else None
        self.predictor = IdentifyingPredictor(s.k, s.noise, s.ft_delay, dt) if s.method == "predictor" else None
        self.damping = energy_matching_damping(s.k, ticks * dt) if s.method == "energy" else 0.0

    def step(
        self, p: float, pd: float, f: float, robot: tuple[float, float] | None, touching: bool
    ) -> tuple[float, float]:
        port, fc = f, 0.0
        if self.lead is not None:
            port = self.lead.step(f)
            fc = port - f
        if self.smith is not None:
            fc += self.smith.step(p, pd)
        elif self.predictor is not None:
            fc += self.predictor.step(p, f, robot)
        elif self.damping and touching:
            fc -= self.damping * pd
        return port, fc
