"""`dockhil stability`: how stiff a contact the robot's delay lets through
(paper Sec. 4: Eq. 12 and the exact boundary), `stability map`: Fig. 7, and `stability multi`: the
multi-axis delayed loop of a 6-DOF scene. Parse, call (dockhil.contact.stability and
stability_maps; the maps, the multi-axis record and the scenes' loops in
dockhil.analysis.stability.report) and print (the text in dockhil.analysis.stability.text)."""

from __future__ import annotations

import argparse
import json
import math

from dockhil.analysis.stability.text import (
    format_compensated,
    format_hybrid,
    format_hybrid_map,
    format_multi_axis,
    format_report,
    format_stiffness_map,
)
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
    report.update(_passivity(args, b, h))
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
    print(format_report(report))
    print(_passivity_text(report))
    if "passivity" in report:
        print(format_compensated(report["passivity"]))
    return 0


def _passivity(args, b: float, h: float) -> dict:
    """The passivity boundary of stability.yaml's loop (dockhil.contact.passivity_bound): the largest K whose
    delayed port the damper b makes passive (none with the damper behind the delay, which itself needs b
    undelayed), and with --K the least undelayed damping the port asks for."""
    from dockhil.contact.passivity_bound import passivity_report

    rate = 1000.0 if args.rate is None else check_rate(args.rate)
    dt = 1.0 / rate
    delayed = args.damper == "delayed"
    out: dict = {
        "passivity_max_K": None if delayed else b / h,
        "sampled_passivity_max_K": None if delayed else b / ((round(h / dt) + 0.5) * dt),
    }
    if args.K is not None:
        out.update(passivity_report(args.K, b if delayed else 0.0, h, 0.0 if delayed else b, dt))
    return out


def check_rate(rate: float) -> float:
    from dockhil.contact.scenario import check_positive

    rate = check_positive("--rate", _within("--rate", rate, MAX_RATE, "Hz"), "Hz")
    if rate < 1.0:
        raise DockhilError(f"--rate must be at least 1 Hz, got {rate:g}")
    return rate


def _passivity_text(r: dict) -> str:
    """The passivity lines of `dockhil stability`'s text."""
    lines = []
    if r.get("passivity_max_K") is None and "passivity_max_K" in r:
        lines.append(
            "passivity: the damper acts behind the delay, so no K makes the port passive (it needs b undelayed)"
        )
    elif "passivity_max_K" in r:
        lines.append(
            f"passivity: the damper makes the delayed port passive for K <= b/h = {r['passivity_max_K']:.6g} N/m "
            f"(sampled: {r['sampled_passivity_max_K']:.6g} N/m)"
        )
    if "passivity_min_damping_Ns_per_m" in r:
        at = r["passivity_frequency_rad_s"]
        sat = r.get("sampled_passivity_frequency_rad_s")
        lines.append(
            f"passivity: least undelayed damping {r['passivity_min_damping_Ns_per_m']:.6g} N s/m "
            f"(max over w of (k_h/w) sin(wh) - b_h cos(wh), at {'w -> 0' if at is None else f'{at:.4g} rad/s'}): "
            f"{'passive' if r['passive'] else 'not passive'}; sampled at {r['sampled_rate_Hz']:g} Hz "
            f"{r['sampled_passivity_min_damping_Ns_per_m']:.6g} N s/m "
            f"(at {'w -> 0' if sat is None else f'{sat:.4g} rad/s'}): {'passive' if r['sampled_passive'] else 'not passive'}"
        )
    return "\n".join(lines)


def _range(name: str, pair, positive: bool, most: float = MAX_COEFF, unit: str = "") -> tuple[float, float]:
    lo = _within(f"{name} LO", pair[0], most, unit)
    hi = _within(f"{name} HI", pair[1], most, unit)
    if lo < 0.0 or (positive and lo <= 0.0):
        raise DockhilError(f"{name} LO must be {'> 0' if positive else '>= 0'}, got {lo:g}")
    if hi <= lo:
        raise DockhilError(f"{name} needs LO < HI, got {lo:g} {hi:g}")
    return lo, hi


def _run_map(args) -> int:
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
    b_range = _range("--b-range", args.b_range, positive=False, unit="N s/m")
    h_range = _range("--h-range", args.h_range, positive=True, most=MAX_DELAY, unit="s")
    args.n = 200 if args.n is None else args.n
    if not 2 <= args.n <= 2000:
        raise DockhilError(f"--n must be between 2 and 2000, got {args.n}")
    compensated = None
    if getattr(args, "compensation", "none") == "passivity":
        compensated = _compensated_region(m, b_range, h_range, args)
    from dockhil.analysis.stability.report import stiffness_map

    summary = stiffness_map(args.png, m, getattr(args, "damper", "delayed"), b_range, h_range, args.n, compensated)
    print(json.dumps(summary) if getattr(args, "json", False) else format_stiffness_map(summary))
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


def _scene_values(args) -> tuple[float, float, float, float, float, float, float]:
    """m, k_d, b_d, k_h, b_h, h, rate of a scene's loop, as the graph will run it."""
    given = [f"--{n.replace('_', '-')}" for n in ("m", "h", *_HYBRID) if getattr(args, n, None) is not None]
    if given:
        raise DockhilError(
            f"{given[0]} and --scene do not go together: the scene gives the loop; change it with "
            f"name:=value after the file"
        )
    path, *overrides = args.scene
    from dockhil.analysis.stability.report import scene_hybrid_loop

    return scene_hybrid_loop(path, overrides)


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
    from dockhil.contact.passivity_bound import passivity_report
    from dockhil.contact.sampled import RootsNotResolved

    m, kd, bd, kh, bh, h, rate = _hybrid_values(args)
    try:
        r = hybrid_report(m, kd, bd, kh, bh, h, rate=rate, pade_order=args.pade_order)
    except RootsNotResolved as exc:
        raise DockhilError(f"{exc}; give a lower --rate") from None
    r.update(passivity_report(kh, bh, h, bd, 1.0 / rate, kd))
    if args.scene is not None:  # the verdict in the words of dockhil calibrate and the launch's scene check
        from dockhil.analysis.stability.verdict import loop_verdict

        r["verdict"] = loop_verdict(m, kd, bd, kh, bh, h)["line"]
    text = format_hybrid(r) + "\n" + _passivity_text(r) + ("\n" + r["verdict"] if "verdict" in r else "")
    print(json.dumps(r) if args.json else text)
    return 0


def _run_hybrid_map(args, m: float) -> int:
    """Stable region of the hybrid loop m s^2 + bcs s + (kcs - k) + k e^(-sh) over (k, h): exact (closed-form
    crossings) and sampled at --rate, beside Eq. 12's verdict on the paper's loop (the whole kcs delayed)."""
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
    from dockhil.analysis.stability.report import hybrid_stability_map

    summary = hybrid_stability_map(args.png, m, kcs, bcs, rate, (k_lo, k_hi), (h_lo, h_hi), args.n)
    print(json.dumps(summary) if getattr(args, "json", False) else format_hybrid_map(summary))
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


def _run_multi(args: argparse.Namespace) -> int:
    from dockhil.analysis.stability import report as stability_report
    from dockhil.contact import stability6

    scene = getattr(args, "scene", None)
    if bool(scene) == bool(args.planar):
        raise DockhilError("give either --scene FILE [NAME:=VALUE ...] or --planar with its values")
    if scene:
        loop, what = stability_report.scene_multi_axis_loop(scene[0], scene[1:])
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
    out = stability_report.multi_axis_report(loop, what)
    print(json.dumps(out) if getattr(args, "json", False) else format_multi_axis(out))
    return 0
