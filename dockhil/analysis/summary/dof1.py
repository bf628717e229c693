"""The run summary of a 1-DOF docking scene: peak contact force, contact duration, entry and exit
velocity, coefficient of restitution, and, where the scene has an ideal reference, the same from
the ideal model and the errors; for a body held against a sheet, the growth rate of its oscillation.

One pass over the ticks with O(1) memory (common.ContactMeter): the live summary of a composed run
(`SummaryCollector1`, a tap), a recorded bag, or arrays of the model library's own loop
(`contact_metrics`, `summarize`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from dockhil import msgs
from dockhil.analysis.scenecheck import first_node, scene_check
from dockhil.analysis.summary.common import (
    ContactMeter,
    RangeMeter,
    Samples,
    TickMatcher,
    bag_messages,
    force_band,
    ideal_force_at,
    range_summary,
)

if TYPE_CHECKING:
    from dockhil.contact.envelope import EnvelopeFit
    from dockhil.contact.passivity import EnergyMeter
    from dockhil.scene.graph import Graph


def _feed(meter: ContactMeter, s: Samples) -> ContactMeter:
    acting = (s.force != 0.0) if s.acting is None else s.acting
    for row in zip(s.t.tolist(), s.p.tolist(), s.pd.tolist(), s.force.tolist(), np.asarray(acting).tolist()):
        meter.add(*row)
    return meter


def contact_metrics(s: Samples) -> dict:
    """peak_force_N, contact_duration_s, entry/exit_velocity_mps, restitution of the first contact
    (None where absent)."""
    return _feed(ContactMeter(), s).result()


def summarize(s: Samples, *, run_time_s: float | None = None, ideal: dict | None = None) -> dict:
    """The run summary of per-tick arrays; `ideal` holds the ideal model's peak_force_N,
    contact_duration_s, exit_velocity_mps and optionally its force series `force_N` on the same ticks."""
    meter = _feed(ContactMeter(), s)
    max_err = None
    if ideal is not None and "force_N" in ideal:
        n = min(len(ideal["force_N"]), len(s.force))
        max_err = float(np.max(np.abs(np.asarray(ideal["force_N"][:n]) - s.force[:n]))) if n else None
    return _summary(meter, run_time_s, ideal, max_err)


_COMPARED = ("peak_force_N", "contact_duration_s", "exit_velocity_mps", "restitution")


def _summary(meter: ContactMeter, run_time_s: float | None, ideal: dict | None, max_err: float | None) -> dict:
    # Both times are set once a tick came.
    sim_time = float(cast(float, meter.t_last) - cast(float, meter.t_first)) if meter.n > 1 else 0.0
    out: dict[str, Any] = {
        "run_time_s": run_time_s,
        "sim_time_s": sim_time,
        "real_time_factor": (sim_time / run_time_s) if run_time_s else None,
    }
    metrics = meter.result()
    out.update({k: v for k, v in metrics.items() if k not in ("contact_start_s", "note")})
    if "note" in metrics:
        out["note"] = metrics["note"]
    if ideal is not None:
        ref = {k: ideal.get(k) for k in _COMPARED}
        out["ideal"] = ref
        err = {k: (None if out[k] is None or ref[k] is None else out[k] - ref[k]) for k in ref}
        if meter.state == "in" or meter.samples_in <= 1:  # the peak so far, or of no resolved contact: no error
            err["peak_force_N"] = None
        err["max_force_N"] = max_err
        out["error"] = {
            k: err.get(k)
            for k in ("peak_force_N", "max_force_N", "contact_duration_s", "exit_velocity_mps", "restitution")
        }
    return out


def ideal_summary(
    *, m1: float, m2: float, kcs: float, bcs: float, v1: float, v2: float, x1: float = 0.0, x2: float = 0.0
) -> dict:
    """The ideal model's peak_force_N, contact_duration_s, exit_velocity_mps, restitution (closed form)."""
    from dockhil.contact.ideal import ideal_contact_summary
    from dockhil.contact.scenario import ContactScenario

    cs = ideal_contact_summary(ContactScenario(m1, m2, kcs, bcs, 0.0, v1, v2))
    dur = cs.duration if math.isfinite(cs.duration) else None
    return {
        "peak_force_N": cs.peak_force,
        "contact_duration_s": dur,
        "exit_velocity_mps": cs.exit_relative_velocity if dur is not None else None,
        "restitution": cs.restitution if dur is not None else None,
    }


