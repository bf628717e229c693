"""The servo and contact fits of `dockhil calibrate` on sampled series: the models, nonlinear least
squares, and one-sigma uncertainties inflated for correlated residuals (docs/calibration.md)."""

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
    # The device's cycle where the delay was read on whole cycles (delay_s is the middle of the cycle that
    # holds it): a robot that acts on whole cycles delays by up to half of it more. None: read on the ticks.
    cycle_s: float | None = None
    # The lag a fit of delay and lag read where a pure delay explains the poses nearly as well: the data do
    # not separate them, lag_s is 0 and delay_s holds it (the robot's own delay may be up to that less).
    unseparated_lag_s: float = 0.0


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


def inflation(residual: np.ndarray) -> float:
    """Variance inflation for correlated residuals: (1 + rho) / (1 - rho), rho the lag-1 autocorrelation."""
    r = residual - residual.mean()
    denom = float(r @ r)
    if len(r) < 3 or denom == 0.0:
        return 1.0
    rho = float(r[1:] @ r[:-1]) / denom
    rho = min(max(rho, 0.0), 0.995)
    return (1.0 + rho) / (1.0 - rho)


def residual_variance(residual: np.ndarray, n_params: int) -> float:
    """The residuals' variance for a fit of `n_params` parameters, inflated for their correlation."""
    return float(residual @ residual) / max(len(residual) - n_params, 1) * inflation(residual)


def covariance(jac: np.ndarray, residual: np.ndarray, n_params: int) -> np.ndarray:
    s2 = residual_variance(residual, n_params)
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
    infl = np.array([inflation(f[:, i]) for i in range(3)])
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


class TickServoModel:
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
    model = TickServoModel(t_cmd, x_cmd, t_state, x_state)
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
    (delay, lag), residual, cov, aic = fit_delay_lag(model, total, max_delay, max_lag, 0.01, 1e-2)
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


def fit_delay_lag(model, total: float, max_delay: float, max_lag: float, scale: float, diff_step: float):
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
    aic = {name: akaike(fits[o].fun, 2) for o, name in ((1, "first-order"), (2, "second-order"))}
    x = tuple(float(v) for v in first.x)
    return x, first.fun, covariance(servo_jacobian(model, *x), first.fun, 2), aic


def grid_then_refine(cost, lo: float, hi: float, step: float, xatol: float) -> float:
    """The argument in [lo, hi] that minimises `cost`: on a grid of `step` first (the delay's cost has local
    minima closer together than the search: a chirp's period, the cycles), then refined within a step of
    the grid's best."""
    from scipy.optimize import minimize_scalar

    grid = np.arange(lo, hi + 1e-12, step)
    best = float(grid[int(np.argmin([cost(d) for d in grid]))])
    fit = minimize_scalar(
        cost, bounds=(max(lo, best - step), min(hi, best + step)), method="bounded", options={"xatol": xatol}
    )
    return float(fit.x)


def akaike(residual: np.ndarray, n_params: int) -> float:
    """Akaike's information criterion of a least-squares fit with `n_params` parameters (Gaussian residuals)."""
    n = len(residual)
    return n * math.log(max(float(residual @ residual), 1e-300) / n) + 2.0 * n_params


def servo_jacobian(model, delay: float, lag: float) -> np.ndarray:
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
            ft_sigma = math.sqrt(2.0 * s2 * inflation(residual) / curvature)
    if ft_sigma is None or ft_sigma > ft_delay:
        ft_delay, ft_sigma = None, None  # no clear minimum: the force's delay is not in these data
    coef, residual, a = _contact_lsq(tf, ff, t_x, x, v, ft_delay or 0.0)
    k, b, c = (float(cv) for cv in coef)
    if not k > 0.0:
        raise CalibrationError(
            f"the press gives a stiffness of {k:.4g} N/m: the force did not rise with the penetration"
        )
    if np.any(a[:, 1]):
        cov = covariance(a, residual, 3)
    else:  # no velocity, no damping in the data: b stays 0, its uncertainty unknown
        sub = covariance(a[:, [0, 2]], residual, 2)
        cov = np.array([[sub[0, 0], 0.0, sub[0, 1]], [0.0, math.inf, 0.0], [sub[1, 0], 0.0, sub[1, 1]]])
    sk, sb = (math.sqrt(max(cov[j, j], 0.0)) for j in (0, 1))
    surface = -c / k
    # s = -c / k: first-order propagation with the covariance of k and c
    kc = cov[np.ix_([0, 2], [0, 2])]
    grad = np.array([c / k**2, -1.0 / k])
    ss = math.sqrt(max(float(grad @ kc @ grad), 0.0))
    return Contact(k, b, surface, sk, sb, ss, ft_delay, ft_sigma, float(np.sqrt(np.mean(residual**2))), n, peak)


# -- timing at the device ---------------------------------------------------------------------------------------------
