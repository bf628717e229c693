"""A one-line progress display for long runs: simulated time, share done, real-time factor."""

from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total_ticks: int | None, dt: float, stream=None, min_interval: float = 0.2):
        self.total = total_ticks
        self.dt = dt
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.start = time.perf_counter()
        self.last = self.start  # nothing to show for the first moments
        self.min_interval = min_interval if self.tty else 5.0  # logs get a line every few seconds
        self.shown = False

    def update(self, ticks_done: int, force: bool = False) -> None:
        now = time.perf_counter()
        if not force and now - self.last < self.min_interval:
            return
        self.last = now
        sim = max(0, ticks_done - 1) * self.dt
        elapsed = now - self.start
        rtf = f"{sim / elapsed:.1f}x real time" if elapsed > 0 else ""
        if self.total:
            share = ticks_done / self.total
            bar = "#" * int(24 * share)
            text = f"[{bar:<24}] {sim:.2f} of {(self.total - 1) * self.dt:.2f} s simulated, {rtf}"
        else:
            text = f"{sim:.2f} s simulated, {rtf}"
        if self.tty:
            self.stream.write("\r" + text + "\x1b[K")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
        self.shown = True

    def done(self) -> None:
        if self.shown and self.tty:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
