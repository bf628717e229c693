"""`dockhil figures [--out DIR]`: the paper's Figs. 7, 9, 10 and 11-12, recomputed, and the off-axis
6-DOF docking of launch/hil6.yaml, as PNGs and JSON."""

from __future__ import annotations

import argparse
import json
import os

from dockhil.errors import DockhilError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out", default="figures", metavar="DIR", help="folder for the PNGs and figures.json (default: figures)"
    )
    p.add_argument(
        "--delay",
        type=float,
        default=0.032,
        metavar="S",
        help="robot delay for Figs. 9-10 and the 6-DOF docking [s] (default 0.032)",
    )


def run(args: argparse.Namespace) -> int:
    if not 0.0 <= args.delay < 1.0:
        raise DockhilError(f"--delay must be between 0 and 1 s, got {args.delay}")
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise DockhilError(f"--out {args.out}: cannot create the folder ({exc.strerror})") from None
    from dockhil.analysis.plots.figures import plot_all

    numbers = plot_all(args.out, args.delay)
    with open(os.path.join(args.out, "figures.json"), "w") as f:
        json.dump(numbers, f, indent=1)
    m = numbers["fig9"]
    delayed = next(k for k in m if "delay" in k and k != "hybrid, no delay")
    print(
        f"Fig. 9: peak force ideal {m['ideal']['peak_force_N']:.3f} N, hybrid {m['hybrid, no delay']['peak_force_N']:.3f} N, "
        f"{delayed} {m[delayed]['peak_force_N']:.3f} N"
    )
    for c in numbers["fig11_12"]:
        print(
            f"Figs. 11-12: b = {c['b_N_s_per_m']:g}: growth {c['growth_rate_1_s']:+.5f} 1/s, "
            f"sampled loop's root {c['predicted_growth_rate_1_s']:+.5f} 1/s (delay equation "
            f"{c['delay_equation_growth_rate_1_s']:+.5f} 1/s), Eq. 12 bound {c['eq12_bound_N_per_m']:.1f} N/m"
        )
    six = numbers["sixdof"]
    print(
        f"6-DOF (hil6.yaml): peak |F| {six['peak_force_N']:.3f} N (ideal {six['ideal']['peak_force_N']:.3f} N), "
        f"peak |T| {six['peak_torque_Nm']:.3f} N m (ideal {six['ideal']['peak_torque_Nm']:.3f} N m)"
    )
    print(
        f"wrote fig7.png, fig9.png, fig10.png, fig11_12.png, sixdof.png (from sixdof.mcap) and figures.json"
        f" to {args.out}"
    )
    return 0
