"""`dockhil stability`: how stiff a contact the robot's delay lets through
(paper Sec. 4: Eq. 12 and the exact boundary), `stability map`: Fig. 7, and `stability multi`: the
multi-axis delayed loop of a 6-DOF scene. Parse, call (dockhil.contact.stability_maps and the
analyses it names; the plots in dockhil.analysis.stability_plot) and print."""

from __future__ import annotations

import argparse
import json
import math
import time

from dockhil.contact.stability_maps import SECONDS
from dockhil.errors import DockhilError

_MAP_MULTIPLES = (1.0, 3.0, 10.0, 30.0, 100.0)  # and the map: wide, since only max_damping limits the compensated loop
_M_HELP = "free-floating mass [kg]: the reduced mass m1 m2 / (m1 + m2) of Eq. 8 (paper: 750)"
_DAMPER_HELP = (
    "where the virtual damper acts: 'delayed' (default, the paper's loop m s^2 + (K + b s) e^(-sh) = 0)"
    " or 'undelayed' (on the simulator's own velocity: m s^2 + b s + K e^(-sh) = 0)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = (
        "Largest contact stiffness K [N/m] that keeps the hardware-in-the-loop contact\n"
        "stable under the robot's response delay h: Eq. 12 (first-order Pade + Routh),\n"
        "0 < K < b (4m - 2bh) / (h (4m - bh)), and the exact bound of the delay\n"
        "equation. With --K, also whether that stiffness is stable and its growth rate\n"
        "(real part of the rightmost characteristic root, 1/s)."
    )
    parser.epilog = (
        "examples:\n"
        "  dockhil stability --m 750 --b 20 --h 0.016 --K 2510     # Fig. 11: unstable\n"
        "  dockhil stability --m 750 --b 60 --h 0.016 --K 2510     # Fig. 12: stable\n"
        "  dockhil stability --m 750 --b 20 --h 0.016 --K 2510 --compensation passivity   # measured, compensated\n"
        "  dockhil stability map --m 750 --png fig7.png             # Fig. 7\n"
        "  dockhil stability --m 749.4 --k-direct 2000 --b-direct 40 --k-delayed 1000 --h 0.032   # hil.yaml\n"
        "  dockhil stability --scene launch/hil.yaml delay:=0.1     # the same, read from the scene\n"
        "  dockhil stability map --m 749.4 --kcs 3000 --bcs 40 --png hybrid.png   # region over (k, h)\n"
        "run 'dockhil stability map --help' for the map's options"
    )
    parser.add_argument("--m", type=float, metavar="KG", help=_M_HELP)
    parser.add_argument("--b", type=float, metavar="NS_M", help="virtual damping b [N s/m] (paper: 20 and 60)")
    parser.add_argument("--h", type=float, metavar="S", help="robot response delay h [s], > 0 (EPOS: 0.016 to 0.032)")
    parser.add_argument(
        "--K", type=float, metavar="N_M", help="contact stiffness to check [N/m] (paper: 2510, the metal sheet)"
    )
    parser.add_argument("--damper", choices=("delayed", "undelayed"), default="delayed", help=_DAMPER_HELP)
    parser.add_argument(
        "--pade-order",
        type=int,
        metavar="N",
        help="also give the bound with an order-N Pade approximation of the delay (1 to 20)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    parser.add_argument(
        "--compensation",
        choices=("none", "passivity"),
        default="none",
        help="passivity: also measure (simulated, 30 s) the loop of stability.yaml with the passivity"
        " controller at 1, 2, 3, 5 and 10 times the exact bound (and at --K)",
    )
    parser.add_argument(
        "--max-damping",
        type=float,
        metavar="NS_M",
        help="the passivity controller's largest damping [N s/m] (default: the scenes', 1e5)",
    )
    hyb = parser.add_argument_group(
        "the hybrid loop",
        "m s^2 + b_d s + k_d + (k_h + b_h s) e^(-sh) = 0: the virtual impedance acts on the"
        " simulator's state (direct), the passive compliance through the robot (delayed); with any of these,"
        " --m is the reduced mass and --h the delay",
    )
    hyb.add_argument("--k-direct", type=float, metavar="N_M", help="undelayed stiffness k_d [N/m] (hil: kcs - k)")
    hyb.add_argument("--b-direct", type=float, metavar="NS_M", help="undelayed damping b_d [N s/m] (hil: bcs)")
    hyb.add_argument("--k-delayed", type=float, metavar="N_M", help="delayed stiffness k_h [N/m] (hil: k)")
    hyb.add_argument("--b-delayed", type=float, metavar="NS_M", help="delayed damping b_h [N s/m] (hil: 0)")
    hyb.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="also the sampled loop at this tick rate (forces held over a step; default 1000,"
        " a scene's own rate with --scene)",
    )
    hyb.add_argument(
        "--scene",
        nargs="+",
        metavar="FILE [NAME:=VALUE",
        help="read the loop from a launch file, with its launch arguments: --scene launch/hil.yaml delay:=0.1 ...]",
    )
    sub = parser.add_subparsers(dest="action", metavar="map | multi", title="subcommands")
    mp = sub.add_parser(
        "map",
        help="plot the critical stiffness surface K_max(b, h) (Fig. 7) to a PNG",
        description="Critical stiffness surface K_max(b, h) of Eq. 12 (the paper's Fig. 7) next to"
        " the exact bound, computed on a grid (vectorized) and saved as a PNG.",
    )
    # SUPPRESS: a value given before 'map' is not overwritten by the map's default.
    mp.add_argument("--m", type=float, metavar="KG", default=argparse.SUPPRESS, help=_M_HELP)
    mp.add_argument(
        "--b-range",
        type=float,
        nargs=2,
        metavar=("LO", "HI"),
        default=(10.0, 200.0),
        help="damping range [N s/m] (default 10 200, as in Fig. 7)",
    )
    mp.add_argument(
        "--h-range",
        type=float,
        nargs=2,
        metavar=("LO", "HI"),
        default=(0.016, 0.032),
        help="delay range [s] (default 0.016 0.032, as in Fig. 7)",
    )
    mp.add_argument("--n", type=int, metavar="N", help="grid points per axis (default 200; hybrid map 60)")
    mp.add_argument("--damper", choices=("delayed", "undelayed"), default=argparse.SUPPRESS, help=_DAMPER_HELP)
    mp.add_argument(
        "--kcs",
        type=float,
        metavar="N_M",
        help="hybrid map: the target contact stiffness; draws the"
        " hybrid loop's stable region over (passive k, delay h) beside Eq. 12's verdict",
    )
    mp.add_argument("--bcs", type=float, metavar="NS_M", help="hybrid map: the target contact damping")
    mp.add_argument(
        "--k-range",
        type=float,
        nargs=2,
        metavar=("LO", "HI"),
        help="hybrid map: passive stiffness range [N/m] (default 0 to 1.5 kcs)",
    )
    mp.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        default=1000.0,
        help="hybrid map: tick rate of the sampled loop drawn beside the exact one (default 1000)",
    )
    comp = mp.add_argument_group(
        "the compensated region",
        "with --compensation passivity, a third panel: over a coarse (b, h) grid, the"
        " largest stiffness (in multiples of the exact bound) at which stability.yaml's loop with the passivity"
        " controller, simulated, neither grows nor saturates",
    )
    comp.add_argument(
        "--compensation",
        choices=("none", "passivity"),
        default=argparse.SUPPRESS,
        help="passivity: also simulate the compensated loop over the grid (default none)",
    )
    comp.add_argument(
        "--max-damping",
        type=float,
        metavar="NS_M",
        default=argparse.SUPPRESS,
        help="the passivity controller's largest damping [N s/m] (default: the scenes', 1e5)",
    )
    comp.add_argument(
        "--sim-n",
        type=int,
        metavar="N",
        default=6,
        help="simulated grid points per axis (default 6; the cost grows as N^2 x multiples)",
    )
    comp.add_argument(
        "--multiples",
        type=float,
        nargs="+",
        metavar="X",
        default=list(_MAP_MULTIPLES),
        help="stiffnesses tried, in multiples of the exact bound (default 1 3 10 30 100)",
    )
    comp.add_argument(
        "--seconds",
        type=float,
        metavar="S",
        default=SECONDS,
        help=f"simulated time per point [s] (default {SECONDS:g})",
    )
    mp.add_argument("--png", metavar="FILE", required=True, help="where to write the figure (PNG)")
    mp.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help="print a JSON summary of the map")
    _add_multi_arguments(
        sub.add_parser(
            "multi", help="the multi-axis delayed loop (6-DOF scene or planar case): which axis limits the stiffness"
        )
    )


