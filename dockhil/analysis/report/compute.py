"""Error against run time, stiff and extreme cases, and lean scenes: what `dockhil report` computes.

Everything here returns plain JSON-ready dicts; the command writes them out
(report.json; report.md by `dockhil.analysis.report.markdown`, the PNG plots by
`dockhil.analysis.report.plots`). Four parts:

* work precision: the ideal contact (closed form known) and the hybrid loop
  with a 32 ms robot delay, every fixed-step integrator over step sizes and
  scipy's solve_ivp over tolerances: maximum force error against run time;
* the graph's cost: hil.yaml as the model library's loop, composed in one
  process, and as separate processes;
* energy drift of an undamped contact over a long run, per integrator;
* stiff and extreme cases, each with an expectation computed from the
  model (closed form, stability analysis, the integrators' stability limits);
* lean scenes: per node type, start-up time, memory and heavy imports
  (measured in `dockhil.analysis.leanness`).

The reference of the delayed hybrid loop is the continuous delay system the
sampled loop converges to as the step shrinks, solved by an independent
method-of-steps solver (`dockhil.contact.delayref`: RK4 written out on the
scalar equation, Hermite history, located events, the delay's breakpoints)
that shares no code with any measured method; it is cross-checked against
itself at half the step and against solve_ivp DOP853 at rtol 1e-13 (the quick
configuration: twice the step, rtol 1e-10). A fine
fixed-step run is not used as the reference because the sampled loop holds
forces over a step and so converges only at first order, whatever its
integrator: even at 1e-5 s it is ~1e-3 N off. The report states each
method's observed order.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict
from typing import TYPE_CHECKING, TextIO

import numpy as np

from dockhil.analysis.report.case import plain
from dockhil.analysis.report.cases import (
    hil_loop_cases,
    mass_ratio_cases,
    overdamped_cases,
    stiff_contact_cases,
    zero_damping_cases,
)
from dockhil.analysis.report.graph import graph_cost
from dockhil.analysis.report.graph_cases import refusal_cases
from dockhil.analysis.report.loop_cases import delay_cases, negative_stiffness_cases, stability_boundary_cases
from dockhil.analysis.report.precision import (
    GRID,
    IDEAL_MODELS,
    REFERENCE_DT,
    ReportConfig,
    convergence_order,
    energy_run_fixed,
    energy_run_ivp,
    hybrid_fixed_step,
    hybrid_ivp,
    hybrid_reference,
    ideal_fixed_step,
    ideal_ivp,
    undamped_scenario,
)
from dockhil.contact.hilloop import simulate_hil
from dockhil.contact.impedance import impedance_closed_form
from dockhil.contact.integrators import (
    METHODS,
)
from dockhil.contact.passivity import DEFAULT_MAX_DAMPING
from dockhil.contact.scenario import (
    TABLE1,
)
from dockhil.errors import DockhilError
from dockhil.progress import TaskProgress

if TYPE_CHECKING:
    from dockhil.contact.delayref import DelayedContactReference

STIFF_GROUPS: tuple[tuple[str, Callable[[ReportConfig], list[dict]]], ...] = (
    ("kcs = 1e9 N/m against 1 kg", stiff_contact_cases),
    ("HIL loop: stiff and late contacts", hil_loop_cases),
    ("overdamped, time constant << step", overdamped_cases),
    ("zero damping", zero_damping_cases),
    ("mass ratios 1e-6 to 1e9", mass_ratio_cases),
    ("delay 0 and delay >> contact", delay_cases),
    ("kcs < k", negative_stiffness_cases),
    ("exact stability boundary", stability_boundary_cases),
    ("NaN, Inf, non-positive masses", refusal_cases),
)


# -- the whole report ---------------------------------------------------------------------------------------


def _count_tasks(cfg: ReportConfig) -> int:
    wp = (len(IDEAL_MODELS) + 1) * (len(METHODS) + len(cfg.ivp_methods)) + 1
    energy = len(METHODS) + len(cfg.ivp_methods)
    graph = 3 if cfg.graph else 0
    return wp + energy + graph + len(STIFF_GROUPS) + (1 if cfg.lean else 0)


def work_precision(cfg: ReportConfig, progress: TaskProgress) -> tuple[list[dict], dict]:
    import scipy.integrate  # noqa: F401  imported here so that no timed run pays for it

    entries: list[dict] = []
    for model in IDEAL_MODELS:
        for method in METHODS:
            progress.step(f"work precision: {model}, {method}")
            entries += [ideal_fixed_step(method, dt, cfg, model) for dt in cfg.steps]
        for method in cfg.ivp_methods:
            progress.step(f"work precision: {model}, solve_ivp {method}")
            entries += [ideal_ivp(method, rtol, cfg, model) for rtol in cfg.rtols]
    progress.step("work precision: delayed hybrid reference")
    ref = hybrid_reference(cfg)
    for method in METHODS:
        progress.step(f"work precision: hybrid 32 ms, {method}")
        entries += [hybrid_fixed_step(method, dt, cfg, ref) for dt in cfg.steps]
    for method in cfg.ivp_methods:
        progress.step(f"work precision: hybrid 32 ms, solve_ivp {method}")
        entries += [hybrid_ivp(method, rtol, cfg, ref) for rtol in cfg.rtols]
    reference = reference_check(cfg, ref)
    return [{k: plain(v) for k, v in e.items()} for e in entries], reference


def reference_check(cfg: ReportConfig, ref: DelayedContactReference) -> dict:
    """How the references were made, and how far the delayed one is trusted: the same solver at
    half the step, and solve_ivp DOP853 (a different method, different code) at rtol 1e-13. The
    quick configuration takes twice the step (a quarter of the work; the difference bounds the
    coarser run's error, which for RK4 is 16 times the reference's) and rtol 1e-10."""
    other_dt = REFERENCE_DT * (2.0 if cfg.quick else 0.5)
    other = hybrid_reference(cfg, dt=other_dt)
    grid = np.arange(int(round(cfg.contact_t_end / GRID)) + 1) * GRID
    step_check = float(np.max(np.abs(ref.sample(grid)["force"] - other.sample(grid)["force"])))
    dop = hybrid_ivp("DOP853", 1e-13 if not cfg.quick else 1e-10, cfg, ref)
    return {
        "ideal": "closed form of Eq. 1 (dockhil.contact.ideal_trajectory)",
        "hybrid_delay": "the continuous delay system that the sampled loop converges to as its step goes to 0,"
        f" solved by an independent method-of-steps solver (dockhil.contact.delayref: RK4 at steps"
        f" of at most {REFERENCE_DT:g} s, Hermite history, contact events located, the delay's"
        " breakpoints landed on), sharing no code with any measured method",
        "hybrid_delay_check": f"the same solver at {'twice' if cfg.quick else 'half'} the step agrees to "
        f"{step_check:.2g} N; solve_ivp DOP853 at rtol {dop['rtol']:g} agrees to "
        f"{dop['max_error_N']:.2g} N",
        "hybrid_delay_check_N": max(step_check, dop["max_error_N"]),
        "hybrid_delay_step_check_N": step_check,
        "hybrid_delay_step_check_dt_s": other_dt,
        "hybrid_delay_dop853_N": dop["max_error_N"],
        "self_comparisons": "none: every row is measured against a reference computed by other code (closed form,"
        " or the method-of-steps solver)",
        "first_order_why": "the sampled HIL loop holds each force over a step (zero-order hold), so it follows the"
        " delay equation with forces about dt/2 late: its error is O(dt) whatever integrator moves"
        " the bodies between ticks (exact, rk4, symplectic Euler and Euler show orders near 1 on"
        " the delayed loop); only solve_ivp, which integrates the delay equation itself, converges"
        " faster",
        "error_grid_s": GRID,
        "force_compared": "the contact law on both states wherever either run is in contact; how much earlier or later"
        " a run separates is exit_error_s",
    }


def work_precision_summary(entries: list[dict]) -> list[dict]:
    """Per model and method: best error, observed order, and the cheapest run within 1 mN."""
    rows = []
    keys = []
    for e in entries:
        key = (e["model"], e["method"])
        if key not in keys:
            keys.append(key)
    for model, method in keys:
        mine = [e for e in entries if e["model"] == model and e["method"] == method]
        ran = [e for e in mine if e.get("max_error_N") is not None]
        refused = [e for e in mine if "refused" in e]
        within = [e for e in ran if e["max_error_N"] <= 1e-3]
        cheapest = min(within, key=lambda e: e["run_time_s"]) if within else None
        rows.append(
            {
                "model": model,
                "method": method,
                "runs": len(ran),
                "refused": len(refused),
                "best_error_N": min((e["max_error_N"] for e in ran), default=None),
                "order": convergence_order(entries, model, method, "step_s" if "step_s" in mine[0] else "rtol"),
                "order_in": "step" if "step_s" in mine[0] else "rtol",
                "cheapest_within_1mN": None
                if cheapest is None
                else {
                    "step_s" if "step_s" in cheapest else "rtol": cheapest.get("step_s", cheapest.get("rtol")),
                    "max_error_N": cheapest["max_error_N"],
                    "run_time_s": cheapest["run_time_s"],
                },
                "largest_stable_step_s": refused[0].get("largest_stable_step_s") if refused else None,
            }
        )
    return rows


def energy_drift(cfg: ReportConfig, progress: TaskProgress) -> dict:
    scn = undamped_scenario()
    runs = []
    for method in METHODS:
        progress.step(f"energy drift: {method}")
        runs.append(energy_run_fixed(method, cfg.energy_dt, cfg.energy_t_end, scn))
    ivp_t_end = min(cfg.energy_t_end, cfg.energy_ivp_t_end)
    for method in cfg.ivp_methods:
        progress.step(f"energy drift: solve_ivp {method}")
        runs.append(energy_run_ivp(method, cfg.energy_ivp_rtol, ivp_t_end, scn))
    return {
        "scenario": {**scn.as_dict(), "bilateral": True, "period_s": 2 * math.pi / scn.natural_frequency},
        "quantity": "relative energy error (E - E0) / E0 of the relative motion, E = m pd^2 / 2 + kcs p^2 / 2",
        "runs": [{k: plain(v) if not isinstance(v, list) else v for k, v in r.items()} for r in runs],
    }


def stiff_cases(cfg: ReportConfig, progress: TaskProgress) -> list[dict]:
    cases = []
    for label, run in STIFF_GROUPS:
        progress.step(f"stiff cases: {label}")
        cases += run(cfg)
    return cases


def lean_scenes(cfg: ReportConfig, progress: TaskProgress) -> dict:
    from dockhil.analysis import leanness

    progress.step("lean scenes: one interpreter per node type")
    rows = leanness.measure_all(repeats=2 if not cfg.quick else 1)
    return {
        "rows": rows,
        "violations": leanness.violations(rows),
        "heavy": list(leanness.HEAVY),
        "ruled": list(leanness.RULED),
        "allowed_at_setup": {k: sorted(v) for k, v in leanness.ALLOWED_AT_SETUP.items()},
    }


PASSIVITY_DELAYS = (0.016, 0.032, 0.064, 0.1, 0.3, 0.785)  # [s] Table 1 with and without passivity compensation,
# up to half the contact
PASSIVITY_MAX_DAMPING = DEFAULT_MAX_DAMPING  # [N s/m] as the shipped scenes


def passivity_compensation() -> dict:
    """Table 1 at 1 kHz with and without the passivity controller: errors against the ideal contact,
    restitution, energy made and left; and the energy over the contact at 32 ms (every 10th tick)."""
    from dockhil.analysis.summary import Samples, contact_metrics, ideal_summary
    from dockhil.contact.passivity import Passivity, left_in_loop

    t = TABLE1
    ideal = ideal_summary(m1=t.m1, m2=t.m2, kcs=t.kcs, bcs=t.bcs, v1=t.v1, v2=t.v2)
    imp = impedance_closed_form(t, warn=False)
    rows, curves = [], {}
    for delay in PASSIVITY_DELAYS:
        for comp in ("none", "passivity"):
            pc = Passivity(t.k, PASSIVITY_MAX_DAMPING) if comp == "passivity" else None
            run = simulate_hil(
                m1=t.m1,
                m2=t.m2,
                k=t.k,
                impedance=imp,
                dt=1e-3,
                n_ticks=int((2.2 + 2.5 * delay) * 1e3),
                v1=t.v1,
                delay=delay,
                passivity=pc,
                energy=True,
            )
            m = contact_metrics(Samples(run.t, run.x1 - run.x2, run.v1 - run.v2, run.force))
            left, allowed = left_in_loop(run.extra)
            rows.append(
                {
                    "delay_s": delay,
                    "compensation": comp,
                    "exit_velocity_error_mps": m["exit_velocity_mps"] - ideal["exit_velocity_mps"],
                    "peak_force_error_N": m["peak_force_N"] - ideal["peak_force_N"],
                    "restitution": m["restitution"],
                    "generated_J": float(run.extra["generated_J"][-1]),
                    "net_generated_J": float(run.extra["net_generated_J"][-1]),
                    "saturated": bool(comp == "passivity" and left > allowed),
                }
            )
            if delay == 0.032:
                curves[comp] = {
                    "t": run.t[::10].tolist(),
                    "generated_J": run.extra["generated_J"][::10].tolist(),
                    "net_generated_J": run.extra["net_generated_J"][::10].tolist(),
                }
    return {
        "ideal_restitution": ideal["restitution"],
        "max_damping_Ns_m": PASSIVITY_MAX_DAMPING,
        "rows": rows,
        "energy_32ms": curves,
    }


def build_report(cfg: ReportConfig | None = None, stream: TextIO | None = None) -> dict:
    """Run everything; progress on `stream` (stderr by default)."""
    import platform

    cfg = cfg or ReportConfig()
    progress = TaskProgress(_count_tasks(cfg), stream)
    started = time.perf_counter()
    entries, reference = work_precision(cfg, progress)
    report = {
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()},
        "work_precision": entries,
        "work_precision_summary": work_precision_summary(entries),
        "reference": reference,
        "energy_drift": energy_drift(cfg, progress),
    }
    if cfg.graph:
        try:
            report["graph_cost"] = graph_cost(cfg, progress)
        except DockhilError as exc:  # the rest of the report stands without it
            report["graph_cost"] = {"error": str(exc)}
    report["stiff_cases"] = stiff_cases(cfg, progress)
    report["passivity"] = passivity_compensation()
    if cfg.lean:
        report["lean"] = lean_scenes(cfg, progress)
    report["run_time_s"] = time.perf_counter() - started
    progress.finish(f"done in {report['run_time_s']:.1f} s")
    return report
