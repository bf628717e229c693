"""Identification of the real HIL loop: pure fits (numpy/scipy) on recorded samples, no I/O.

What `dockhil calibrate` measures, each with its one-sigma uncertainty:

* at rest: the F/T sensor's bias (force and torque, per axis: the mean) and noise (the
  standard deviation per axis);
* in free space, from the setpoints the robot driver's link sent to the controller and the poses it
  read back, each at the controller's cycle (/robot/cycles): the command-to-motion delay d and the
  servo lag tau of the model

      x(t) = L[x_cmd](t - d),   L: first-order lag 1 / (1 + tau s)

  fitted by nonlinear least squares; a second-order lag (two equal poles) is fitted too and
  the model with the smaller Akaike information criterion is named (`lag_model`). The delay
  is the robot's own, at the device; the link (a command's tick to the device cycle that takes it,
  and a pose's device cycle to the tick that publishes it) is measured apart, and the loop's delay
  is their sum. A recording without device cycles is fitted on the graph's ticks (/robot/command
  against /robot/state): the delay is then the loop's, the link included;
* pressed into the passive compliance: the stiffness k, damping b and the surface position s
  of the unilateral contact  F = k (x - s) + b v  (F > 0 pushes the probe back), fitted on the
  samples where the force stands clear of the noise band, against the pose and velocity read
  back at the force's time minus the F/T measurement delay; that delay is searched over a grid
  and reported where the residual has a clear minimum (a slow press alone cannot tell a delay
  of the force from less damping: k d and b enter alike; then it is None and b is the damping
  the loop sees).

Uncertainties come from the fit's Jacobian, with the residual variance inflated for the
residuals' correlation (lag-1 autocorrelation, an AR(1) effective sample size): samples of a
wall-time loop are not independent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dockhil.analysis.calibration.device_cycles import DeviceCycles, Link, device_servo, link
from dockhil.analysis.calibration.end_to_end import EndToEnd, end_to_end
from dockhil.analysis.calibration.servo_fit import CalibrationError, Contact, Rest, Servo, contact, rest, servo

# The fits' names, as the calibration's users and tests reach them.
__all__ = [
    "CalibrationError",
    "Contact",
    "DeviceCycles",
    "EndToEnd",
    "Link",
    "Rest",
    "Servo",
    "contact",
    "device_servo",
    "end_to_end",
    "link",
    "rest",
    "servo",
]


@dataclass
class Recording:
    """What an identification run recorded, as arrays; times in seconds on one clock.

    phases: (start time, phase name) in order, as the identification node announced them.
    """

    t_cmd: np.ndarray
    x_cmd: np.ndarray
    t_state: np.ndarray
    x_state: np.ndarray
    v_state: np.ndarray
    t_ft: np.ndarray
    force: np.ndarray  # (n, 3) [N], as the driver publishes it (no tare)
    torque: np.ndarray  # (n, 3) [N m]
    phases: list[tuple[float, str]]
    cycles: DeviceCycles | None = None  # the driver's device exchanges (/robot/cycles); None: not recorded

    def window(self, *names: str) -> tuple[float, float]:
        """Start and end time of the run of consecutive phases `names` (end: the next phase's start)."""
        starts = [t for t, p in self.phases if p in names]
        if not starts:
            raise CalibrationError(
                f"the run has no {' or '.join(names)} phase: it is not an identification run "
                f"of dockhil calibrate, or it stopped before it"
            )
        begin = min(starts)
        later = [t for t, p in self.phases if t > max(starts) and p not in names]
        return begin, (min(later) if later else math.inf)


def _between(t: np.ndarray, window: tuple[float, float]) -> np.ndarray:
    return (t >= window[0]) & (t < window[1])


NO_DAMPING = (
    "the press reads a damping of {b:.3g} +- {s:.2g} N s/m, negative beyond its uncertainty: no hardware has it "
    "(the force leads the pose by a delay the slow press cannot separate from damping); not identified"
)

NO_CYCLES = (
    "no device cycles (/robot/cycles) in the recording: the delay is timed on the graph's ticks, so it is "
    "the loop's, the link included (a recording from before the drivers published them)"
)


NO_SPLIT = (
    "the controller does not tell which cycle took a correction (its answer follows the pose): the robot's own "
    "delay and the link are not separated by these data (a controller that takes a correction as it arrives, "
    "or samples the pose before the servo's step, spends up to about a cycle and the link's wait less than "
    "assumed); the robot's delay lies in delay_range_s; the loop's delay, end to end, is measured"
)

NO_LAG = (
    "a pure delay explains the poses nearly as well as a {lag:.2f} ms lag and as much less delay: the steps and "
    "the chirp do not separate a lag of a few cycles from delay; the lag is taken as 0 and the delay holds it "
    "(a pure delay is the more cautious loop for the verdict)"
)


@dataclass(frozen=True)
class Calibration:
    rest: Rest
    servo: Servo
    contact: Contact
    link: Link | None = None  # None: timed on the graph's ticks (no device cycles), the link in servo's delay
    loop: EndToEnd | None = None  # the loop's delay end to end; None: a Calibration built without the run

    @property
    def loop_delay_s(self) -> float:
        """The loop's delay: end to end, from a command leaving the graph to the pose answering it arriving,
        at a high percentile of what the run saw, and never below the robot's own delay; without the run's
        end-to-end fit, the robot's at the device plus the link to it and back."""
        if self.loop is not None:
            return max(self.loop.delay_s, self.servo.delay_s)
        return self.servo.delay_s + (self.link.total_s if self.link is not None else 0.0)

    @property
    def split_identified(self) -> bool:
        """The loop's delay separated into the robot's at the device and the link: where the device shows the
        cycle that took each setpoint (or no device cycles were recorded: the delay is then the loop's)."""
        return self.link is None or self.link.take_seen

    def delay_range_s(self) -> tuple[float, float]:
        """Where the robot's own delay lies, whatever the controller's inside (device cycles recorded): from
        the device model's (the take at the cycle read back, or the next where the device does not echo it,
        and the pose after the servo's step), less half its cycle and what the lag may trade with it (up to
        another half), to that plus two cycles (the pose sampled before the servo's step; a setpoint taken as
        it is written, up to a cycle before the cycle that echoes it), the lag up to a cycle (a lag under a
        cycle or two blends with the delay's cycle: the fit may read that much of the delay as lag) and, where
        the device does not echo its takes, the link's forward part (the correction taken as it arrived, not
        at the next cycle)."""
        s, ln = self.servo, self.link
        cycle = s.cycle_s or 0.0
        forward = ln.forward_s if ln is not None and not ln.take_seen else 0.0
        # The delay may be shorter by what the lag may be longer (two of the lag's sigmas, up to half a cycle: a
        # 16.71 ms lag read as 16.29 +- 0.29 ms left the delay 0.67 ms long), and a lag the delay holds (not
        # separated) is not its.
        trade = s.unseparated_lag_s or min(2.0 * s.lag_sigma_s, 0.5 * cycle)
        return max(s.delay_s - 0.5 * cycle - trade, 0.0), s.delay_s + 2.0 * cycle + min(s.lag_s, cycle) + forward

    @property
    def lag_note(self) -> str | None:
        """The line that says the lag is not identified (the delay holds it); None where it is."""
        lag = self.servo.unseparated_lag_s
        return NO_LAG.format(lag=1e3 * lag) if lag else None

    @property
    def damping_identified(self) -> bool:
        """A passive damping hardware can have: not negative beyond its uncertainty (a force that leads the
        pose reads as negative damping where the press cannot separate the force's delay)."""
        c = self.contact
        return math.isfinite(c.b_Ns_per_m) and c.b_Ns_per_m + max(c.b_sigma, 0.0) >= 0.0

    def as_dict(self) -> dict:
        r, s, c, ln, e2e = self.rest, self.servo, self.contact, self.link, self.loop
        b_known = self.damping_identified
        split = self.split_identified
        return {
            "delay_s": s.delay_s if split else None,
            "delay_range_s": None if ln is None else list(self.delay_range_s()),
            "loop_delay_s": self.loop_delay_s,
            "loop_delay_typical_s": None if e2e is None else e2e.typical_s,
            "link_s": None if ln is None or not split else ln.total_s,
            "timing": "device cycles" if ln is not None else NO_CYCLES,
            "lag_s": s.lag_s,
            "k_N_per_m": c.k_N_per_m,
            "b_Ns_per_m": c.b_Ns_per_m if b_known else None,
            "bias_N": list(r.bias_N),
            "noise_N": list(r.noise_N),
            "bias_Nm": list(r.bias_Nm),
            "noise_Nm": list(r.noise_Nm),
            "ft_delay_s": c.ft_delay_s,
            "surface_m": c.surface_m,
            "uncertainty": {
                "delay_s": s.delay_sigma_s if split else None,
                "link_s": None if ln is None or not split else math.hypot(ln.forward_spread_s, ln.back_spread_s),
                "lag_s": s.lag_sigma_s,
                "k_N_per_m": c.k_sigma,
                "b_Ns_per_m": c.b_sigma if b_known else None,
                "bias_N": list(r.bias_sigma_N),
                "noise_N": list(r.noise_sigma_N),
                "ft_delay_s": c.ft_delay_sigma_s,
                "surface_m": c.surface_sigma_m,
            },
            "lag_model": s.lag_model,
            "fit": {
                "servo_rms_m": s.rms_m,
                "servo_samples": s.samples,
                "contact_rms_N": c.rms_N,
                "contact_samples": c.samples,
                "peak_force_N": c.peak_force_N,
                "rest_samples": r.samples,
                **({"b_not_identified": NO_DAMPING.format(b=c.b_Ns_per_m, s=c.b_sigma)} if not b_known else {}),
                **({} if split else {"split_not_identified": NO_SPLIT}),
                **({"lag_not_identified": self.lag_note} if self.lag_note else {}),
                **(
                    {}
                    if e2e is None
                    else {
                        "loop_delay_whole_run_s": e2e.whole_s,
                        "loop_delay_spread_s": e2e.spread_s,
                        "loop_delay_windows": e2e.windows,
                        "loop_delay_percentile": e2e.percentile,
                    }
                ),
                **(
                    {}
                    if ln is None
                    else {
                        "link_forward_s": ln.forward_s,
                        "link_back_s": ln.back_s,
                        "link_forward_spread_s": ln.forward_spread_s,
                        "link_back_spread_s": ln.back_spread_s,
                    }
                ),
            },
        }


def identify(rec: Recording) -> Calibration:
    """Rest, servo and contact fits from one identification run."""
    at_rest = _between(rec.t_ft, rec.window("rest"))
    r = rest(rec.force[at_rest], rec.torque[at_rest])
    free = rec.window("steps", "chirp")
    cmd, state = _between(rec.t_cmd, free), _between(rec.t_state, free)
    timed = None
    if rec.cycles is not None:
        inside = rec.cycles.select(_between(rec.cycles.sent, free))
        if inside.written.sum() >= 10:
            timed = inside
    if timed is None:
        s, ln = servo(rec.t_cmd[cmd], rec.x_cmd[cmd], rec.t_state[state], rec.x_state[state]), None
    else:  # at the device boundary: the robot's own delay, and the link apart
        s = device_servo(timed)
        ln = link(timed, rec.t_cmd[cmd], rec.t_state[state])
    # The loop's delay, end to end on the graph's ticks, with the servo's lag: what the loop has
    e2e = end_to_end(rec.t_cmd[cmd], rec.x_cmd[cmd], rec.t_state[state], rec.x_state[state], s.lag_s)
    press = rec.window("approach", "press", "hold", "release")
    ft, st = _between(rec.t_ft, press), _between(rec.t_state, press)
    # The force on the probe pushes it back (-x); the bias is taken off.
    pushing = -(rec.force[ft, 0] - r.bias_N[0])
    c = contact(rec.t_ft[ft], pushing, rec.t_state[st], rec.x_state[st], rec.v_state[st], r.noise_N[0])
    return Calibration(r, s, c, ln, e2e)


def check(cal: Calibration) -> None:
    """CalibrationError when an estimate the loop depends on is no measurement: its uncertainty is larger
    than its value (or not finite)."""
    d = cal.as_dict()
    for key, what in (("delay_s", "delay"), ("k_N_per_m", "stiffness k")):
        value, sigma = d[key], d["uncertainty"][key]
        if value is None:  # not identified (the split): said so in the result, nothing to check
            continue
        if not (math.isfinite(value) and math.isfinite(sigma)) or sigma > abs(value):
            raise CalibrationError(
                f"the {what} fit is no measurement: {value:.4g} +- {sigma:.3g} (the uncertainty "
                f"is larger than the value); repeat the identification with the probe free at "
                f"rest and the robot following"
            )


def recording(messages) -> Recording:
    """A Recording from (topic, message) pairs of an identification run (a bag's, decoded), timed by
    their header stamps (each the publishing node's tick)."""
    cmd, state, ft, phases, cycles = [], [], [], [], []
    for topic, msg in messages:
        stamp = msg.header.stamp
        if topic == "/robot/command":
            cmd.append((stamp, msg.pose.position.x))
        elif topic == "/robot/state":
            state.append((stamp, msg.pose.position.x, msg.twist.linear.x))
        elif topic == "/ft/wrench":
            f, t = msg.wrench.force, msg.wrench.torque
            ft.append((stamp, f.x, f.y, f.z, t.x, t.y, t.z))
        elif topic == "/calibration/phase":
            phases.append((stamp, msg.state))
        elif topic == "/robot/cycles":
            cycles += [
                (e.sent, e.read, e.setpoint.position.x, e.written, e.actual.position.x, e.device_cycle, e.taken)
                for e in msg.cycles
            ]
    if not phases:
        raise CalibrationError(
            "no /calibration/phase messages: this is not a recording of an identification run "
            "(dockhil calibrate records one with --bag-out)"
        )
    for what, rows in (("/robot/command", cmd), ("/robot/state", state), ("/ft/wrench", ft)):
        if not rows:
            raise CalibrationError(f"no {what} messages in the identification run")
    c, s, w = (np.array(sorted(rows), dtype=float) for rows in (cmd, state, ft))
    return Recording(
        c[:, 0], c[:, 1], s[:, 0], s[:, 1], s[:, 2], w[:, 0], w[:, 1:4], w[:, 4:7], sorted(phases), _cycles(cycles)
    )


def _cycles(rows: list) -> DeviceCycles | None:
    if not rows:
        return None
    cols = list(zip(*rows))
    return DeviceCycles(
        *(np.array(cols[i], dtype=float) for i in (0, 1, 2)),
        np.array(cols[3], dtype=bool),
        np.array(cols[4], dtype=float),
        np.array(cols[5], dtype=np.int64),
        np.array(cols[6], dtype=bool),
    )


def loop_h(cal: Calibration) -> float:
    """The delay the loop's force has [s]: the loop's delay end to end (to the pose), the servo's lag (a lag
    tau counts as delay: 1 / (1 + tau s) and e^(-s tau) agree to first order, and the loop crosses at a low
    frequency, omega tau << 1), and the force's delay behind the pose where the press separates it."""
    return cal.loop_delay_s + cal.servo.lag_s + (cal.contact.ft_delay_s or 0.0)


def verdict(cal: Calibration, m: float, kcs: float, bcs: float, damper: str = "delayed") -> dict:
    """The stability of the identified loop for a scene's reduced mass m, stiffness kcs and damping bcs:
    the exact bound of m s^2 + (K + b s) e^(-sh) = 0 (damper "delayed", the paper's), or of
    m s^2 + b s + K e^(-sh) = 0 (damper "undelayed": the damper acts on the simulated velocity, the
    stiffness is the hardware's behind the robot), with h = loop_h (the run's own loop, end to end); the
    growth rate of the loop at kcs (its rightmost root)."""
    from dockhil.contact.stability import exact_bound, growth_rate

    h = loop_h(cal)
    bound = exact_bound(m, bcs, h, damper)
    k_max = None if bound.k_max is None or math.isinf(bound.k_max) else bound.k_max
    return {
        "m_kg": m,
        "kcs_N_per_m": kcs,
        "bcs_Ns_per_m": bcs,
        "damper": damper,
        "h_s": h,
        "kcs_max_N_per_m": k_max,
        "margin": None if k_max is None else k_max / kcs,
        "growth_rate_1_s": growth_rate(m, kcs, bcs, h, damper),
        "stable": bool(bound.k_max is not None and kcs < bound.k_max),
        "reason": bound.reason,
    }
