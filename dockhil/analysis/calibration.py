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
from dataclasses import dataclass, field

import numpy as np

from dockhil.errors import DockhilError

GRID_S = 1e-4  # simulation step of the servo model [s]: a tenth of the device cycle
MAX_DELAY_S = 0.5
MAX_LAG_S = 0.5


class CalibrationError(DockhilError):
    """The data do not allow the identification; the message says what was missing."""


@dataclass(frozen=True)
class Rest:
    """Sensor at rest: bias and noise per axis (force [N], torque [N m]) and their uncertainties."""

    bias_N: tuple[float, float, float]
    noise_N: tuple[float, float, float]
    bias_Nm: tuple[float, float, float]
    noise_Nm: tuple[float, float, float]
    bias_sigma_N: tuple[float, float, float]
    noise_sigma_N: tuple[float, float, float]
    samples: int


@dataclass(frozen=True)
class Servo:
    """Command-to-motion model: delay [s], first-order lag [s], their sigmas, and the fit."""

    delay_s: float
    lag_s: float
    delay_sigma_s: float
    lag_sigma_s: float
    rms_m: float
    samples: int
    lag_model: str  # "first-order" or "second-order": the smaller AIC
    aic: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Contact:
    """Passive compliance: stiffness [N/m], damping [N s/m], surface position [m], F/T delay [s] or None."""

    k_N_per_m: float
    b_Ns_per_m: float
    surface_m: float
    k_sigma: float
    b_sigma: float
    surface_sigma_m: float
    ft_delay_s: float | None
    ft_delay_sigma_s: float | None
    rms_N: float
    samples: int
    peak_force_N: float


def _inflation(residual: np.ndarray) -> float:
    """Variance inflation for correlated residuals: (1 + rho) / (1 - rho), rho the lag-1 autocorrelation."""
    r = residual - residual.mean()
    denom = float(r @ r)
    if len(r) < 3 or denom == 0.0:
        return 1.0
    rho = float(r[1:] @ r[:-1]) / denom
    rho = min(max(rho, 0.0), 0.995)
    return (1.0 + rho) / (1.0 - rho)


def _covariance(jac: np.ndarray, residual: np.ndarray, n_params: int) -> np.ndarray:
    n = len(residual)
    dof = max(n - n_params, 1)
    s2 = float(residual @ residual) / dof * _inflation(residual)
    jtj = jac.T @ jac
    try:
        return np.linalg.inv(jtj) * s2
    except np.linalg.LinAlgError:
        return np.full((n_params, n_params), np.inf)


# -- at rest ---------------------------------------------------------------------------------------------------


def rest(force: np.ndarray, torque: np.ndarray | None = None) -> Rest:
    """Bias (mean) and noise (standard deviation) per axis of samples taken at rest; shape (n, 3)."""
    f = np.asarray(force, dtype=float).reshape(-1, 3)
    n = len(f)
    if n < 20:
        raise CalibrationError(f"only {n} F/T samples at rest; the bias and noise need at least 20")
    t = np.zeros_like(f) if torque is None else np.asarray(torque, dtype=float).reshape(-1, 3)
    noise = f.std(axis=0, ddof=1)
    infl = np.array([_inflation(f[:, i]) for i in range(3)])
    bias_sigma = noise * np.sqrt(infl / n)
    noise_sigma = noise / math.sqrt(2.0 * (n - 1)) * np.sqrt(infl)
    return Rest(
        tuple(map(float, f.mean(axis=0))),
        tuple(map(float, noise)),
        tuple(map(float, t.mean(axis=0))),
        tuple(map(float, t.std(axis=0, ddof=1))),
        tuple(map(float, bias_sigma)),
        tuple(map(float, noise_sigma)),
        n,
    )


# -- the servo: delay and lag ------------------------------------------------------------------------------------


class _ServoModel:
    """The delayed, lagged response to a zero-order-held command, simulated on a fine uniform grid."""

    def __init__(self, t_cmd, x_cmd, t_state, x_state, grid: float = GRID_S):
        self.t_cmd = np.asarray(t_cmd, dtype=float)
        self.x_cmd = np.asarray(x_cmd, dtype=float)
        self.t_state = np.asarray(t_state, dtype=float)
        self.x_state = np.asarray(x_state, dtype=float)
        self.grid = grid
        self.t = np.arange(self.t_cmd[0], self.t_state[-1] + grid, grid)
        self.x0 = float(self.x_state[0])
        self.keep = self.t_state >= self.t_cmd[0]
        idx = np.searchsorted(self.t_cmd, self.t, side="right") - 1
        self.u = self.x_cmd[np.clip(idx, 0, None)]  # the held command on the grid

    def response(self, delay: float, lag: float, order: int = 1) -> np.ndarray:
        from scipy.signal import lfilter

        # Shifted by interpolation on the grid, so the response is continuous in the delay (a fit needs that).
        y = np.interp(self.t - delay, self.t, self.u, left=self.x0)
        if lag > 0.0:
            a = math.exp(-self.grid / lag)
            for _ in range(order):
                # y[n] = a y[n-1] + (1 - a) u[n-1]: the exact step of a first-order lag over a held input
                y, _ = lfilter([0.0, 1.0 - a], [1.0, -a], y - self.x0, zi=[0.0])
                y = y + self.x0
        return np.interp(self.t_state[self.keep], self.t, y)

    def residual(self, params, order: int = 1) -> np.ndarray:
        delay, lag = params
        return self.response(delay, lag, order) - self.x_state[self.keep]