def _need(args, name: str, what: str) -> float:
    value = getattr(args, name, None)
    if value is None:
        raise DockhilError(f"missing --{name} ({what})")
    return value


# What the tool resolves: beyond these a value is a typo, and the numbers would overflow.
MAX_COEFF, MAX_DELAY, MAX_RATE = 1e12, 10.0, 1e7


def _mass(value: float) -> float:
    """--m within the range of docking hardware (dockhil/physical.py), as a scene's masses are."""
    from dockhil import physical
    from dockhil.contact.scenario import check_positive

    m = check_positive("--m", _within("--m", value, physical.MASS[1], "kg"), "kg")
    if m < physical.MASS[0]:
        raise DockhilError(
            f"--m {m:g} kg is below {physical.MASS[0]:g} kg, the range of docking hardware; give a physical mass"
        )
    return m


def _within(name: str, value: float, hi: float, unit: str) -> float:
    from dockhil.contact.scenario import check_finite

    check_finite(name, value, unit)
    if abs(value) > hi:
        raise DockhilError(f"{name} must be at most {hi:g}{' ' + unit if unit else ''} in size, got {value:g}")
    return value


def _loop_values(args) -> tuple[float, float, float]:
    from dockhil.contact.scenario import check_nonnegative

    m = _mass(_need(args, "m", "free-floating mass [kg]"))
    b = check_nonnegative(
        "--b", _within("--b", _need(args, "b", "virtual damping [N s/m]"), MAX_COEFF, "N s/m"), "N s/m"
    )
    h = check_nonnegative("--h", _within("--h", _need(args, "h", "robot delay [s]"), MAX_DELAY, "s"), "s")
    if h == 0.0:
        raise DockhilError("--h must be > 0 s: without delay every K > 0 is stable when b > 0")
    if args.K is not None:
        _within("--K", args.K, MAX_COEFF, "N/m")
    if args.pade_order is not None and not 1 <= args.pade_order <= 20:
        raise DockhilError(f"--pade-order must be between 1 and 20, got {args.pade_order}")
    return m, b, h


