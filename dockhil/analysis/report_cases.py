"""The report's stiff and extreme cases, each with an expectation computed from the model (closed
form, stability analysis, the integrators' stability limits) and what was measured."""

from __future__ import annotations

import math
import os
import re
import tempfile
import warnings

import numpy as np

from dockhil.analysis.report_ivp import DelayedContactRun
from dockhil.analysis.report_graph import bag_samples, composed_samples, last_line, launch_subprocess, run_cli
from dockhil.analysis.report_precision import (
    EXPLICIT,
    LAUNCH_DIR,
    REFERENCE_DT,
    ReportConfig,
    compared_force,
    energy_run_fixed,
    hybrid_impedance,
    hybrid_reference,
    named_stable_step,
    relative_energy,
    undamped_scenario,
)
from dockhil.contact.hilloop import simulate_hil, simulate_ideal
from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.ideal import ideal_contact_summary, ideal_trajectory, relative_motion
from dockhil.contact.impedance import impedance_closed_form, negative_stiffness_message
from dockhil.contact.integrators import (
    METHODS,
    Integrator,
    LinearSecondOrderSystem,
    max_stable_step,
    simulate_contact,
)
from dockhil.contact.scenario import (
    TABLE1,
    ContactModelError,
    ContactScenario,
    NegativeVirtualStiffnessWarning,
    StepTooLargeError,
)
from dockhil.errors import DockhilError

# -- stiff and extreme cases -----------------------------------------------------------------------------
# Each case computes its expectation from the model (closed form, the
# integrators' stability limits, the delay equation's roots) and measures it
# by running the simulation; `passed` compares the two.

STIFF = ContactScenario(m1=1.0, m2=1e6, kcs=1e9, bcs=1e3, v1=0.1, v2=0.0)
STIFF_GAP = 1.234e-4  # [m] onset at 1.234 ms: inside a 1 ms step, not on the grid
STIFF_DT = 1e-3


def case(
    group: str,
    name: str,
    expected: str,
    measured: str,
    passed: bool,
    *,
    params: dict | None = None,
    expected_value=None,
    measured_value=None,
    tolerance=None,
) -> dict:
    return {
        "group": group,
        "name": name,
        "expected": expected,
        "measured": measured,
        "passed": bool(passed),
        "params": params or {},
        "expected_value": plain(expected_value),
        "measured_value": plain(measured_value),
        "tolerance": tolerance,
    }


def plain(value):
    """JSON-ready: numpy scalars to floats, non-finite floats to strings."""
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def _rel(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-300)


def energy_growth(scn: ContactScenario, method: str, dt: float, steps: int = 4000) -> float:
    """log10 of the largest relative-motion energy over the last tenth of a
    bilateral run of `steps` steps over the largest over the first tenth:
    <= 0 when the step map is stable, > 0 when it amplifies. Uses the raw step
    map, so that steps outside the stability region can be shown to grow."""
    from dockhil.contact.integrators import step_matrices

    phi = step_matrices(LinearSecondOrderSystem.ideal_contact(scn), method, dt)[0]
    x = np.array([0.0, 0.0, scn.v1, scn.v2])
    log_energy = np.empty(steps)
    shift = 0.0  # log10 of the energy scaled out of x, so that growth never overflows
    for i in range(steps):
        x = phi @ x
        e = float(relative_energy(scn, x[0] - x[1], x[2] - x[3]))
        if e > 1e100 or 0.0 < e < 1e-100:
            scale = math.sqrt(e)
            x = x / scale
            shift += math.log10(e)
            e = 1.0
        log_energy[i] = (math.log10(e) if e > 0.0 else -math.inf) + shift
    tenth = steps // 10
    return float(np.max(log_energy[-tenth:]) - np.max(log_energy[:tenth]))