def servo(t_cmd, x_cmd, t_state, x_state, max_delay: float = MAX_DELAY_S, max_lag: float = MAX_LAG_S) -> Servo:
    """Delay and first-order lag from a command stream (times [s], positions [m]) and the poses read back."""

    t_cmd, x_cmd, t_state, x_state = (np.asarray(a, dtype=float) for a in (t_cmd, x_cmd, t_state, x_state))
    if len(t_cmd) < 10 or len(t_state) < 20:
        raise CalibrationError(
            f"{len(t_cmd)} commands and {len(t_state)} poses in free space; the delay and lag "
            f"need a run of small steps and a chirp (at least 10 commands and 20 poses)"
        )
    travel = float(np.ptp(x_cmd))
    if travel <= 0.0:
        raise CalibrationError(
            "the commands in free space never moved the robot: nothing to identify the delay and lag from"
        )
    model = _ServoModel(t_cmd, x_cmd, t_state, x_state)
    n = int(model.keep.sum())
    if n < 20:
        raise CalibrationError(
            f"only {n} poses read back after the first command in free space; the delay and lag need at least 20"
        )
    # Coarse: the total delay (a lag looks like more delay) from the held command shifted on a 1 ms grid;
    # then delay and lag together, from a few splits of that total.
    ts, xs = model.t_state[model.keep], model.x_state[model.keep]
    costs = []
    delays = np.arange(0.0, max_delay, 0.001)
    for d in delays:
        idx = np.searchsorted(t_cmd, ts - d, side="right") - 1
        r = np.where(idx >= 0, x_cmd[np.clip(idx, 0, None)], model.x0) - xs
        costs.append(float(r @ r))
    total = float(delays[int(np.argmin(costs))])
    (delay, lag), residual, cov, aic = _fit_delay_lag(model, total, max_delay, max_lag, 0.01, 1e-2)
    sigmas = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return Servo(
        delay,
        lag,
        float(sigmas[0]),
        float(sigmas[1]),
        float(np.sqrt(np.mean(residual**2))),
        n,
        min(aic, key=aic.get),
        aic,
    )


def _fit_delay_lag(model, total: float, max_delay: float, max_lag: float, scale: float, diff_step: float):
    """((delay, lag), residual, covariance, AIC per lag model) of `model` (its residual((delay, lag), order)),
    by nonlinear least squares from a few splits of the total delay `total` between delay and lag; a
    second-order lag (two equal poles) fitted too, for the AIC."""
    from scipy.optimize import least_squares

    fits = {}
    for order in (1, 2):
        best = None
        for share in (0.0, 0.3, 0.6):
            lag = min(share * total, max_lag) / order
            fit = least_squares(
                model.residual,
                x0=[max(total - order * lag, 0.0), lag],
                args=(order,),
                bounds=([0.0, 0.0], [max_delay, max_lag]),
                diff_step=[diff_step, diff_step],
                x_scale=[scale, scale],
            )
            if best is None or fit.cost < best.cost:
                best = fit
        fits[order] = best
    first = fits[1]
    if not first.success:
        raise CalibrationError(f"the delay and lag fit did not converge ({first.message})")
    n = len(first.fun)
    aic = {
        name: n * math.log(max(float(fits[o].fun @ fits[o].fun), 1e-300) / n) + 4.0
        for o, name in ((1, "first-order"), (2, "second-order"))
    }
    x = tuple(float(v) for v in first.x)
    return x, first.fun, _covariance(_servo_jacobian(model, *x), first.fun, 2), aic


def _servo_jacobian(model: _ServoModel | _CycleServo, delay: float, lag: float) -> np.ndarray:
    """d residual / d (delay, lag) by differences of 0.2 ms, one-sided where a bound (zero) is near."""
    h = 2e-4
    cols = []
    for j, value in enumerate((delay, lag)):
        lo, hi = max(value - h, 0.0), value + h
        a, b = [delay, lag], [delay, lag]
        a[j], b[j] = lo, hi
        cols.append((model.residual(b) - model.residual(a)) / (hi - lo))
    return np.column_stack(cols)


