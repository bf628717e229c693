"""The summary of a docking run: peak contact force, contact duration, exit velocity,
and, where the scene has an ideal reference, the same from the ideal model and the errors.

Works on per-tick arrays, so the same code summarizes a bag, a composed run's
taps, or the model library's own loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import msgs


@dataclass
class Samples:
    """Per-tick series: time [s], penetration p = x1 - x2 [m], its rate [m/s],
    compressive contact force on the chaser [N]."""

    t: np.ndarray
    p: np.ndarray
    pd: np.ndarray
    force: np.ndarray


def contact_metrics(s: Samples) -> dict:
    """peak_force_N, contact_duration_s, exit_velocity_mps of the first contact (None where absent)."""
    touching = (s.p > 0.0) | ((s.p == 0.0) & (s.pd > 0.0))
    out = {"peak_force_N": None, "contact_duration_s": None, "exit_velocity_mps": None, "contact_start_s": None}
    if not touching.any():
        return out
    i0 = int(np.argmax(touching))
    after = np.nonzero(~touching[i0:])[0]
    i1 = i0 + int(after[0]) if after.size else len(s.t)
    # Contact start and end at the zero crossings of p, interpolated between ticks.
    t_start = s.t[i0] if i0 == 0 or s.p[i0] == 0.0 else _crossing(s.t, s.p, i0 - 1)
    out["contact_start_s"] = float(t_start)
    if after.size and i1 - i0 <= 1:
        out["note"] = ("the contact lasted less than one sample: its peak force and duration are not "
                       "resolved at this rate")
        out["exit_velocity_mps"] = float(s.pd[i1])
        return out
    out["peak_force_N"] = float(np.max(s.force[i0:i1]))
    if after.size:
        out["contact_duration_s"] = float(_crossing(s.t, s.p, i1 - 1) - t_start)
        # In free flight the relative velocity no longer changes: the first sample after is the exit.
        out["exit_velocity_mps"] = float(s.pd[i1])
    return out


def _crossing(t, p, i) -> float:
    """Time where p crosses zero between ticks i and i+1 (linear)."""
    dp = p[i + 1] - p[i]
    return float(t[i] if dp == 0.0 else t[i] - p[i] * (t[i + 1] - t[i]) / dp)


def summarize(s: Samples, *, run_time_s: float | None = None, ideal: dict | None = None) -> dict:
    """The run summary; `ideal` holds the ideal model's peak_force_N, contact_duration_s,
    exit_velocity_mps and optionally its force series `force_N` on the same ticks."""
    sim_time = float(s.t[-1] - s.t[0]) if len(s.t) > 1 else 0.0
    out = {"run_time_s": run_time_s, "sim_time_s": sim_time,
           "real_time_factor": (sim_time / run_time_s) if run_time_s else None}
    metrics = contact_metrics(s)
    out.update({k: v for k, v in metrics.items() if k not in ("contact_start_s", "note")})
    if "note" in metrics:
        out["note"] = metrics["note"]
    if ideal is not None:
        ref = {k: ideal[k] for k in ("peak_force_N", "contact_duration_s", "exit_velocity_mps")}
        out["ideal"] = ref
        err = {k: (None if out[k] is None or ref[k] is None else out[k] - ref[k]) for k in ref}
        if "force_N" in ideal:
            n = min(len(ideal["force_N"]), len(s.force))
            err["max_force_N"] = float(np.max(np.abs(np.asarray(ideal["force_N"][:n]) - s.force[:n])))
        out["error"] = {k: err.get(k) for k in ("peak_force_N", "max_force_N", "contact_duration_s",
                                                 "exit_velocity_mps")}
    return out


def ideal_reference(*, m1: float, m2: float, kcs: float, bcs: float, v1: float, v2: float,
                    t: np.ndarray, x1: float = 0.0, x2: float = 0.0) -> dict:
    """The ideal model's summary (closed form) and its force on the ticks t."""
    from dockhil.contact.ideal import ideal_contact_summary, ideal_trajectory
    from dockhil.contact.scenario import ContactScenario

    scn = ContactScenario(m1, m2, kcs, bcs, 0.0, v1, v2)
    cs = ideal_contact_summary(scn)
    traj = ideal_trajectory(scn, t, gap=max(0.0, x2 - x1))
    force = np.where(traj.in_contact, kcs * traj.penetration + bcs * traj.penetration_rate, 0.0)
    dur = cs.duration if math.isfinite(cs.duration) else None
    return {"peak_force_N": cs.peak_force, "contact_duration_s": dur,
            "exit_velocity_mps": cs.exit_relative_velocity if dur is not None else None, "force_N": force}


