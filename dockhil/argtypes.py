"""argparse types that refuse a bad number at parse time, in one line, before anything runs."""

from __future__ import annotations

import argparse
import math
import re

from dockhil.scene.schema import MAX_AGE, MAX_DURATION, MAX_RATE, MIN_RATE, NODE_NAME


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


def max_age_setting(text: str) -> tuple[str, str, float]:
    """`NODE.INPUT=SECONDS` -> (node, input, seconds): a wall-time input's maximum age, > 0 and at
    most MAX_AGE as in a launch file, or `inf` for no limit. Whether the node and input exist is the
    graph's to say (dockhil.scene.graph.set_max_ages)."""
    target, sep, value = text.partition("=")
    node, dot, port = target.rpartition(".")
    if not (sep and dot and node and port):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not NODE.INPUT=SECONDS (e.g. dynamics.ft=0.05, or =inf for no limit)"
        )
    try:
        age = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: {value!r} is not a number of seconds (or inf for no limit)"
        ) from None
    if not (0.0 < age <= MAX_AGE or age == math.inf):
        raise argparse.ArgumentTypeError(
            f"{text!r}: the maximum age must be > 0 and at most {MAX_AGE:g} s, or inf for no limit"
        )
    return node, port, age