# -- the passive compliance --------------------------------------------------------------------------------------


def _contact_lsq(t_f, f, t_x, x, v, ft_delay: float):
    """(k, b, c) of f = k x + b v + c, its residual and design matrix; b is 0 (and its column zero) where
    the velocity read back never changed (the damping is then not in the data)."""
    xi = np.interp(t_f - ft_delay, t_x, x)
    vi = np.interp(t_f - ft_delay, t_x, v)
    moving = np.ptp(vi) > 0.0
    a = np.column_stack([xi, vi, np.ones_like(xi)] if moving else [xi, np.ones_like(xi)])
    coef, *_ = np.linalg.lstsq(a, f, rcond=None)
    residual = a @ coef - f
    if not moving:
        coef, a = np.array([coef[0], 0.0, coef[1]]), np.column_stack([xi, vi, np.ones_like(xi)])
    return coef, residual, a


def contact(t_f, force, t_x, x, v, noise: float, max_ft_delay: float = 0.03) -> Contact:
    """k, b and the surface from a press: force pushing the probe back [N] (bias removed) at times t_f, and
    the pose x [m] and velocity v [m/s] read back at times t_x; `noise` the force noise [N] at rest."""
    t_f, f, t_x, x, v = (np.asarray(a, dtype=float) for a in (t_f, force, t_x, x, v))
    if len(t_f) == 0 or len(t_x) < 2:
        raise CalibrationError("no press into the passive compliance was recorded: k needs one")
    peak = float(f.max())
    threshold = max(5.0 * noise, 0.05 * peak, 0.05)
    inside = (f > threshold) & (t_f - max_ft_delay >= t_x[0]) & (t_f <= t_x[-1])
    if inside.sum() < 20 or peak < 4.0 * threshold:
        raise CalibrationError(
            f"the press met too little force ({peak:.2f} N at most against a noise band of "
            f"{threshold:.2f} N): k needs a press well above the noise"
        )
    tf, ff = t_f[inside], f[inside]
    delays = np.arange(0.0, max_ft_delay + 1e-12, 0.0005)
    costs = []
    for d in delays:
        _, residual, _ = _contact_lsq(tf, ff, t_x, x, v, float(d))
        costs.append(float(residual @ residual))
    costs = np.array(costs)
    i = int(np.argmin(costs))
    ft_delay: float | None = float(delays[i])
    ft_sigma: float | None = None
    n = len(ff)
    s2 = costs[i] / max(n - 3, 1)
    if 0 < i < len(delays) - 1:
        curvature = (costs[i - 1] - 2 * costs[i] + costs[i + 1]) / (delays[1] - delays[0]) ** 2
        if curvature > 0:
            _, residual, _ = _contact_lsq(tf, ff, t_x, x, v, ft_delay)
            ft_sigma = math.sqrt(2.0 * s2 * _inflation(residual) / curvature)
    if ft_sigma is None or ft_sigma > ft_delay:
        ft_delay, ft_sigma = None, None  # no clear minimum: the force's delay is not in these data
    coef, residual, a = _contact_lsq(tf, ff, t_x, x, v, ft_delay or 0.0)
    k, b, c = (float(cv) for cv in coef)
    if not k > 0.0:
        raise CalibrationError(
            f"the press gives a stiffness of {k:.4g} N/m: the force did not rise with the penetration"
        )
    if np.any(a[:, 1]):
        cov = _covariance(a, residual, 3)
    else:  # no velocity, no damping in the data: b stays 0, its uncertainty unknown
        sub = _covariance(a[:, [0, 2]], residual, 2)
        cov = np.array([[sub[0, 0], 0.0, sub[0, 1]], [0.0, math.inf, 0.0], [sub[1, 0], 0.0, sub[1, 1]]])
    sk, sb = (math.sqrt(max(cov[j, j], 0.0)) for j in (0, 1))
    surface = -c / k
    # s = -c / k: first-order propagation with the covariance of k and c
    kc = cov[np.ix_([0, 2], [0, 2])]
    grad = np.array([c / k**2, -1.0 / k])
    ss = math.sqrt(max(float(grad @ kc @ grad), 0.0))
    return Contact(k, b, surface, sk, sb, ss, ft_delay, ft_sigma, float(np.sqrt(np.mean(residual**2))), n, peak)


# -- timing at the device ---------------------------------------------------------------------------------------------


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

    @property
    def total_s(self) -> float:
        return self.forward_s + self.back_s


