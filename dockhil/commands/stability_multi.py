"""`dockhil stability multi`: the multi-axis delayed loop (dockhil.contact.stability6).

The linearised 6-DOF hybrid loop det(M s^2 + B_d s + K_d + (B_h s + K_h) e^{-sh}) = 0 of a
6-DOF scene (read from its launch file, at its start configuration) or the paper's planar
case (normal x and rotation rz of a body touched off its CoM); prints the rightmost root and
the axis leading its mode, and the stiffness margin with the axis or mode that limits it.
"""

from __future__ import annotations

import argparse
import json
import math

from dockhil.errors import DockhilError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.description = __doc__.split("\n\n", 1)[1].strip()
    p.epilog = ("examples:\n"
                "  dockhil stability multi --scene launch/hil6.yaml delay:=0.016\n"
                "  dockhil stability multi --planar --m 750 --inertia 500 --lever 0.5 --k-normal 2510"
                " --b-normal 60 --k-rot 300 --b-rot 4 --h 0.016")
    # SUPPRESS: names shared with `dockhil stability` keep a value given before 'multi'.
    p.add_argument("--scene", nargs="+", metavar="FILE [NAME:=VALUE", default=argparse.SUPPRESS,
                   help="a 6-DOF launch file (satellite_dynamics and virtual_impedance with dof: 6, a delay_injector)"
                        " and its"
                        " launch arguments ...]")
    p.add_argument("--planar", action="store_true", help="the 2-D case: --m --inertia --lever --k-normal --b-normal"
                   " [--k-rot --b-rot --direct] --h")
    p.add_argument("--m", type=float, metavar="KG", default=argparse.SUPPRESS, help="planar: body mass [kg]")
    p.add_argument("--inertia", type=float, metavar="KG_M2", help="planar: inertia about z [kg m^2]")
    p.add_argument("--lever", type=float, default=0.0, metavar="M", help="planar: contact point off the CoM [m]")
    p.add_argument("--k-normal", type=float, metavar="N_M", help="planar: normal stiffness [N/m]")
    p.add_argument("--b-normal", type=float, metavar="NS_M", help="planar: normal damping [N s/m]")
    p.add_argument("--k-rot", type=float, default=0.0, metavar="NM_RAD", help="planar: rotational stiffness")
    p.add_argument("--b-rot", type=float, default=0.0, metavar="NMS_RAD", help="planar: rotational damping")
    p.add_argument("--direct", type=float, default=0.0, metavar="F",
                   help="planar: fraction of stiffness and damping on the undelayed (virtual) side, 0 to 1")
    p.add_argument("--h", type=float, metavar="S", default=argparse.SUPPRESS, help="planar: robot delay [s]")
    p.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help="print one JSON object")


def _scene_loop(items: list[str]):
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
        named = [f"{nodes.ONE_DOF[t]} with dof: 6" for t in ("satellite_dynamics6", "virtual_impedance6")
                 if t not in types]
        raise DockhilError(f"{path}: not a 6-DOF hybrid scene (no {' and no '.join(named)});"
                           " for a 1-DOF scene run `dockhil stability --scene`")
    return loop, f"6-DOF hybrid loop of {path} at its start configuration, delay h = {loop.h:g} s"


def run(args: argparse.Namespace) -> int:
    from dockhil.contact import stability6

    scene = getattr(args, "scene", None)
    if bool(scene) == bool(args.planar):
        raise DockhilError("give either --scene FILE [NAME:=VALUE ...] or --planar with its values")
    if scene:
        loop, what = _scene_loop(scene)
    else:
        values = {}
        for name in ("m", "inertia", "k_normal", "b_normal", "h"):
            v = getattr(args, name, None)
            if v is None:
                raise DockhilError(f"--planar needs --{name.replace('_', '-')}")
            values[name] = v
        if not 0.0 <= args.direct <= 1.0:
            raise DockhilError(f"--direct must be between 0 and 1, got {args.direct:g}")
        loop = stability6.planar_loop(values["m"], values["inertia"], args.lever, values["k_normal"], values["b_normal"],
                                      values["h"], args.k_rot, args.b_rot, args.direct)
        what = f"planar loop (x at the contact point, rz), lever {args.lever:g} m, delay h = {values['h']:g} s"
    root = stability6.rightmost(loop)
    margin = stability6.stiffness_margin(loop)
    modes = stability6.modal_loops(loop)
    out = {
        "loop": what, "axes": list(loop.axes), "h_s": loop.h,
        "rightmost_root_1_s": [root.s.real, root.s.imag], "rightmost_axis": root.axis,
        "rightmost_mode": [abs(c) for c in root.mode], "stable": root.s.real < 0.0,
        "stiffness_margin": None if margin.alpha is None or math.isinf(margin.alpha) else margin.alpha,
        "crossing_rad_s": margin.omega, "limiting_axis": None if margin.root is None else margin.root.axis,
        "limiting_mode": None if margin.root is None else [abs(c) for c in margin.root.mode],
        "reason": margin.reason, "decoupled_modes": modes is not None,
    }
    if getattr(args, "json", False):
        print(json.dumps(out))
        return 0
    print(what)
    print(f"rightmost root   {root.s.real:+.6g} {root.s.imag:+.6g}j 1/s, led by axis {root.axis}: "
          + ("stable (decays)" if out["stable"] else "UNSTABLE (grows)"))
    print("its mode         " + "  ".join(f"{a} {abs(c):.3g}" for a, c in zip(loop.axes, root.mode)))
    if out["stiffness_margin"] is not None:
        print(f"stiffness margin stable up to {margin.alpha:.6g} times the delayed (passive) stiffness; there the"
              f" mode led by axis {out['limiting_axis']} crosses at {margin.omega:.6g} rad/s")
        print("crossing mode    " + "  ".join(f"{a} {abs(c):.3g}" for a, c in zip(loop.axes, margin.root.mode)))
    else:
        print(f"stiffness margin {margin.reason}")
    print("modes: " + ("the loop splits into independent 1-DOF modal loops" if modes is not None else
                       "the axes couple (the bound is not one axis's 1-DOF bound)")
          + "; translations [m] and rotations [rad] are compared as numbers in the mode shapes")
    return 0