def ideal_reference(
    *,
    m1: float,
    m2: float,
    kcs: float,
    bcs: float,
    v1: float,
    v2: float,
    t: np.ndarray,
    x1: float = 0.0,
    x2: float = 0.0,
) -> dict:
    """The ideal model's summary (closed form) and its force on the ticks t."""
    params = dict(m1=m1, m2=m2, kcs=kcs, bcs=bcs, v1=v1, v2=v2, x1=x1, x2=x2)
    out = ideal_summary(**params)
    out["force_N"] = ideal_force_at(params, np.asarray(t, float))
    return out


class Collector:
    """Gathers the per-tick series from published messages (a composed tap, or a bag), for
    plots and comparisons; the run summary itself streams (`SummaryCollector1`)."""

    def __init__(self, ideal_force: tuple[float, float] | None = None, dt: float | None = None):
        self.rows: list[tuple] = []
        self.match = TickMatcher(lambda *row: self.rows.append(row), ideal_force, dt)

    def __call__(self, topic: str, msg: object) -> None:
        self.match(topic, msg)

    def samples(self) -> Samples:
        self.match.flush()
        if not self.rows:
            return Samples(*(np.array([]),) * 4, np.array([], bool))
        t, p, pd, f, acting = (np.array(v) for v in zip(*self.rows))
        return Samples(t.astype(float), p.astype(float), pd.astype(float), f.astype(float), acting.astype(bool))


class SummaryCollector1:
    """The run summary of a 1-DOF scene, gathered from published messages in one pass with O(1) memory."""

    def __init__(self, graph: Graph):
        from dockhil.contact.passivity import EnergyMeter

        self.graph = graph
        ref = scene_reference(graph)
        growth = ref.get("growth")
        self.meter = ContactMeter(ideal=ref.get("ideal"), growth_about=None if growth is None else growth["about"])
        self.match = TickMatcher(
            self.meter.add, ref.get("ideal_force"), graph.scene.dt, expect=graph.publishers, band=force_band(graph)
        )
        self.energy = EnergyMeter()
        self.ranges = RangeMeter()

    def __call__(self, topic: str, msg: object) -> None:
        if topic == "/energy" and isinstance(msg, msgs.Energy):
            self.energy.add(msg)
            return
        if isinstance(msg, msgs.SatelliteState):
            self.ranges(msg)
        self.match(topic, msg)

    def summary(self, run_time_s: float | None = None) -> dict:
        self.match.flush()
        out = scene_summary(self.graph, self.meter, run_time_s)
        energy_summary(out, self.graph, self.energy)
        range_summary(out, self.graph, self.ranges, self.meter.largest if self.meter.n else None)
        return out


def energy_summary(out: dict, graph: Graph, meter: EnergyMeter) -> None:
    """Add the run's energy account (`energy`) to a summary; a passivity controller that left
    energy in the loop marks the run invalid."""
    if meter.last is None:
        return
    e = meter.last
    out.setdefault("valid", True)
    out.setdefault("invalid_reasons", [])
    out["energy"] = {
        "generated_J": e.generated_J,
        "compensation_dissipated_J": e.compensation_dissipated_J,
        "net_generated_J": e.net_generated_J,
        "virtual_dissipated_J": e.virtual_dissipated_J,
        "port_work_J": e.port_work_J,
    }
    imp = first_node(graph, "virtual_impedance")
    if imp is None or imp.params["compensation"] != "passivity":
        out["energy"]["compensation"] = "none"
        return
    max_damping = imp.params["max_damping"]
    line = meter.saturation(max_damping)
    left = meter.residual()
    out["energy"].update(
        compensation="passivity",
        max_damping_Ns_m=max_damping,
        ticks_at_max_damping=meter.ticks_at_max,
        saturated=line is not None,
        left_in_loop_J=left if math.isfinite(left) else None,
    )
    if line is not None:
        out["valid"] = False
        out["invalid_reasons"].append(line)