class Collector:
    """Gathers the per-tick series from published messages (a composed tap, or a bag).

    Time is simulated time: (tick - first tick) * dt when dt is known, else the
    stamps from the first state on. Forces are matched to each state by header
    stamp, taking the newest force at or before it: in sim time that is the
    force of the same tick (stamps are k dt everywhere), in wall time the one
    the dynamics would have seen."""

    def __init__(self, ideal_force: tuple[float, float] | None = None, dt: float | None = None):
        self.ideal_force = ideal_force  # (kcs, bcs) when the dynamics run the ideal model inside
        self.dt = dt
        self.state: list[tuple[float, int, float, float]] = []
        self.ft: list[tuple[float, float]] = []
        self.virtual: list[tuple[float, float]] = []

    def __call__(self, topic: str, msg) -> None:
        if isinstance(msg, msgs.SatelliteState) and len(msg.bodies) >= 2:
            c, g = msg.bodies[0], msg.bodies[1]
            self.state.append((msg.header.stamp, msg.header.tick, c.pose.position.x - g.pose.position.x,
                               c.twist.linear.x - g.twist.linear.x))
        elif topic == "/ft/wrench" and isinstance(msg, msgs.WrenchStamped):
            self.ft.append((msg.header.stamp, msg.wrench.force.x))
        elif topic == "/impedance/wrench" and isinstance(msg, msgs.BodyWrenches) and msg.wrenches:
            self.virtual.append((msg.header.stamp, msg.wrenches[0].force.x))

    @staticmethod
    def _at(series: list[tuple[float, float]], t: np.ndarray) -> np.ndarray:
        """The newest value at or before each time in t (0 before the first)."""
        if not series:
            return np.zeros_like(t)
        st, v = (np.array(x, dtype=float) for x in zip(*sorted(series)))
        i = np.searchsorted(st, t, side="right") - 1
        return np.where(i >= 0, v[np.clip(i, 0, None)], 0.0)

    def samples(self) -> Samples:
        if not self.state:
            return Samples(*(np.array([]),) * 4)
        stamp, tick, p, pd = (np.array(v, dtype=float) for v in zip(*sorted(self.state)))
        t = (tick - tick[0]) * self.dt if self.dt is not None else stamp - stamp[0]
        if self.ideal_force is not None:
            kcs, bcs = self.ideal_force
            touching = (p > 0.0) | ((p == 0.0) & (pd > 0.0))
            force = np.where(touching, kcs * p + bcs * pd, 0.0)
        else:
            # Compressive force on the chaser: minus (measured + virtual) force along +x.
            force = -(self._at(self.ft, stamp) + self._at(self.virtual, stamp))
        return Samples(t, p, pd, force)


def growth_rate(t: np.ndarray, y: np.ndarray) -> float:
    """Exponential growth rate [1/s] of an oscillation's envelope: a least-squares line
    through log |peaks| of y about its median (positive grows, negative settles)."""
    e = np.asarray(y, float) - np.median(y)
    a = np.abs(e)
    peaks = np.nonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:]))[0] + 1
    peaks = peaks[a[peaks] > 0.0]
    if peaks.size < 4:
        raise ValueError("fewer than 4 peaks: run longer to measure a growth rate")
    return float(np.polyfit(np.asarray(t, float)[peaks], np.log(a[peaks]), 1)[0])


def samples_from_bag(path: str, ideal_force: tuple[float, float] | None = None, dt: float | None = None) -> Samples:
    """Per-tick series of a recorded run, through the same Collector the live summary uses."""
    from dockhil.bag import BagReader

    collect = Collector(ideal_force, dt)
    with BagReader(path) as bag:
        for topic, _t, msg in bag.decoded(["/satellite/state", "/ft/wrench", "/impedance/wrench"]):
            collect(topic, msg)
    return collect.samples()


