"""Entry point of one node process: `python -m dockhil.process [--keys KEY_FILE] SPEC_JSON`.

The spec names the graph's key file (mode 0600, checked when read); the
keys never appear on the command line, which every user can read in /proc.
--keys overrides the spec's key file (a node started by hand on another host).

The launcher starts one of these per node. It logs one line per error
(dockhil.log: forwarded to the launcher, which logs it under the node's name;
on stderr when started by hand), prints a READY line (read by the launcher,
not shown) once its device is open, and exits 0 when its ticks are done or
it is asked to stop.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

import msgspec

from dockhil.runtime.parent import die_with_parent  # the recorder takes it from here too

if TYPE_CHECKING:
    from dockhil.runtime.executor import RunSpec, Stop

READY = "\x1edockhil-ready"  # a line the launcher intercepts


def _wait_for_go(go: list, stop: Stop) -> None:
    """Sleep until the launcher's go (SIGUSR1, whose handler fills `go`) or a stop. The signal's
    byte on the wake-up fd ends the wait at once, on whichever thread the signal lands; the
    time-out only bounds a signal that came just before the fd was set."""
    import select

    r, w = os.pipe()
    os.set_blocking(w, False)
    old = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    try:
        while not go and not stop.requested:
            if select.select([r], [], [], 0.1)[0]:
                os.read(r, 512)
    finally:
        signal.set_wakeup_fd(old)
        os.close(r)
        os.close(w)


def run_node(
    spec: RunSpec, log: Callable[[str], object] | None = None, on_ready: Callable[[], object] | None = None
) -> int:
    """Set up and run one node until its ticks are done or a stop is requested."""
    from dockhil import log as logs
    from dockhil import node_types
    from dockhil.errors import NODE_RAISES, DockhilError, failure_line
    from dockhil.runtime import ownership
    from dockhil.runtime.executor import TIMING, NodeExecutor, Stop

    log = log or (lambda m: logs.node_line(spec.name, m))
    ownership.set_graph(spec.run_id)
    stop = Stop()
    stop.install()
    go = []
    if spec.wait_for_go:  # installed before READY is said, so the launcher's go cannot be missed
        signal.signal(signal.SIGUSR1, lambda signum, frame: go.append(True))
    executor = None
    ticking = close_failed = False
    from dockhil.runtime import realtime

    if spec.realtime and spec.clock == "wall":  # first: every thread made from here on inherits it
        realtime.ask(realtime.LOOP_PRIORITY, "the node loop", log)
    try:
        node_type = node_types.load(spec.type_name)
        if node_type.free_running:  # an emulated device: above the loops, as a real one is never starved by them
            realtime.raise_device_thread(log, "the emulated device's loop")
        executor = NodeExecutor(spec, node_type, stop, log)
        executor.start()
        ticking = True  # past setup: a failure from here on is at a tick
        if on_ready:
            on_ready()
        if spec.wait_for_go:  # the other nodes are still opening their devices
            _wait_for_go(go, stop)
        if spec.clock == "sim":
            executor.run_sim()
        else:
            duration = None if spec.n_ticks is None else spec.n_ticks * spec.dt
            stats = executor.run_wall(duration)
            if stats["deadline_misses"]:
                log(f"warning: {stats['deadline_misses']} of {stats['ticks']} ticks missed their deadline")
    except DockhilError as exc:
        log(f"error: {exc}")
        return 2
    except NODE_RAISES as exc:  # a bug in a node (a sys.exit would leave the graph waiting): one line
        where = f"tick {executor.ticks_done}" if ticking and executor is not None else "setup"
        log(f"error: {failure_line(spec.name, where, exc)}")
        if os.environ.get("DOCKHIL_TRACEBACK"):  # as the dockhil command shows its own
            import traceback

            traceback.print_exc()
        return 1
    finally:
        if executor is not None:
            try:
                executor.close()
            except NODE_RAISES as exc:  # closing must not hide the first error
                # A DockhilError says where itself (a container's names its member).
                log(f"error: {exc if isinstance(exc, DockhilError) else failure_line(spec.name, 'close', exc)}")
                close_failed = True  # a driver holds the robot in close: its failure fails the run
            timing = getattr(executor, "timing", None)
            if timing is not None:  # the launcher judges the run's validity on these figures
                import json

                print(TIMING + json.dumps(timing.report(spec.name)), flush=True)
    if executor.dropped:
        log(f"warning: {executor.dropped} bad message(s) dropped")
    return 1 if close_failed else 0


def main() -> int:
    from dockhil import log
    from dockhil.runtime.executor import RunSpec

    die_with_parent()
    log.setup_child()
    say = log.Log("[dockhil.process]")
    args = sys.argv[1:]
    key_file = None
    if len(args) == 3 and args[0] == "--keys":
        key_file, args = args[1], args[2:]
    if len(args) != 1:
        say.error("usage: python -m dockhil.process [--keys KEY_FILE] SPEC_JSON")
        return 2
    try:
        spec = msgspec.json.decode(args[0].encode(), type=RunSpec)
    except msgspec.DecodeError as exc:
        say.error(f"node spec: {exc}")
        return 2
    if key_file is not None:
        spec.key_file = key_file
    log.capture_others(f"[{spec.name}]")
    profile_dir = os.environ.get("DOCKHIL_PROFILE")
    if profile_dir:  # developers: one cProfile dump per node, named after it
        import cProfile

        prof = cProfile.Profile()
        code = prof.runcall(run_node, spec, on_ready=lambda: print(READY, flush=True))
        prof.dump_stats(os.path.join(profile_dir, f"{spec.name}.prof"))
        return code
    return run_node(spec, on_ready=lambda: print(READY, flush=True))


if __name__ == "__main__":
    sys.exit(main())
