"""argparse types that refuse a bad number at parse time, in one line, before anything runs."""

from __future__ import annotations

import argparse
import math
import re

from dockhil.scene.schema import MAX_DURATION, MAX_RATE, MIN_RATE, NODE_NAME


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def seconds(text: str) -> float:
    """A run length [s]: finite, > 0, at most MAX_DURATION."""
    value = _number(text)
    if not 0.0 < value <= MAX_DURATION:
        raise argparse.ArgumentTypeError(f"{text} s must be > 0 and at most {MAX_DURATION:g} s")
    return value


def hertz(text: str) -> float:
    """A loop rate [Hz]: finite, between MIN_RATE and MAX_RATE."""
    value = _number(text)
    if not MIN_RATE <= value <= MAX_RATE:
        raise argparse.ArgumentTypeError(f"{text} Hz must be between {MIN_RATE:g} and {MAX_RATE:g} Hz")
    return value


def node_name(text: str) -> str:
    """A node name as in a launch file: it names files and registry entries, so no / or spaces."""
    if not re.fullmatch(NODE_NAME, text) or len(text) > 64:
        raise argparse.ArgumentTypeError(f"{text!r} is not a node name: letters, digits, _ . - (at most 64)")
    return text


def nonnegative(text: str) -> float:
    """A physical coefficient (a stiffness, a damping): finite and >= 0."""
    value = _number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"{text} must be >= 0")
    return value