_HYBRID = ("k_direct", "b_direct", "k_delayed", "b_delayed")


def run(args: argparse.Namespace) -> int:
    if getattr(args, "action", None) == "map":
        return _run_map(args)
    if getattr(args, "action", None) == "multi":
        return _run_multi(args)
    if args.scene is not None or any(getattr(args, n) is not None for n in _HYBRID):
        if args.compensation == "passivity":
            raise DockhilError(
                "--compensation passivity measures stability.yaml's loop (--m, --b, --h); the hybrid "
                "loop (--scene, --k-direct ...) has no compensated measurement: leave one of them out"
            )
        return _run_hybrid(args)
    from dockhil.contact.stability import stability_report

    m, b, h = _loop_values(args)
    report = stability_report(m, b, h, K=args.K, damper=args.damper, pade_order=args.pade_order)
    if args.compensation == "passivity":
        from dockhil.contact.passivity import DEFAULT_MAX_DAMPING

        max_damping = DEFAULT_MAX_DAMPING if args.max_damping is None else args.max_damping
        if not (math.isfinite(max_damping) and max_damping > 0.0):
            raise DockhilError(f"--max-damping must be > 0 N s/m, got {max_damping:g}")
        from dockhil.contact.stability_maps import compensated_runs

        report["passivity"] = compensated_runs(m, b, h, args.K, max_damping)
    if args.json:
        print(json.dumps(report))
        return 0
    _print_report(report)
    if "passivity" in report:
        _print_compensated(report["passivity"])
    return 0


def _print_compensated(r: dict) -> None:
    print(f"with passivity compensation (max_damping {r['max_damping']:g} N s/m), measured on {r['loop']}:")
    for row in r["runs"]:
        if row["diverged"]:
            verdict = "diverged"
        elif row["growth_rate"] is None:
            verdict = "settled" if row.get("settled") else "too few peaks to fit a growth rate"
        else:
            verdict = f"growth rate {row['growth_rate']:+.4g} 1/s, {'decays' if row['growth_rate'] < 0 else 'GROWS'}"
        sat = ", SATURATED (energy left in the loop)" if row["saturated"] else ""
        print(f"  K = {row['K']:<10.6g} N/m ({row['label']}): {verdict}{sat}")
    largest = r["largest_decaying_K"]
    print(
        f"  largest K that decays without saturating: {_fmt(largest)} N/m"
        + ("" if largest is None or not r["exact_undelayed"] else f" ({largest / r['exact_undelayed']:.3g}x exact)")
    )


def _fmt(value: float | None) -> str:
    return "none" if value is None else f"{value:.6g}"


