"""The fixed-memory histogram of durations behind the loops' figures and the RSI emulator's latencies."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from dockhil.runtime.histogram import BINS, TOP, UNIT, Histogram, _bin, _middle


def test_bins_are_contiguous_and_each_holds_values_within_a_tenth_of_a_percent_of_its_middle():
    edges = [0, 1, 2047, 2048, 2049, 4095, 4096, 123_456_789, TOP - 1, TOP]
    for units in edges:
        index = _bin(units)
        assert 0 <= index < BINS
        middle = _middle(index) / UNIT
        assert abs(middle - units) <= max(0.5, 1e-3 * units), units
    # every unit maps to the bin after its predecessor's or the same: no bin skipped, none out of order
    previous = _bin(0)
    for units in list(range(1, 20_000)) + list(range(1 << 30, (1 << 30) + 5000)):
        index = _bin(units)
        assert index - previous in (0, 1) or units == 1 << 30
        previous = index
    assert _bin(TOP) == BINS - 1


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_percentiles_are_numpys_within_the_bins(seed):
    rng = random.Random(seed)
    values = [rng.lognormvariate(math.log(2e-4), 1.5) for _ in range(5000)] + [-3e-5, 0.0, 2.5]
    histogram = Histogram()
    for v in values:
        histogram.add(v)
    absolute = np.abs(values)
    assert histogram.count == len(values)
    assert histogram.min == absolute.min() and histogram.max == absolute.max()
    for p in (0, 1, 50, 90, 99, 99.9, 100):
        assert histogram.percentile(p) == pytest.approx(np.percentile(absolute, p), rel=1e-3, abs=1e-7)


def test_empty_single_and_out_of_range_values():
    histogram = Histogram()
    assert histogram.percentile(50) is None and histogram.count == 0
    histogram.add(1e-3)
    assert histogram.percentile(50) == histogram.percentile(99) == 1e-3
    for bad in (math.inf, math.nan, 1e9):  # counted in the last bin, never an error in a running loop
        histogram.add(bad)
    assert histogram.count == 4 and histogram.counts[BINS - 1] == 3
    assert histogram.max == math.inf
