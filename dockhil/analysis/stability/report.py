"""What `dockhil stability` computes beyond the contact library: Fig. 7's map and the hybrid loop's
map over a grid, drawn and summed up; the multi-axis loop's rightmost root and stiffness margin as
one record; and the delayed loop a launch file builds (1-DOF or 6-DOF). Its text is
`dockhil.analysis.stability.text`."""

from __future__ import annotations

import math
import time

from dockhil.errors import DockhilError


def stiffness_map(png: str, m: float, damper: str, b_range, h_range, n: int, compensated: dict | None = None) -> dict:
    """Eq. 12's critical stiffness and the exact bound over an n x n (b, h) grid (Fig. 7), drawn to
    png beside the compensated region when given; returns the map's summary."""
    import numpy as np

    from dockhil.analysis.stability.plot import plot_map
    from dockhil.contact.passivity_bound import passive_stiffness_map
    from dockhil.contact.stability import critical_stiffness_map
    from dockhil.contact.stability_maps import nan_extreme

    b = np.linspace(b_range[0], b_range[1], n)
    h = np.linspace(h_range[0], h_range[1], n)
    start = time.perf_counter()
    pade1 = critical_stiffness_map(m, b, h, "pade1", damper)
    exact = critical_stiffness_map(m, b, h, "exact", damper)
    passive = passive_stiffness_map(b, h, damper)
    compute_seconds = time.perf_counter() - start
    plot_map(png, m, b, h, pade1, exact, damper, compensated, passive)
    with np.errstate(invalid="ignore"):
        overestimate = (pade1 - exact) / exact
    summary = {
        "png": png,
        "m": m,
        "damper": damper,
        "grid": [n, n],
        "b_range": [b_range[0], b_range[1]],
        "h_range": [h_range[0], h_range[1]],
        "compute_seconds": compute_seconds,
        "pade1_min": nan_extreme(np.nanmin, pade1),
        "pade1_max": nan_extreme(np.nanmax, pade1),
        "exact_min": nan_extreme(np.nanmin, exact),
        "exact_max": nan_extreme(np.nanmax, exact),
        "max_pade1_overestimate": nan_extreme(np.nanmax, overestimate),
        "points_without_stable_K": int(np.sum(np.isnan(exact))),
        # The passivity boundary: the largest K the undelayed damper b makes passive behind h (b / h), none
        # for the delayed damper; passive is stable for every mass, so it lies under the exact bound.
        "passivity_max_K_min": nan_extreme(np.nanmin, passive),
        "passivity_max_K_max": nan_extreme(np.nanmax, passive),
        "passivity_over_exact_max": nan_extreme(np.nanmax, passive / exact),
    }
    if compensated is not None:
        summary["passivity"] = compensated
    return summary


def hybrid_stability_map(png: str, m: float, kcs: float, bcs: float, rate: float, k_range, h_range, n: int) -> dict:
    """The hybrid loop m s^2 + bcs s + (kcs - k) + k e^(-sh) over an n x n (k, h) grid: stable exactly
    and sampled at rate, beside Eq. 12's verdict on the whole kcs delayed; drawn to png, summed up."""
    import numpy as np

    from dockhil.analysis.stability.plot import plot_hybrid
    from dockhil.contact.stability_maps import hybrid_map

    ks, hs = np.linspace(k_range[0], k_range[1], n), np.linspace(h_range[0], h_range[1], n)
    start = time.perf_counter()
    exact, sampled, eq12 = hybrid_map(m, kcs, bcs, rate, ks, hs)
    seconds = time.perf_counter() - start
    plot_hybrid(png, m, kcs, bcs, rate, ks, hs, exact, sampled, eq12)
    return {
        "png": png,
        "m": m,
        "kcs": kcs,
        "bcs": bcs,
        "rate": rate,
        "grid": [n, n],
        "k_range": [k_range[0], k_range[1]],
        "h_range": [h_range[0], h_range[1]],
        "compute_seconds": seconds,
        "exact_stable_fraction": float(exact.mean()),
        "sampled_stable_fraction": float(sampled.mean()),
        "sampled_disagrees_fraction": float((exact != sampled).mean()),
        "eq12_stable_delays": float(eq12.mean()),
    }


def multi_axis_report(loop, what: str) -> dict:
    """The multi-axis loop's rightmost root and the axis leading its mode, its stiffness margin and
    the axis or mode that limits it, and whether it splits into 1-DOF modal loops."""
    from dockhil.contact import stability6

    root = stability6.rightmost(loop)
    margin = stability6.stiffness_margin(loop)
    modes = stability6.modal_loops(loop)
    return {
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


def scene_hybrid_loop(path: str, overrides: list[str]) -> tuple[float, float, float, float, float, float, float]:
    """m, k_d, b_d, k_h, b_h, h, rate of a scene's loop, as the graph will run it."""
    from dockhil.analysis.scenecheck import scene_loop
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

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
    # the servo's lag counts as delay (1/(1 + tau s) and e^(-s tau) agree to first order), as the scene check
    # and dockhil calibrate count it: one loop, one verdict (analysis/stability/verdict.py)
    return info["m"], info["kd"], info["bd"], info["kh"], info["bh"], info["h"] + info["loop"].lag, graph.scene.rate


def scene_multi_axis_loop(path: str, overrides: list[str]):
    """(loop, description) of a 6-DOF scene at its start configuration."""
    from dockhil import node_types
    from dockhil.analysis.scenecheck import scene_loop6
    from dockhil.scene import graph as graphmod
    from dockhil.scene import launchfile

    graph = graphmod.build(launchfile.load(path, launchfile.parse_overrides(overrides)))
    loop = scene_loop6(graph)
    if loop is None:
        types = {gn.type_name for gn in graph.nodes.values()}
        named = [
            f"{node_types.ONE_DOF[t]} with dof: 6"
            for t in ("satellite_dynamics6", "virtual_impedance6")
            if t not in types
        ]
        raise DockhilError(
            f"{path}: not a 6-DOF hybrid scene (no {' and no '.join(named)});"
            " for a 1-DOF scene run `dockhil stability --scene`"
        )
    return loop, f"6-DOF hybrid loop of {path} at its start configuration, delay h = {loop.h:g} s"
