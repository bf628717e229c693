"""`dockhil report [--out DIR] [--quick]`: error against run time, stiff and extreme
cases, lean scenes; writes report.json, report.md and PNG plots."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from dockhil.errors import DockhilError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Measure the contact model and the graph: maximum force error against run time for every"
        " integrator and solve_ivp method (ideal contact and the hybrid loop with 32 ms delay), the"
        " graph's cost (library loop, composed, multi-process), energy drift over a long run, a"
        " suite of stiff and extreme cases with computed expectations, and each node type's"
        " start-up time, memory and heavy imports. A few minutes on two cores."
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        default="report",
        help="directory for report.json, report.md and the PNG plots (default: ./report)",
    )
    parser.add_argument(
        "--no-lean", action="store_true", help="skip the lean-scene measurement (one interpreter per node type)"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a small configuration (fewer steps and tolerances, shorter runs): seconds, for tests",
    )


def run(args: argparse.Namespace) -> int:
    from dockhil.analysis.report import compute as report
    from dockhil.analysis.report import markdown as report_markdown
    from dockhil.analysis.report import plots as report_plots

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise DockhilError(f"--out {out}: exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".dockhil-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise DockhilError(f"--out {out}: cannot write there: {exc.strerror or exc}") from None
    cfg = report.ReportConfig.quick_config() if args.quick else report.ReportConfig()
    if args.no_lean:
        import dataclasses

        cfg = dataclasses.replace(cfg, lean=False)
    data = report.build_report(cfg)
    plots = report_plots.write_plots(data, out)
    data["plots"] = plots
    (out / "report.json").write_text(json.dumps(data, indent=1, allow_nan=False) + "\n")
    (out / "report.md").write_text(report_markdown.render_markdown(data, plots))
    cases = data["stiff_cases"]
    failed = [c for c in cases if not c["passed"]]
    print(f"wrote {out / 'report.json'}, {out / 'report.md'} and {len(plots)} plots")
    print(
        f"stiff cases: {len(cases) - len(failed)} of {len(cases)} passed"
        + "".join(
            f"\n  not passed: {c['group']}: {c['name']}: expected {c['expected']}, measured {c['measured']}"
            for c in failed
        )
    )
    return 0
