"""Signals that end a long command as Ctrl-C does."""

from __future__ import annotations

from types import FrameType


class StopOnSignal:
    """SIGTERM and SIGHUP end a long command (a sweep, a benchmark) as Ctrl-C does (a KeyboardInterrupt):
    its workers are ended and it says what it kept in one line, where Python's default would exit at once
    without a word. `what` names the signal for that line, `number` gives the exit (128 + it)."""

    def __init__(self):
        import signal
        import threading

        self.number: int = signal.SIGINT
        self.what = "interrupted"
        self.old = {}
        if threading.current_thread() is threading.main_thread():  # where Python runs handlers
            self.old = {sig: signal.signal(sig, self._stop) for sig in (signal.SIGTERM, signal.SIGHUP)}

    def _stop(self, signum: int, frame: FrameType | None) -> None:
        import signal

        if self.number != signal.SIGINT:  # ending already: a second signal must not cut that short
            return
        self.number, self.what = signum, f"stopped by {signal.Signals(signum).name}"
        raise KeyboardInterrupt

    def restore(self) -> None:
        import signal

        for sig, handler in self.old.items():
            signal.signal(sig, handler)
