"""The distribution of a duration (a tick's lateness, an input's age, an answer's latency) in fixed
memory, for its percentiles at the end of a run.

A loop that kept every value grew its arrays by reallocation for as long as it ran (480 kB a minute
per figure at 1 kHz); each growth copied the array into fresh pages while the thread held the
interpreter, and a first touch of a page costs ~9 us on a virtual machine (milliseconds at worst):
the growth of a node's figures stalled the device thread beside it. Here every bin is allocated and
touched before the loop, and a value only increments one.

Bins are log-linear: 0.1 us wide up to 204.8 us, then 1024 to each doubling (a bin is within 0.1 % of
its values) up to ~30 h; larger values, infinities and NaN count in the last bin.
"""

from __future__ import annotations

import math
from array import array

UNIT = 1e-7  # s: the finest bin
EXACT = 2048  # bins of one unit below this many units
PER_OCTAVE = 1024
TOP = (1 << 40) - 1  # units (~30 h): the last bin holds this and everything above
BINS = EXACT + (TOP.bit_length() - EXACT.bit_length() + 1) * PER_OCTAVE


def _bin(units: int) -> int:
    if units < EXACT:
        return units
    shift = units.bit_length() - 11  # units >> shift is in [1024, 2048)
    return EXACT + (shift - 1) * PER_OCTAVE + (units >> shift) - PER_OCTAVE


def _middle(index: int) -> float:
    """The middle of a bin's values [s]."""
    if index < EXACT:
        return (index + 0.5) * UNIT
    shift, j = divmod(index - EXACT, PER_OCTAVE)
    shift += 1
    low = (PER_OCTAVE + j) << shift
    return (low + ((1 << shift) - 1) / 2) * UNIT


class Histogram:
    """Absolute values of a duration [s]: count, exact min and max, and percentiles within 0.1 %."""

    def __init__(self) -> None:
        self.counts = array("Q", [0]) * BINS  # made (and its pages touched) here, before the loop
        self.count = 0
        self.min = math.inf
        self.max = 0.0

    def add(self, seconds: float) -> None:
        value = abs(seconds)
        units = int(value / UNIT) if value < TOP * UNIT else TOP  # NaN and inf too
        self.counts[_bin(units)] += 1
        self.count += 1
        if value < self.min:
            self.min = value
        if value > self.max:
            self.max = value

    def percentile(self, p: float) -> float | None:
        """numpy.percentile's linear method over the bins' middles (the extremes exact); None if empty."""
        if not self.count:
            return None
        at = p / 100 * (self.count - 1)
        below = math.floor(at)
        a, b = self._ranked(below), self._ranked(min(below + 1, self.count - 1))
        return a + (b - a) * (at - below)

    def _ranked(self, rank: int) -> float:
        """The value of the rank-th smallest (from 0): the bin's middle, clipped to the exact extremes."""
        if rank == 0:
            return self.min
        if rank == self.count - 1:
            return self.max
        seen = 0
        for index, n in enumerate(self.counts):
            seen += n
            if seen > rank:
                return min(max(_middle(index), self.min), self.max)
        return self.max