def _print_report(r: dict) -> None:
    equation = "m s^2 + (K + b s) e^(-sh) = 0" if r["damper"] == "delayed" else "m s^2 + b s + K e^(-sh) = 0"
    print(f"delayed contact loop ({r['damper']} damper): {equation}")
    print(f"  m = {r['m']:g} kg, b = {r['b']:g} N s/m, h = {r['h']:g} s   (b h / m = {r['beta']:.4g})")
    print(f"  {'bound':30} K_max [N/m]")
    label = "Eq. 12 (Pade 1 + Routh)" if r["damper"] == "delayed" else "Pade 1 + Routh"
    note = ""
    if "pade1_error" in r:
        note = f"   ({100 * r['pade1_error']:+.3g} % against exact)"
    print(f"  {label:30} {_fmt(r['pade1']):12}{note}")
    if "pade_order" in r:
        print(f"  {'Pade ' + str(r['pade_order']):30} {_fmt(r['pade_n'])}")
    print(f"  {'exact':30} {_fmt(r['exact'])}")
    print(f"  {r['reason']}")
    if "pade1_reason" in r:
        print(f"  Pade 1: {r['pade1_reason']}")
    if "K" in r:
        re_, im_ = r["rightmost_root"]
        verdict = "stable" if r["stable"] else "UNSTABLE"
        print(
            f"  K = {r['K']:g} N/m: {verdict}, growth rate {r['growth_rate']:+.4g} 1/s"
            f" (rightmost root {re_:.4g} {'+' if im_ >= 0 else '-'} {abs(im_):.4g}j 1/s)"
        )


def _range(name: str, pair, positive: bool, most: float = MAX_COEFF, unit: str = "") -> tuple[float, float]:
    lo = _within(f"{name} LO", pair[0], most, unit)
    hi = _within(f"{name} HI", pair[1], most, unit)
    if lo < 0.0 or (positive and lo <= 0.0):
        raise DockhilError(f"{name} LO must be {'> 0' if positive else '>= 0'}, got {lo:g}")
    if hi <= lo:
        raise DockhilError(f"{name} needs LO < HI, got {lo:g} {hi:g}")
    return lo, hi


def _run_map(args) -> int:
    import numpy as np

    from dockhil.contact.stability_maps import nan_extreme

    from dockhil.contact.stability import critical_stiffness_map

    if getattr(args, "m", None) is None:
        raise DockhilError("missing --m (free-floating mass [kg])")
    m = _mass(args.m)
    if args.kcs is not None or args.bcs is not None:
        if getattr(args, "compensation", "none") == "passivity":
            raise DockhilError(
                "--compensation passivity draws its region on the Fig. 7 map over (b, h); the hybrid "
                "map (--kcs, --bcs) has none: leave one of them out"
            )
        return _run_hybrid_map(args, m)
    b_lo, b_hi = _range("--b-range", args.b_range, positive=False, unit="N s/m")
    h_lo, h_hi = _range("--h-range", args.h_range, positive=True, most=MAX_DELAY, unit="s")
    args.n = 200 if args.n is None else args.n
    if not 2 <= args.n <= 2000:
        raise DockhilError(f"--n must be between 2 and 2000, got {args.n}")
    damper = getattr(args, "damper", "delayed")
    b = np.linspace(b_lo, b_hi, args.n)
    h = np.linspace(h_lo, h_hi, args.n)
    start = time.perf_counter()
    pade1 = critical_stiffness_map(m, b, h, "pade1", damper)
    exact = critical_stiffness_map(m, b, h, "exact", damper)
    compute_seconds = time.perf_counter() - start
    compensated = None
    if getattr(args, "compensation", "none") == "passivity":
        compensated = _compensated_region(m, (b_lo, b_hi), (h_lo, h_hi), args)
    from dockhil.analysis.stability_plot import plot_map

    plot_map(args.png, m, b, h, pade1, exact, damper, compensated)
    with np.errstate(invalid="ignore"):
        overestimate = (pade1 - exact) / exact
    summary = {
        "png": args.png,
        "m": m,
        "damper": damper,
        "grid": [args.n, args.n],
        "b_range": [b_lo, b_hi],
        "h_range": [h_lo, h_hi],
        "compute_seconds": compute_seconds,
        "pade1_min": nan_extreme(np.nanmin, pade1),
        "pade1_max": nan_extreme(np.nanmax, pade1),
        "exact_min": nan_extreme(np.nanmin, exact),
        "exact_max": nan_extreme(np.nanmax, exact),
        "max_pade1_overestimate": nan_extreme(np.nanmax, overestimate),
        "points_without_stable_K": int(np.sum(np.isnan(exact))),
    }
    if compensated is not None:
        summary["passivity"] = compensated
    if getattr(args, "json", False):
        print(json.dumps(summary))
    else:
        print(f"wrote {args.png}: K_max over {args.n} x {args.n} (b, h) points in {compute_seconds * 1e3:.1f} ms")
        print(f"  Eq. 12: {_fmt(summary['pade1_min'])} to {_fmt(summary['pade1_max'])} N/m")
        print(f"  exact:  {_fmt(summary['exact_min'])} to {_fmt(summary['exact_max'])} N/m")
        if summary["max_pade1_overestimate"] is not None:
            print(f"  Eq. 12 overestimates the exact bound by up to {100 * summary['max_pade1_overestimate']:.3g} %")
        if summary["points_without_stable_K"]:
            print(f"  {summary['points_without_stable_K']} grid points have no stabilizing K at all")
        if compensated is not None:
            _print_region(compensated)
    return 0


