"""The report's cases measured through the graph and the `dockhil` command: the stiffest contact
launched (as separate processes, or composed here) against the library loop, a contact its step
does not resolve refused before it runs, and bad masses refused in the library and on the command
line with one clear line."""

from __future__ import annotations

import math
import os
import re
import tempfile
from typing import Any

import numpy as np

from dockhil.analysis.report.case import case, plain, relative_difference
from dockhil.analysis.report.graph import bag_samples, composed_samples, last_line, launch_subprocess, run_cli
from dockhil.analysis.report.precision import LAUNCH_DIR, ReportConfig, hybrid_impedance, named_stable_step
from dockhil.contact.hilloop import simulate_hil, simulate_ideal
from dockhil.contact.ideal import ideal_contact_summary
from dockhil.contact.integrators import LinearSecondOrderSystem, max_stable_step
from dockhil.contact.scenario import TABLE1, ContactModelError, ContactScenario
from dockhil.errors import DockhilError


def stiff_graph_cases(cfg: ReportConfig, group: str, scn: ContactScenario, dt: float) -> list[dict]:
    """The stiffest contact (scn, at the step dt) through the graph: launch/ideal.yaml, where
    satellite_dynamics runs the ideal model inside the node; as separate processes, or composed in
    this process in the quick configuration (whose multi-process runs are graph_cost's: one timed
    and recorded, one start-up)."""
    ref = ideal_contact_summary(scn)
    args: dict[str, Any] = {"kcs": scn.kcs, "bcs": scn.bcs, "m1": scn.m1, "m2": scn.m2, "v1": scn.v1, "v2": scn.v2}
    duration = 5 * dt
    mode = "composed" if cfg.quick else "multi-process"
    params = {**args, "scene": "launch/ideal.yaml", "duration": duration, "mode": mode}
    cases = [refused_launch_case(group, "ideal.yaml", args, scn, duration)]
    args = {**args, "allow_coarse": "true"}  # below: what the graph computes when told to run anyway
    s, failed = None, None
    if cfg.quick:
        try:
            s = composed_samples("ideal.yaml", duration, args, (scn.kcs, scn.bcs))
        except DockhilError as exc:
            failed = str(exc)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "stiff.mcap")
            result = launch_subprocess(LAUNCH_DIR / "ideal.yaml", duration, args, bag=path)
            if result["code"] != 0 or not os.path.exists(path):
                failed = last_line(result)
            else:
                s = bag_samples(path, (scn.kcs, scn.bcs))
    if s is None:
        cases.append(
            case(group, f"{mode} graph (launch/ideal.yaml)", "runs", f"failed: {failed}", False, params=params)
        )
    else:
        exit_v = float(s.pd[-1])
        cases.append(
            case(
                group,
                f"{mode} graph (launch/ideal.yaml), exact",
                f"exit {ref.exit_relative_velocity:.9g} m/s",
                f"exit {exit_v:.9g} m/s" + ("" if s.p[-1] < 0 else " (bodies still touching)"),
                relative_difference(exit_v, ref.exit_relative_velocity) < 1e-6 and s.p[-1] < 0.0,
                params=params,
                tolerance=1e-6,
                expected_value=ref.exit_relative_velocity,
                measured_value=exit_v,
            )
        )
        lib = simulate_ideal(
            m1=scn.m1, m2=scn.m2, kcs=scn.kcs, bcs=scn.bcs, v1=scn.v1, v2=scn.v2, dt=dt, n_ticks=len(s.t)
        )
        same = np.array_equal(s.p, lib.x1 - lib.x2) and np.array_equal(s.pd, lib.v1 - lib.v2)
        cases.append(
            case(
                group,
                f"{mode} graph equals the library loop",
                "bit-identical to simulate_ideal",
                "bit-identical" if same else f"differs by {np.max(np.abs(s.pd - (lib.v1 - lib.v2))):.3g} m/s",
                same,
                params=params,
            )
        )
    limit = max_stable_step(LinearSecondOrderSystem.ideal_contact(scn), "rk4")
    if cfg.quick:
        try:
            composed_samples("ideal.yaml", duration, {**args, "method": "rk4"})
            code, text = 0, ""
        except DockhilError as exc:
            code, text = 1, f"error: {exc}"
    else:
        result = launch_subprocess(LAUNCH_DIR / "ideal.yaml", duration, {**args, "method": "rk4"})
        code, text = result["code"], result["stdout"] + result["stderr"]
    named = named_stable_step(text)
    error_lines = [ln for ln in text.splitlines() if "error:" in ln]
    ok = code != 0 and named is not None and relative_difference(named, limit) < 1e-5 and len(error_lines) == 1
    cases.append(
        case(
            group,
            f"{mode} graph, method rk4",
            f"fails with one error line naming {limit:.6g} s",
            f"exit code {code}, {len(error_lines)} error line(s)" + (f", names {named:.6g} s" if named else ""),
            ok,
            params={**params, "method": "rk4"},
            expected_value=limit,
            measured_value=named,
        )
    )
    return cases


