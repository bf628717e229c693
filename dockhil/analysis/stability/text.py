"""The text `dockhil stability` prints: the delayed loop's bounds, the passivity-compensated runs,
the hybrid loop's critical delays, the maps' summaries and the multi-axis loop's root and margin,
each from the record that `dockhil.contact.stability` or `dockhil.analysis.stability.report` made."""

from __future__ import annotations

import math


def fmt(value: float | None) -> str:
    return "none" if value is None else f"{value:.6g}"


def format_report(r: dict) -> str:
    """The delayed contact loop's bounds (`stability_report`) and, with K, its verdict."""
    equation = "m s^2 + (K + b s) e^(-sh) = 0" if r["damper"] == "delayed" else "m s^2 + b s + K e^(-sh) = 0"
    out = [
        f"delayed contact loop ({r['damper']} damper): {equation}",
        f"  m = {r['m']:g} kg, b = {r['b']:g} N s/m, h = {r['h']:g} s   (b h / m = {r['beta']:.4g})",
        f"  {'bound':30} K_max [N/m]",
    ]
    label = "Eq. 12 (Pade 1 + Routh)" if r["damper"] == "delayed" else "Pade 1 + Routh"
    note = ""
    if "pade1_error" in r:
        note = f"   ({100 * r['pade1_error']:+.3g} % against exact)"
    out.append(f"  {label:30} {fmt(r['pade1']):12}{note}")
    if "pade_order" in r:
        out.append(f"  {'Pade ' + str(r['pade_order']):30} {fmt(r['pade_n'])}")
    out.append(f"  {'exact':30} {fmt(r['exact'])}")
    out.append(f"  {r['reason']}")
    if "pade1_reason" in r:
        out.append(f"  Pade 1: {r['pade1_reason']}")
    if "K" in r:
        re_, im_ = r["rightmost_root"]
        verdict = "stable" if r["stable"] else "UNSTABLE"
        out.append(
            f"  K = {r['K']:g} N/m: {verdict}, growth rate {r['growth_rate']:+.4g} 1/s"
            f" (rightmost root {re_:.4g} {'+' if im_ >= 0 else '-'} {abs(im_):.4g}j 1/s)"
        )
    return "\n".join(out)


def format_compensated(r: dict) -> str:
    """The passivity-compensated runs at multiples of the exact bound (`compensated_runs`)."""
    out = [f"with passivity compensation (max_damping {r['max_damping']:g} N s/m), measured on {r['loop']}:"]
    for row in r["runs"]:
        if row["diverged"]:
            verdict = "diverged"
        elif row["growth_rate"] is None:
            verdict = "settled" if row.get("settled") else "too few peaks to fit a growth rate"
        else:
            verdict = f"growth rate {row['growth_rate']:+.4g} 1/s, {'decays' if row['growth_rate'] < 0 else 'GROWS'}"
        sat = ", SATURATED (energy left in the loop)" if row["saturated"] else ""
        out.append(f"  K = {row['K']:<10.6g} N/m ({row['label']}): {verdict}{sat}")
    largest = r["largest_decaying_K"]
    out.append(
        f"  largest K that decays without saturating: {fmt(largest)} N/m"
        + ("" if largest is None or not r["exact_undelayed"] else f" ({largest / r['exact_undelayed']:.3g}x exact)")
    )
    return "\n".join(out)


def format_hybrid(r: dict) -> str:
    """The hybrid loop's critical delays, crossings and verdict, exact and sampled (`hybrid_report`)."""
    m, kd, bd, kh, bh, h = (r[k] for k in ("m", "k_direct", "b_direct", "k_delayed", "b_delayed", "h"))
    out = [
        f"hybrid contact loop: {r['equation']}",
        f"  m = {m:g} kg, k_d = {kd:g} N/m, b_d = {bd:g} N s/m, k_h = {kh:g} N/m, b_h = {bh:g} N s/m, h = {h:g} s",
    ]
    if not r["stable_without_delay"]:
        out.append("  unstable already without delay: m s^2 + (b_d + b_h) s + k_d + k_h has a root with Re >= 0")
    elif r["no_delay_destabilizes"]:
        out.append("  no delay destabilizes it: |k_d - m w^2 + j b_d w| > |k_h + j b_h w| at every frequency")
    else:
        out.append(
            f"  {'critical delay (exact)':30} {r['critical_delay']:.6g} s, oscillating at "
            f"{r['critical_frequency']:.6g} rad/s"
        )
        out.append(f"  {'critical delay (Pade 1)':30} {fmt(r['pade1_critical_delay'])} s")
        if "pade_order" in r:
            out.append(
                f"  {'critical delay (Pade ' + str(r['pade_order']) + ')':30} {fmt(r['pade_n_critical_delay'])} s"
            )
    for c in r["crossings"]:
        out.append(
            f"  crossing s = j {c['omega']:.6g} rad/s at h = {c['h0']:.6g} s + n {2 * math.pi / c['omega']:.6g} s "
            f"({'destabilizing' if c['destabilizing'] else 'stabilizing'})"
        )
    re_, im_ = r["rightmost_root"]
    verdict = "stable" if r["stable"] else "UNSTABLE"
    out.append(f"  at h = {h:g} s: {verdict}, growth rate {re_:+.4g} 1/s (rightmost root {re_:.4g} + {im_:.4g}j 1/s)")
    out.append(
        f"  (were the whole contact delayed, as in Eq. 12's loop: growth rate {r['whole_delayed_growth_rate']:+.4g} 1/s)"
    )
    sm = r["sampled"]
    verdict = "stable" if sm["stable"] else "UNSTABLE"
    out.append(
        f"  sampled at {sm['rate']:g} Hz ({sm['delay_ticks']} ticks of delay, forces held over a step): {verdict}, "
        f"spectral radius {sm['spectral_radius']:.9g}, growth rate {fmt(sm['growth_rate'])} 1/s"
    )
    if "critical_delay_ticks" in sm:
        out.append(f"  sampled critical delay: {sm['critical_delay_ticks']} ticks ({sm['critical_delay']:.6g} s)")
    return "\n".join(out)