def samples_from_bag(path: str, ideal_force: tuple[float, float] | None = None, dt: float | None = None) -> Samples:
    """Per-tick series of a recorded run (for plots), through the same matching the live summary uses."""
    collect = Collector(ideal_force, dt)
    for topic, _t, msg in bag_messages(path):
        collect(topic, msg)
    return collect.samples()


def scene_reference(graph: Graph) -> dict:
    """What the summary of this scene can be compared with, read from its nodes' parameters:
    `ideal_force` (kcs, bcs) when the dynamics run the ideal model, `ideal` (the ideal
    contact's parameters) for a free contact, `growth` (m, K, b, h, about) for a body pushed
    against a fixed sheet through a delay (Figs. 11-12); `about` is its equilibrium."""
    dyn = first_node(graph, "satellite_dynamics")
    if dyn is None:
        return {}
    p = dyn.params
    out: dict = {}
    if p["model"] == "ideal":
        out["ideal_force"] = (p["kcs"], p["bcs"])
        kcs, bcs = p["kcs"], p["bcs"]
    else:
        imp = first_node(graph, "virtual_impedance")
        kcs = bcs = None
        # A Hunt-Crossley target has no closed form here: no ideal to compare with (dockhil benchmark
        # compensation compares it with its integrated ideal).
        if imp is not None and imp.params["mode"] == "determine" and imp.params.get("contact", "linear") == "linear":
            kcs, bcs = imp.params["kcs"], imp.params["bcs"]
    free_contact = p["thrust"] == 0.0 and p["m2"] > 0.0 and p["v1"] > p["v2"]
    if kcs is not None and free_contact:
        out["ideal"] = dict(m1=p["m1"], m2=p["m2"], kcs=kcs, bcs=bcs, v1=p["v1"], v2=p["v2"], x1=p["x1"], x2=p["x2"])
    ft, imp, delay = (
        first_node(graph, "ft_sim"),
        first_node(graph, "virtual_impedance"),
        first_node(graph, "delay_injector"),
    )
    if p["m2"] == 0.0 and p["thrust"] != 0.0 and ft and imp and delay and imp.params["mode"] == "given":
        K = ft.params["k"]
        out["growth"] = dict(
            m=p["m1"], K=K, b=imp.params["b1"], h=delay.params["delay"], about=(p["thrust"] / K) if K > 0.0 else 0.0
        )
    return out