def _compensated_region(m: float, b_range, h_range, args) -> dict:
    """The compensated region of the map (dockhil.contact.compensated), its arguments checked first."""
    from dockhil.contact.passivity import DEFAULT_MAX_DAMPING
    from dockhil.contact.stability_maps import MAX_DELAY_TICKS, RATE, compensated_region
    from dockhil.progress import Progress

    max_damping = getattr(args, "max_damping", None)
    max_damping = DEFAULT_MAX_DAMPING if max_damping is None else max_damping
    if not (math.isfinite(max_damping) and max_damping > 0.0):
        raise DockhilError(f"--max-damping must be > 0 N s/m, got {max_damping:g}")
    if not 2 <= args.sim_n <= 40:
        raise DockhilError(f"--sim-n must be between 2 and 40, got {args.sim_n}")
    multiples = sorted(set(args.multiples))
    if not all(math.isfinite(x) and 0.0 < x <= 1000.0 for x in multiples) or len(multiples) > 20:
        raise DockhilError(
            f"--multiples must be 1 to 20 values in (0, 1000], got {' '.join(f'{x:g}' for x in args.multiples)}"
        )
    if not (math.isfinite(args.seconds) and 1.0 <= args.seconds <= 600.0):
        raise DockhilError(f"--seconds must be between 1 and 600 s, got {args.seconds:g}")
    if h_range[1] * RATE > MAX_DELAY_TICKS:
        raise DockhilError(
            f"--h-range reaches {h_range[1] * RATE:.0f} ticks of delay at {RATE:g} Hz: the simulated "
            f"sweep goes up to {MAX_DELAY_TICKS}"
        )
    return compensated_region(
        m,
        b_range,
        h_range,
        args.sim_n,
        multiples,
        max_damping,
        args.seconds,
        progress=Progress(int(round(args.seconds * RATE)) + 1, 1.0 / RATE),
    )


def _print_region(r: dict) -> None:
    flat = [x for row in r["largest_stable_multiple"] for x in row if x is not None]
    print(
        f"  with passivity compensation (max_damping {r['max_damping']:g} N s/m), simulated over {r['grid'][0]} x "
        f"{r['grid'][1]} (b, h) points at {', '.join(f'{x:g}' for x in r['multiples'])} x the exact bound "
        f"({r['points']} runs, {r['cpu_seconds']:.1f} s CPU):"
    )
    print(
        f"    stable (neither grows nor saturates) in {r['stable_points']} of {r['points']} runs; "
        f"{r['saturated_points']} saturated"
    )
    if flat:
        print(
            f"    largest stiffness stable at every point: {min(flat):g} x exact; at some point: {max(flat):g} x exact"
        )


def _scene_values(args) -> tuple[float, float, float, float, float, float, float]:
    """m, k_d, b_d, k_h, b_h, h, rate of a scene's loop, as the graph will run it."""
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build
    from dockhil.analysis.scenecheck import scene_loop

    given = [f"--{n.replace('_', '-')}" for n in ("m", "h", *_HYBRID) if getattr(args, n, None) is not None]
    if given:
        raise DockhilError(
            f"{given[0]} and --scene do not go together: the scene gives the loop; change it with "
            f"name:=value after the file"
        )
    path, *overrides = args.scene
    graph = build(launchfile.load(path, launchfile.parse_overrides(overrides)))
    info = scene_loop(graph)
    if info is None:
        raise DockhilError(f"{path}: no satellite_dynamics node, so no contact loop to analyse")
    if not info["loop"].held:
        raise DockhilError(f"{path}: the ideal model has no delay; its step is checked when it launches")
    if not info["delay_known"]:
        raise DockhilError(
            f"{path}: the robot's delay is the hardware's, which the scene does not give; "
            f"analyse the scene with its simulated robot at the measured delay (delay:=H), or "
            f"give it with --h and the loop's values"
        )
    return info["m"], info["kd"], info["bd"], info["kh"], info["bh"], info["h"], graph.scene.rate


