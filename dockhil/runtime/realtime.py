"""`--realtime`: SCHED_FIFO for the whole delivery path of a wall-time run.

A node process asks for it on its main thread before anything else starts, so every thread it
makes afterwards (the node loop, a driver's device thread, an emulator's cycle) inherits it. The
threads that meet a device's own clock (a driver's answering or receiving thread, an emulator's
cycle standing in for the device) go above the loops, and ZeroMQ's I/O threads, which carry every
message between processes, go between: a busy core then delays none of them behind ordinary work.

Without the privilege (not root, no CAP_SYS_NICE, no rtprio limit: docs/time.md) the OS refuses;
the process says so in one line and runs at normal priority.

Sim time asks for no privilege: only the launch's recorder, which no tick waits for, is lowered to
SCHED_BATCH (`trailing`), so that its wake-ups do not preempt the lock-step nodes, and each node
process's ZeroMQ I/O threads to a nice of IO_NICE (`lower_io_threads`), so that a send's does not
preempt the loop that made it.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zmq

# Sim time: the nice of a node process's ZeroMQ I/O threads (bench/graph.py, load 2 and with both cores
# busy: 8.5-8.9 switches a tick to 7.7 for the process graph, the same real-time factor; SCHED_BATCH gave
# 7.0 quiet, but with both cores busy a batch thread waits out a busy loop's slice: 20-40 % slower).
IO_NICE = 10

# The graph's recorders run at normal policy with a nice of -10: ordinary work cannot starve them (nine
# times a busy loop's share), and they are not real-time. At SCHED_FIFO (40, once) their bursts left the
# busy loops beside them starved, and the kernel's guard for normal tasks (the fair server: 50 ms of each
# second, ahead of every real-time thread) then stopped the whole graph for tens of milliseconds: with two
# busy loops, a 60 s RSI run counted 75 late answers and 85 controller cycles lost that way, 6 and 0 without.
RECORD_NICE = -10
LOOP_PRIORITY = 50  # node loops
IO_PRIORITY = 55  # ZeroMQ's I/O threads: between the loops and the devices they serve
DEVICE_PRIORITY = 60  # threads that meet a device's clock: drivers' link threads, emulators' cycles
# The launcher while it starts or stops the graph's nodes, all in one go: above the loops and I/O threads,
# level with the devices (a FIFO thread is not preempted by its equals), within the rtprio limit of 60.
SIGNAL_PRIORITY = DEVICE_PRIORITY

HOW = "grant CAP_SYS_NICE or an rtprio limit to use --realtime: docs/time.md"


def ask(priority: int, what: str, say: Callable[[str], object]) -> bool:
    """SCHED_FIFO at `priority` for the calling thread; where the OS refuses, one line through
    `say` naming `what` runs at normal priority, and False."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError, AttributeError) as exc:
        say(f"warning: real-time scheduling of {what} refused ({exc}); running at normal priority ({HOW})")
        return False
    return True


def favour(pid: int, what: str, say: Callable[[str], object]) -> bool:
    """Nice RECORD_NICE for another process (its main thread, before it makes others); where the OS
    refuses, one line through `say`, and False."""
    try:
        os.setpriority(os.PRIO_PROCESS, pid, RECORD_NICE)
    except (PermissionError, OSError, AttributeError) as exc:
        say(
            f"warning: a nice of {RECORD_NICE} for {what} refused ({exc}); running at normal priority "
            f"(grant CAP_SYS_NICE or a nice limit of {RECORD_NICE}: docs/time.md)"
        )
        return False
    return True


def trailing(pid: int) -> bool:
    """Sim time: SCHED_BATCH for every thread of a trailing reader's process (the launch's recorder).
    No tick waits for it, yet at normal policy each of its wake-ups may preempt a lock-step node on a
    busy core; a batch thread never preempts on waking, and takes an idle core or its turn. Lowering
    one's own policy needs no privilege; where the OS refuses anyway, it runs as it was (False)."""
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:  # not Linux, or it exited already
        return False
    done = True
    for tid in tids:
        try:
            os.sched_setscheduler(int(tid), os.SCHED_BATCH, os.sched_param(0))
        except (PermissionError, OSError, AttributeError):
            done = False
    return done


def lower_io_threads(wait_s: float = 0.5) -> bool:
    """Sim time: a nice of IO_NICE for this process's ZeroMQ I/O threads. A node sends, then soon waits
    for its next input; at the loop's own priority the I/O thread that wakes to carry the send preempts
    the loop on its core (about one involuntary switch in two hops); niced, it waits the moment until the
    loop waits. A new I/O thread names itself once it runs: looked for up to `wait_s`. No privilege
    needed (a thread may always lower its own priority); where refused or not found, False."""
    import time

    deadline = time.monotonic() + wait_s
    while True:
        try:
            tids = os.listdir("/proc/self/task")
        except OSError:  # not Linux
            return False
        found = False
        for tid in tids:
            try:
                with open(f"/proc/self/task/{tid}/comm") as f:
                    if not f.read().startswith("ZMQbg/IO"):
                        continue
                os.setpriority(os.PRIO_PROCESS, int(tid), IO_NICE)
                found = True
            except (PermissionError, OSError, AttributeError):
                return False
        if found or time.monotonic() >= deadline:
            return found
        time.sleep(0.005)


def granted() -> bool:
    """Whether the calling thread runs under a real-time policy (asked for, or inherited)."""
    try:
        return os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR)
    except (OSError, AttributeError):
        return False


def raise_device_thread(say: Callable[[str], object], what: str) -> None:
    """A device thread of a process running real-time: above the loops (it inherited theirs)."""
    if granted():
        ask(DEVICE_PRIORITY, what, say)


def zmq_options(ctx: zmq.Context) -> bool:
    """SCHED_FIFO for a ZeroMQ context's I/O threads, set before its first socket starts them.
    Only where this thread already holds a real-time policy: libzmq aborts the process when the
    OS refuses the policy to its thread, so it is asked only once the privilege is proven."""
    import zmq

    if not granted():
        return False
    ctx.set(zmq.THREAD_SCHED_POLICY, os.SCHED_FIFO)
    ctx.set(zmq.THREAD_PRIORITY, IO_PRIORITY)
    return True


@contextlib.contextmanager
def signalling(enabled: bool) -> Iterator[None]:
    """The launcher's thread above every node while it signals them all (start, stop): a busy core that
    preempted it between two nodes' signals would stop a publisher while its reader, told later, took the
    silence for a stall. Back to its own policy after; without the privilege, as it was (no line: the
    nodes' own requests already said it)."""
    old = None
    if enabled:
        try:
            old = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(SIGNAL_PRIORITY))
        except (PermissionError, OSError, AttributeError):
            old = None
    try:
        yield
    finally:
        if old is not None:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, old[0], old[1])
