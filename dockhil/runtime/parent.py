"""A child process that ends with its parent, however the parent ends (a SIGKILL included): node
processes and the recorder (SIGTERM: a node closes, a driver holds its robot) and a sweep's local
workers (SIGKILL: a sim-time run has nothing to save, the parent keeps the rows)."""

from __future__ import annotations

import os
import signal
import time


def die_with_parent(sig: int = signal.SIGTERM, parent: int | None = None) -> None:
    """Have the kernel send `sig` to this process when its parent ends (PR_SET_PDEATHSIG, Linux).

    Given the parent's pid as the parent knew it (`parent`), also where the kernel cannot (not
    Linux: a thread watches the parent) and when the parent ended before this call, which the
    kernel never signals: this process then exits at once."""
    try:
        import ctypes

        if ctypes.CDLL(None, use_errno=True).prctl(1, sig, 0, 0, 0) != 0:  # PR_SET_PDEATHSIG
            raise OSError
    except (OSError, AttributeError):  # not Linux
        if parent is not None:
            import threading

            threading.Thread(target=_watch, args=(parent,), daemon=True).start()
    if parent is not None and not alive(parent):  # it died before the prctl
        os._exit(1)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except OSError:  # gone, or its number now another user's
        return False
    return True


def _watch(parent: int) -> None:
    while alive(parent):
        time.sleep(0.5)
    os._exit(1)
