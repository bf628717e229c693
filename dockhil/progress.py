"""Progress on stderr for long runs: redrawn in place on a terminal, one line at a time in logs.

Log records (dockhil.log) are written through write_between(), so they never run into the line.

`Progress` follows a sim-time run (simulated time, share done, real-time
factor); `TaskProgress` counts named steps (the report).
"""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

# One screen: the status line and log records (from any thread) take turns at it.
_screen = threading.RLock()
_active: StatusLine | None = None  # the status line now drawn on a terminal


class StatusLine:
    """One line of status: rewritten in place on a terminal; elsewhere each update is a new line."""

    def __init__(self, stream=None):
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.shown = False
        self.text = ""

    def show(self, text: str) -> None:
        global _active
        with _screen:
            self.text = text
            self.stream.write(("\r" + text + "\x1b[K") if self.tty else text + "\n")
            self.stream.flush()
            self.shown = True
            if self.tty:
                _active = self

    def end(self, keep: bool = False) -> None:
        """Leave the line (keep=True) or erase it, on a terminal."""
        global _active
        with _screen:
            if self.shown and self.tty:
                self.stream.write("\n" if keep else "\r\x1b[K")
                self.stream.flush()
            if _active is self:
                _active = None


def write_between(stream: TextIO, text: str) -> None:
    """Write `text` (whole lines) so that it never shares a line with the status line on the
    terminal: the status line is erased first and drawn again below it."""
    with _screen:
        line = _active
        if line is not None:
            line.stream.write("\r\x1b[K")
            line.stream.flush()
        stream.write(text)
        stream.flush()
        if line is not None:
            line.stream.write("\r" + line.text + "\x1b[K")
            line.stream.flush()


def bar(fraction: float, width: int) -> str:
    filled = int(width * min(1.0, max(0.0, fraction)))
    return "#" * filled + "." * (width - filled)


class Progress:
    """A sim-time run: simulated time, share done, real-time factor."""

    def __init__(self, total_ticks: int | None, dt: float, stream: TextIO | None = None, min_interval: float = 0.2):
        self.total = total_ticks
        self.dt = dt
        self.line = StatusLine(stream)
        self.start = time.perf_counter()
        self.last = self.start  # nothing to show for the first moments
        self.min_interval = min_interval if self.line.tty else 5.0  # logs get a line every few seconds

    def update(self, ticks_done: int, force: bool = False) -> None:
        now = time.perf_counter()
        if not force and now - self.last < self.min_interval:
            return
        self.last = now
        sim = max(0, ticks_done - 1) * self.dt
        elapsed = now - self.start
        rtf = f"{sim / elapsed:.1f}x real time" if elapsed > 0 else ""
        if self.total:
            text = (
                f"[{bar(ticks_done / self.total, 24)}] {sim:.2f} of {(self.total - 1) * self.dt:.2f} s simulated, {rtf}"
            )
        else:
            text = f"{sim:.2f} s simulated, {rtf}"
        self.line.show(text)

    def done(self) -> None:
        self.line.end()


class TaskProgress:
    """Named steps of a long job: `step(label)` before each, `finish()` at the end."""

    def __init__(self, total: int, stream: TextIO | None = None, width: int = 30):
        self.total = max(1, total)
        self.done = 0
        self.width = width
        self.line = StatusLine(stream)
        self.started = time.perf_counter()

    def step(self, label: str) -> None:
        """Announce the task about to run (counts the previous one as done)."""
        self._draw(label)
        self.done = min(self.total, self.done + 1)

    def finish(self, label: str = "done") -> None:
        self.done = self.total
        self._draw(label)
        self.line.end(keep=True)

    def stop(self) -> None:
        """Cut short (Ctrl-C): the bar stays as far as it got, and what follows starts on a line of its own."""
        self.line.end(keep=True)

    def _draw(self, label: str) -> None:
        elapsed = time.perf_counter() - self.started
        self.line.show(
            f"[{bar(self.done / self.total, self.width)}] {self.done:>3}/{self.total} {elapsed:6.1f} s  {label}"
        )