def explicit_refusal_case(
    group: str, scenario: ContactScenario, method: str, dt: float, *, impedance: VirtualImpedance | None = None
) -> dict:
    """An explicit method at a step outside its stability region must refuse and
    name the largest stable step; inside, it must run."""
    system = (
        LinearSecondOrderSystem.ideal_contact(scenario)
        if impedance is None
        else LinearSecondOrderSystem.hybrid_contact(scenario, impedance)
    )
    limit = max_stable_step(system, method)
    should_refuse = dt > limit * (1.0 + 1e-9)
    params = {**scenario.as_dict(), "method": method, "dt": dt}
    expected = f"refuses, names {limit:.6g} s" if should_refuse else f"runs (stable up to {limit:.6g} s)"
    try:
        simulate_contact(scenario, impedance=impedance, method=method, dt=dt, t_end=dt)
    except StepTooLargeError as exc:
        named = named_stable_step(str(exc))
        ok = should_refuse and named is not None and (named == limit == 0.0 or _rel(named, limit) < 1e-5)
        shown = "no stable step" if named == 0.0 else f"{named:.6g} s"
        return case(
            group,
            f"{method} at {dt:g} s",
            expected,
            f"refused, names {shown}",
            ok,
            params=params,
            expected_value=limit,
            measured_value=named,
        )
    return case(group, f"{method} at {dt:g} s", expected, "ran", not should_refuse, params=params, expected_value=limit)


def stiff_contact_cases(cfg: ReportConfig) -> list[dict]:
    """kcs = 1e9 N/m against m = 1 kg at a 1 ms step: the contact (0.1 ms) fits inside one step."""
    group = "kcs = 1e9 N/m, m = 1 kg, 1 ms step"
    scn, dt, gap = STIFF, STIFF_DT, STIFF_GAP
    ref = ideal_contact_summary(scn)
    params = {**scn.as_dict(), "gap": gap, "dt": dt}
    t_end = 5 * dt
    cases = []
    # The whole contact (0.1 ms) fits in one step, so where it starts within the
    # step matters: try onsets at tenths of the first step.
    phases = np.arange(10) / 10.0
    results = []
    for phase in phases:
        tr = simulate_contact(scn, method="exact", dt=dt, gap=scn.closing_velocity * phase * dt, t_end=t_end)
        results.append(float(tr.v1[-1] - tr.v2[-1]))
    errors = [_rel(v, ref.exit_relative_velocity) for v in results]
    good = [e < 1e-6 for e in errors]
    worst = int(np.argmax(errors))
    cases.append(
        case(
            group,
            "exact step, onset at tenths of a step",
            f"exit {ref.exit_relative_velocity:.9g} m/s at every onset phase",
            f"{sum(good)} of {len(good)} phases; worst exit {results[worst]:.6g} m/s (onset at {phases[worst]:g} dt)",
            all(good),
            params={**params, "method": "exact", "onset_phases": phases.tolist()},
            tolerance=1e-6,
            expected_value=ref.exit_relative_velocity,
            measured_value=results,
        )
    )
    system = LinearSecondOrderSystem.ideal_contact(scn)
    for method in EXPLICIT:
        cases.append(explicit_refusal_case(group, scn, method, dt))
        limit = max_stable_step(system, method)
        if limit > 0.0:
            inside, outside = energy_growth(scn, method, 0.9 * limit), energy_growth(scn, method, 1.1 * limit)
            cases.append(
                case(
                    group,
                    f"{method} at 0.9 and 1.1 x its named step",
                    "energy late/early: shrinks inside, grows outside",
                    f"x 10^{inside:+.3g} inside, x 10^{outside:+.3g} outside",
                    inside <= 1e-12 < outside,
                    params={**params, "method": method, "dt": [0.9 * limit, 1.1 * limit]},
                    expected_value=limit,
                    measured_value=[inside, outside],
                )
            )
    for method in ("Radau", "LSODA"):
        run = DelayedContactRun(scn, gap=gap, t_end=t_end, method=method, rtol=1e-10, atol=1e-16)
        s = run.sample(np.array([t_end]))
        exit_v = float(s["v1"][0] - s["v2"][0])
        cases.append(
            case(
                group,
                f"solve_ivp {method} (implicit), rtol 1e-10",
                f"exit {ref.exit_relative_velocity:.9g} m/s",
                f"exit {exit_v:.9g} m/s",
                _rel(exit_v, ref.exit_relative_velocity) < 1e-6,
                params={**params, "method": method, "rtol": 1e-10},
                tolerance=1e-6,
                expected_value=ref.exit_relative_velocity,
                measured_value=exit_v,
            )
        )
    if cfg.graph:
        cases.extend(stiff_graph_cases(cfg))
    return cases


