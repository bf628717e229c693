"""Error against run time, stiff and extreme cases, and lean scenes: what `dockhil report` computes.

Everything here returns plain JSON-ready dicts; the command writes them out
(report.json, report.md, PNG plots). Four parts:

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
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from dockhil.analysis.report_case import plain
from dockhil.analysis.report_cases import (
    hil_loop_cases,
    mass_ratio_cases,
    overdamped_cases,
    stiff_contact_cases,
    zero_damping_cases,
)
from dockhil.analysis.report_graph_cases import refusal_cases
from dockhil.analysis.report_loop_cases import delay_cases, negative_stiffness_cases, stability_boundary_cases
from dockhil.analysis.report_graph import graph_cost
from dockhil.analysis.report_precision import (
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


def reference_check(cfg: ReportConfig, ref) -> dict:
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


def build_report(cfg: ReportConfig | None = None, stream=None) -> dict:
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


# -- output ---------------------------------------------------------------------------------------------------


def _g(value, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:.{digits}g}"


def _md_table(header: list[str], rows: list[list]) -> str:
    def cell(v) -> str:
        return str(v).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def _cheapest(run: dict | None) -> str:
    if run is None:
        return "none"
    how = f"step {_g(run['step_s'])} s" if "step_s" in run else f"rtol {_g(run['rtol'])}"
    return f"{how}: {_g(run['max_error_N'])} N in {_g(run['run_time_s'])} s"


def render_markdown(report: dict, plots: dict[str, str]) -> str:
    cfg = report["config"]
    out = ["# dockhil report", ""]
    out.append(
        f"Generated in {report['run_time_s']:.1f} s on {report['machine']['platform']}, Python "
        f"{report['machine']['python']}, {report['machine']['cpus']} CPUs"
        + (" (quick configuration)." if cfg["quick"] else ".")
    )
    repeats = (
        f"the fastest of repeated runs where a run takes under {cfg['min_timing_s']:g} s"
        if cfg["min_timing_s"] > 0
        else "single runs"
    )
    out.append(f"Run times are {repeats}; the machine may be shared, so compare orders of magnitude.")
    out += ["", "## Error against run time", ""]
    ref = report["reference"]
    out.append(
        "Ideal contact: Table 1 (m1 = 750 kg, m2 = 1e6 kg, kcs = 3000 N/m, bcs = 40 N s/m, v1 = 0.03 m/s); "
        "ideal_stiff: the same with kcs = 3e6 N/m (63 rad/s, contact 50 ms), where explicit methods reach"
        f" their stability limits; reference {ref['ideal']}. Hybrid loop: Table 1 with k = 1000 N/m and a 32 ms "
        f"robot delay, reference "
        f"{ref['hybrid_delay']}; {ref['hybrid_delay_check']}. Errors are the largest force error on the "
        f"{1 / ref['error_grid_s']:g} Hz grid ({ref['force_compared']}). Fixed-step runs of the hybrid loop are "
        "`simulate_hil`, the arithmetic every node of hil.yaml does; a step that does not divide 32 ms "
        "rounds the delay (noted). Order: the slope of log error against log step (against log rtol for "
        f"solve_ivp). Why every fixed-step method is first order on the delayed loop: {ref['first_order_why']}. "
        f"Self-comparisons: {ref['self_comparisons']}."
    )
    if "work_precision" in plots:
        out += ["", f"![work precision]({plots['work_precision']})"]
    out += [
        "",
        _md_table(
            ["model", "method", "runs", "refused", "best error [N]", "order", "cheapest run within 1 mN"],
            [
                [
                    r["model"],
                    r["method"],
                    r["runs"],
                    r["refused"] or "-",
                    _g(r["best_error_N"]),
                    _g(r["order"], 2),
                    _cheapest(r["cheapest_within_1mN"]),
                ]
                for r in report["work_precision_summary"]
            ],
        ),
    ]
    refusals: dict[tuple[str, str], list[dict]] = {}
    for e in report["work_precision"]:
        if "refused" in e:
            refusals.setdefault((e["model"], e["method"]), []).append(e)
    if refusals:
        out += ["", "Refused steps (outside the method's stability region):", ""]
        for (model, method), refused in refusals.items():
            steps = ", ".join(f"{e['step_s']:g}" for e in refused)
            out.append(f'- {model}, {method} at {steps} s: "{refused[0]["refused"]}"')
    out += [
        "",
        "<details><summary>every run</summary>",
        "",
        _md_table(
            ["model", "method", "step [s] / rtol", "max error [N]", "run time [s]", "exit error [s]", "note"],
            [
                [
                    e["model"],
                    e["method"],
                    _g(e.get("step_s", e.get("rtol"))),
                    _g(e["max_error_N"]),
                    _g(e["run_time_s"]),
                    _g(e.get("exit_error_s")),
                    "refused" if "refused" in e else (f"delay rounded to {e['delay_s']:g} s" if "delay_s" in e else ""),
                ]
                for e in report["work_precision"]
            ],
        ),
        "",
        "</details>",
    ]

    if "error" in report.get("graph_cost", {}):
        out += ["", "## The graph's cost", "", f"Not measured: {report['graph_cost']['error']}"]
    elif "graph_cost" in report:
        g = report["graph_cost"]
        out += [
            "",
            "## The graph's cost",
            "",
            f"{g['scene']}, {g['sim_time_s']:g} s simulated. The force error"
            " against the ideal contact is what the 32 ms delay does to the loop (the same in every mode), not"
            " numerical error.",
            "",
        ]
        out.append(
            _md_table(
                ["mode", "run time [s]", "real-time factor", "peak force [N]", "force error vs ideal [N]", "how"],
                [
                    [
                        m["mode"],
                        _g(m["run_time_s"]),
                        _g(m["real_time_factor"]),
                        _g(m.get("peak_force_N"), 6),
                        _g((m.get("error_vs_ideal") or {}).get("max_force_N")),
                        m["what"],
                    ]
                    for m in g["modes"]
                ],
            )
        )
        mp = next(m for m in g["modes"] if m["mode"] == "multiprocess")
        out += [
            "",
            f"- composed == library loop, bit for bit: {_g(g['composed_equals_library'])}",
            f"- multi-process == library loop, bit for bit: {_g(g['multiprocess_equals_library'])}"
            f" (trajectory {mp['trajectory']})",
            f"- multi-process start-up (a one-tick launch): {_g(mp.get('startup_s'))} s",
        ]

    e = report["energy_drift"]
    scn = e["scenario"]
    out += [
        "",
        "## Energy over a long run",
        "",
        f"Undamped contact kept closed (bilateral spring): m1 = {scn['m1']:g} kg, m2 = {scn['m2']:g} kg, "
        f"kcs = {scn['kcs']:g} N/m, period {scn['period_s']:.3g} s. {e['quantity']}.",
    ]
    if "energy_drift" in plots:
        out += ["", f"![energy drift]({plots['energy_drift']})"]
    out += [
        "",
        _md_table(
            ["method", "step [s] / rtol", "simulated [s]", "final drift", "largest error", "run time [s]"],
            [
                [
                    r["method"],
                    _g(r.get("step_s", r.get("rtol"))),
                    _g(r.get("t_end_s")),
                    _g(r.get("final_relative_drift")) if "refused" not in r else "refused: " + r["refused"],
                    _g(r.get("max_relative_error")),
                    _g(r.get("run_time_s")),
                ]
                for r in e["runs"]
            ],
        ),
    ]

    cases = report["stiff_cases"]
    passed = sum(c["passed"] for c in cases)
    out += [
        "",
        "## Stiff and extreme cases",
        "",
        f"{passed} of {len(cases)} passed. Each expectation is computed from the model (closed form, the "
        "integrators' stability limits, the delay equation's rightmost root), not written in.",
        "",
    ]
    out.append(
        _md_table(
            ["group", "case", "expected", "measured", "passed"],
            [[c["group"], c["name"], c["expected"], c["measured"], "yes" if c["passed"] else "**NO**"] for c in cases],
        )
    )

    if "passivity" in report:
        pas = report["passivity"]
        out += [
            "",
            "## Passivity compensation",
            "",
            "Table 1 at 1 kHz, without and with the passivity controller (`compensation:=passivity`, "
            f"max_damping {pas['max_damping_Ns_m']:g} N s/m), at delays up to half the contact: errors against "
            f"the ideal contact (restitution {pas['ideal_restitution']:.5g}), the energy the delay and the "
            "sampling made, and what was left in the loop. Compensated, the chaser feels the delay-free spring "
            "wherever the delay would make energy, so both errors stay at the sampled ideal contact's own. "
            "`bench/passivity.py` measures the rest (every delay to half the contact, Fig. 11, the Fig. 7 grid).",
        ]
        if "passivity" in plots:
            out += ["", f"![energy over a contact]({plots['passivity']})"]
        out += [
            "",
            _md_table(
                [
                    "delay [s]",
                    "compensation",
                    "exit velocity error [m/s]",
                    "peak force error [N]",
                    "restitution",
                    "energy made [J]",
                    "left [J]",
                    "saturated",
                ],
                [
                    [
                        _g(r["delay_s"]),
                        r["compensation"],
                        _g(r["exit_velocity_error_mps"]),
                        _g(r["peak_force_error_N"]),
                        _g(r["restitution"], 5),
                        _g(r["generated_J"]),
                        _g(r["net_generated_J"]),
                        ("yes" if r["saturated"] else "no") if r["compensation"] == "passivity" else "-",
                    ]
                    for r in pas["rows"]
                ],
            ),
        ]

    if "lean" in report:
        lean = report["lean"]
        out += [
            "",
            "## Lean scenes",
            "",
            "Each row is a fresh interpreter: import the node class, construct it, set it up and step it once"
            " (hardware drivers against absent devices: their setup fails after loading what it needs). Start-up"
            " is the wall time of the whole process, interpreter included; memory is the peak resident set.",
        ]
        if "lean" in plots:
            out += ["", f"![lean scenes]({plots['lean']})"]
        out += [
            "",
            _md_table(
                [
                    "what",
                    "start-up [s]",
                    "import [s]",
                    "setup + 1 step [s]",
                    "memory [MB]",
                    "loaded at import",
                    "loaded after setup",
                    "setup",
                ],
                [
                    [
                        r["node"],
                        _g(r.get("startup_s")),
                        _g(r.get("import_s")),
                        _g(r.get("setup_s")),
                        _g(r.get("rss_mb")),
                        ", ".join(r.get("after_import", [])) or "-",
                        ", ".join(r.get("after_setup", [])) or "-",
                        r.get("setup", "")[:90],
                    ]
                    for r in lean["rows"]
                ],
            ),
        ]
        out += [
            "",
            "Rule: no node imports " + ", ".join(lean["ruled"]) + " at import time; in setup only what it "
            "talks to ("
            + "; ".join(f"{k}: {', '.join(v) or 'none'}" for k, v in lean["allowed_at_setup"].items())
            + "; every other node: none).",
            "Violations: " + ("; ".join(lean["violations"]) if lean["violations"] else "none") + ".",
        ]
    return "\n".join(out) + "\n"


def write_plots(report: dict, out_dir: Path) -> dict[str, str]:
    """PNG figures next to report.md; returns name -> file name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    quick = report["config"]["quick"]

    def save(fig, name: str) -> None:
        # The quick configuration's figures skip the layout pass (measuring every tick label:
        # a third of the plotting time) and are drawn at a lower resolution.
        if not quick:
            fig.tight_layout()
        fig.savefig(out_dir / name, dpi=72 if quick else 110)
        plt.close(fig)

    plots = {}
    floor = 1e-16  # errors at round-off are drawn here on the log scale
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8))
    for ax, model, title in (
        (axes[0], "ideal", "ideal contact, Table 1 (closed form)"),
        (axes[1], "ideal_stiff", "ideal contact, kcs = 3e6 N/m (closed form)"),
        (axes[2], "hybrid_delay", "hybrid loop, 32 ms delay"),
    ):
        methods = []
        for e in report["work_precision"]:
            if e["model"] == model and e["method"] not in methods:
                methods.append(e["method"])
        for method in methods:
            pts = [
                (e["run_time_s"], max(e["max_error_N"], floor))
                for e in report["work_precision"]
                if e["model"] == model and e["method"] == method and e["max_error_N"] is not None
            ]
            if pts:
                style = "s--" if method.startswith("solve_ivp") else "o-"
                ax.loglog(*zip(*sorted(pts)), style, label=method, markersize=4)
        ax.set_xlabel("run time [s]")
        ax.set_ylabel("max force error [N]")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    save(fig, "work_precision.png")
    plots["work_precision"] = "work_precision.png"

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in report["energy_drift"]["runs"]:
        if "t" in r:
            ax.semilogy(r["t"][1:], np.maximum(np.abs(r["relative_error"][1:]), floor), label=r["method"])
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel("|E - E0| / E0")
    ax.set_title("energy of an undamped contact over a long run")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    save(fig, "energy_drift.png")
    plots["energy_drift"] = "energy_drift.png"

    if "passivity" in report:
        fig, ax = plt.subplots(figsize=(8, 4.5))
        for comp, c in report["passivity"]["energy_32ms"].items():
            (line,) = ax.plot(c["t"], c["generated_J"], label=f"{comp}: made by the delay and the sampling")
            if comp == "passivity":
                ax.plot(c["t"], c["net_generated_J"], "--", color=line.get_color(), label="passivity: left in the loop")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("energy [J]")
        ax.set_title("Table 1 contact, 32 ms robot delay")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        save(fig, "passivity.png")
        plots["passivity"] = "passivity.png"

    if "lean" in report:
        rows = [r for r in report["lean"]["rows"] if r.get("startup_s") is not None and "rss_mb" in r]
        fig, axes = plt.subplots(1, 2, figsize=(12, 0.35 * len(rows) + 1.5))
        names = [r["node"] for r in rows]
        axes[0].barh(names, [r["startup_s"] for r in rows])
        axes[0].set_xlabel("start-up [s]")
        axes[1].barh(names, [r["rss_mb"] for r in rows])
        axes[1].set_xlabel("peak resident memory [MB]")
        axes[1].set_yticklabels([])
        for ax in axes:
            ax.invert_yaxis()
            ax.grid(True, axis="x", alpha=0.3)
        save(fig, "lean.png")
        plots["lean"] = "lean.png"
    return plots
