"""`dockhil calibrate SCENE [name:=value ...] --out LOOP.yaml`: identify the real loop (delay, lag, passive
stiffness and damping, the F/T sensor's bias and noise) on the scene's hardware, or from a recorded run
(`--bag RUN.mcap`). The excitation is dockhil/nodes/identification.py, the fits dockhil/analysis/calibration/loop.py."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile

from dockhil.errors import DockhilError, LaunchError

# Node types of the simulated loop: left out of the identification graph (it drives the hardware alone).
_SIMULATED = {
    "satellite_dynamics",
    "satellite_dynamics6",
    "virtual_impedance",
    "virtual_impedance6",
    "delay_injector",
    "robot_sim",
    "robot_sim6",
    "ft_sim",
    "ft_sim6",
}
MOST_STIFFNESS = 1e7  # N/m: the stiffest contact the bound is searched to
_START_S = 5.0  # s: the devices' setup and the first pose and force, beyond the profile's own length
_SLOWEST_LOOP_S = 0.15  # s: the longest robot delay + lag + link calibrate is specified for (120 + 20 + 10 ms)
_LOOP_ARGS = ("delay", "lag", "k", "ft_noise")  # what a loop file sets in a scene (of scene/loopfile.LOOP_ARGS)


def add_arguments(p) -> None:
    import argparse

    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.description = (
        "Identify the real HIL loop on the scene's hardware: the F/T sensor's bias and noise at rest,\n"
        "the robot's delay and lag from small steps and a chirp in free space, the passive\n"
        "compliance's stiffness and damping from a slow press to a fraction of max_force. The\n"
        "scene's safety limits stay in force. Writes LOOP.yaml, which a scene takes as loop:=LOOP.yaml."
    )
    p.epilog = (
        "examples:\n"
        "  dockhil calibrate hil.yaml ft:=can robot:=modbus --out loop.yaml\n"
        "  dockhil calibrate hil.yaml ft:=can robot:=modbus emulators:=true --out loop.yaml --json\n"
        "  dockhil calibrate --bag run.mcap --out loop.yaml      # from a recorded identification run\n"
        "  dockhil launch hil.yaml loop:=loop.yaml               # the scene at the identified loop\n"
        "exit status: 0 identified; 1 the run stopped (a safety stop, no contact found); 2 bad input or\n"
        "a fit that is no measurement (nothing written); 3 the run was INVALID (nothing written)"
    )
    p.add_argument("scene", nargs="?", help="launch file with the hardware (robot and F/T drivers, or emulators)")
    p.add_argument("overrides", nargs="*", metavar="name:=value", help="launch arguments of the scene")
    p.add_argument("--out", metavar="LOOP.yaml", help="write the identified loop here (a scene's loop:=)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument(
        "--bag",
        metavar="RUN.mcap",
        help="identify from this recorded run instead of running one "
        "(the stability verdict is then for SCENE, default hil.yaml)",
    )
    p.add_argument("--bag-out", metavar="PATH", help="keep the live run's recording here")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="run the node loops with real-time (SCHED_FIFO) "
        "priority where the OS allows: a busy machine's lateness would count as delay",
    )


def run(args) -> int:
    from dockhil.log import Log
    from dockhil.scene import launchfile

    say = Log("dockhil calibrate:")
    if args.out is not None:
        _check_out(args.out)
    if args.bag is not None:
        if args.bag_out is not None:
            raise LaunchError("--bag reads a recorded run and --bag-out records one: give one of them")
        scene = launchfile.load(args.scene or "hil.yaml", launchfile.parse_overrides(args.overrides))
        code, cal = 0, _identify(args.bag)
    else:
        if args.scene is None:
            raise LaunchError("give a scene with hardware (e.g. hil.yaml ft:=can robot:=modbus) or --bag RUN.mcap")
        scene = launchfile.load(args.scene, launchfile.parse_overrides(args.overrides))
        code, cal = _live(scene, args.bag_out, args.realtime, say)
        if cal is None:
            say.error(f"the identification run stopped (exit {code}; the line above says why); nothing written")
            return code
    from dockhil.analysis.calibration import loop as calibration

    calibration.check(cal)
    if cal.link is None:
        say.warning(calibration.NO_CYCLES)
    elif not cal.split_identified:
        say.info(calibration.NO_SPLIT)
    if cal.lag_note:
        say.info(cal.lag_note)
    out = cal.as_dict()
    out.update(_verdict(scene, cal))
    out["run_valid"] = code == 0
    if args.json:
        print(json.dumps(out))
    else:
        _print_table(out, scene.path)
    if code != 0:
        say.error(
            f"the identification run was INVALID (exit {code}; the INVALID line above says why: a run that fell "
            f"behind real time or whose devices stalled, or a robot that left its commanded path); nothing "
            f"written: run it again (with --realtime, on a quieter machine)"
        )
    elif args.out is not None:
        _write_loop(args.out, out, scene.path)
        say.info(f"loop written to {args.out} (a scene takes it as loop:={args.out})")
    return code


def _check_out(path: str) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise LaunchError(f"--out {path}: folder {folder} does not exist")
    if os.path.isdir(path):
        raise LaunchError(f"--out {path}: is a directory; name a file, e.g. {os.path.join(path, 'loop.yaml')}")


def _identify(bag: str):
    from dockhil.analysis.calibration import loop as calibration
    from dockhil.bags.reader import BagReader

    if not os.path.isfile(bag):
        raise LaunchError(f"--bag {bag}: no such file")
    try:
        with BagReader(bag) as reader:
            rec = calibration.recording((topic, msg) for topic, _t, msg in reader.decoded())
        return calibration.identify(rec)
    except calibration.CalibrationError as exc:
        raise DockhilError(f"{bag}: {exc}") from None


def calibration_scene(scene):
    """The identification graph's scene: the scene's hardware nodes (drivers, emulators) and the
    identification node, without the simulated loop; LaunchError naming the arguments when the scene
    has no hardware to identify."""
    from dockhil import node_types as registry
    from dockhil.nodes.identification import Identification
    from dockhil.scene.launchfile import NodeSpec

    kept, robot, sensor = [], None, None
    for spec in scene.nodes:
        type_name, cls, params = registry.resolve(spec.type, spec.name, spec.params)
        if type_name in _SIMULATED:
            continue
        if type_name == "bag_source":
            raise LaunchError(
                f"{scene.path}: node {spec.name!r} replays a recording; calibrate identifies live "
                f"hardware: give the scene its F/T driver (e.g. ft:=can)"
            )
        outs = {o.topic for o in cls.outputs.values()}
        if cls.moves_hardware:
            robot = params
            if "anchor" in cls.params:  # RSI: the state from the start pose on, where the profile starts
                spec = dataclasses.replace(spec, params={**spec.params, "anchor": "origin"})
            if params.get("max_path_error"):
                # The profile moves at half max_speed: a robot as slow as calibrate is specified for is that
                # speed times its delay and lag behind the command (7 mm at 114 + 15 ms), past the 5 mm a
                # scene's slower contact needs; the run is valid while it stays within that.
                behind = 0.5 * (params.get("max_speed") or 0.1) * _SLOWEST_LOOP_S
                spec = dataclasses.replace(
                    spec, params={**spec.params, "max_path_error": params["max_path_error"] + behind}
                )
        elif "/ft/wrench" in outs:
            sensor = spec
            if "tare_samples" in cls.params:  # the bias is measured, not tared away
                spec = dataclasses.replace(spec, params={**spec.params, "tare_samples": 0})
        kept.append(spec)
    missing = [
        (what, arg)
        for what, arg, found in (("robot", "robot:=modbus", robot), ("F/T sensor", "ft:=can", sensor))
        if found is None
    ]
    if missing:
        raise LaunchError(
            f"{scene.path}: the scene's {' and '.join(w for w, _ in missing)} "
            f"{'are' if len(missing) > 1 else 'is'} simulated; calibrate identifies hardware: give "
            f"{' '.join(a for _, a in missing)} (with emulators:=true to try it on the emulators)"
        )
    if not robot.get("max_force"):
        raise LaunchError(
            f"{scene.path}: the robot driver's max_force is 0 (off); calibrate presses only under a "
            f"force limit: give one"
        )
    params = {"max_speed": robot["max_speed"] or 0.1, "max_force": robot["max_force"], "x_max": robot["x_max"]}
    ident = NodeSpec("identification", "identification", params, {}, "dockhil calibrate")
    duration = Identification.duration(params) + _START_S
    return dataclasses.replace(scene, nodes=[*kept, ident], duration=duration)


def _live(scene, bag_out: str | None, realtime: bool, say):
    from dockhil.scene.graph import build
    from dockhil.session import run_scene

    calib = calibration_scene(scene)
    graph = build(calib)
    tmp = None
    bag = bag_out
    if bag is None:
        tmp = tempfile.TemporaryDirectory(prefix="dockhil-calibrate-")
        bag = os.path.join(tmp.name, "identification.mcap")
    try:
        say.info(f"identification run on {scene.path}: at most {calib.duration:.0f} s; keep clear of the robot")
        code = run_scene(
            graph,
            clock="wall",
            duration=calib.duration,
            bag=bag,
            progress=False,
            show_summary=False,
            realtime=realtime,
            end_on=("/calibration/phase", "done"),  # the profile's end: the robot back and holding
        )
        if code not in (0, 3):
            return code, None
        return code, _identify(bag)
    finally:
        if tmp is not None:
            tmp.cleanup()


def _verdict(scene, cal) -> dict:
    """The stability of the scene's loop at the identified one: the loop as the scene places each force (what
    acts on the simulated state, what acts through the robot's delay: dockhil/analysis/scenecheck.py's
    reading, with the identified compliance behind the delay), its delay the identified loop's end to end
    with the lag (analysis/calibration/loop.loop_h); judged as `dockhil stability --scene` and the launch's
    scene check judge it (analysis/stability/verdict.py). `kcs_max_N_per_m`: the largest scene kcs (or, where
    the scene gives its impedance, the largest surface stiffness) that stays stable. The paper's bound, with
    the whole contact delayed, is given beside it (`paper`)."""
    from dockhil import node_types as registry
    from dockhil.analysis.calibration import loop as calibration
    from dockhil.analysis.scenecheck import scene_loop
    from dockhil.analysis.stability.verdict import largest_stable, loop_verdict
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    def none(reason: str) -> dict:
        return {"stable": None, "kcs_max_N_per_m": None, "verdict": {"reason": reason}}

    k = cal.contact.k_N_per_m
    h = calibration.loop_h(cal)

    args = {name: scene.values[name] for name in scene.args}

    def loop_at(**values):
        given = {**args, "k": k, **values} if "k" in args else {**args, **values}
        return scene_loop(build(launchfile.load(scene.path, given)))

    info = loop_at()
    if info is None or not info["loop"].held:
        return none(f"{scene.path} has no delayed 1-DOF loop (dynamics, impedance, robot) to judge")
    m, kd, bd = info["m"], info["kd"], info["bd"]
    kh = k if info.get("hardware") else info["kh"]
    v = loop_verdict(m, kd, bd, kh, 0.0, h)
    paper = None
    modes = {
        registry.resolve(n.type, n.name, n.params)[2].get("mode")
        for n in scene.nodes
        if registry.resolve(n.type, n.name, n.params)[0] == "virtual_impedance"
    }
    if "determine" in modes and "kcs" in args:
        kcs = float(args["kcs"])

        def judge(x: float) -> bool:
            at = loop_at(kcs=x)
            return loop_verdict(at["m"], at["kd"], at["bd"], kh, 0.0, h)["stable"]

        v["kcs_N_per_m"] = kcs
        bcs = float(args.get("bcs", 0.0))
        paper = calibration.verdict(cal, m, kcs, bcs)
    else:  # the scene gives its impedance: the largest surface stiffness behind the delay
        kcs = kh

        def judge(x: float) -> bool:
            return loop_verdict(m, kd, bd, x, 0.0, h)["stable"]

        v["kcs_N_per_m"] = kh
    k_max = largest_stable(judge, kcs, most=MOST_STIFFNESS)
    if k_max == MOST_STIFFNESS:  # no stiffness makes it grow: no bound
        v["kcs_max_note"] = f"stable for every stiffness up to {MOST_STIFFNESS:g} N/m"
        k_max = None
    v["kcs_max_N_per_m"] = k_max
    v["margin"] = None if k_max is None else k_max / kcs
    if paper is not None:
        v["paper"] = paper
    return {"stable": v["stable"], "kcs_max_N_per_m": k_max, "verdict": v}


def _pm(value, sigma, scale: float = 1.0, digits: int = 4) -> str:
    if value is None:
        return "not resolved by these data"
    s = f"{value * scale:.{digits}g}"
    return s + (f" +- {sigma * scale:.2g}" if sigma is not None and math.isfinite(sigma) else "")


def _print_table(r: dict, scene: str) -> None:
    u = r["uncertainty"]
    link = r["link_s"]
    span = r.get("delay_range_s")
    rows = [
        (
            "delay (the robot's, at the device)" if span is not None else "delay (command to pose, link included)",
            _pm(r["delay_s"], u["delay_s"], 1e3)
            + (
                ""
                if span is None
                else f" (within {span[0] * 1e3:.4g} to {span[1] * 1e3:.4g}, whatever the controller's timing)"
            )
            if r["delay_s"] is not None
            else f"not identified apart from the link: {span[0] * 1e3:.4g} to {span[1] * 1e3:.4g}",
            "ms",
        ),
        *(
            [
                ("link (to the device and back)", _pm(link, u["link_s"], 1e3), "ms"),
            ]
            if link is not None
            else []
        ),
        (
            f"loop delay (end to end, p{r['fit'].get('loop_delay_percentile', 95):g})",
            _pm(r["loop_delay_s"], None, 1e3),
            "ms",
        ),
        ("loop delay (typical)", _pm(r["loop_delay_typical_s"], None, 1e3), "ms"),
        (f"lag ({r['lag_model']} fits better)", _pm(r["lag_s"], u["lag_s"], 1e3), "ms"),
        ("passive stiffness k", _pm(r["k_N_per_m"], u["k_N_per_m"]), "N/m"),
        (
            "passive damping b",
            _pm(r["b_Ns_per_m"], u["b_Ns_per_m"]) if r["b_Ns_per_m"] is not None else "not identified",
            "N s/m" if r["b_Ns_per_m"] is not None else "",
        ),
        ("F/T delay", _pm(r["ft_delay_s"], u["ft_delay_s"], 1e3), "ms" if r["ft_delay_s"] is not None else ""),
        ("contact surface x", _pm(r["surface_m"], u["surface_m"], 1e3), "mm"),
    ]
    for i, axis in enumerate("xyz"):
        rows.append((f"F/T bias F{axis}", _pm(r["bias_N"][i], u["bias_N"][i], 1.0, 3), "N"))
    for i, axis in enumerate("xyz"):
        rows.append((f"F/T noise F{axis} (std)", _pm(r["noise_N"][i], u["noise_N"][i], 1.0, 3), "N"))
    print(f"identified loop ({scene}):")
    for name, value, unit in rows:
        print(f"  {name:36} {value} {unit}".rstrip())
    v = r["verdict"]
    if "line" not in v:
        print(f"  stability: {v['reason']}")
        return
    print(f"stability: {v['line']}")
    if v["kcs_max_N_per_m"] is not None:
        print(
            f"  {'largest stable stiffness':36} {v['kcs_max_N_per_m']:.6g} N/m (the scene's {v['kcs_N_per_m']:g} N/m: "
            f"margin {v['margin']:.3g}x)"
        )
    if "kcs_max_note" in v:
        print(f"  {'largest stable stiffness':36} none: {v['kcs_max_note']}")
    paper = v.get("paper")
    if paper is not None and paper["kcs_max_N_per_m"] is not None:
        print(f"  {'the paper bound (kcs wholly delayed)':36} {paper['kcs_max_N_per_m']:.6g} N/m")
    if not r["run_valid"]:
        print("  the run was INVALID (the line above says why): nothing written")


def _write_loop(path: str, r: dict, scene: str) -> None:
    from dockhil.files import complete_or_nothing

    # the force's delay behind the pose, where identified, is the loop's too: a scene's delay stands for it all
    delay = r["loop_delay_s"] + (r["ft_delay_s"] or 0.0)
    values = {"delay": delay, "lag": r["lag_s"], "k": r["k_N_per_m"], "ft_noise": r["noise_N"][0]}
    lines = [
        f"# the loop identified by dockhil calibrate on {scene}",
        f"# a scene takes it as loop:={os.path.basename(path)}; a name:=value on the command line wins",
        "args:",
    ]
    lines += [f"  {name}: {values[name]!r}" for name in _LOOP_ARGS]
    lines += [
        "# the sensor's tare and what else was measured, with one-sigma uncertainties",
        f"tare: {json.dumps({'force_N': r['bias_N'], 'torque_Nm': r['bias_Nm']})}",
        f"calibration: {json.dumps({k: v for k, v in r.items() if k not in ('verdict',)})}",
        f"verdict: {json.dumps(r['verdict'])}",
    ]
    with complete_or_nothing(path) as part, open(part, "w") as f:
        f.write("\n".join(lines) + "\n")
