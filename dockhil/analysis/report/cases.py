"""The report's stiff and extreme cases of the integrators and the HIL loop, each with an expectation
computed from the model (closed form, stability analysis, the integrators' stability limits) and
what was measured: the stiffest contact, the HIL loop's stiff and late contacts, an overdamped and
an undamped contact, and mass ratios from 1e-6 to 1e9. The record of a case is
`dockhil.analysis.report.case`; the cases run through the graph and the command line are
`report_graph_cases`, those of the delay and the virtual impedance `report_loop_cases`."""

from __future__ import annotations

import math

import numpy as np

from dockhil.analysis.report.case import case, relative_difference
from dockhil.analysis.report.graph_cases import fine_rate_expected, refused_launch_case, stiff_graph_cases
from dockhil.analysis.report.ivp import DelayedContactRun
from dockhil.analysis.report.precision import (
    EXPLICIT,
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
from dockhil.contact.hilloop import simulate_hil
from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.ideal import ideal_contact_summary, ideal_trajectory
from dockhil.contact.integrators import (
    METHODS,
    Integrator,
    LinearSecondOrderSystem,
    max_stable_step,
    simulate_contact,
)
from dockhil.contact.scenario import TABLE1, ContactScenario, StepTooLargeError

# -- stiff and extreme cases -----------------------------------------------------------------------------
# Each case computes its expectation from the model (closed form, the
# integrators' stability limits, the delay equation's roots) and measures it
# by running the simulation; `passed` compares the two.

STIFF = ContactScenario(m1=1.0, m2=1e6, kcs=1e9, bcs=1e3, v1=0.1, v2=0.0)
STIFF_GAP = 1.234e-4  # [m] onset at 1.234 ms: inside a 1 ms step, not on the grid
STIFF_DT = 1e-3


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
        ok = should_refuse and named is not None and (named == limit == 0.0 or relative_difference(named, limit) < 1e-5)
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
    errors = [relative_difference(v, ref.exit_relative_velocity) for v in results]
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
                relative_difference(exit_v, ref.exit_relative_velocity) < 1e-6,
                params={**params, "method": method, "rtol": 1e-10},
                tolerance=1e-6,
                expected_value=ref.exit_relative_velocity,
                measured_value=exit_v,
            )
        )
    if cfg.graph:
        cases.extend(stiff_graph_cases(cfg, group, scn, dt))
    return cases


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
            relative_difference(coarse["peak_force_N"], ideal.peak_force) > 0.1,
            params={**params, "dt": 1e-3},
            expected_value=ideal.peak_force,
            measured_value=coarse["peak_force_N"],
        )
    )
    rate = fine_rate_expected(scn)
    fine = _hil_metrics(scn, 1.0 / rate, 0.006, 0.0)
    errs = [
        relative_difference(fine["peak_force_N"], ideal.peak_force),
        relative_difference(fine["exit_velocity_mps"], ideal.exit_relative_velocity),
    ]
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
                    named is not None and (named == limit or relative_difference(named, limit) < 1e-5),
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
