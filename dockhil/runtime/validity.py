"""Is a run's result valid? Exit 0 means yes.

A sim-time run is lock-step: it cannot fall behind, so it is valid unless
messages were lost. A wall-time run is valid only if every node kept its
schedule well enough that the simulated time is the time that passed:

- covered: the ticks a node ran, times the step, cover at least
  MIN_COVERED of the wall time its loop ran (a node that falls far behind
  skips ticks, and the simulation runs slow against the hardware);
- lateness: no tick started later than the node's tightest input maximum
  age (default_max_age of the rate where it declares none): a tick that late
  used, or handed on, data its readers would refuse;
- deadline misses: at most MAX_MISS_RATIO of the ticks ended after their
  deadline;
  (these three do not apply to a free-running node, an emulated device:
  its loop stands for hardware that keeps its own time, and the drivers'
  watchdogs judge what it delivers)
- input ages: no input was used older than its maximum age (the node stops
  when that happens, so this reads only in a report that a node wrote);
- no node respawned: the run went on, but the restarted node's data has a gap (a force held
  stale while the F/T driver restarted, integrated by the dynamics);
- no message lost: none dropped by a full queue (a subscriber that did not
  keep up), none dropped as malformed;
- the devices kept the loop: a driver's account of its device's cycles (`device` in its figures,
  `device_figures()` of the node) says the device went no longer than its tolerance without taking
  a command or delivering a reading while the loop moved it (a stalled controller, sensor or
  emulator: the loop that ran was not the scene's), and the robot's actual path stayed within the
  following-error tolerance of the commanded one. A stall is never a valid run.

(Messages the recorder lost, in wall time also the end of the run that a recorder which fell behind is
told was sent, dockhil.bags.tail, fail the run instead, exit 1: its recording is not the run.)

An invalid run prints one INVALID line, gets "valid": false and its
reasons in the summary JSON, and exits with INVALID_EXIT.
"""

from __future__ import annotations

import math

from dockhil.node import default_max_age

INVALID_EXIT = 3  # the run completed, but its result is not valid (see the reasons printed)

MIN_COVERED = 0.80
MAX_MISS_RATIO = 0.25


def wall_time_reasons(timings: dict[str, dict], expected: dict[str, bool], dt: float) -> list[str]:
    """Why a wall-time run is not valid, from each node's loop figures (LoopTiming.report);
    `expected`: the nodes that must have reported, each mapped to whether it is a device emulator."""
    reasons = []
    for name, device in expected.items():
        t = timings.get(name)
        if t is None:
            reasons.append(f"node {name!r} reported no loop timing")
            continue
        reasons.extend(node_reasons(t, dt, device=device))
    return reasons


def respawn_reasons(respawns: list[tuple[str, float, int]]) -> list[str]:
    """One reason per respawned node, from each respawn (node, seconds into the run, exit code)."""
    out = []
    for name in dict.fromkeys(n for n, _, _ in respawns):
        times = [f"{at:.1f} s" for n, at, _ in respawns if n == name]
        code = next(c for n, _, c in respawns if n == name)
        out.append(
            f"node {name!r} exited (code {code}) and was respawned {len(times)} time(s), at "
            f"{', '.join(times)} into the run: its data has a gap"
        )
    return out


def sim_time_reasons(timings: dict[str, dict]) -> list[str]:
    """Lock-step cannot fall behind: a sim-time run is judged only on messages it lost."""
    return [r for t in timings.values() for r in message_reasons(t)]


def node_reasons(t: dict, dt: float, device: bool = False) -> list[str]:
    name = t["node"]
    out = [] if device else schedule_reasons(t, dt)
    for port, age in (t.get("worst_input_age_s") or {}).items():
        limit = (t.get("max_age_s") or {}).get(port)
        if limit is not None and age > limit:
            out.append(f"node {name!r}: input {port!r} was used {age:.3f} s old (> max_age {limit:g} s)")
    return out + message_reasons(t) + device_reasons(t)


def device_reasons(t: dict) -> list[str]:
    """What a driver's account of its device's cycles says against the run (none without one)."""
    d = t.get("device")
    if not d:
        return []
    name, out = t["node"], []
    gap, limit = d.get("longest_gap_s"), d.get("gap_limit_s")
    if gap is not None and limit is not None and gap > limit:
        out.append(
            f"node {name!r}: {d.get('what', 'the device')} went {gap:.3f} s without {d.get('gap_is', 'a cycle')} "
            f"(> {limit:g} s): the device stalled, or the loop did, and the loop that ran was not the scene's"
        )
    err, limit = d.get("path_error_m"), d.get("path_error_limit_m")
    if err is not None and limit is not None and err > limit:
        out.append(
            f"node {name!r}: the robot's actual path left the commanded one by {err:.4f} m "
            f"(> following-error tolerance {limit:g} m)"
        )
    return out


def message_reasons(t: dict) -> list[str]:
    name, out = t["node"], []
    if t.get("dropped_out"):
        out.append(f"node {name!r} dropped {t['dropped_out']} output message(s): a subscriber did not keep up")
    if t.get("dropped_in"):
        out.append(f"node {name!r} dropped {t['dropped_in']} bad input message(s)")
    return out


def schedule_reasons(t: dict, dt: float) -> list[str]:
    """Did the node's loop keep real time?"""
    name = t["node"]
    out = []
    elapsed, covered, ticks = t.get("elapsed_s", 0.0), t.get("covered_s", 0.0), t.get("ticks", 0)
    if elapsed > 0 and covered < MIN_COVERED * elapsed:
        out.append(
            f"node {name!r} simulated {covered:.3f} s in {elapsed:.3f} s of wall time "
            f"(fell behind real time; at least {MIN_COVERED:.0%} needed)"
        )
    limits = [a for a in (t.get("max_age_s") or {}).values() if a is not None and math.isfinite(a)]
    late_limit = min(limits, default=default_max_age(dt))
    worst = t.get("worst_late_s", 0.0)
    if worst > late_limit:
        out.append(f"node {name!r}: a tick started {worst:.3f} s late (> {late_limit:g} s)")
    if ticks and t.get("deadline_misses", 0) > MAX_MISS_RATIO * ticks:
        out.append(
            f"node {name!r} missed {t['deadline_misses']} of {ticks} deadlines "
            f"({t['deadline_misses'] / ticks:.0%} > {MAX_MISS_RATIO:.0%})"
        )
    return out


def invalid_line(reasons: list[str]) -> str:
    return "INVALID: " + "; ".join(reasons)
