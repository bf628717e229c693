"""The loop's delay end to end: from a command's tick on /robot/command (it leaves the graph) to the tick of
the /robot/state that answers it (the pose comes back into the graph), from the run itself.

No assumption about where inside the controller its cycles are spent (which cycle takes a correction,
whether a pose is read before or after the servo's step): the poses published are fitted against the
commands published, held from their ticks, delayed and through the servo's lag (servo_fit's tick model),
over windows of the steps and the chirp. A busy machine stretches the loop for a while, and the loop a run
has is the loop it runs: the delay taken is a high percentile (PERCENTILE) of the windows', not the typical
one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dockhil.analysis.calibration.servo_fit import (
    MAX_DELAY_S,
    CalibrationError,
    TickServoModel,
    grid_then_refine,
    servo,
)

PERCENTILE = 95.0  # of the windows' delays: the loop's delay
WINDOW_S = 0.5  # s: a window, about the period of a contact's oscillation (the loop's delay counts over one)
MIN_TRAVEL_M = 2e-4  # a window whose poses move less tells no delay


@dataclass(frozen=True)
class EndToEnd:
    """The loop's delay [s] at PERCENTILE of the windows', the median window's, the whole run's (one fit),
    the lag held while fitting them, the windows' spread (half their 5-95 % range) and their number."""

    delay_s: float
    typical_s: float
    whole_s: float
    lag_s: float
    spread_s: float
    windows: int
    percentile: float = PERCENTILE


def _fit_delay(model: TickServoModel, lag: float, mask: np.ndarray, lo: float, hi: float) -> float:
    target = model.x_state[model.keep][mask]

    def cost(d: float) -> float:
        r = model.response(d, lag)[mask] - target
        return float(r @ r)

    return grid_then_refine(cost, lo, hi, 5e-4, 1e-5)  # coarse on 0.5 ms: minima a chirp's period apart


def end_to_end(t_cmd, x_cmd, t_state, x_state, lag: float | None = None) -> EndToEnd:
    """The loop's delay from the commands published (ticks t_cmd [s], x_cmd [m]) to the poses published
    (t_state, x_state) in free space. `lag`: the servo's, where identified at the device (the delay is then
    fitted alone, so that delay + lag is the loop's); None: fitted here with the delay."""
    t_cmd, x_cmd, t_state, x_state = (np.asarray(a, dtype=float) for a in (t_cmd, x_cmd, t_state, x_state))
    if lag is None:
        lag = servo(t_cmd, x_cmd, t_state, x_state).lag_s
    model = TickServoModel(t_cmd, x_cmd, t_state, x_state)
    ts = model.t_state[model.keep]
    if len(ts) < 20:
        raise CalibrationError(f"only {len(ts)} poses published in free space; the loop's delay needs at least 20")
    # The total (a lag looks like more delay) from the held command shifted on a 1 ms grid, cheaply; the
    # delay behind the lag then lies within a few lags under it.
    xs = model.x_state[model.keep]
    shifts = np.arange(0.0, MAX_DELAY_S, 0.001)
    costs = []
    for d in shifts:
        i = np.searchsorted(t_cmd, ts - d, side="right") - 1
        r = np.where(i >= 0, x_cmd[np.clip(i, 0, None)], model.x0) - xs
        costs.append(float(r @ r))
    total = float(shifts[int(np.argmin(costs))])
    everything = np.ones(len(ts), dtype=bool)
    whole = _fit_delay(model, lag, everything, max(total - 2.0 * lag - 0.005, 0.0), total + 0.005)
    lo, hi = max(whole - 0.01, 0.0), whole + 0.02  # a window's delay: -10 to +20 ms of the whole run's
    moved = model.response(whole, lag)
    delays = []
    for start in np.arange(ts[0], ts[-1], WINDOW_S):
        mask = (ts >= start) & (ts < start + WINDOW_S)
        if mask.sum() < 20 or np.ptp(moved[mask]) < MIN_TRAVEL_M:
            continue
        delays.append(_fit_delay(model, lag, mask, lo, hi))
    if len(delays) < 3:
        delays = [whole]
    d = np.array(delays)
    p5, p95 = np.percentile(d, [5.0, 95.0])
    return EndToEnd(
        float(np.percentile(d, PERCENTILE)),
        float(np.median(d)),
        whole,
        float(lag),
        float(p95 - p5) / 2.0,
        len(delays),
    )
