"""`dockhil benchmark compensation`: every delay compensation on the same scenes against the ideal
contact, with the hardware as told and as a lab has it (dockhil.contact.compensation_grid): one JSON row
per run, the goals, a table, and the figures (error against omega h per method; the method map)."""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from typing import Any

from dockhil.errors import DockhilError

FAILURES_SHOWN = 5  # failed runs named in the summary and the table; rows.jsonl has them all


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = (
        "examples:\n"
        "  dockhil benchmark compensation --quick --out bench-comp/   # 2-3 min: 7 methods, 11 targets, omega h 0-0.5\n"
        "  dockhil benchmark compensation --full --out bench-comp/    # 13 omega h to 1.0, 9 hardware cases\n"
        "  dockhil benchmark compensation --full --workers 2 --out bench-comp/     # in 2 worker processes\n"
        "  dockhil benchmark compensation --full --dask tcp://host:8786 --out bench-comp/   # on a Dask cluster\n"
        "\n"
        "exit status: 0 every run gave its row, 1 some run failed (its row and the table say which),\n"
        "2 bad input (nothing ran), 130 interrupted (Ctrl-C: nothing written)\n"
        "\n"
        "see docs/compensation.md"
    )
    sub = parser.add_subparsers(dest="what", metavar="compensation", title="benchmarks")
    p = sub.add_parser(
        "compensation",
        help="delay compensation methods against the ideal contact, under what a lab does not know",
        description=__doc__,
        epilog=parser.epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    size = p.add_mutually_exclusive_group()
    size.add_argument(
        "--quick", action="store_true", help="6 omega h (0 to 0.5), the hardware as told and mismatched (default)"
    )
    size.add_argument(
        "--full",
        action="store_true",
        help="13 omega h (0 to 1.0) and each mismatch alone (-+30 %% k, -+20 %% delay, ...)",
    )
    p.add_argument("--out", metavar="DIR", default="benchmark-compensation", help="where rows, summary and figures go")
    p.add_argument("--scenes", nargs="+", metavar="NAME", help="only these scenes (table1, spring, push, offaxis6)")
    p.add_argument("--methods", nargs="+", metavar="NAME", help="only these methods (none is always run)")
    p.add_argument("--no-figures", action="store_true", help="leave out the PNGs")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object instead of the table")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="runs in N worker processes that end with this one (default: in this process); "
        "with --dask local: the LocalCluster's processes (default: the usable CPUs)",
    )
    p.add_argument(
        "--dask",
        metavar="ADDRESS|local",
        help="runs on a Dask distributed scheduler (tcp://host:8786), or 'local' for a LocalCluster",
    )


def run(args: argparse.Namespace) -> int:
    if getattr(args, "what", None) != "compensation":
        raise DockhilError("name the benchmark: dockhil benchmark compensation [--quick | --full]")
    from dockhil.contact import compensation_grid as grid
    from dockhil.contact.compensation import METHODS

    known = sorted({s.name for s in grid.scenes()} | {grid.OFFAXIS6.name})
    for name in args.scenes or []:
        if name not in known:
            raise DockhilError(f"--scenes: unknown scene {name!r}; the scenes are {', '.join(known)}")
    for name in args.methods or []:
        if name not in METHODS:
            raise DockhilError(f"--methods: unknown method {name!r}; the methods are {', '.join(METHODS)}")
    methods = None if args.methods is None else sorted({"none", *args.methods}, key=METHODS.index)
    if args.workers is not None and not 1 <= args.workers <= 64:
        raise DockhilError(f"--workers must be between 1 and 64, got {args.workers}")
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise DockhilError(f"--out {args.out}: cannot make the directory ({exc.strerror or exc})") from None
    from dockhil.analysis.compensation_runs import make_executor, run_grid
    from dockhil.commands.stop_signal import StopOnSignal
    from dockhil.log import Log

    started, cpu = time.perf_counter(), time.process_time()
    progress = None
    executor = None
    signals = StopOnSignal()
    try:
        executor = make_executor(args.workers, args.dask)
        todo = grid.tasks(args.full, args.scenes, methods)
        if not args.quiet:
            from dockhil.progress import TaskProgress

            progress = TaskProgress(len(todo))
        rows = run_grid(todo, executor, None if progress is None else progress.step)
    except KeyboardInterrupt:
        if progress is not None:
            progress.stop()
        Log("dockhil benchmark:").info(
            f"{signals.what}; nothing written to {args.out}: rerun the command to start over"
        )
        return 128 + signals.number
    finally:
        if executor is not None:
            executor.close()
        signals.restore()
    if progress is not None:
        progress.finish()
    failed = [r for r in rows if r.get("failed")]
    summary: dict[str, Any] = {
        "grid": "full" if args.full else "quick",
        "runs": len(rows),
        "failed": len(failed),
        "failures": [r["error"] for r in failed[:FAILURES_SHOWN]],
        "wall_seconds": time.perf_counter() - started,
        "cpu_seconds": time.process_time() - cpu,  # this process's: with workers, not the workers'
        "executor": "this process" if executor is None else executor.name,
        "workers": 1 if executor is None else executor.workers,
        "goals": grid.GOALS,
        "goal_hardware": "mismatch: hw_k_scale 0.7, hw_delay_scale 1.2, ft_delay 2 ms, ft_noise 0.2 N",
        "goal_omega_h": grid.GOAL_OMEGA_H,
        "scenes": grid.goals(rows, "mismatch"),
        "scenes_as_told": grid.goals(rows, "as_told"),
        "best_map": {hw: grid.best_map(rows, hw) for hw in ("mismatch", "as_told")},
    }
    _write(os.path.join(args.out, "rows.jsonl"), "".join(json.dumps(_plain(r)) + "\n" for r in rows))
    _write(os.path.join(args.out, "summary.json"), json.dumps(_plain(summary), indent=1) + "\n")
    table = format_table(summary)
    _write(os.path.join(args.out, "table.txt"), table + "\n")
    if not args.no_figures:
        from dockhil.commands.benchmark_plots import error_figure, map_figure

        summary["figures"] = [
            error_figure(rows, os.path.join(args.out, "error_vs_omega_h.png")),
            map_figure(summary["best_map"], os.path.join(args.out, "method_map.png")),
        ]
    print(json.dumps(_plain(summary)) if args.json else table, flush=True)
    if failed:
        Log("dockhil benchmark:").error(
            f"{len(failed)} of {len(rows)} runs failed, the first: {failed[0]['error']} "
            f"(each failed row is in {os.path.join(args.out, 'rows.jsonl')})"
        )
        return 1
    return 0


