"""The robot controller's own cycles in a recording (/robot/cycles): its clock on the graph's time, the
cycle that took each setpoint, the servo fitted on that clock, and the graph-to-device link."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dockhil.analysis.calibration.servo_fit import (
    MAX_DELAY_S,
    MAX_LAG_S,
    CalibrationError,
    Servo,
    akaike,
    covariance,
    fit_delay_lag,
    grid_then_refine,
    residual_variance,
    servo_jacobian,
)


@dataclass
class DeviceCycles:
    """The robot driver's exchanges with the controller (RobotCycles), as arrays in the order made: when the
    setpoint went out and when the pose came back [s, graph clock], the setpoint's and the pose's x [m],
    whether a setpoint was written, the device's cycle count of the pose, and whether that cycle had taken
    the exchange's setpoint."""

    sent: np.ndarray
    read: np.ndarray
    x_set: np.ndarray
    written: np.ndarray
    x_actual: np.ndarray
    cycle: np.ndarray
    taken: np.ndarray

    def select(self, keep: np.ndarray) -> DeviceCycles:
        return DeviceCycles(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))


@dataclass(frozen=True)
class Link:
    """The graph-to-device link [s]: from a command's tick to the device cycle that takes it (forward), and
    from the device cycle that measured a pose to the tick that publishes it (back): medians and spreads."""

    forward_s: float
    back_s: float
    forward_spread_s: float  # half the 5-95 % range
    back_spread_s: float
    samples: int
    # The device echoed the setpoint a cycle took (Modbus): the take is seen. Not (RSI: the answer follows the
    # pose), the take is placed by assumption at the next cycle, and where inside the controller the time is
    # spent (that cycle or the correction's arrival, the pose before or after the servo's step) the data do
    # not tell: the split of the loop into the robot's delay and the link is then not identified.
    take_seen: bool = True

    @property
    def total_s(self) -> float:
        return self.forward_s + self.back_s


def unwrap(count: np.ndarray) -> np.ndarray:
    """A device's cycle count made monotonic: it is 16 bits and wraps (Modbus: the controller's counter;
    RSI: IPOC // the cycle in ms, as the driver publishes it)."""
    steps = np.diff(count.astype(np.int64))
    steps[steps < 0] += 1 << 16
    return np.concatenate([[0], np.cumsum(steps)]) + int(count[0]) if len(count) else count.astype(np.int64)


# A pure delay that explains the poses within this factor of a delay-and-lag fit's residual energy (and
# moves the delay by half a cycle or more: where it moves it less, the split does not matter to it): the
# steps (ramps at the link's speed limit) and the chirp show a lag of a few cycles as as much more delay,
# and the split the free fit makes is then not the data's (a 1.3 ms lag at 1 kHz read as 3.0 ms, the delay
# as much short, where a pure delay left 1.6 times the residual energy; 5.4 ms and more left 12 times).
SEPARATION = 2.0

CLOCK_HALF_WINDOW = 100  # cycles either side of a knot of the device's clock: a local line through ~150 exchanges


def _line_at(x: np.ndarray, y: np.ndarray) -> float:
    """The value at x = 0 of a line through (x, y) by least squares, twice trimmed of points more than three
    robust standard deviations off (an exchange that a stall of the machine stretched)."""
    keep = np.ones(len(x), dtype=bool)
    for _ in range(3):
        if np.ptp(x[keep]) == 0:
            return float(np.median(y[keep]))
        a = np.column_stack([np.ones(keep.sum()), x[keep]])
        coef, *_ = np.linalg.lstsq(a, y[keep], rcond=None)
        r = y - (coef[0] + coef[1] * x)
        scale = 1.4826 * float(np.median(np.abs(r[keep]))) or 1e-9
        new = np.abs(r) <= 3.0 * scale
        if new.sum() < 3 or (new == keep).all():
            break
        keep = new
    return float(coef[0])