def _first(graph, type_name: str):
    return next((gn for gn in graph.nodes.values() if gn.type_name == type_name), None)


def scene_reference(graph) -> dict:
    """What the summary of this scene can be compared with, read from its nodes' parameters:
    `ideal_force` (kcs, bcs) when the dynamics run the ideal model, `ideal` (the ideal
    contact's parameters) for a free contact, `growth` (m, K, b, h) for a body pushed
    against a fixed sheet through a delay (Figs. 11-12)."""
    dyn = _first(graph, "satellite_dynamics")
    if dyn is None:
        return {}
    p = dyn.params
    out: dict = {}
    if p["model"] == "ideal":
        out["ideal_force"] = (p["kcs"], p["bcs"])
        kcs, bcs = p["kcs"], p["bcs"]
    else:
        imp = _first(graph, "virtual_impedance")
        kcs = bcs = None
        if imp is not None and imp.params["mode"] == "determine":
            kcs, bcs = imp.params["kcs"], imp.params["bcs"]
    free_contact = p["thrust"] == 0.0 and p["m2"] > 0.0 and p["v1"] > p["v2"]
    if kcs is not None and free_contact:
        out["ideal"] = dict(m1=p["m1"], m2=p["m2"], kcs=kcs, bcs=bcs, v1=p["v1"], v2=p["v2"], x1=p["x1"], x2=p["x2"])
    ft, imp, delay = _first(graph, "ft_sim"), _first(graph, "virtual_impedance"), _first(graph, "delay_injector")
    if p["m2"] == 0.0 and p["thrust"] != 0.0 and ft and imp and delay and imp.params["mode"] == "given":
        out["growth"] = dict(m=p["m1"], K=ft.params["k"], b=imp.params["b1"], h=delay.params["delay"])
    return out


def scene_summary(graph, s: Samples, run_time_s: float | None) -> dict:
    """The run summary of a scene, with its ideal reference or predicted growth where it has one."""
    ref = scene_reference(graph)
    ideal = None
    if "ideal" in ref and len(s.t):
        ideal = ideal_reference(t=s.t, **ref["ideal"])
    out = summarize(s, run_time_s=run_time_s, ideal=ideal)
    if "growth" in ref and len(s.t):
        from dockhil.contact.stability import growth_rate as predicted

        g = ref["growth"]
        try:
            out["growth_rate_1_s"] = growth_rate(s.t, s.p)
        except ValueError:
            out["growth_rate_1_s"] = None
        # The sampled loop holds forces over a step: on average half a step more delay.
        out["predicted_growth_rate_1_s"] = predicted(g["m"], g["K"], g["b"], g["h"] + graph.scene.dt / 2,
                                                     damper="undelayed")
    return out


def format_summary(out: dict) -> str:
    """A few readable lines of a summary."""
    def f(v, unit, fmt="{:.4g}"):
        return "-" if v is None else fmt.format(v) + f" {unit}"

    rtf = out.get("real_time_factor")
    lines = [f"simulated {f(out['sim_time_s'], 's')} in {f(out['run_time_s'], 's', '{:.2f}')}"
             + (f" ({rtf:.1f}x real time)" if rtf else "")]
    rows = [("peak force", "peak_force_N", "N"), ("contact duration", "contact_duration_s", "s"),
            ("exit velocity", "exit_velocity_mps", "m/s")]
    w = 16
    if "ideal" in out:
        lines.append(f"{'':18}{'run':>{w}}{'ideal':>{w}}{'error':>{w}}")
        for label, key, unit in rows:
            lines.append(f"{label:18}{f(out[key], unit):>{w}}{f(out['ideal'][key], unit):>{w}}"
                         f"{f(out['error'][key], unit):>{w}}")
        lines.append(f"{'max force error':18}{f(out['error']['max_force_N'], 'N'):>{w}}")
    else:
        for label, key, unit in rows:
            lines.append(f"{label:18}{f(out[key], unit):>{w}}")
    if "predicted_growth_rate_1_s" in out:
        lines.append(f"{'growth rate':18}{f(out['growth_rate_1_s'], '1/s'):>{w}}   "
                     f"predicted {f(out['predicted_growth_rate_1_s'], '1/s')} (rightmost root)")
    if "note" in out:
        lines.append(f"note: {out['note']}")
    return "\n".join(lines)