def format_region(r: dict) -> str:
    """The compensated region over the map's (b, h) grid (`compensated_region`)."""
    flat = [x for row in r["largest_stable_multiple"] for x in row if x is not None]
    out = [
        f"  with passivity compensation (max_damping {r['max_damping']:g} N s/m), simulated over {r['grid'][0]} x "
        f"{r['grid'][1]} (b, h) points at {', '.join(f'{x:g}' for x in r['multiples'])} x the exact bound "
        f"({r['points']} runs, {r['cpu_seconds']:.1f} s CPU):",
        f"    stable (neither grows nor saturates) in {r['stable_points']} of {r['points']} runs; "
        f"{r['saturated_points']} saturated",
    ]
    if flat:
        out.append(
            f"    largest stiffness stable at every point: {min(flat):g} x exact; at some point: {max(flat):g} x exact"
        )
    return "\n".join(out)


def format_stiffness_map(summary: dict) -> str:
    """Fig. 7's map (`stiffness_map`), with the compensated region when it was simulated."""
    n = summary["grid"][0]
    out = [
        f"wrote {summary['png']}: K_max over {n} x {n} (b, h) points in {summary['compute_seconds'] * 1e3:.1f} ms",
        f"  Eq. 12: {fmt(summary['pade1_min'])} to {fmt(summary['pade1_max'])} N/m",
        f"  exact:  {fmt(summary['exact_min'])} to {fmt(summary['exact_max'])} N/m",
    ]
    if summary["max_pade1_overestimate"] is not None:
        out.append(f"  Eq. 12 overestimates the exact bound by up to {100 * summary['max_pade1_overestimate']:.3g} %")
    if summary["points_without_stable_K"]:
        out.append(f"  {summary['points_without_stable_K']} grid points have no stabilizing K at all")
    if "passivity" in summary:
        out.append(format_region(summary["passivity"]))
    return "\n".join(out)


def format_hybrid_map(summary: dict) -> str:
    """The hybrid loop's map over (k, h) (`hybrid_stability_map`)."""
    n = summary["grid"][0]
    return "\n".join(
        [
            f"wrote {summary['png']}: the hybrid loop over {n} x {n} (k, h) points in {summary['compute_seconds']:.2f} s",
            f"  stable: {100 * summary['exact_stable_fraction']:.3g} % exact, "
            f"{100 * summary['sampled_stable_fraction']:.3g} % sampled at {summary['rate']:g} Hz; Eq. 12 (kcs wholly "
            f"delayed) calls {100 * summary['eq12_stable_delays']:.3g} % of the delays stable, whatever k",
        ]
    )


def format_multi_axis(r: dict) -> str:
    """The multi-axis loop's rightmost root, its mode and the stiffness margin (`multi_axis_report`)."""
    re_, im_ = r["rightmost_root_1_s"]
    out = [
        r["loop"],
        f"rightmost root   {re_:+.6g} {im_:+.6g}j 1/s, led by axis {r['rightmost_axis']}: "
        + ("stable (decays)" if r["stable"] else "UNSTABLE (grows)"),
        "its mode         " + "  ".join(f"{a} {c:.3g}" for a, c in zip(r["axes"], r["rightmost_mode"])),
    ]
    if r["stiffness_margin"] is not None:
        out.append(
            f"stiffness margin stable up to {r['stiffness_margin']:.6g} times the delayed (passive) stiffness; there"
            f" the mode led by axis {r['limiting_axis']} crosses at {r['crossing_rad_s']:.6g} rad/s"
        )
        out.append("crossing mode    " + "  ".join(f"{a} {c:.3g}" for a, c in zip(r["axes"], r["limiting_mode"])))
    else:
        out.append(f"stiffness margin {r['reason']}")
    out.append(
        "modes: "
        + (
            "the loop splits into independent 1-DOF modal loops"
            if r["decoupled_modes"]
            else "the axes couple (the bound is not one axis's 1-DOF bound)"
        )
        + "; translations [m] and rotations [rad] are compared as numbers in the mode shapes"
    )
    return "\n".join(out)