def device_clock(c: DeviceCycles):
    """(knots, times): the device's cycles on the graph's clock, linear between the knots. An exchange in
    which the device echoed the setpoint it took (`taken`) within a quick exchange brackets that cycle
    between the write and the read, so at their midpoint within half the exchange; without such exchanges
    (RSI: the pose comes first), the reads, which follow the cycle by the link's latency. A controller's
    cycles are regular, so a line through the cycles of the neighbouring ~200 (CLOCK_HALF_WINDOW either
    side of each knot, robust to stretched exchanges) times them within a small part of that scatter; the
    knots every half window follow a clock that drifts or a device that lost cycles. Monotonic."""
    n = unwrap(c.cycle)
    span = c.read - c.sent
    tight = c.taken & (span <= np.median(span[c.taken]) * 2.0) if c.taken.any() else c.taken
    if tight.sum() >= 3:
        cycle, t = n[tight], 0.5 * (c.sent[tight] + c.read[tight])
    else:
        cycle, t = n, c.read
    lo, hi = int(n.min()), int(n.max())
    knots = np.unique(np.concatenate([np.arange(lo, hi, CLOCK_HALF_WINDOW // 2), [hi]]))
    times = np.empty(len(knots))
    for j, k in enumerate(knots):
        half = CLOCK_HALF_WINDOW
        near = np.abs(cycle - k) <= half
        while near.sum() < 10 and half < hi - lo:
            half *= 2
            near = np.abs(cycle - k) <= half
        times[j] = _line_at((cycle[near] - k).astype(float), t[near])
    return knots, np.maximum.accumulate(times)


def _cycle_times(cycles: np.ndarray, knots: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Times of cycles on the device's clock, extended beyond its ends at the end segments' rates."""
    t = np.interp(cycles, knots, times)
    if len(knots) > 1:
        first = (times[1] - times[0]) / (knots[1] - knots[0])
        last = (times[-1] - times[-2]) / (knots[-1] - knots[-2])
        t = t + np.minimum(cycles - knots[0], 0) * first + np.maximum(cycles - knots[-1], 0) * last
    return t


def _taking(c: DeviceCycles, knots: np.ndarray, times: np.ndarray) -> np.ndarray:
    """The device cycle that took each written setpoint: one the device echoed, the one read back, or in an
    exchange stretched over several cycles the first after its write (by the clock, after the cycle the
    exchange before read back); one it did not echo, the next after the one read back (RSI's answer
    follows its pose)."""
    n = unwrap(c.cycle)
    after = np.maximum.accumulate(np.concatenate([[n[0] - 1], n[:-1]])) + 1
    by_clock = np.clip(np.ceil(np.interp(c.sent, times, knots)).astype(np.int64), after, n)
    span = c.read - c.sent
    first = np.where(span > 2.0 * np.median(span), by_clock, n)  # a quick exchange spans one cycle at most
    w = c.written
    return np.where(c.taken[w], first[w], n[w] + 1)


def device_timing(c: DeviceCycles):
    """(t_set, x_set, t_pose, x_pose): each setpoint at the device cycle that took it and each pose at the
    device cycle that measured it, on the graph's clock. A setpoint the device echoed in the same
    exchange was taken by the cycle read back; one it did not, by the next (the first after the send
    where the device tells nothing: RSI's answer follows its pose)."""
    cycles, times = device_clock(c)
    n = unwrap(c.cycle)
    pose_cycle, first = np.unique(n, return_index=True)
    t_pose = _cycle_times(pose_cycle, cycles, times)
    w = c.written
    t_set = _cycle_times(_taking(c, cycles, times), cycles, times)
    order = np.argsort(t_set, kind="stable")
    return t_set[order], c.x_set[w][order], t_pose, c.x_actual[first]


class _CycleServo:
    """The controller's servo on its own cycle of period T. The setpoint held at cycle j, u[j], is the one
    taken at the latest cycle up to j; it becomes the target D = (C + f) T later, between two cycles
    interpolated ((1 - f) u[k - C] + f u[k - C - 1]: the share f of the takes that a jittered cycle phase
    puts one cycle later); the pose follows the held target as a first-order lag over each cycle,
    x[k+1] = a x[k] + (1 - a) target[k] with a = exp(-T / tau) (order 2: two such poles)."""

    def __init__(self, t_take, x_take, t_cycles, pose_index, x_pose, period: float):
        i = np.searchsorted(t_take, t_cycles, side="right") - 1
        self.x0 = float(x_pose[0])
        self.held = np.where(i >= 0, x_take[np.clip(i, 0, None)], self.x0)
        self.t_cycles, self.pose_index, self.x_pose, self.period = t_cycles, pose_index, x_pose, period

    def response(self, delay: float, lag: float, order: int = 1) -> np.ndarray:
        from scipy.signal import lfilter

        y = np.interp(self.t_cycles - delay, self.t_cycles, self.held, left=self.x0) - self.x0
        a = math.exp(-self.period / lag) if lag > 0.0 else 0.0
        for _ in range(order):
            y = lfilter([0.0, 1.0 - a], [1.0, -a], y)
        return y[self.pose_index] + self.x0

    def residual(self, params, order: int = 1) -> np.ndarray:
        return self.response(params[0], params[1], order) - self.x_pose


def device_servo(c: DeviceCycles, max_delay: float = MAX_DELAY_S, max_lag: float = MAX_LAG_S) -> Servo:
    """Delay and first-order lag of the controller from its own cycles: each setpoint at the cycle that
    took it, each pose at the cycle that measured it, the model `_CycleServo`. The controller acts on
    whole cycles: a setpoint taken at t_m acts from the first cycle at or after t_m + d. So the fitted D is
    d rounded up to a cycle (D = C T), or, where the cycle's phase jitters, the mean of those roundings,
    d + T/2; the delay reported is D - T/2, the middle of the cycle that holds d, and its uncertainty adds
    that cycle's, T / sqrt 12, to the fit's."""

    knots, times = device_clock(c)
    n = unwrap(c.cycle)
    w = c.written
    if w.sum() < 10 or len(np.unique(n)) < 20:
        raise CalibrationError(
            f"{int(w.sum())} setpoints and {len(np.unique(n))} device cycles read in free space; the delay "
            f"and lag need a run of small steps and a chirp (at least 10 setpoints and 20 cycles)"
        )
    if np.ptp(c.x_set[w]) <= 0.0:
        raise CalibrationError(
            "the setpoints in free space never moved the robot: nothing to identify the delay and lag from"
        )
    period = float(np.median(np.diff(times) / np.diff(knots))) if len(knots) > 1 else 1e-3
    taking = _taking(c, knots, times)
    order = np.argsort(taking, kind="stable")
    pose_cycle, first = np.unique(n, return_index=True)
    model = _CycleServo(
        _cycle_times(taking[order], knots, times),
        c.x_set[w][order],
        _cycle_times(np.arange(pose_cycle[0], pose_cycle[-1] + 1), knots, times),
        pose_cycle - pose_cycle[0],
        c.x_actual[first],
        period,
    )
    # The total delay (a lag looks like more delay), the lag left out, on whole cycles; then delay and lag
    # together from a few splits of it.
    shifts = np.arange(0.0, max_delay, period)
    total = float(shifts[int(np.argmin([np.sum(model.residual((d, 0.0)) ** 2) for d in shifts]))])
    (whole, lag), residual, cov, aic = fit_delay_lag(model, total, max_delay, max_lag, period, 1e-3)
    (whole, lag), residual, cov = whole_cycles(model, whole, lag, residual, cov, period, max_lag)
    unseparated = 0.0
    if lag >= 0.5 * period:  # a smaller lag, folded in, would move the delay by less than half a cycle
        fused, r0, var0 = pure_delay(model, whole + lag, period, max_delay)
        # not separated where the lag-free delay moves by half a cycle or more (the split matters to the delay)
        # and explains the poses nearly as well
        if fused - whole >= 0.5 * period and float(r0 @ r0) <= SEPARATION * float(residual @ residual):
            unseparated, (whole, lag), residual, cov = lag, (fused, 0.0), r0, np.diag([var0, lag**2])
    npose = len(residual)
    sigmas = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return Servo(
        max(whole - 0.5 * period, 0.0),
        lag,
        math.hypot(float(sigmas[0]), period / math.sqrt(12.0)),
        float(sigmas[1]),
        float(np.sqrt(np.mean(residual**2))),
        npose,
        min(aic, key=aic.get),
        aic,
        period,
        unseparated,
    )


def pure_delay(model, near: float, period: float, max_delay: float) -> tuple[float, np.ndarray, float]:
    """(delay, residual, its variance) of the poses as the setpoints delayed alone, no lag, the delay within
    three cycles of `near` (a lag looks like as much more delay)."""
    d = grid_then_refine(
        lambda d: float(np.sum(model.residual((d, 0.0)) ** 2)),
        max(near - 3.0 * period, 0.0),
        min(near + 3.0 * period, max_delay),
        0.1 * period,  # a tenth of a cycle first: the cost has local minima between the cycles
        1e-6,
    )
    r = model.residual((d, 0.0))
    return d, r, float(covariance(servo_jacobian(model, d, 0.0)[:, :1], r, 1)[0, 0])


def whole_cycles(model, delay: float, lag: float, residual: np.ndarray, cov: np.ndarray, period: float, max_lag: float):
    """((delay, lag), residual, covariance): the free fit, or the delay at the whole cycle on either side of it
    with the lag fitted alone, where that explains the poses as well for one parameter less (the smaller AIC).
    A controller acts on whole cycles; a delay between two cycles blends them as a lag of under a cycle would,
    so where the lag is small the free fit may trade one for the other (0.01 ms of lag read as 1.5 ms, the
    delay a cycle short). At a whole cycle the delay is not fitted (no variance of its own: the caller adds
    the cycle's resolution), and the lag's variance is that of its fit alone."""
    from scipy.optimize import minimize_scalar

    best = (akaike(residual, 2), (delay, lag), residual, cov)
    for cycles in {math.floor(delay / period + 1e-9), math.ceil(delay / period - 1e-9)}:
        d = cycles * period
        if d < 0.0:
            continue
        fit = minimize_scalar(
            lambda tau, d=d: float(np.sum(model.residual((d, tau)) ** 2)),
            bounds=(0.0, max_lag),
            method="bounded",
            options={"xatol": 1e-6},
        )
        tau = float(fit.x)
        r = model.residual((d, tau))
        aic = akaike(r, 1)
        if aic < best[0]:
            best = (aic, (d, tau), r, np.diag([0.0, _lag_above(model, d, tau, r, max_lag) ** 2]))
    return best[1:]


def _lag_above(model, delay: float, lag: float, residual: np.ndarray, max_lag: float) -> float:
    """One sigma of the lag fitted alone, from its profile: how much longer a lag fits the poses within one
    residual variance (linearised, a lag far under the cycle, which the poses barely see, would read
    +- 90 ms)."""
    from scipy.optimize import brentq

    def excess(tau: float) -> float:
        return float(np.sum(model.residual((delay, tau)) ** 2)) - target

    target = float(residual @ residual) + residual_variance(residual, 1)
    if excess(max_lag) <= 0.0:
        return math.inf
    return brentq(excess, lag, max_lag, xtol=1e-7) - lag


def _spread(values: np.ndarray) -> float:
    lo, hi = np.percentile(values, [5.0, 95.0])
    return float(hi - lo) / 2.0


def link(c: DeviceCycles, t_cmd, t_state) -> Link:
    """The link from the commands' ticks (t_cmd) to the device and back to the states' ticks (t_state)."""
    cycles, times = device_clock(c)
    t_set, _x, _tp, _xp = device_timing(c)
    sent = np.sort(c.sent[c.written])
    # forward: the latest command before each send, to the device cycle that took the setpoint
    i = np.searchsorted(t_cmd, sent, side="right") - 1
    forward = (t_set - t_cmd[np.clip(i, 0, None)])[i >= 0]
    # back: each state published, from the device cycle of the latest pose read before its tick
    order = np.argsort(c.read, kind="stable")
    j = np.searchsorted(c.read[order], t_state, side="right") - 1
    measured = np.interp(unwrap(c.cycle)[order], cycles, times)
    back = (t_state - measured[np.clip(j, 0, None)])[j >= 0]
    if len(forward) < 10 or len(back) < 10:
        raise CalibrationError(
            f"the device cycles match {len(forward)} commands and {len(back)} poses published; the link needs 10 each"
        )
    return Link(
        float(np.median(forward)),
        float(np.median(back)),
        _spread(forward),
        _spread(back),
        min(len(forward), len(back)),
        bool(c.taken[c.written].any()),
    )


# -- the whole identification --------------------------------------------------------------------------------------