def _hybrid_values(args) -> tuple[float, float, float, float, float, float, float]:
    from dockhil.contact.scenario import check_nonnegative, check_positive

    if args.scene is not None:
        m, kd, bd, kh, bh, h, rate = _scene_values(args)
        rate = rate if args.rate is None else args.rate
    else:
        m = _mass(_need(args, "m", "reduced mass [kg]"))
        h = check_nonnegative("--h", _within("--h", _need(args, "h", "robot delay [s]"), MAX_DELAY, "s"), "s")
        kd, bd, kh, bh = (
            _within(
                f"--{n.replace('_', '-')}", getattr(args, n) or 0.0, MAX_COEFF, "N/m" if n.startswith("k") else "N s/m"
            )
            for n in _HYBRID
        )
        rate = 1000.0 if args.rate is None else args.rate
    rate = check_positive("--rate", _within("--rate", rate, MAX_RATE, "Hz"), "Hz")
    from dockhil.contact.sampled import MAX_DELAY_TICKS

    if h * rate > MAX_DELAY_TICKS:
        raise DockhilError(
            f"--rate {rate:g} Hz with h = {h:g} s is {h * rate:.0f} ticks of delay; the sampled "
            f"loop is analysed up to {MAX_DELAY_TICKS} ticks: lower --rate"
        )
    if args.pade_order is not None and not 1 <= args.pade_order <= 20:
        raise DockhilError(f"--pade-order must be between 1 and 20, got {args.pade_order}")
    return m, kd, bd, kh, bh, h, rate


def _run_hybrid(args) -> int:
    from dockhil.contact.hybrid_stability import hybrid_report

    from dockhil.contact.sampled import RootsNotResolved

    m, kd, bd, kh, bh, h, rate = _hybrid_values(args)
    try:
        r = hybrid_report(m, kd, bd, kh, bh, h, rate=rate, pade_order=args.pade_order)
    except RootsNotResolved as exc:
        raise DockhilError(f"{exc}; give a lower --rate") from None
    if args.json:
        print(json.dumps(r))
        return 0
    print(f"hybrid contact loop: {r['equation']}")
    print(f"  m = {m:g} kg, k_d = {kd:g} N/m, b_d = {bd:g} N s/m, k_h = {kh:g} N/m, b_h = {bh:g} N s/m, h = {h:g} s")
    if not r["stable_without_delay"]:
        print("  unstable already without delay: m s^2 + (b_d + b_h) s + k_d + k_h has a root with Re >= 0")
    elif r["no_delay_destabilizes"]:
        print("  no delay destabilizes it: |k_d - m w^2 + j b_d w| > |k_h + j b_h w| at every frequency")
    else:
        print(
            f"  {'critical delay (exact)':30} {r['critical_delay']:.6g} s, oscillating at "
            f"{r['critical_frequency']:.6g} rad/s"
        )
        print(f"  {'critical delay (Pade 1)':30} {_fmt(r['pade1_critical_delay'])} s")
        if "pade_order" in r:
            print(f"  {'critical delay (Pade ' + str(r['pade_order']) + ')':30} {_fmt(r['pade_n_critical_delay'])} s")
    for c in r["crossings"]:
        print(
            f"  crossing s = j {c['omega']:.6g} rad/s at h = {c['h0']:.6g} s + n {2 * math.pi / c['omega']:.6g} s "
            f"({'destabilizing' if c['destabilizing'] else 'stabilizing'})"
        )
    re_, im_ = r["rightmost_root"]
    verdict = "stable" if r["stable"] else "UNSTABLE"
    print(f"  at h = {h:g} s: {verdict}, growth rate {re_:+.4g} 1/s (rightmost root {re_:.4g} + {im_:.4g}j 1/s)")
    print(
        f"  (were the whole contact delayed, as in Eq. 12's loop: growth rate {r['whole_delayed_growth_rate']:+.4g} 1/s)"
    )
    sm = r["sampled"]
    verdict = "stable" if sm["stable"] else "UNSTABLE"
    line = (
        f"  sampled at {sm['rate']:g} Hz ({sm['delay_ticks']} ticks of delay, forces held over a step): {verdict}, "
        f"spectral radius {sm['spectral_radius']:.9g}, growth rate {_fmt(sm['growth_rate'])} 1/s"
    )
    print(line)
    if "critical_delay_ticks" in sm:
        print(f"  sampled critical delay: {sm['critical_delay_ticks']} ticks ({sm['critical_delay']:.6g} s)")
    return 0


