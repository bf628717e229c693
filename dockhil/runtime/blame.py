"""Whose fault a stale input was: the publisher's process tells a publisher that ended, one stopped
(SIGSTOP, a debugger) and one alive but late (a busy machine starves it of CPU) apart, so the line
that stops the graph blames the right one."""

from __future__ import annotations

import subprocess
from typing import Any


def stopped(pid: int) -> bool:
    """The process is stopped by a signal or traced (its state in /proc, Linux)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rpartition(")")[2].split()[0] in ("T", "t")
    except (OSError, IndexError):
        return False


def blame(stale: dict, publisher: str, proc: subprocess.Popen) -> str:
    """The end of the stop's line for an input gone stale (executor.STALE's record) whose publisher,
    node `publisher`, runs as `proc`."""
    what = f": its input {stale['topic']}'s publisher, node {publisher!r},"
    code = proc.poll()
    if code is not None:
        return f"{what} had exited with code {code}"
    if stopped(proc.pid):
        return f"{what} is stopped (SIGSTOP, a debugger)"
    return f"{what} is running but its message was late by {stale['late']:.3f} s; a busy machine? try --realtime"


def first_stale(child: Any, children: list[Any]) -> Any:
    """Of the launcher's children that exited on a stale input (each `.stale` with the time it said so,
    "at"), the one that said so before `child` did, first; else `child`. A stopped node, once resumed,
    finds its own inputs stale too, and may exit before the reader that found it stopped is seen to."""
    at = child.stale["at"] if child.stale else 0.0
    gone = [c for c in children if c.stale and c.proc and c.proc.poll() and c.stale["at"] < at]
    return min(gone, key=lambda c: c.stale["at"]) if gone else child