def _unwrap(count: np.ndarray) -> np.ndarray:
    """A device's cycle count made monotonic: a 16-bit counter (Modbus) wraps; IPOC does not."""
    steps = np.diff(count.astype(np.int64))
    steps[steps < 0] += 1 << 16
    return np.concatenate([[0], np.cumsum(steps)]) + int(count[0]) if len(count) else count.astype(np.int64)


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
    n = _unwrap(c.cycle)
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
    n = _unwrap(c.cycle)
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
    n = _unwrap(c.cycle)
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
    n = _unwrap(c.cycle)
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
    (whole, lag), residual, cov, aic = _fit_delay_lag(model, total, max_delay, max_lag, period, 1e-3)
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
    )


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
    measured = np.interp(_unwrap(c.cycle)[order], cycles, times)
    back = (t_state - measured[np.clip(j, 0, None)])[j >= 0]
    if len(forward) < 10 or len(back) < 10:
        raise CalibrationError(
            f"the device cycles match {len(forward)} commands and {len(back)} poses published; the link needs 10 each"
        )
    return Link(
        float(np.median(forward)), float(np.median(back)), _spread(forward), _spread(back), min(len(forward), len(back))
    )


# -- the whole identification --------------------------------------------------------------------------------------


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


NO_CYCLES = (
    "no device cycles (/robot/cycles) in the recording: the delay is timed on the graph's ticks, so it is "
    "the loop's, the link included (a recording from before the drivers published them)"
)


@dataclass(frozen=True)
class Calibration:
    rest: Rest
    servo: Servo
    contact: Contact
    link: Link | None = None  # None: timed on the graph's ticks (no device cycles), the link in servo's delay

    @property
    def loop_delay_s(self) -> float:
        """The loop's delay: the robot's at the device plus the link to it and back."""
        return self.servo.delay_s + (self.link.total_s if self.link is not None else 0.0)

    def as_dict(self) -> dict:
        r, s, c, ln = self.rest, self.servo, self.contact, self.link
        return {
            "delay_s": s.delay_s,
            "loop_delay_s": self.loop_delay_s,
            "link_s": None if ln is None else ln.total_s,
            "timing": "device cycles" if ln is not None else NO_CYCLES,
            "lag_s": s.lag_s,
            "k_N_per_m": c.k_N_per_m,
            "b_Ns_per_m": c.b_Ns_per_m,
            "bias_N": list(r.bias_N),
            "noise_N": list(r.noise_N),
            "bias_Nm": list(r.bias_Nm),
            "noise_Nm": list(r.noise_Nm),
            "ft_delay_s": c.ft_delay_s,
            "surface_m": c.surface_m,
            "uncertainty": {
                "delay_s": s.delay_sigma_s,
                "link_s": None if ln is None else math.hypot(ln.forward_spread_s, ln.back_spread_s),
                "lag_s": s.lag_sigma_s,
                "k_N_per_m": c.k_sigma,
                "b_Ns_per_m": c.b_sigma,
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
    press = rec.window("approach", "press", "hold", "release")
    ft, st = _between(rec.t_ft, press), _between(rec.t_state, press)
    # The force on the probe pushes it back (-x); the bias is taken off.
    pushing = -(rec.force[ft, 0] - r.bias_N[0])
    c = contact(rec.t_ft[ft], pushing, rec.t_state[st], rec.x_state[st], rec.v_state[st], r.noise_N[0])
    return Calibration(r, s, c, ln)


def check(cal: Calibration) -> None:
    """CalibrationError when an estimate the loop depends on is no measurement: its uncertainty is larger
    than its value (or not finite)."""
    d = cal.as_dict()
    for key, what in (("delay_s", "delay"), ("k_N_per_m", "stiffness k")):
        value, sigma = d[key], d["uncertainty"][key]
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


def verdict(cal: Calibration, m: float, kcs: float, bcs: float) -> dict:
    """The stability of the identified loop for a scene's reduced mass m, kcs and bcs: the exact bound of
    m s^2 + (K + b s) e^(-sh) = 0 with h = the loop's delay (the robot's and the link's) + lag (a lag tau
    counts as delay: 1 / (1 + tau s) and e^(-s tau) agree to first order, and the crossing frequency is
    low, omega tau << 1)."""
    from dockhil.contact.stability import exact_bound

    h = cal.loop_delay_s + cal.servo.lag_s
    bound = exact_bound(m, bcs, h)
    k_max = bound.k_max
    stable = k_max is not None and kcs < k_max
    return {
        "m_kg": m,
        "kcs_N_per_m": kcs,
        "bcs_Ns_per_m": bcs,
        "h_s": h,
        "kcs_max_N_per_m": None if k_max is None or math.isinf(k_max) else k_max,
        "margin": None if k_max is None or math.isinf(k_max) else k_max / kcs,
        "stable": bool(stable),
        "reason": bound.reason,
    }