def stiff_graph_cases(cfg: ReportConfig) -> list[dict]:
    """The stiffest contact through the graph: launch/ideal.yaml, where satellite_dynamics runs the
    ideal model inside the node; as separate processes, or composed in this process in the quick
    configuration (whose multi-process runs are graph_cost's: one timed and recorded, one start-up)."""
    group = "kcs = 1e9 N/m, m = 1 kg, 1 ms step"
    scn = STIFF
    ref = ideal_contact_summary(scn)
    args = {"kcs": scn.kcs, "bcs": scn.bcs, "m1": scn.m1, "m2": scn.m2, "v1": scn.v1, "v2": scn.v2}
    duration = 5 * STIFF_DT
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
                _rel(exit_v, ref.exit_relative_velocity) < 1e-6 and s.p[-1] < 0.0,
                params=params,
                tolerance=1e-6,
                expected_value=ref.exit_relative_velocity,
                measured_value=exit_v,
            )
        )
        lib = simulate_ideal(
            m1=scn.m1, m2=scn.m2, kcs=scn.kcs, bcs=scn.bcs, v1=scn.v1, v2=scn.v2, dt=STIFF_DT, n_ticks=len(s.t)
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
    ok = code != 0 and named is not None and _rel(named, limit) < 1e-5 and len(error_lines) == 1
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
    # The refusal comes before any node starts: the command runs in this process.
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


# The stiff contact of issue 12 (item 1): 2605 rad/s, a 1.2 ms contact, at 1 kHz the graph reported
# 1444 N and -0.845 m/s for 559 N and -0.141 m/s.
HIL_STIFF = ContactScenario(m1=2.3, m2=4.1, kcs=1e7, bcs=150.0, k=2e6, v1=0.12, v2=-0.03)
# A slow contact through a long delay (item 2): the delayed spring pushes for 0.1 s after separation.
HIL_LATE = ContactScenario(m1=300.0, m2=1100.0, kcs=22000.0, bcs=45.0, k=9000.0, v1=0.08, v2=0.05)


def _hil_metrics(scn: ContactScenario, dt: float, t_end: float, delay: float) -> dict:
    from dockhil.analysis.summary import Samples, contact_metrics

    r = simulate_hil(
        m1=scn.m1,
        m2=scn.m2,
        k=scn.k,
        impedance=hybrid_impedance(scn),
        dt=dt,
        n_ticks=int(round(t_end / dt)) + 1,
        v1=scn.v1,
        v2=scn.v2,
        delay=delay,
    )
    return contact_metrics(Samples(r.t, r.x1 - r.x2, r.v1 - r.v2, r.force))


def hil_loop_cases(cfg: ReportConfig) -> list[dict]:
    """The HIL loop itself (simulate_hil: what every node of hil.yaml computes) on a stiff contact
    and behind a long delay, against the closed form and the independent delay-equation reference."""
    cases = []
    group = "HIL loop: stiff contact (issue 12 case)"
    scn = HIL_STIFF
    ideal = ideal_contact_summary(scn)
    params = {**scn.as_dict(), "delay": 0.0}
    coarse = _hil_metrics(scn, 1e-3, 0.026, 0.0)
    cases.append(
        case(
            group,
            "at 1 kHz (what the graph would run)",
            "peak off by more than 10 % (why it is refused)",
            f"peak {coarse['peak_force_N']:.4g} N against {ideal.peak_force:.4g} N",
            _rel(coarse["peak_force_N"], ideal.peak_force) > 0.1,
            params={**params, "dt": 1e-3},
            expected_value=ideal.peak_force,
            measured_value=coarse["peak_force_N"],
        )
    )
    rate = fine_rate_expected(scn)
    fine = _hil_metrics(scn, 1.0 / rate, 0.006, 0.0)
    errs = [_rel(fine["peak_force_N"], ideal.peak_force), _rel(fine["exit_velocity_mps"], ideal.exit_relative_velocity)]
    cases.append(
        case(
            group,
            f"at the named rate {rate:g} Hz",
            "peak within 1.5 %, exit within 2.5 % of Eq. 1",
            f"peak {fine['peak_force_N']:.5g} N ({100 * errs[0]:.2g} %), exit "
            f"{fine['exit_velocity_mps']:.5g} m/s ({100 * errs[1]:.2g} %)",
            errs[0] < 0.015 and errs[1] < 0.025,
            params={**params, "dt": 1.0 / rate},
            tolerance=0.015,
            expected_value=[ideal.peak_force, ideal.exit_relative_velocity],
            measured_value=[fine["peak_force_N"], fine["exit_velocity_mps"]],
        )
    )
    if cfg.graph:
        args = {k: getattr(scn, k) for k in ("m1", "m2", "kcs", "bcs", "k", "v1", "v2")}
        cases.append(refused_launch_case(group, "hil.yaml", {**args, "delay": 0.0}, scn, 0.026))
    group = "HIL loop: 0.1 s delay, slow contact (issue 12 case)"
    scn, h, t_end = HIL_LATE, 0.1, 0.7
    ref = hybrid_reference(cfg, scn, delay=h, dt=REFERENCE_DT, t_end=t_end)
    want = float(ref.sample(np.array([t_end]))["pd"][0])  # after the last delayed push (t > exit + h)
    params = {**scn.as_dict(), "delay": h, "t_end": t_end}
    errors = []
    for dt in (1e-3, 1e-4):
        got = _hil_metrics(scn, dt, t_end, h)["exit_velocity_mps"]
        errors.append(abs(got - want))
        cases.append(
            case(
                group,
                f"exit velocity after the last force, {dt:g} s step",
                f"{want:.6g} m/s (delay-equation reference) to O(dt)",
                f"{got:.6g} m/s",
                abs(got - want) < 1.0 * dt,
                params={**params, "dt": dt},
                expected_value=want,
                measured_value=got,
                tolerance=dt,
            )
        )
    order = math.log(errors[0] / errors[1]) / math.log(10.0) if errors[1] > 0 else None
    cases.append(
        case(
            group,
            "observed order of the sampled loop",
            "1 (forces held over a step)",
            "-" if order is None else f"{order:.3g}",
            order is not None and 0.8 < order < 1.2,
            params=params,
            expected_value=1.0,
            measured_value=order,
        )
    )
    return cases


def overdamped_cases(cfg: ReportConfig) -> list[dict]:
    """An overdamped contact whose fast time constant m/bcs (1 us) is far below the step (1 ms)."""
    group = "overdamped, time constant 1e-6 s, 1 ms step"
    scn = ContactScenario(m1=1.0, m2=1e6, kcs=1e5, bcs=1e6, v1=0.1, v2=0.0)
    dt, t_end = 1e-3, 0.1
    tau = scn.reduced_mass / scn.bcs
    params = {**scn.as_dict(), "dt": dt, "t_end": t_end, "fast_time_constant_s": tau}
    cases = []
    tr = simulate_contact(scn, method="exact", dt=dt, t_end=t_end)
    ref = ideal_trajectory(scn, tr.t)
    # The penetration is a ~1e-7 m creep after the first microseconds: compare it relative to its peak.
    scale = float(np.max(np.abs(ref.penetration)))
    err = float(np.max(np.abs(tr.penetration - ref.penetration))) / scale
    cases.append(
        case(
            group,
            "exact step against the closed form",
            "penetration error < 1e-6 of its peak",
            f"{err:.3g} of peak",
            err < 1e-6 and bool(np.all(tr.in_contact[:-1] | (ref.penetration[:-1] <= 0))),
            params={**params, "method": "exact"},
            tolerance=1e-6,
            expected_value=scale,
            measured_value=err,
        )
    )
    for method in EXPLICIT:
        cases.append(explicit_refusal_case(group, scn, method, dt))
    for method in ("Radau", "LSODA"):
        run = DelayedContactRun(scn, t_end=t_end, method=method, rtol=1e-8, atol=1e-18)
        s = run.sample(tr.t)
        err = float(np.max(np.abs((s["x1"] - s["x2"]) - ref.penetration))) / scale
        cases.append(
            case(
                group,
                f"solve_ivp {method} (implicit), rtol 1e-8",
                "penetration error < 1e-5 of its peak",
                f"{err:.3g} of peak, {run.steps} steps",
                err < 1e-5,
                params={**params, "method": method, "rtol": 1e-8},
                tolerance=1e-5,
                measured_value=err,
            )
        )
    return cases


def zero_damping_cases(cfg: ReportConfig) -> list[dict]:
    """bcs = 0: the contact returns all its energy (restitution 1), and over a long
    bilateral run no method may drift beyond what its step map predicts."""
    group = "zero damping (bcs = 0)"
    scn = undamped_scenario()
    params = {**scn.as_dict()}
    cases = []
    ref = ideal_contact_summary(scn)
    tr = simulate_contact(scn, method="exact", dt=1e-3)
    restitution = float(-(tr.v1[-1] - tr.v2[-1]) / scn.closing_velocity)
    cases.append(
        case(
            group,
            "unilateral contact, exact step: restitution",
            f"{ref.restitution:.12g} (closed form)",
            f"{restitution:.12g}",
            abs(restitution - ref.restitution) < 1e-9,
            params={**params, "method": "exact", "dt": 1e-3},
            tolerance=1e-9,
            expected_value=ref.restitution,
            measured_value=restitution,
        )
    )
    # Long bilateral run: the step map's spectral radius rho predicts the energy
    # ratio after n steps, rho^(2n) (1 for exact and symplectic Euler, < 1 for RK4).
    dt = cfg.energy_dt
    t_end = min(cfg.energy_t_end, 200.0)
    n = int(round(t_end / dt))
    system = LinearSecondOrderSystem.ideal_contact(scn)
    basis = system.flexible_basis()
    for method in METHODS:
        run = energy_run_fixed(method, dt, t_end, scn)
        if "refused" in run:
            limit = run["largest_stable_step_s"]
            named = named_stable_step(run["refused"])
            cases.append(
                case(
                    group,
                    f"{method}: long run at {dt:g} s",
                    "refuses: no stable step" if limit == 0.0 else f"refuses, names {limit:.6g} s",
                    "refused: " + ("no stable step" if named == 0.0 else f"names {named:.6g} s"),
                    named is not None and (named == limit or _rel(named, limit) < 1e-5),
                    params={**params, "method": method, "dt": dt},
                    expected_value=limit,
                    measured_value=named,
                )
            )
            continue
        phi = Integrator(system, method).step_matrices(dt)[0]
        rho = float(np.max(np.abs(np.linalg.eigvals(basis.T @ phi @ basis))))
        predicted = rho ** (2 * n) - 1.0
        drift = run["final_relative_drift"]
        if method == "symplectic_euler":
            # |lambda| = 1 (det = 1): no drift, only a bounded oscillation of the energy error.
            err = np.abs(np.array(run["relative_error"]))
            tenth = max(2, len(err) // 10)
            first, last = float(np.max(err[:tenth])), float(np.max(err[-tenth:]))
            cases.append(
                case(
                    group,
                    f"{method}: {t_end:g} s at {dt:g} s",
                    f"no drift (|eigenvalues| = {rho:.15g}): late error <= early error",
                    f"max |dE|/E early {first:.3g}, late {last:.3g}",
                    last <= first * 1.01 + 1e-15,
                    params={**params, "method": method, "dt": dt, "t_end": t_end},
                    expected_value=rho,
                    measured_value=[first, last],
                )
            )
            continue
        tol = 1e-9 if abs(predicted) < 1e-9 else 0.02 * abs(predicted)
        shown = "0 (|eigenvalues| = 1)" if abs(predicted) < 1e-9 else f"{predicted:.3g} (rho^2n - 1)"
        cases.append(
            case(
                group,
                f"{method}: {t_end:g} s at {dt:g} s",
                f"energy drift {shown}",
                f"drift {drift:.3g}",
                abs(drift - predicted) <= tol,
                params={**params, "method": method, "dt": dt, "t_end": t_end},
                tolerance=tol,
                expected_value=predicted,
                measured_value=drift,
            )
        )
    return cases


MASS_RATIOS = (1e-6, 1e-3, 1.0, 1e3, 1e6, 1e9)


def mass_ratio_cases(cfg: ReportConfig) -> list[dict]:
    """m2/m1 from 1e-6 to 1e9: the ideal model and the undelayed hybrid model
    (closed-form impedance) against the closed form, and momentum conserved."""
    group = "mass ratio m2/m1"
    cases = []
    for ratio in MASS_RATIOS:
        scn = TABLE1.replace(m2=TABLE1.m1 * ratio)
        ref = ideal_contact_summary(scn)
        t_end = 2.0 * ref.duration if math.isfinite(ref.duration) else 50.0 * scn.reduced_mass / scn.bcs + 0.01
        imp = hybrid_impedance(scn)
        worst = {}
        momentum = 0.0
        p0 = scn.m1 * scn.v1 + scn.m2 * scn.v2
        for label, impedance in (("ideal", None), ("hybrid", imp)):
            tr = simulate_contact(scn, impedance=impedance, method="exact", dt=1e-3, t_end=t_end)
            r = ideal_trajectory(scn, tr.t)
            mine = compared_force(scn, None, tr.penetration, tr.penetration_rate, tr.in_contact, r.in_contact)
            theirs = compared_force(scn, None, r.penetration, r.penetration_rate, r.in_contact, tr.in_contact)
            worst[label] = float(np.max(np.abs(mine - theirs))) / ref.peak_force
            momentum = max(momentum, float(np.max(np.abs(scn.m1 * tr.v1 + scn.m2 * tr.v2 - p0))) / abs(p0))
        ok = worst["ideal"] < 1e-6 and worst["hybrid"] < 1e-6 and momentum < 1e-9
        cases.append(
            case(
                group,
                f"m2/m1 = {ratio:g} ({ref.regime})",
                f"force within 1e-6 of the closed-form peak {ref.peak_force:.6g} N; momentum kept",
                f"ideal {worst['ideal']:.2g}, hybrid {worst['hybrid']:.2g}, momentum {momentum:.2g}",
                ok,
                params={**scn.as_dict(), "dt": 1e-3, "method": "exact", "t_end": t_end},
                tolerance=1e-6,
                expected_value=ref.peak_force,
                measured_value=[worst["ideal"], worst["hybrid"], momentum],
            )
        )
    return cases


def _hil_samples(scn: ContactScenario, delay: float, dt: float, t_end: float, imp: VirtualImpedance | None = None):
    imp = imp or hybrid_impedance(scn)
    return simulate_hil(
        m1=scn.m1,
        m2=scn.m2,
        k=scn.k,
        impedance=imp,
        dt=dt,
        n_ticks=int(round(t_end / dt)) + 1,
        delay=delay,
        v1=scn.v1,
        v2=scn.v2,
    )


def delay_cases(cfg: ReportConfig) -> list[dict]:
    """Delay 0 (the hybrid loop is the ideal contact) and a delay much longer
    than the contact (during it only the virtual part acts, kcs - k; the
    stale robot pose then pushes the separated bodies)."""
    from dockhil.analysis.summary import Samples, contact_metrics

    group = "robot delay"
    scn, dt = TABLE1, 1e-3
    ref = ideal_contact_summary(scn)
    cases = []
    run = _hil_samples(scn, 0.0, dt, cfg.contact_t_end)
    closed = ideal_trajectory(scn, run.t)
    step_change = float(np.max(np.abs(np.diff(closed.force))))
    m = contact_metrics(Samples(run.t, run.x1 - run.x2, run.v1 - run.v2, run.force))
    err = abs(m["peak_force_N"] - ref.peak_force)
    cases.append(
        case(
            group,
            "delay 0: hybrid loop = ideal contact",
            f"peak {ref.peak_force:.6g} N within one step's force change ({step_change:.3g} N)",
            f"peak {m['peak_force_N']:.6g} N",
            err <= step_change,
            params={**scn.as_dict(), "delay": 0.0, "dt": dt},
            tolerance=step_change,
            expected_value=ref.peak_force,
            measured_value=m["peak_force_N"],
        )
    )
    # Delay far beyond the contact: until h passes the robot reports no pose.
    h = 10.0
    soft = scn.replace(kcs=scn.kcs - scn.k)
    soft_ref = ideal_contact_summary(soft)
    run = _hil_samples(scn, h, dt, h + soft_ref.duration + 0.5)
    before = run.t < h
    s = Samples(run.t[before], (run.x1 - run.x2)[before], (run.v1 - run.v2)[before], run.force[before])
    m = contact_metrics(s)
    soft_closed = ideal_trajectory(soft, run.t[before])
    step_change = float(np.max(np.abs(np.diff(soft_closed.force))))
    cases.append(
        case(
            group,
            f"delay {h:g} s >> contact: the contact runs on the virtual part only",
            f"ideal contact with kcs - k: peak {soft_ref.peak_force:.6g} N",
            f"peak {m['peak_force_N']:.6g} N",
            abs(m["peak_force_N"] - soft_ref.peak_force) <= step_change,
            params={**scn.as_dict(), "delay": h, "dt": dt},
            tolerance=step_change,
            expected_value=soft_ref.peak_force,
            measured_value=m["peak_force_N"],
        )
    )
    # After h the delayed pose replays the contact on separated bodies: an impulse k * integral(p dt).
    tq = np.linspace(0.0, soft_ref.duration, 20001)
    p, _ = relative_motion(soft.reduced_mass, soft.kcs, soft.bcs, soft.closing_velocity, tq)
    impulse = scn.k * float(np.sum((p[1:] + p[:-1]) * np.diff(tq)) / 2.0)
    expected_dv = -impulse / scn.reduced_mass
    i0 = int(np.searchsorted(run.t, h - 10 * dt))
    measured_dv = float((run.v1 - run.v2)[-1] - (run.v1 - run.v2)[i0])
    cases.append(
        case(
            group,
            f"delay {h:g} s: stale pose pushes after separation",
            f"relative velocity change -k/m * int p dt = {expected_dv:.6g} m/s",
            f"{measured_dv:.6g} m/s",
            _rel(measured_dv, expected_dv) < 0.01,
            params={**scn.as_dict(), "delay": h, "dt": dt},
            tolerance=0.01,
            expected_value=expected_dv,
            measured_value=measured_dv,
        )
    )
    return cases


def negative_stiffness_cases(cfg: ReportConfig) -> list[dict]:
    """kcs < k: the virtual springs come out negative; the model warns and the
    undelayed hybrid model still reproduces the ideal contact."""
    group = "kcs < k (negative virtual stiffness)"
    scn = TABLE1.replace(kcs=500.0, k=1000.0)
    params = scn.as_dict()
    expected_message = negative_stiffness_message(scn)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        imp = impedance_closed_form(scn)
    warned = [w for w in caught if issubclass(w.category, NegativeVirtualStiffnessWarning)]
    predicted_k1 = (scn.kcs - scn.k) * (1.0 + scn.m1 / scn.m2)
    cases = [
        case(
            group,
            "impedance warns, k1 and k2 negative",
            f"warning; k1 = {predicted_k1:.6g} N/m",
            f"{len(warned)} warning(s); k1 = {imp.k1:.6g} N/m",
            expected_message is not None
            and len(warned) == 1
            and str(warned[0].message) == expected_message
            and imp.k1 < 0
            and imp.k2 < 0
            and _rel(imp.k1, predicted_k1) < 1e-12,
            params=params,
            expected_value=predicted_k1,
            measured_value=imp.k1,
        )
    ]
    ref = ideal_contact_summary(scn)
    tr = simulate_contact(scn, impedance=imp, method="exact", dt=1e-3)
    r = ideal_trajectory(scn, tr.t)
    mine = compared_force(scn, None, tr.penetration, tr.penetration_rate, tr.in_contact, r.in_contact)
    theirs = compared_force(scn, None, r.penetration, r.penetration_rate, r.in_contact, tr.in_contact)
    err = float(np.max(np.abs(mine - theirs)))
    cases.append(
        case(
            group,
            "undelayed hybrid model = ideal contact",
            f"force error < 1e-6 of the peak {ref.peak_force:.6g} N",
            f"{err:.3g} N",
            err < 1e-6 * ref.peak_force,
            params={**params, "method": "exact", "dt": 1e-3},
            tolerance=1e-6 * ref.peak_force,
            expected_value=ref.peak_force,
            measured_value=err,
        )
    )
    return cases


def stability_boundary_cases(cfg: ReportConfig) -> list[dict]:
    """Figs. 11-12's loop (750 kg, 10 N thrust, virtual damper on the simulated
    velocity, 16 ms delay) with K just inside and just outside the exact bound.
    The sampled loop holds forces over a step, which acts as about half a step
    of extra delay: the bound is taken at h + dt/2; the expected growth rate is
    the sampled loop's own dominant eigenvalue (dockhil.contact.sampled), and the
    envelope is fitted about the true equilibrium thrust / K."""
    from dockhil.contact.envelope import growth_rate as measured_growth
    from dockhil.contact.sampled import SampledLoop, sampled_growth_rate
    from dockhil.contact.stability import exact_bound

    group = "exact stability boundary"
    m, b, h, thrust, dt = 750.0, 60.0, 0.016, 10.0, cfg.stability_dt
    h_eff = h + dt / 2.0
    k_max = exact_bound(m, b, h_eff, "undelayed").k_max
    cases = []
    for factor, where in ((0.95, "just inside"), (1.05, "just outside")):
        K = factor * k_max
        predicted = sampled_growth_rate(SampledLoop(m, 0.0, b, K, 0.0, dt=dt, delay_ticks=int(round(h / dt))))
        x_eq = thrust / K
        run = simulate_hil(
            m1=m,
            m2=0.0,
            k=K,
            impedance=VirtualImpedance(0.0, b, 0.0, 0.0),
            dt=dt,
            n_ticks=int(round(cfg.stability_t_end / dt)) + 1,
            delay=h,
            thrust=thrust,
            x1=x_eq + 5e-4,
        )
        measured = measured_growth(run.t, run.x1, about=x_eq)
        cases.append(
            case(
                group,
                f"K = {factor:g} K_max ({where})",
                f"growth rate {predicted:+.4g} 1/s ({'decays' if predicted < 0 else 'grows'}), within 2 %",
                f"{measured:+.4g} 1/s",
                (measured > 0) == (predicted > 0) and _rel(measured, predicted) < 0.02,
                params={"m": m, "b": b, "h": h, "K": K, "K_max": k_max, "dt": dt, "damper": "undelayed"},
                expected_value=predicted,
                measured_value=measured,
            )
        )
    return cases


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