def _run_hybrid_map(args, m: float) -> int:
    """Stable region of the hybrid loop m s^2 + bcs s + (kcs - k) + k e^(-sh) over (k, h): exact (closed-form
    crossings) and sampled at --rate, beside Eq. 12's verdict on the paper's loop (the whole kcs delayed)."""
    import numpy as np

    from dockhil.contact.scenario import check_nonnegative, check_positive

    if args.kcs is None or args.bcs is None:
        raise DockhilError("the hybrid map needs both --kcs and --bcs (the target contact)")
    kcs = check_positive("--kcs", _within("--kcs", args.kcs, MAX_COEFF, "N/m"), "N/m")
    bcs = check_nonnegative("--bcs", _within("--bcs", args.bcs, MAX_COEFF, "N s/m"), "N s/m")
    rate = check_positive("--rate", _within("--rate", args.rate, MAX_RATE, "Hz"), "Hz")
    k_lo, k_hi = _range("--k-range", args.k_range or (0.0, 1.5 * kcs), positive=False, unit="N/m")
    h_given = args.h_range if tuple(args.h_range) != (0.016, 0.032) else (0.001, 0.1)
    h_lo, h_hi = _range("--h-range", h_given, positive=True, most=MAX_DELAY, unit="s")
    if h_hi * rate > 400:
        raise DockhilError(
            f"the map reaches {h_hi * rate:.0f} ticks of delay: narrow --h-range or lower --rate (at most 400 ticks)"
        )
    args.n = 60 if args.n is None else args.n
    if not 2 <= args.n <= 400:
        raise DockhilError(f"--n must be between 2 and 400 for the hybrid map, got {args.n}")
    from dockhil.contact.stability_maps import hybrid_map

    ks, hs = np.linspace(k_lo, k_hi, args.n), np.linspace(h_lo, h_hi, args.n)
    start = time.perf_counter()
    exact, sampled, eq12 = hybrid_map(m, kcs, bcs, rate, ks, hs)
    seconds = time.perf_counter() - start
    from dockhil.analysis.stability_plot import plot_hybrid

    plot_hybrid(args.png, m, kcs, bcs, rate, ks, hs, exact, sampled, eq12)
    summary = {
        "png": args.png,
        "m": m,
        "kcs": kcs,
        "bcs": bcs,
        "rate": rate,
        "grid": [args.n, args.n],
        "k_range": [k_lo, k_hi],
        "h_range": [h_lo, h_hi],
        "compute_seconds": seconds,
        "exact_stable_fraction": float(exact.mean()),
        "sampled_stable_fraction": float(sampled.mean()),
        "sampled_disagrees_fraction": float((exact != sampled).mean()),
        "eq12_stable_delays": float(eq12.mean()),
    }
    if getattr(args, "json", False):
        print(json.dumps(summary))
    else:
        print(f"wrote {args.png}: the hybrid loop over {args.n} x {args.n} (k, h) points in {seconds:.2f} s")
        print(
            f"  stable: {100 * summary['exact_stable_fraction']:.3g} % exact, "
            f"{100 * summary['sampled_stable_fraction']:.3g} % sampled at {rate:g} Hz; Eq. 12 (kcs wholly delayed) "
            f"calls {100 * summary['eq12_stable_delays']:.3g} % of the delays stable, whatever k"
        )
    return 0


# -- `dockhil stability multi`: the multi-axis delayed loop (dockhil.contact.stability6) ------------------

_MULTI_DOC = """The linearised 6-DOF hybrid loop det(M s^2 + B_d s + K_d + (B_h s + K_h) e^{-sh}) = 0 of a
6-DOF scene (read from its launch file, at its start configuration) or the paper's planar
case (normal x and rotation rz of a body touched off its CoM); prints the rightmost root and
the axis leading its mode, and the stiffness margin with the axis or mode that limits it."""


def _add_multi_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.description = _MULTI_DOC
    p.epilog = (
        "examples:\n"
        "  dockhil stability multi --scene launch/hil6.yaml delay:=0.016\n"
        "  dockhil stability multi --planar --m 750 --inertia 500 --lever 0.5 --k-normal 2510"
        " --b-normal 60 --k-rot 300 --b-rot 4 --h 0.016"
    )
    # SUPPRESS: names shared with `dockhil stability` keep a value given before 'multi'.
    p.add_argument(
        "--scene",
        nargs="+",
        metavar="FILE [NAME:=VALUE",
        default=argparse.SUPPRESS,
        help="a 6-DOF launch file (satellite_dynamics and virtual_impedance with dof: 6, a delay_injector)"
        " and its"
        " launch arguments ...]",
    )
    p.add_argument(
        "--planar",
        action="store_true",
        help="the 2-D case: --m --inertia --lever --k-normal --b-normal [--k-rot --b-rot --direct] --h",
    )
    p.add_argument("--m", type=float, metavar="KG", default=argparse.SUPPRESS, help="planar: body mass [kg]")
    p.add_argument("--inertia", type=float, metavar="KG_M2", help="planar: inertia about z [kg m^2]")
    p.add_argument("--lever", type=float, default=0.0, metavar="M", help="planar: contact point off the CoM [m]")
    p.add_argument("--k-normal", type=float, metavar="N_M", help="planar: normal stiffness [N/m]")
    p.add_argument("--b-normal", type=float, metavar="NS_M", help="planar: normal damping [N s/m]")
    p.add_argument("--k-rot", type=float, default=0.0, metavar="NM_RAD", help="planar: rotational stiffness")
    p.add_argument("--b-rot", type=float, default=0.0, metavar="NMS_RAD", help="planar: rotational damping")
    p.add_argument(
        "--direct",
        type=float,
        default=0.0,
        metavar="F",
        help="planar: fraction of stiffness and damping on the undelayed (virtual) side, 0 to 1",
    )
    p.add_argument("--h", type=float, metavar="S", default=argparse.SUPPRESS, help="planar: robot delay [s]")
    p.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help="print one JSON object")


