"""report.md: the report's dict (`dockhil.analysis.report.compute.build_report`) written as markdown, with
the figures that `dockhil.analysis.report.plots` drew."""

from __future__ import annotations


def _g(value: object, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:.{digits}g}"


def _md_table(header: list[str], rows: list[list]) -> str:
    def cell(v: object) -> str:
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
