"""`dockhil params`: the virtual impedance k1, b1, k2, b2 that makes the hybrid
model (passive k + virtual impedance) behave like the ideal contact."""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from typing import TYPE_CHECKING

from dockhil import physical
from dockhil.errors import DockhilError

if TYPE_CHECKING:
    from dockhil.contact.scenario import ContactScenario

_SCENARIO_ARGS = (
    # name, unit, check, help
    ("m1", "kg", "positive", "chaser mass [kg] (Table 1: 750)"),
    ("m2", "kg", "positive", "target mass [kg] (Table 1: 1e6)"),
    ("kcs", "N/m", "nonnegative", "ideal contact stiffness of Eq. 1 [N/m] (Table 1: 3000)"),
    ("bcs", "N s/m", "nonnegative", "ideal contact damping of Eq. 1 [N s/m] (Table 1: 40)"),
    ("k", "N/m", "nonnegative", "stiffness of the passive compliance on the robot [N/m] (Table 1: 1000)"),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = (
        "Virtual impedance k1, b1, k2, b2 (SI) such that the hybrid model of Eqs. 2-4\n"
        "(passive compliance k + virtual springs/dampers on a wall at the centre of mass)\n"
        "reproduces the ideal spring-dashpot contact of Eq. 1. Found by the two-time fit\n"
        "of Eqs. 5-6 (signs corrected) on the ideal model's states and checked against\n"
        "the closed form k1 = (kcs - k)(1 + m1/m2), b1 = bcs (1 + m1/m2),\n"
        "k2 = (kcs - k)(1 + m2/m1), b2 = bcs (1 + m2/m1)."
    )
    parser.epilog = (
        "examples:\n"
        "  dockhil params --table1                 # the paper's Table 1\n"
        "  dockhil params --m1 750 --m2 1e6 --kcs 3000 --bcs 40 --k 1000 --json\n"
        "  dockhil params --table1 --t1 0.3 --t2 1.2 --states rk4 --dt 0.01"
    )
    for name, _unit, _check, help_text in _SCENARIO_ARGS:
        parser.add_argument(f"--{name}", type=float, metavar="X", help=help_text)
    parser.add_argument(
        "--table1",
        action="store_true",
        help="take every value not given from the paper's Table 1"
        " (m1=750, m2=1e6, kcs=3000, bcs=40, k=1000, v1=0.03, v2=0)",
    )
    parser.add_argument(
        "--v1",
        type=float,
        default=0.03,
        metavar="V",
        help="chaser velocity before contact [m/s] (default 0.03); the result does not depend on it,"
        " but the chaser must close in (v1 > v2)",
    )
    parser.add_argument(
        "--v2", type=float, default=0.0, metavar="V", help="target velocity before contact [m/s] (default 0)"
    )
    parser.add_argument(
        "--t1",
        type=float,
        metavar="T",
        help="first fit time after contact onset [s], strictly inside the contact (default: T/4 of the contact duration T)",
    )
    parser.add_argument("--t2", type=float, metavar="T", help="second fit time [s] (default: 3T/4)")
    parser.add_argument(
        "--states",
        default="exact",
        choices=("exact", "closed_form", "rk4", "symplectic_euler", "euler", "solve_ivp"),
        help="where the ideal model's states at t1, t2 come from: a simulation with the exact"
        " step (default), the closed form, a fixed-step method with --dt, or solve_ivp",
    )
    parser.add_argument(
        "--dt",
        type=float,
        default=1e-3,
        metavar="S",
        help="step [s] for --states rk4|symplectic_euler|euler (default 0.001)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")


def _scenario(args):
    from dockhil.contact.scenario import TABLE1, ContactScenario, check_finite, check_nonnegative, check_positive

    checks = {"positive": check_positive, "nonnegative": check_nonnegative}
    values = {}
    for name, unit, check, help_text in _SCENARIO_ARGS:
        value = getattr(args, name)
        if value is None:
            if not args.table1:
                raise DockhilError(
                    f"missing --{name} ({help_text.split(' (')[0]}); give --m1 --m2 --kcs --bcs --k,"
                    " or --table1 to take the paper's values"
                )
            value = getattr(TABLE1, name)
        values[name] = checks[check](f"--{name}", value, unit)
    values["v1"] = check_finite("--v1", args.v1, "m/s")
    values["v2"] = check_finite("--v2", args.v2, "m/s")
    if values["kcs"] == 0.0 and values["bcs"] == 0.0:
        raise DockhilError("--kcs and --bcs are both 0: the ideal contact has no force to reproduce")
    if values["v1"] <= values["v2"]:
        raise DockhilError(
            f"--v1 = {values['v1']:g} m/s must exceed --v2 = {values['v2']:g} m/s so that the bodies"
            " come into contact (the result does not depend on the velocities)"
        )
    for name in ("t1", "t2"):
        if getattr(args, name) is not None:
            check_finite(f"--{name}", getattr(args, name), "s")
    check_positive("--dt", args.dt, "s")
    for name, value in (*values.items(), ("t1", args.t1), ("t2", args.t2), ("dt", args.dt)):
        if value and abs(value) < sys.float_info.min:
            raise DockhilError(
                f"--{name} {value!r} is too small to compute with (a subnormal number); "
                f"give a value of physical size, in SI units"
            )
    scenario = ContactScenario(**values)
    _check_scales(scenario)
    return scenario


# Most fixed-step simulation steps to the later fit time: a Python loop, so also a bound on time.
MAX_STEPS = 1_000_000
# Docking hardware spans a gram-scale probe to a space station, and a contact lasts from nanoseconds
# (stiff metal) to years (a near-free drift): outside these the contact models are not the tool, and
# the fit's solvers would take as long as the numbers are absurd.
PLAUSIBLE = {
    "m1": (*physical.MASS, "kg"),
    "m2": (*physical.MASS, "kg"),
    "kcs": (*physical.STIFFNESS, "N/m"),
    "bcs": (*physical.DAMPING, "N s/m"),
    "k": (*physical.STIFFNESS, "N/m"),
    "v1": (-physical.SPEED[1], physical.SPEED[1], "m/s"),
    "v2": (-physical.SPEED[1], physical.SPEED[1], "m/s"),
}
TIME_SCALE = (1e-9, 1e9)  # [s]


def _check_scales(s: ContactScenario) -> None:
    """Each value within the range of docking hardware and the contact's time scales physical: then
    no product or quotient the fit forms leaves the floating-point range, and its solvers end."""
    for name, (low, high, unit) in PLAUSIBLE.items():
        value = getattr(s, name)
        if not low <= value <= high:
            raise DockhilError(
                f"--{name} {value:g} {unit} is outside {low:g} to {high:g} {unit}, the range of "
                f"docking hardware these models are for"
            )
    scales = {
        "sqrt(m/kcs)": math.sqrt(s.reduced_mass / s.kcs) if s.kcs else None,
        "m/bcs": s.reduced_mass / s.bcs if s.bcs else None,
    }
    for name, seconds in scales.items():
        if seconds is not None and not TIME_SCALE[0] <= seconds <= TIME_SCALE[1]:
            raise DockhilError(
                f"the contact's time scale {name} = {seconds:.3g} s is outside {TIME_SCALE[0]:g} to "
                f"{TIME_SCALE[1]:g} s: the masses, stiffness and damping are not of one physical system"
            )


def _check_steps(scenario: ContactScenario, args: argparse.Namespace) -> None:
    """A fixed-step state source steps to the later fit time: refuse a step that makes that endless."""
    from dockhil.contact.impedance import recommended_fit_times

    if args.states not in ("rk4", "symplectic_euler", "euler"):
        return
    t1, t2 = recommended_fit_times(scenario)
    t_end = max(args.t1 if args.t1 is not None else t1, args.t2 if args.t2 is not None else t2)
    steps = t_end / args.dt
    if not steps <= MAX_STEPS:
        raise DockhilError(
            f"--dt {args.dt:g} s takes {steps:.3g} steps to t = {t_end:.6g} s with --states "
            f"{args.states}; at most {MAX_STEPS:g}: give a larger --dt"
        )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from dockhil.contact.impedance import fit_impedance
    from dockhil.contact.scenario import NegativeVirtualStiffnessWarning

    scenario = _scenario(args)
    _check_steps(scenario, args)
    # numpy's overflow warnings are not printed: the fit checks its results and says what is wrong.
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        # The warning text is reported below, in the table or the JSON.
        warnings.simplefilter("ignore", NegativeVirtualStiffnessWarning)
        try:
            fit = fit_impedance(scenario, args.t1, args.t2, states=args.states, dt=args.dt)
        except (ArithmeticError, ValueError) as exc:
            raise DockhilError(
                f"the fit left the floating-point range ({exc}); give values of physical size (SI units)"
            ) from None
    imp, closed = fit.impedance.as_dict(), fit.closed_form.as_dict()
    duration = None if math.isinf(fit.contact_duration) else fit.contact_duration
    result = {
        **imp,
        "units": {"k1": "N/m", "b1": "N s/m", "k2": "N/m", "b2": "N s/m"},
        "method": "two-time fit of Eqs. 5-6 (signs corrected) on the ideal model's states",
        "states": fit.states,
        "t1": fit.t1,
        "t2": fit.t2,
        "contact_duration": duration,
        "condition_number": max(fit.condition_chaser, fit.condition_target),
        "closed_form": closed,
        "max_relative_deviation": fit.max_relative_deviation,
        "agrees_with_closed_form": fit.agrees,
        "inputs": scenario.as_dict(),
        "warnings": list(fit.warnings),
    }
    if args.json:
        print(json.dumps(result))
        return 0
    units = result["units"]
    print(f"virtual impedance: two-time fit of Eqs. 5-6 on the ideal model's states ({fit.states})")
    print(f"  {'':4}{'fit':>16}  {'closed form':>16}  unit")
    for name in ("k1", "b1", "k2", "b2"):
        print(f"  {name:4}{imp[name]:16.8g}  {closed[name]:16.8g}  {units[name]}")
    span = f"{duration:.6g} s" if duration is not None else "no end (not underdamped)"
    print(f"  fit times t1 = {fit.t1:.6g} s, t2 = {fit.t2:.6g} s; contact duration {span}")
    print(
        f"  condition number {result['condition_number']:.3g};"
        f" fit and closed form {'agree' if fit.agrees else 'DIFFER'}"
        f" to {fit.max_relative_deviation:.2g} (relative)"
    )
    from dockhil.log import Log

    for note in fit.warnings:
        Log("dockhil params:").warning(note)
    return 0