def _scene_loop6(items: list[str]):
    """(loop, description) of a 6-DOF scene at its start configuration."""
    from dockhil.scene import graph as graphmod
    from dockhil.scene import launchfile
    from dockhil import nodes
    from dockhil.analysis.scenecheck import scene_loop6

    path, overrides = items[0], launchfile.parse_overrides(items[1:])
    graph = graphmod.build(launchfile.load(path, overrides))
    loop = scene_loop6(graph)
    if loop is None:
        types = {gn.type_name for gn in graph.nodes.values()}
        named = [
            f"{nodes.ONE_DOF[t]} with dof: 6" for t in ("satellite_dynamics6", "virtual_impedance6") if t not in types
        ]
        raise DockhilError(
            f"{path}: not a 6-DOF hybrid scene (no {' and no '.join(named)});"
            " for a 1-DOF scene run `dockhil stability --scene`"
        )
    return loop, f"6-DOF hybrid loop of {path} at its start configuration, delay h = {loop.h:g} s"


def _run_multi(args: argparse.Namespace) -> int:
    from dockhil.contact import stability6

    scene = getattr(args, "scene", None)
    if bool(scene) == bool(args.planar):
        raise DockhilError("give either --scene FILE [NAME:=VALUE ...] or --planar with its values")
    if scene:
        loop, what = _scene_loop6(scene)
    else:
        values = {}
        for name in ("m", "inertia", "k_normal", "b_normal", "h"):
            v = getattr(args, name, None)
            if v is None:
                raise DockhilError(f"--planar needs --{name.replace('_', '-')}")
            values[name] = v
        if not 0.0 <= args.direct <= 1.0:
            raise DockhilError(f"--direct must be between 0 and 1, got {args.direct:g}")
        loop = stability6.planar_loop(
            values["m"],
            values["inertia"],
            args.lever,
            values["k_normal"],
            values["b_normal"],
            values["h"],
            args.k_rot,
            args.b_rot,
            args.direct,
        )
        what = f"planar loop (x at the contact point, rz), lever {args.lever:g} m, delay h = {values['h']:g} s"
    root = stability6.rightmost(loop)
    margin = stability6.stiffness_margin(loop)
    modes = stability6.modal_loops(loop)
    out = {
        "loop": what,
        "axes": list(loop.axes),
        "h_s": loop.h,
        "rightmost_root_1_s": [root.s.real, root.s.imag],
        "rightmost_axis": root.axis,
        "rightmost_mode": [abs(c) for c in root.mode],
        "stable": root.s.real < 0.0,
        "stiffness_margin": None if margin.alpha is None or math.isinf(margin.alpha) else margin.alpha,
        "crossing_rad_s": margin.omega,
        "limiting_axis": None if margin.root is None else margin.root.axis,
        "limiting_mode": None if margin.root is None else [abs(c) for c in margin.root.mode],
        "reason": margin.reason,
        "decoupled_modes": modes is not None,
    }
    if getattr(args, "json", False):
        print(json.dumps(out))
        return 0
    print(what)
    print(
        f"rightmost root   {root.s.real:+.6g} {root.s.imag:+.6g}j 1/s, led by axis {root.axis}: "
        + ("stable (decays)" if out["stable"] else "UNSTABLE (grows)")
    )
    print("its mode         " + "  ".join(f"{a} {abs(c):.3g}" for a, c in zip(loop.axes, root.mode)))
    if out["stiffness_margin"] is not None:
        print(
            f"stiffness margin stable up to {margin.alpha:.6g} times the delayed (passive) stiffness; there the"
            f" mode led by axis {out['limiting_axis']} crosses at {margin.omega:.6g} rad/s"
        )
        print("crossing mode    " + "  ".join(f"{a} {abs(c):.3g}" for a, c in zip(loop.axes, margin.root.mode)))
    else:
        print(f"stiffness margin {margin.reason}")
    print(
        "modes: "
        + (
            "the loop splits into independent 1-DOF modal loops"
            if modes is not None
            else "the axes couple (the bound is not one axis's 1-DOF bound)"
        )
        + "; translations [m] and rotations [rad] are compared as numbers in the mode shapes"
    )
    return 0