def scene_summary(graph: Graph, s: Samples | ContactMeter, run_time_s: float | None) -> dict:
    """The run summary of a scene (per-tick `Samples`, or a fed `ContactMeter`), with its ideal
    reference or growth rate where it has one, and the check of its sampled loop."""
    ref = scene_reference(graph)
    growth = ref.get("growth")
    if isinstance(s, Samples):
        meter = _feed(ContactMeter(ideal=ref.get("ideal"), growth_about=None if growth is None else growth["about"]), s)
    else:
        meter = s
    ideal = ideal_summary(**ref["ideal"]) if "ideal" in ref and meter.n else None
    out = _summary(meter, run_time_s, ideal, meter.max_force_error() if ideal is not None else None)
    dyn = first_node(graph, "satellite_dynamics")
    if dyn is None:  # no 1-DOF dynamics (the 6-DOF scene): its CoM x is not the contact axis
        out.update(
            dict.fromkeys(
                ("peak_force_N", "contact_duration_s", "entry_velocity_mps", "exit_velocity_mps", "restitution")
            )
        )
        out["note"] = (
            "only the run and simulated times are summarised: the contact numbers are those of a 1-DOF "
            "scene; `dockhil plot` draws a 6-DOF bag"
        )
    elif dyn.params["thrust"] != 0.0:
        out["restitution"] = None  # pushed by thrust, the body's exit is not a rebound
    check = scene_check(graph, refuse=False)
    if growth is not None and meter.n:
        try:
            out["growth_rate_1_s"] = cast("EnvelopeFit", meter.growth).rate()  # made with the scene's growth
        except ValueError:
            out["growth_rate_1_s"] = None
        # The loop the graph runs: its dominant eigenvalue, ln|z| / dt; and the delay equation's root.
        out["predicted_growth_rate_1_s"] = check["loop"].get("sampled_growth_rate_1_s")
        out["delay_equation_growth_rate_1_s"] = check["loop"].get("continuous_growth_rate_1_s")
    out["loop"] = check["loop"]
    out["warnings"] = check["warnings"]
    return out


def format_summary1(out: dict) -> str:
    """A few readable lines of a 1-DOF summary."""

    def f(v, unit, fmt="{:.4g}"):
        return "-" if v is None else fmt.format(v) + f" {unit}"

    rtf = out.get("real_time_factor")
    lines = [
        f"simulated {f(out['sim_time_s'], 's')}"
        + ("" if out["run_time_s"] is None else f" in {out['run_time_s']:.2f} s")  # a bag analyzed: not known
        + (f" ({rtf:.1f}x real time)" if rtf else "")
    ]
    rows = [
        ("peak force", "peak_force_N", "N"),
        ("contact duration", "contact_duration_s", "s"),
        ("exit velocity", "exit_velocity_mps", "m/s"),
        ("restitution", "restitution", ""),
    ]
    w = 16
    if "ideal" in out:
        lines.append(f"{'':18}{'run':>{w}}{'ideal':>{w}}{'error':>{w}}")
        for label, key, unit in rows:
            lines.append(
                f"{label:18}{f(out[key], unit):>{w}}{f(out['ideal'][key], unit):>{w}}{f(out['error'][key], unit):>{w}}"
            )
        lines.append(f"{'max force error':18}{f(out['error']['max_force_N'], 'N'):>{w}}")
    else:
        for label, key, unit in rows:
            lines.append(f"{label:18}{f(out.get(key), unit):>{w}}")
    if "predicted_growth_rate_1_s" in out:
        compensated = (out.get("energy") or {}).get("compensation") == "passivity"
        lines.append(
            f"{'growth rate':18}{f(out['growth_rate_1_s'], '1/s'):>{w}}   "
            f"predicted {f(out['predicted_growth_rate_1_s'], '1/s')} (sampled loop's dominant root"
            + (", without the compensation)" if compensated else ")")
        )
    loop = out.get("loop") or {}
    if loop:
        per = next((k for k in loop if k.startswith("samples_per_")), None)
        lines.append(
            f"{'sampled loop':18}{loop['rate_Hz']:g} Hz, omega*dt {loop['omega_dt']:.3g}"
            + (f", {loop[per]:.4g} {per.replace('_', ' ')}" if per and loop[per] is not None else "")
            + f", spectral radius {loop['spectral_radius']:.9g}"
            + (f" ({loop['note']})" if "note" in loop else "")
        )
    energy = out.get("energy")
    if energy:
        taken = (
            f", compensation took {energy['compensation_dissipated_J']:.4g} J, net {energy['net_generated_J']:.4g} J"
            if energy["compensation"] == "passivity"
            else ""
        )
        lines.append(f"{'energy made':18}{f(energy['generated_J'], 'J'):>{w}}   by the delay and the sampling{taken}")
    if "note" in out:
        lines.append(f"note: {out['note']}")
    return "\n".join(lines)  # an invalid run's one INVALID line follows the table (dockhil.session)
