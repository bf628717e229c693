"""`dockhil stability`: how stiff a contact the robot's delay lets through
(paper Sec. 4: Eq. 12 and the exact boundary), and `stability map`: Fig. 7."""

from __future__ import annotations

import argparse
import json
import math
import time

from dockhil.errors import DockhilError

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
        "  dockhil stability map --m 750 --png fig7.png             # Fig. 7\n"
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
    sub = parser.add_subparsers(dest="action", metavar="map", title="subcommands")
    mp = sub.add_parser(
        "map",
        help="plot the critical stiffness surface K_max(b, h) (Fig. 7) to a PNG",
        description="Critical stiffness surface K_max(b, h) of Eq. 12 (the paper's Fig. 7) next to"
        " the exact bound, computed on a grid (vectorized) and saved as a PNG.",
    )
    # SUPPRESS: a value given before 'map' is not overwritten by the map's default.
    mp.add_argument("--m", type=float, metavar="KG", default=argparse.SUPPRESS, help=_M_HELP)
    mp.add_argument(
        "--b-range", type=float, nargs=2, metavar=("LO", "HI"), default=(10.0, 200.0),
        help="damping range [N s/m] (default 10 200, as in Fig. 7)",
    )
    mp.add_argument(
        "--h-range", type=float, nargs=2, metavar=("LO", "HI"), default=(0.016, 0.032),
        help="delay range [s] (default 0.016 0.032, as in Fig. 7)",
    )
    mp.add_argument("--n", type=int, default=200, metavar="N", help="grid points per axis (default 200)")
    mp.add_argument("--damper", choices=("delayed", "undelayed"), default=argparse.SUPPRESS, help=_DAMPER_HELP)
    mp.add_argument("--png", metavar="FILE", required=True, help="where to write the figure (PNG)")
    mp.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help="print a JSON summary of the map")


def _need(args, name: str, what: str) -> float:
    value = getattr(args, name, None)
    if value is None:
        raise DockhilError(f"missing --{name} ({what})")
    return value


def _loop_values(args) -> tuple[float, float, float]:
    from dockhil.contact.scenario import check_finite, check_nonnegative, check_positive

    m = check_positive("--m", _need(args, "m", "free-floating mass [kg]"), "kg")
    b = check_nonnegative("--b", _need(args, "b", "virtual damping [N s/m]"), "N s/m")
    h = check_nonnegative("--h", _need(args, "h", "robot delay [s]"), "s")
    if h == 0.0:
        raise DockhilError("--h must be > 0 s: without delay every K > 0 is stable when b > 0")
    if args.K is not None:
        check_finite("--K", args.K, "N/m")
    if args.pade_order is not None and not 1 <= args.pade_order <= 20:
        raise DockhilError(f"--pade-order must be between 1 and 20, got {args.pade_order}")
    return m, b, h


def run(args: argparse.Namespace) -> int:
    if getattr(args, "action", None) == "map":
        return _run_map(args)
    from dockhil.contact.stability import stability_report

    m, b, h = _loop_values(args)
    report = stability_report(m, b, h, K=args.K, damper=args.damper, pade_order=args.pade_order)
    if args.json:
        print(json.dumps(report))
        return 0
    _print_report(report)
    return 0


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


def _range(name: str, pair, positive: bool) -> tuple[float, float]:
    from dockhil.contact.scenario import check_finite

    lo = check_finite(f"{name} LO", pair[0])
    hi = check_finite(f"{name} HI", pair[1])
    if lo < 0.0 or (positive and lo <= 0.0):
        raise DockhilError(f"{name} LO must be {'> 0' if positive else '>= 0'}, got {lo:g}")
    if hi <= lo:
        raise DockhilError(f"{name} needs LO < HI, got {lo:g} {hi:g}")
    return lo, hi


def _run_map(args) -> int:
    import numpy as np

    from dockhil.contact.scenario import check_positive
    from dockhil.contact.stability import critical_stiffness_map

    if getattr(args, "m", None) is None:
        raise DockhilError("missing --m (free-floating mass [kg])")
    m = check_positive("--m", args.m, "kg")
    b_lo, b_hi = _range("--b-range", args.b_range, positive=False)
    h_lo, h_hi = _range("--h-range", args.h_range, positive=True)
    if not 2 <= args.n <= 2000:
        raise DockhilError(f"--n must be between 2 and 2000, got {args.n}")
    damper = getattr(args, "damper", "delayed")
    b = np.linspace(b_lo, b_hi, args.n)
    h = np.linspace(h_lo, h_hi, args.n)
    start = time.perf_counter()
    pade1 = critical_stiffness_map(m, b, h, "pade1", damper)
    exact = critical_stiffness_map(m, b, h, "exact", damper)
    compute_seconds = time.perf_counter() - start
    _plot(args.png, m, b, h, pade1, exact, damper)
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
        "pade1_min": _nanreduce(np.nanmin, pade1),
        "pade1_max": _nanreduce(np.nanmax, pade1),
        "exact_min": _nanreduce(np.nanmin, exact),
        "exact_max": _nanreduce(np.nanmax, exact),
        "max_pade1_overestimate": _nanreduce(np.nanmax, overestimate),
        "points_without_stable_K": int(np.sum(np.isnan(exact))),
    }
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
    return 0


def _nanreduce(fn, values) -> float | None:
    import numpy as np

    if np.all(np.isnan(values)):
        return None
    out = float(fn(values))
    return None if math.isnan(out) else out


def _plot(path: str, m: float, b, h, pade1, exact, damper: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    bb, hh = np.meshgrid(b, h * 1e3)
    fig = plt.figure(figsize=(12, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.plot_surface(bb, hh, pade1, cmap="viridis", linewidth=0, antialiased=False)
    ax.set_xlabel("b [N s/m]")
    ax.set_ylabel("h [ms]")
    ax.set_zlabel("K_max [N/m]")
    ax.set_title(f"Eq. 12 critical stiffness, m = {m:g} kg (Fig. 7)")
    ax2 = fig.add_subplot(1, 2, 2)
    filled = ax2.contourf(bb, hh, exact, levels=20, cmap="viridis")
    fig.colorbar(filled, ax=ax2, label="exact K_max [N/m]")
    with np.errstate(invalid="ignore", divide="ignore"):
        percent = 100.0 * (pade1 - exact) / exact
    if np.any(np.isfinite(percent)):
        lines = ax2.contour(bb, hh, percent, colors="white", linewidths=0.8, levels=6)
        ax2.clabel(lines, fmt="%.2g %%", fontsize=7)
    ax2.set_xlabel("b [N s/m]")
    ax2.set_ylabel("h [ms]")
    ax2.set_title(f"exact bound ({damper} damper); white: Eq. 12 excess [%]")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise DockhilError(f"--png {path}: cannot write the figure ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