def _write(path: str, text: str) -> None:
    try:
        with open(path, "w") as f:
            f.write(text)
    except OSError as exc:
        raise DockhilError(f"{path}: cannot write ({exc.strerror or exc})") from None


def _plain(value):
    """JSON has no infinity: inf becomes None, as elsewhere in dockhil's JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _cell(value: Any, fmt: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and not math.isfinite(value):
        return format("fail", ">" + fmt.rstrip("f%").split(".")[0])
    return format(value, fmt)


def format_table(summary: dict) -> str:
    """The worst errors for omega h up to 0.5 per scene and method, with the hardware mismatched and as told."""
    failed = summary.get("failed", 0)
    lines = [
        f"compensation benchmark ({summary['grid']}, {summary['runs']} runs"
        + (f", {failed} failed" if failed else "")
        + f", {summary['wall_seconds']:.0f} s): "
        f"worst errors for omega h <= {summary['goal_omega_h']:g}; goals |e| <= 0.02, |F|, |impulse| <= 5 %, "
        f"energy residual <= 2 %, growth over 10 periods <= 2 %"
    ]
    for error in summary.get("failures", []):
        lines.append(f"  failed: {error}")
    if failed > len(summary.get("failures", [])):
        lines.append(f"  and {failed - len(summary['failures'])} more failed (rows.jsonl: their rows say why)")
    for key, title in (("scenes", summary["goal_hardware"]), ("scenes_as_told", "hardware as told")):
        lines.append("")
        lines.append(title)
        head = (
            f"  {'method':22s} {'|e err|':>8s} {'|F err|':>8s} {'|imp err|':>9s} {'|E res|':>8s} {'growth':>8s}  goals"
        )
        for scene, r in summary[key].items():
            ratio = r["restitution_error_ratio_none_over_best_at_0.16"]
            lines.append(
                f" {scene}: best {r['best']} ({'meets every goal' if r['best_meets_all'] else 'misses a goal'})"
                + ("" if ratio is None else f"; |e err| none / best at omega h 0.16: {ratio:.3g}")
            )
            lines.append(head)
            for method, m in r["methods"].items():
                w = m["worst"]
                missed = ", ".join(k for k, ok in m["meets"].items() if not ok)
                lines.append(
                    f"  {method:22s} {_cell(w['restitution_error'], '8.4f')} {_cell(w['peak_force_error'], '8.2%')} "
                    f"{_cell(w['impulse_error'], '9.2%')} {_cell(w['energy_residual'], '8.4f')} "
                    f"{_cell(w['growth_10'], '8.4f')}  {'all' if m['all_met'] else 'no: ' + missed}"
                )
    return "\n".join(lines)
