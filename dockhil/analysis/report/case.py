"""One stiff or extreme case of the report as a JSON-ready record: what was expected (computed
from the model), what was measured, and whether the two agree."""

from __future__ import annotations

import math

import numpy as np


def case(
    group: str,
    name: str,
    expected: str,
    measured: str,
    passed: bool,
    *,
    params: dict | None = None,
    expected_value: object = None,
    measured_value: object = None,
    tolerance: float | None = None,
) -> dict:
    return {
        "group": group,
        "name": name,
        "expected": expected,
        "measured": measured,
        "passed": bool(passed),
        "params": params or {},
        "expected_value": plain(expected_value),
        "measured_value": plain(measured_value),
        "tolerance": tolerance,
    }


def plain(value):
    """JSON-ready: numpy scalars to floats, non-finite floats to strings."""
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def relative_difference(a: float, b: float) -> float:
    """|a - b| relative to |b| (|b| taken as at least 1e-300)."""
    return abs(a - b) / max(abs(b), 1e-300)