def fine_rate_expected(scn: ContactScenario) -> float:
    """The rate [Hz] a refusal should name, from the closed form: omega*dt <= 0.025 and 100 samples per
    contact (the criterion in dockhil.contact.sampled), rounded up to two digits."""
    m = scn.reduced_mass
    poles = np.roots([m, scn.bcs, scn.kcs])
    omega = float(np.max(np.abs(poles)))
    need = max(omega / 0.025, 100.0 / ideal_contact_summary(scn).duration)
    scale = 10.0 ** (math.floor(math.log10(need)) - 1)
    return math.ceil(need / scale - 1e-9) * scale


def refused_launch_case(group: str, scene: str, args: dict, scn: ContactScenario, duration: float) -> dict:
    """`dockhil launch` of a contact its step does not resolve: one line, exit 2, naming the rate
    (as `rate:=` when a scene can run at it, else as the rate it would need)."""
    want = fine_rate_expected(scn)
    # The refusal comes before any node starts.
    code, err = run_cli(
        ["launch", str(LAUNCH_DIR / scene), "--duration", repr(duration), "--quiet"]
        + [f"{k}:={v}" for k, v in args.items()]
    )
    text = err.strip()
    named = re.search(r"rate:=([0-9.e+]+)|needs a rate of ([0-9.e+]+) Hz", text)
    named_rate = float(named.group(1) or named.group(2)) if named else None
    ok = code == 2 and len(text.splitlines()) == 1 and named_rate == want
    return case(
        group,
        f"{scene} at 1 kHz: refused before it runs",
        f"exit 2, one line naming {want:g} Hz",
        f"exit {code}, {len(text.splitlines())} line(s)" + (f", names {named_rate:g} Hz" if named_rate else ""),
        ok,
        params={**args, "scene": f"launch/{scene}", "duration": duration},
        expected_value=want,
        measured_value=named_rate,
    )


def refusal_cases(cfg: ReportConfig) -> list[dict]:
    """NaN, Inf and non-positive masses are refused with one clear line, in the
    library and on the launch command line."""
    group = "bad input refused"
    cases = []
    for name in ("m1", "m2"):
        for value in (math.nan, math.inf, 0.0, -1.0):
            try:
                TABLE1.replace(**{name: value})
            except ContactModelError as exc:
                text = str(exc)
                ok = name in text and "\n" not in text
                cases.append(
                    case(
                        group,
                        f"ContactScenario({name} = {value!r})",
                        f"ContactModelError naming {name}",
                        text,
                        ok,
                        params={name: plain(value)},
                    )
                )
            else:
                cases.append(
                    case(
                        group,
                        f"ContactScenario({name} = {value!r})",
                        f"ContactModelError naming {name}",
                        "accepted",
                        False,
                        params={name: plain(value)},
                    )
                )
    for value in (math.nan, -750.0):
        try:
            simulate_hil(m1=value, m2=1e6, k=1000.0, impedance=hybrid_impedance(), dt=1e-3, n_ticks=2)
        except ContactModelError as exc:
            cases.append(
                case(
                    group,
                    f"simulate_hil(m1 = {value!r})",
                    "ContactModelError naming the mass",
                    str(exc),
                    "mass" in str(exc) and "\n" not in str(exc),
                    params={"m1": plain(value)},
                )
            )
        else:
            cases.append(
                case(
                    group,
                    f"simulate_hil(m1 = {value!r})",
                    "ContactModelError naming the mass",
                    "accepted",
                    False,
                    params={"m1": plain(value)},
                )
            )
    if (LAUNCH_DIR / "ideal.yaml").exists():
        for text in ("nan", "inf", "0", "-1"):
            code, err = run_cli(
                ["launch", str(LAUNCH_DIR / "ideal.yaml"), f"m1:={text}", "--duration", "0.01", "--quiet"]
            )
            lines = [ln for ln in err.splitlines() if ln.strip()]
            ok = code == 2 and len(lines) == 1 and "m1" in lines[0]
            cases.append(
                case(
                    group,
                    f"dockhil launch ideal.yaml m1:={text}",
                    "exit 2, one line naming m1",
                    f"exit {code}: {lines[0] if lines else '(no message)'}"
                    if len(lines) <= 1
                    else f"exit {code}, {len(lines)} lines",
                    ok,
                    params={"m1": text},
                )
            )
    return cases
