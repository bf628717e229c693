"""The delay of the loop a run had, read from its contact: the force measured (/ft/wrench) against the pose
commanded (/robot/command). Through the passive compliance the measured force is k (x - surface), x the
robot's pose, which is the command delayed by the robot, its link and the sensor's path: the one delay
the loop feeds back. A run in wall time on hardware and a run in sim time measured the same way have the
same loop where these delays agree, whatever each hop of the two takes; so a simulated run set to a
hardware run's delay compares their restitutions (bench/restitution_wall_vs_sim.py).

Fit: for each candidate delay d, the forces that stand clear of the sensor's noise band against the
commanded pose at t - d (interpolated between ticks), a line by least squares; the d of the smallest
residual, on a grid then refined. A contact lasts a period of about 2 pi sqrt(m / k); its force is
smooth, so the residual's minimum is clear to a fraction of a millisecond. No I/O but `from_bag`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

MAX_DELAY_S = 0.2  # s: the longest loop delay searched
GRID_S = 2.5e-4  # s: the coarse grid
CLEAR_N = 2.0  # N: a force counts where it stands this far out of the band (clear of the contact's edge)
MIN_SAMPLES = 50  # forces clear of the band needed for a fit


class NoContactError(ValueError):
    """The run has too few forces clear of the noise band to read its delay from."""


@dataclass(frozen=True)
class ContactDelay:
    """The loop's delay [s] from command to measured force, the compliance's gain [N/m] (the sign the
    sensor's axis gives it), the residual's RMS [N] and the number of forces fitted."""

    delay_s: float
    gain_N_per_m: float
    rms_N: float
    samples: int


def _cost(t_cmd: np.ndarray, x_cmd: np.ndarray, t_f: np.ndarray, f: np.ndarray, d: float) -> tuple[float, float]:
    x = np.interp(t_f - d, t_cmd, x_cmd)
    a = np.column_stack((x, np.ones_like(x)))
    coef, *_ = np.linalg.lstsq(a, f, rcond=None)
    r = a @ coef - f
    return float(r @ r), float(coef[0])


def fit(
    t_cmd: Sequence[float] | np.ndarray,
    x_cmd: Sequence[float] | np.ndarray,
    t_f: Sequence[float] | np.ndarray,
    f: Sequence[float] | np.ndarray,
    band: float = 0.0,
) -> ContactDelay:
    """The delay from the commanded poses (ticks t_cmd [s], x_cmd [m]) to the measured forces (t_f [s],
    f [N], tared) of one contact; `band` [N]: the sensor's noise band's half width (the forces within it,
    and CLEAR_N beyond, are left out: the contact's edge, where the compliance lets go)."""
    from scipy.optimize import minimize_scalar

    tc, xc, tf, ff = (np.asarray(v, dtype=float) for v in (t_cmd, x_cmd, t_f, f))
    order = np.argsort(tc, kind="stable")
    tc, xc = tc[order], xc[order]
    keep = (np.abs(ff) > band + CLEAR_N) & (tf - MAX_DELAY_S >= tc[0]) if len(tc) else np.zeros(len(ff), bool)
    if len(tc) < 2 or int(np.count_nonzero(keep)) < MIN_SAMPLES:
        raise NoContactError(
            f"{int(np.count_nonzero(keep))} forces stand {CLEAR_N:g} N out of the noise band after the first "
            f"command: at least {MIN_SAMPLES} are needed to read the loop's delay"
        )
    tf, ff = tf[keep], ff[keep]
    grid = np.arange(0.0, MAX_DELAY_S + 1e-12, GRID_S)
    costs = [_cost(tc, xc, tf, ff, d)[0] for d in grid]
    best = float(grid[int(np.argmin(costs))])
    lo, hi = max(0.0, best - GRID_S), min(MAX_DELAY_S, best + GRID_S)
    d = float(minimize_scalar(lambda v: _cost(tc, xc, tf, ff, v)[0], bounds=(lo, hi), method="bounded").x)
    cost, gain = _cost(tc, xc, tf, ff, d)
    return ContactDelay(d, gain, float(np.sqrt(cost / len(ff))), len(ff))


def from_bag(path: str, band: float = 0.0) -> ContactDelay:
    """The delay of the run recorded in the bag at `path` (its /robot/command and /ft/wrench)."""
    from dockhil.bags.reader import BagReader

    t_cmd: list[float] = []
    x_cmd: list[float] = []
    t_f: list[float] = []
    f: list[float] = []
    with BagReader(path) as bag:
        for topic, _t, msg in bag.decoded(["/robot/command", "/ft/wrench"]):
            if topic == "/robot/command":
                t_cmd.append(msg.header.stamp)
                x_cmd.append(msg.pose.position.x)
            else:
                t_f.append(msg.header.stamp)
                f.append(msg.wrench.force.x)
    return fit(t_cmd, x_cmd, t_f, f, band)
