"""Wall-time loop timing: each tick's lateness against its schedule, missed deadlines, input ages
(what validity judges a run on), and the sleep to the next tick; in both clocks, the span of the
ticks and the context switches of each thread over it."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable

from dockhil.runtime import switches
from dockhil.runtime.histogram import Histogram


class LoopTiming:
    """Wall-time loop statistics: how late each tick started against its schedule,
    missed deadlines, and how old each input's latest message was when used
    (by its stamp, and by the time since it arrived against its maximum age)."""

    def __init__(self, ports: list[str], period: float = 0.0, max_age: dict[str, float] | None = None):
        self.lateness = Histogram()  # from the second tick: the first has no schedule to keep
        self.ages = {port: Histogram() for port in ports}
        self.worst_tick: int | None = None  # which tick (from 0) started latest
        self.misses = 0
        self.ticks = 0
        self.started_ticks = 0
        self.period = period
        self.elapsed = 0.0
        self.max_age = dict(max_age or {})
        self.worst_age = {port: 0.0 for port in ports}  # since arrival [s]
        self.dropped_in = 0
        self.dropped_out = 0
        self.device: Callable[[], dict] | None = None  # a driver's device_figures, read at report
        self.worst_overrun = 0.0
        # When the loop's first tick began and its last ended (time.time(), comparable across the
        # graph's processes): the run's real-time factor counts this span, not the start-up.
        self.first_tick_at: float | None = None
        self.last_tick_at: float | None = None
        # Wall time: topic -> messages its publisher's socket took (Publisher.taken), set as the loop ends.
        self.published: dict[str, int] = {}
        # Thread name -> [voluntary, involuntary] context switches from the first tick to the end of the last.
        self.switches: dict[str, list[int]] = {}
        self._switches_before: dict[str, list[int]] | None = None
        # [the process's, the loop thread's] CPU seconds over the same span: what a tick costs where.
        self.cpu: list[float] = []
        self._cpu_before = (0.0, 0.0)

    def first_tick(self) -> None:
        """The first tick begins: the run's span and its context switches count from here."""
        self.first_tick_at = time.time()
        self._switches_before = switches.by_thread()
        self._cpu_before = (time.process_time(), time.thread_time())

    def last_tick(self, at: float | None = None) -> None:
        """The last tick has ended (at `at`, time.time() by default)."""
        self.last_tick_at = time.time() if at is None else at
        if self._switches_before is not None:
            self.switches = switches.since(self._switches_before, switches.by_thread())
            self.cpu = [time.process_time() - self._cpu_before[0], time.thread_time() - self._cpu_before[1]]

    def aged(self, port: str, age: float) -> None:
        if age > self.worst_age.get(port, 0.0):
            self.worst_age[port] = age

    def started(self, late_s: float) -> None:
        self.started_ticks += 1
        if self.started_ticks == 1:
            return
        if self.worst_tick is None or abs(late_s) > self.lateness.max:
            self.worst_tick = self.started_ticks - 1
        self.lateness.add(late_s)

    def inputs(self, now: float, latest: dict) -> None:
        for port, ages in self.ages.items():
            msg = latest.get(port)
            if msg is not None:
                ages.add(now - msg.header.stamp)

    def missed(self, late: float = 0.0) -> None:
        """A tick ended `late` seconds after its deadline (a long one re-bases the schedule, so the
        next start does not show it: keep the worst here)."""
        self.misses += 1
        self.worst_overrun = max(self.worst_overrun, late)

    def report(self, name: str) -> dict:
        def pct(values: Histogram) -> dict:
            p50, p99 = values.percentile(50), values.percentile(99)
            if p50 is None or p99 is None:  # nothing counted
                return {}
            return {"p50": p50 * 1e6, "p99": p99 * 1e6, "max": values.max * 1e6}

        worst = self.lateness.max
        out = {
            "node": name,
            "ticks": self.ticks,
            "deadline_misses": self.misses,
            "jitter_us": pct(self.lateness),
            "worst_tick": self.worst_tick,
            "input_age_us": {port: pct(a) for port, a in self.ages.items()},
            # What validity is judged on (dockhil/runtime/validity.py):
            "period_s": self.period,
            "elapsed_s": self.elapsed,
            "covered_s": self.ticks * self.period,
            "worst_late_s": max(worst, self.worst_overrun),
            "max_age_s": {p: (None if math.isinf(a) else a) for p, a in self.max_age.items()},
            "worst_input_age_s": dict(self.worst_age),
            "dropped_in": self.dropped_in,
            "dropped_out": self.dropped_out,
            "first_tick_at_s": self.first_tick_at,
            "last_tick_at_s": self.last_tick_at,
            "published": dict(self.published),
            "switches": dict(self.switches),
            "cpu_s": list(self.cpu),
        }
        if self.device is not None:  # a driver's account of its device's cycles (validity.device_reasons)
            out["device"] = self.device()
        return out


SPIN_S = float(os.environ.get("DOCKHIL_SPIN_S", "0.0002"))


def sleep_until(deadline: float, clock: Callable[[], float] = time.monotonic, spin: float = SPIN_S) -> None:
    # Sleep most of the way, then spin the last `spin` seconds: time.sleep alone overshoots by
    # ~60-150 us, but every microsecond spun is CPU the other nodes on the machine do not get.
    if clock is not time.monotonic:  # a test's clock: its time moves when the test says, never by waiting
        if hasattr(clock, "sleep_until"):
            clock.sleep_until(deadline)
        return
    left = deadline - time.monotonic()
    if left > spin:
        time.sleep(left - spin)
    while time.monotonic() < deadline:
        pass


def loop_spin() -> float:
    """The spin of this thread's loop: none under a real-time policy, where the sleep wakes within
    tens of microseconds and spun time counts against the kernel's real-time budget (95 % of each
    second, sched_rt_runtime_us): a graph whose loops spend it stops every real-time thread, the
    devices' too, for the rest of that second."""
    from dockhil.runtime import realtime

    return 0.0 if realtime.granted() else SPIN_S
