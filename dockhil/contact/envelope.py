"""The growth rate of a measured oscillation: a least-squares line through the log of its envelope's
peaks, accumulated tick by tick in O(1) memory (`EnvelopeFit`, fed by the run summary) or over
arrays (`growth_rate`). The predicted rate of a loop is `stability.growth_rate` (the delay
equation's rightmost root) and `sampled.sampled_growth_rate` (the sampled loop's)."""

from __future__ import annotations

import math

import numpy as np


class EnvelopeFit:
    """Least-squares line through log |peaks| of p - about, accumulated as sums (O(1) memory)."""

    def __init__(self, about: float):
        self.about = about
        self.a1: float | None = None  # |e| of the two previous ticks
        self.a2: float | None = None
        self.t1: float | None = None
        self.sums = np.zeros(5)  # n, sum t, sum t^2, sum y, sum t y

    def add(self, t: float, p: float) -> None:
        a = abs(p - self.about)
        a1, a2, t1 = self.a1, self.a2, self.t1  # a1 and t1 are set once a2 is
        if a2 is not None and a1 is not None and t1 is not None and a1 > a2 and a1 >= a and a1 > 0.0:
            y = math.log(a1)
            self.sums += (1.0, t1, t1 * t1, y, t1 * y)
        self.a2, self.a1, self.t1 = a1, a, t

    def rate(self) -> float:
        n, st, stt, sy, sty = self.sums
        if n < 4:
            raise ValueError("fewer than 4 peaks: run longer to measure a growth rate")
        # Centred sums keep the slope accurate when t is large.
        return float((sty - st * sy / n) / (stt - st * st / n))


def growth_rate(t: np.ndarray, y: np.ndarray, about: float | None = None) -> float:
    """Exponential growth rate [1/s] of an oscillation's envelope: a least-squares line through
    log |peaks| of y - about (positive grows, negative settles). `about` is the equilibrium;
    give it where it is known: the median of a growing or decaying oscillation is not its
    centre, and fitting about it biases the rate (by 8 to 9 % on Figs. 11-12 over 20 s)."""
    y = np.asarray(y, float)
    fit = EnvelopeFit(float(np.median(y)) if about is None else float(about))
    for ti, yi in zip(np.asarray(t, float).tolist(), y.tolist()):
        fit.add(ti, yi)
    return fit.rate()
