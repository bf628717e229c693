"""The report's cases of the hybrid loop's delay and virtual impedance at their extremes: no delay
and a delay far beyond the contact, a contact stiffness below the passive one (negative virtual
springs), and the delayed loop just inside and just outside its exact stability boundary."""

from __future__ import annotations

import warnings
from typing import cast

import numpy as np

from dockhil.analysis.report.case import case, relative_difference
from dockhil.analysis.report.precision import ReportConfig, compared_force, hybrid_impedance
from dockhil.contact.hilloop import HilRun, simulate_hil
from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.ideal import ideal_contact_summary, ideal_trajectory, relative_motion
from dockhil.contact.impedance import impedance_closed_form, negative_stiffness_message
from dockhil.contact.integrators import simulate_contact
from dockhil.contact.scenario import TABLE1, ContactScenario, NegativeVirtualStiffnessWarning


def _hil_samples(
    scn: ContactScenario, delay: float, dt: float, t_end: float, imp: VirtualImpedance | None = None
) -> HilRun:
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
            relative_difference(measured_dv, expected_dv) < 0.01,
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
            and relative_difference(imp.k1, predicted_k1) < 1e-12,
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
    k_max = cast(float, exact_bound(m, b, h_eff, "undelayed").k_max)  # b > 0, h > 0: a finite bound
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
                (measured > 0) == (predicted > 0) and relative_difference(measured, predicted) < 0.02,
                params={"m": m, "b": b, "h": h, "K": K, "K_max": k_max, "dt": dt, "damper": "undelayed"},
                expected_value=predicted,
                measured_value=measured,
            )
        )
    return cases
