"""`dockhil report` on its small configuration, and each stiff or extreme case on its own.

Expected values come from closed forms of Eq. 1, from stability limits and loop matrices
computed here, and from a delay-equation solver written here (`heun_delay`: Heun's method on
a uniform grid aligned with the delay, events and breakpoints by splitting the step), which
shares no code with the library or with the report's reference; the report's own pass flags
are not what is tested."""

import bisect
import contextlib
import io
import json
import math

import numpy as np
import pytest

from dockhil.analysis.report import cases as report_cases
from dockhil.analysis.report import precision as report_precision
from dockhil.cli import main
from dockhil.contact.hilloop import simulate_hil
from dockhil.contact.scenario import TABLE1, ContactModelError, ContactScenario
from dockhil.progress import TaskProgress

QUICK = report_precision.ReportConfig.quick_config()
# One worker runs this file under pytest-xdist: the report and the solver below are built once.
pytestmark = pytest.mark.xdist_group("report")


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    err = io.StringIO()
    runtime = tmp_path_factory.mktemp("rt")
    # Module scope runs before conftest's per-test runtime directory: give the launches their own.
    # Lean scenes are measured (and tested) on their own: skipped here to keep the fixture short.
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        mp.setenv("DOCKHIL_RUNTIME_DIR", str(runtime))
        code = main(["report", "--quick", "--no-lean", "--out", str(out)])
    return code, out, err.getvalue()


# -- closed forms and an independent delay-equation solver, written here ----------------------------


def ideal_closed_form(m1, m2, kcs, bcs, v0):
    """Peak force, duration and exit relative velocity of Eq. 1 (underdamped), from its solution
    p = v0/wd e^{-zeta w t} sin(wd t)."""
    m = m1 * m2 / (m1 + m2)
    w = math.sqrt(kcs / m)
    zeta = bcs / (2 * math.sqrt(kcs * m))
    wd = w * math.sqrt(1 - zeta * zeta)
    duration = math.pi / wd
    t = np.linspace(0, duration, 400001)
    env = np.exp(-zeta * w * t)
    p = v0 / wd * env * np.sin(wd * t)
    pd = v0 * env * (np.cos(wd * t) - zeta * w / wd * np.sin(wd * t))
    return float(np.max(kcs * p + bcs * pd)), duration, -v0 * math.exp(-zeta * w * duration)


def heun_delay(m1, m2, kcs, bcs, k, h, v0, t_end, n_per_delay):
    """p'' = -((kcs - k) p + bcs p') / m [touching] - k max(p(t - h), 0) / m [t >= h], m the reduced
    mass (the closed-form impedance makes the virtual part exactly kcs - k, bcs). Heun's method on
    a grid of h / n; the delayed value at a grid time is a stored grid value; a step in which the
    contact starts or ends, or in which event + h falls, is split there (linear interpolation)."""
    m = m1 * m2 / (m1 + m2)
    dt = h / n_per_delay
    n = int(round(t_end / dt))
    ps, vs = np.zeros(n + 1), np.zeros(n + 1)
    ps[0], vs[0] = 0.0, v0
    touching = True
    kinks = []  # event + h: where the delayed force has a kink

    def past(t):
        if t < h - 1e-15:
            return 0.0
        x = (t - h) / dt
        i = int(math.floor(x + 1e-9))
        f = x - i
        val = ps[i] if f < 1e-9 else ps[i] * (1 - f) + ps[i + 1] * f
        return max(val, 0.0)

    def acc(t, p, v, on):
        return (-((kcs - k) * p + bcs * v) / m if on else 0.0) - k * past(t) / m

    def heun(t, p, v, step, on):
        a1 = acc(t, p, v, on)
        pp, vp = p + step * v, v + step * a1
        a2 = acc(t + step, pp, vp, on)
        return p + 0.5 * step * (v + vp), v + 0.5 * step * (a1 + a2)

    for i in range(n):
        t, p, v = i * dt, ps[i], vs[i]
        end = t + dt
        cuts = [c for c in kinks if t < c < end]
        while True:
            stop = cuts.pop(0) if cuts else end
            p1, v1 = heun(t, p, v, stop - t, touching)
            if (p1 <= 0) if touching else (p1 > 0):
                te = t + (stop - t) * p / (p - p1)  # the crossing, linearly
                p, v = heun(t, p, v, te - t, touching)
                p, t, touching = 0.0, te, not touching
                bisect.insort(kinks, te + h)
                if te + h < end:
                    cuts = sorted(cuts + [te + h])
                continue
            p, v, t = p1, v1, stop
            if stop >= end:
                break
        ps[i + 1], vs[i + 1] = p, v
    tt = np.arange(n + 1) * dt
    fs = np.array([k * past(x) for x in tt])
    return tt, ps, vs, fs


@pytest.fixture(scope="module")
def table1_delay_solution():
    """Table 1, k = 1000 N/m, h = 32 ms: Heun at h/1280 and h/2560, Richardson-extrapolated (order 2)."""
    a = heun_delay(TABLE1.m1, TABLE1.m2, TABLE1.kcs, TABLE1.bcs, TABLE1.k, 0.032, TABLE1.v1, 2.0, 640)
    b = heun_delay(TABLE1.m1, TABLE1.m2, TABLE1.kcs, TABLE1.bcs, TABLE1.k, 0.032, TABLE1.v1, 2.0, 1280)
    sel = np.arange(0, len(b[0]), 2)
    p = (4 * b[1][sel] - a[1]) / 3
    pd = (4 * b[2][sel] - a[2]) / 3
    fs = (4 * b[3][sel] - a[3]) / 3
    return a[0], p, pd, fs, float(np.max(np.abs(b[1][sel] - a[1])))


def compressive(p, pd, fs, touching):
    """Force on the chaser: the virtual part (kcs - k) p + bcs p' while touching, plus the passive push."""
    return np.where(touching, (TABLE1.kcs - TABLE1.k) * p + TABLE1.bcs * pd, 0.0) + fs


def test_report_writes_json_markdown_and_plots(quick_report):
    code, out, _ = quick_report
    assert code == 0
    data = json.loads((out / "report.json").read_text())
    for key in (
        "work_precision",
        "work_precision_summary",
        "reference",
        "graph_cost",
        "energy_drift",
        "stiff_cases",
        "plots",
        "run_time_s",
    ):
        assert key in data, key
    assert "lean" not in data  # --no-lean
    for name in data["plots"].values():
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "report.md").read_text()
    for heading in (
        "## Error against run time",
        "## The graph's cost",
        "## Energy over a long run",
        "## Stiff and extreme cases",
    ):
        assert heading in md
    assert "first order" in md and "Self-comparisons: none" in md
    assert md.count("\n| ") > len(data["stiff_cases"])  # the case table is there


def test_progress_goes_to_stderr_line_by_line_when_not_a_terminal(quick_report):
    _, _, err = quick_report
    bars = [ln for ln in err.splitlines() if ln.startswith("[")]
    assert len(bars) > 10 and "\r" not in err
    assert bars[-1].startswith("[" + "#" * 30 + "]") and "done" in bars[-1]


def test_progress_redraws_in_place_on_a_terminal():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    stream = Tty()
    bar = TaskProgress(3, stream)
    for label in ("a", "b", "c"):
        bar.step(label)
    assert "\n" not in stream.getvalue() and stream.getvalue().count("\r") == 3
    bar.finish()
    assert stream.getvalue().endswith("\n")


# -- the references ------------------------------------------------------------------------------------


def test_the_reports_reference_agrees_with_the_independent_solver_written_here(table1_delay_solution):
    t, p, pd, fs, heun_spread = table1_delay_solution
    ref = report_precision.hybrid_reference(report_precision.ReportConfig(min_timing_s=0.0))
    grid = np.arange(2001) * 1e-3
    idx = np.round(grid / (0.032 / 640)).astype(int)
    s = ref.sample(grid)
    assert heun_spread < 1e-6  # the two Heun runs agree: the extrapolation is meaningful
    assert np.max(np.abs(compressive(p[idx], pd[idx], fs[idx], s["touching"]) - s["force"])) < 1e-8
    # The delay raises the peak force over the ideal contact's (Fig. 9); about 1 N as the paper measured.
    peak, _, _ = ideal_closed_form(TABLE1.m1, TABLE1.m2, TABLE1.kcs, TABLE1.bcs, TABLE1.v1)
    assert 0.3 < np.max(s["force"]) - peak < 1.5


def test_reference_check_is_stated_and_no_row_compares_with_itself(quick_report):
    _, out, _ = quick_report
    ref = json.loads((out / "report.json").read_text())["reference"]
    assert "method-of-steps" in ref["hybrid_delay"] and "solve_ivp" not in ref["hybrid_delay"]
    # The quick report checks its reference against the same solver at twice the step.
    assert ref["hybrid_delay_step_check_dt_s"] == 2 * report_precision.REFERENCE_DT
    assert "twice the step" in ref["hybrid_delay_check"]
    assert ref["hybrid_delay_step_check_N"] < 1e-8 and ref["hybrid_delay_dop853_N"] < 1e-6
    entries = json.loads((out / "report.json").read_text())["work_precision"]
    dop = [e for e in entries if e["model"] == "hybrid_delay" and e["method"] == "solve_ivp RK45"]
    # Measured against other code, the solve_ivp rows now show their own tolerance-dependent error.
    errors = [e["max_error_N"] for e in sorted(dop, key=lambda e: e["rtol"])]
    assert errors[0] < errors[-1]


def test_hybrid_work_precision_error_is_the_one_computed_here(quick_report, table1_delay_solution):
    _, out, _ = quick_report
    entries = json.loads((out / "report.json").read_text())["work_precision"]
    entry = next(e for e in entries if e["model"] == "hybrid_delay" and e["method"] == "exact" and e["step_s"] == 1e-3)
    t, p, pd, fs, _ = table1_delay_solution
    run = simulate_hil(
        m1=TABLE1.m1,
        m2=TABLE1.m2,
        k=TABLE1.k,
        impedance=report_precision.hybrid_impedance(TABLE1),
        dt=1e-3,
        n_ticks=2001,
        v1=TABLE1.v1,
        delay=0.032,
    )
    idx = np.round(run.t / (0.032 / 640)).astype(int)
    rp, rpd = run.x1 - run.x2, run.v1 - run.v2
    mine_touch = (rp > 0) | ((rp == 0) & (rpd > 0))
    ref_touch = (p[idx] > 0) | ((p[idx] == 0) & (pd[idx] > 0))
    either = mine_touch | ref_touch
    # The contact law on both states wherever either touches, plus each one's passive push.
    passive_run = run.force - np.where(mine_touch, (TABLE1.kcs - TABLE1.k) * rp + TABLE1.bcs * rpd, 0.0)
    mine = np.where(either, (TABLE1.kcs - TABLE1.k) * rp + TABLE1.bcs * rpd, 0.0) + passive_run
    theirs = np.where(either, (TABLE1.kcs - TABLE1.k) * p[idx] + TABLE1.bcs * pd[idx], 0.0) + fs[idx]
    assert entry["max_error_N"] == pytest.approx(float(np.max(np.abs(mine - theirs))), rel=1e-4)


def test_observed_orders(quick_report):
    _, out, _ = quick_report
    data = json.loads((out / "report.json").read_text())
    rows = {(r["model"], r["method"]): r for r in data["work_precision_summary"]}
    # Euler on the ideal contact and every integrator on the held-force delayed loop: first order.
    assert rows[("ideal", "euler")]["order"] == pytest.approx(1.0, abs=0.1)
    for method in ("exact", "rk4", "euler"):
        assert rows[("hybrid_delay", method)]["order"] == pytest.approx(1.0, abs=0.15), method
    assert rows[("ideal", "solve_ivp RK45")]["order_in"] == "rtol"
    assert "zero-order hold" in data["reference"]["first_order_why"]


def test_work_precision_entries(quick_report):
    _, out, _ = quick_report
    entries = json.loads((out / "report.json").read_text())["work_precision"]
    assert {e["model"] for e in entries} == {"ideal", "ideal_stiff", "hybrid_delay"}
    for e in entries:
        assert ("step_s" in e) != ("rtol" in e), e
        if "refused" not in e:
            assert e["max_error_N"] >= 0 and e["run_time_s"] > 0

    def error(model, method, dt):
        return next(
            e["max_error_N"] for e in entries if e["model"] == model and e["method"] == method and e.get("step_s") == dt
        )

    assert error("ideal", "exact", 1e-3) < 1e-9
    # Explicit Euler on the stiff contact is refused above |R(lambda dt)| = 1, which the entry names:
    # for Euler, R(z) = 1 + z on the contact's poles lambda, so dt_max = -2 Re(lambda) / |lambda|^2.
    stiff = report_precision.IDEAL_MODELS["ideal_stiff"][0]
    lam = np.roots([stiff.reduced_mass, stiff.bcs, stiff.kcs])[0]
    limit = -2 * lam.real / abs(lam) ** 2
    refused = [e for e in entries if e["model"] == "ideal_stiff" and e["method"] == "euler" and "refused" in e]
    assert refused and all(e["step_s"] > limit for e in refused)
    assert all(e["largest_stable_step_s"] == pytest.approx(limit, rel=1e-5) for e in refused)


def test_graph_modes_are_bit_identical(quick_report):
    _, out, _ = quick_report
    g = json.loads((out / "report.json").read_text())["graph_cost"]
    assert g["composed_equals_library"] is True and g["multiprocess_equals_library"] is True
    assert {m["mode"] for m in g["modes"]} == {"library", "composed", "multiprocess"}


def test_energy_drift_per_integrator(quick_report):
    _, out, _ = quick_report
    runs = {r["method"]: r for r in json.loads((out / "report.json").read_text())["energy_drift"]["runs"]}
    assert abs(runs["exact"]["final_relative_drift"]) < 1e-9
    assert runs["rk4"]["final_relative_drift"] < 0  # RK4 damps an undamped oscillation
    assert "refused" in runs["euler"] and runs["euler"]["largest_stable_step_s"] == 0.0


# -- the cases, measured values against expectations computed here -------------------------------------


def cases_of(quick_report, group_start):
    _, out, _ = quick_report
    return [
        c for c in json.loads((out / "report.json").read_text())["stiff_cases"] if c["group"].startswith(group_start)
    ]


def fine_rate(m1, m2, kcs, bcs):
    """The documented criterion: omega*dt <= 0.025 and 100 samples per contact, two digits up."""
    peak, duration, _ = ideal_closed_form(m1, m2, kcs, bcs, 1.0)
    m = m1 * m2 / (m1 + m2)
    need = max(math.sqrt(kcs / m) / 0.025, 100 / duration)
    scale = 10 ** (math.floor(math.log10(need)) - 1)
    return math.ceil(need / scale - 1e-9) * scale


def test_hil_stiff_contact_cases(quick_report):
    by = {c["name"]: c for c in cases_of(quick_report, "HIL loop: stiff")}
    sc = report_cases.HIL_STIFF
    peak, _, exit_v = ideal_closed_form(sc.m1, sc.m2, sc.kcs, sc.bcs, sc.v1 - sc.v2)
    assert peak == pytest.approx(559.0, abs=0.5) and exit_v == pytest.approx(-0.141, abs=5e-4)
    coarse = by["at 1 kHz (what the graph would run)"]
    assert coarse["measured_value"] == pytest.approx(1444, abs=1)  # the silent garbage
    rate = fine_rate(sc.m1, sc.m2, sc.kcs, sc.bcs)
    assert rate == 110000
    fine = by[f"at the named rate {rate:g} Hz"]["measured_value"]
    assert fine[0] == pytest.approx(peak, rel=0.015) and fine[1] == pytest.approx(exit_v, rel=0.025)
    refused = by["hil.yaml at 1 kHz: refused before it runs"]
    assert refused["measured_value"] == rate and "exit 2, 1 line(s)" in refused["measured"]


def test_hil_late_contact_exit_against_the_solver_written_here(quick_report):
    sc = report_cases.HIL_LATE
    cases = cases_of(quick_report, "HIL loop: 0.1 s delay")
    a = heun_delay(sc.m1, sc.m2, sc.kcs, sc.bcs, sc.k, 0.1, sc.v1 - sc.v2, 0.7, 2000)
    b = heun_delay(sc.m1, sc.m2, sc.kcs, sc.bcs, sc.k, 0.1, sc.v1 - sc.v2, 0.7, 4000)
    want = (4 * b[2][-1] - a[2][-1]) / 3  # after the last delayed push (exit ~0.33 s, + 0.1 s)
    exits = [c for c in cases if c["name"].startswith("exit velocity")]
    for c in exits:
        assert c["expected_value"] == pytest.approx(want, abs=1e-8)
        assert abs(c["measured_value"] - want) < c["params"]["dt"]  # first order in the step
    e3, e4 = (abs(c["measured_value"] - want) for c in exits)
    assert math.log10(e3 / e4) == pytest.approx(1.0, abs=0.2)


def test_stiff_graph_is_refused_and_runs_bit_identical_when_allowed(quick_report):
    by = {c["name"]: c for c in cases_of(quick_report, "kcs = 1e9")}
    sc = report_cases.STIFF
    refused = by["ideal.yaml at 1 kHz: refused before it runs"]
    m = sc.m1 * sc.m2 / (sc.m1 + sc.m2)
    lam = np.roots([m, sc.bcs, sc.kcs])
    want = max(float(np.max(np.abs(lam))) / 0.025, 100 / (math.pi / abs(lam[0].imag)))
    scale = 10 ** (math.floor(math.log10(want)) - 1)
    assert refused["measured_value"] == math.ceil(want / scale - 1e-9) * scale
    _, _, exit_v = ideal_closed_form(sc.m1, sc.m2, sc.kcs, sc.bcs, sc.v1 - sc.v2)
    # The quick report composes the graph here (its multi-process runs are the graph cost's).
    graph = by["composed graph (launch/ideal.yaml), exact"]
    assert graph["measured_value"] == pytest.approx(exit_v, rel=1e-6) and graph["params"]["mode"] == "composed"
    assert by["composed graph equals the library loop"]["measured"] == "bit-identical"
    rk4 = by["composed graph, method rk4"]
    assert rk4["measured_value"] == pytest.approx(method_limit(sc, "rk4"), rel=1e-5)
    assert rk4["measured"].startswith("exit code 1, 1 error line(s)")


def method_limit(scn, method):
    """Largest stable step of an explicit method on the contact's poles (bisection on the step map)."""
    m = scn.reduced_mass
    lam = np.roots([m, scn.bcs, scn.kcs])

    def stable(dt):
        if method == "euler":
            return all(abs(1 + z) <= 1 for z in lam * dt)
        if method == "rk4":
            return all(abs(1 + z + z * z / 2 + z**3 / 6 + z**4 / 24) <= 1 for z in lam * dt)
        a = np.array(
            [[1 - dt * dt * scn.kcs / m, dt - dt * dt * scn.bcs / m], [-dt * scn.kcs / m, 1 - dt * scn.bcs / m]]
        )
        return max(abs(np.linalg.eigvals(a))) <= 1 + 1e-12

    lo, hi = 0.0, 1.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return lo


@pytest.mark.parametrize("method", report_precision.EXPLICIT)
def test_explicit_method_refuses_and_names_the_largest_stable_step(method):
    case = report_cases.explicit_refusal_case("t", report_cases.STIFF, method, 1e-3)
    limit = method_limit(report_cases.STIFF, method)
    assert case["measured"].startswith("refused") and case["measured_value"] == pytest.approx(limit, rel=1e-5)
    report_cases.simulate_contact(
        report_cases.STIFF, method=method, dt=0.99 * limit, t_end=0.99 * limit
    )  # just inside, it runs


@pytest.mark.parametrize("method", report_precision.EXPLICIT)
def test_named_step_separates_decay_from_growth(method):
    limit = method_limit(report_cases.STIFF, method)
    growth = report_cases.energy_growth
    assert growth(report_cases.STIFF, method, 0.9 * limit) <= 0.0 < growth(report_cases.STIFF, method, 1.1 * limit)


def test_stiff_contact_exit_at_every_onset_phase_and_with_implicit_solvers(quick_report):
    sc = report_cases.STIFF
    _, _, exit_v = ideal_closed_form(sc.m1, sc.m2, sc.kcs, sc.bcs, sc.v1 - sc.v2)
    by = {c["name"]: c for c in cases_of(quick_report, "kcs = 1e9")}
    assert all(
        v == pytest.approx(exit_v, rel=1e-6) for v in by["exact step, onset at tenths of a step"]["measured_value"]
    )
    implicit = [c for c in by.values() if c["name"].startswith("solve_ivp")]
    assert len(implicit) == 2 and all(c["measured_value"] == pytest.approx(exit_v, rel=1e-6) for c in implicit)


def test_mass_ratios_against_the_closed_form_peak(quick_report):
    cases = cases_of(quick_report, "mass ratio")
    assert [c["params"]["m2"] / c["params"]["m1"] for c in cases] == pytest.approx(list(report_cases.MASS_RATIOS))
    for c in cases:
        p = c["params"]
        m = p["m1"] * p["m2"] / (p["m1"] + p["m2"])
        if p["bcs"] ** 2 < 4 * p["kcs"] * m:  # underdamped: the closed form written here
            peak, _, _ = ideal_closed_form(p["m1"], p["m2"], p["kcs"], p["bcs"], p["v1"] - p["v2"])
            assert c["expected_value"] == pytest.approx(peak, rel=1e-6)
        assert max(c["measured_value"]) < 1e-6  # force error / peak, ideal and hybrid; momentum


def test_zero_damping_restitution_and_rk4_loss(quick_report):
    by = {c["name"]: c for c in cases_of(quick_report, "zero damping")}
    assert by["unilateral contact, exact step: restitution"]["measured_value"] == pytest.approx(1.0, abs=1e-9)
    rk4 = next(c for c in by.values() if c["name"].startswith("rk4"))
    scn = report_precision.undamped_scenario()
    dt, n = rk4["params"]["dt"], round(rk4["params"]["t_end"] / rk4["params"]["dt"])
    z = 1j * math.sqrt(scn.kcs / scn.reduced_mass) * dt  # RK4's amplification on the undamped pole
    rho = abs(1 + z + z * z / 2 + z**3 / 6 + z**4 / 24)
    assert rk4["measured_value"] == pytest.approx(rho ** (2 * n) - 1.0, rel=1e-3) and rk4["measured_value"] < 0


def test_delay_zero_and_far_beyond_the_contact(quick_report):
    by = {c["name"]: c for c in cases_of(quick_report, "robot delay")}
    peak, _, _ = ideal_closed_form(TABLE1.m1, TABLE1.m2, TABLE1.kcs, TABLE1.bcs, TABLE1.v1)
    assert by["delay 0: hybrid loop = ideal contact"]["measured_value"] == pytest.approx(peak, abs=0.05)
    soft_peak, soft_duration, _ = ideal_closed_form(TABLE1.m1, TABLE1.m2, TABLE1.kcs - TABLE1.k, TABLE1.bcs, TABLE1.v1)
    far = next(c for c in by.values() if "virtual part only" in c["name"])
    assert far["measured_value"] == pytest.approx(soft_peak, abs=0.05) and far["params"]["delay"] > 3 * soft_duration


def test_negative_virtual_stiffness(quick_report):
    cases = cases_of(quick_report, "kcs < k")
    p = cases[0]["params"]
    want = (p["kcs"] - p["k"]) * (1 + p["m1"] / p["m2"])  # k1 of the closed form, negative here
    assert want < 0 and cases[0]["measured_value"] == pytest.approx(want, rel=1e-12)
    assert cases[1]["measured_value"] < 1e-9 * cases[1]["expected_value"]


def test_growth_just_inside_and_outside_the_boundary_is_the_sampled_loops(quick_report):
    for c in cases_of(quick_report, "exact stability boundary"):
        p = c["params"]
        d, dt = int(round(p["h"] / p["dt"])), p["dt"]
        n = 2 * (d + 1)
        a = np.zeros((n, n))  # [p, p']_k ... [p, p']_{k-d}: damper now, sheet d ticks late, forces held
        a[0, :2] = [1.0, dt - 0.5 * dt * dt * p["b"] / p["m"]]
        a[1, :2] = [0.0, 1 - dt * p["b"] / p["m"]]
        a[0, 2 * d] += -0.5 * dt * dt * p["K"] / p["m"]
        a[1, 2 * d] += -dt * p["K"] / p["m"]
        a[2:, : 2 * d] = np.eye(2 * d)
        root = math.log(max(abs(np.linalg.eigvals(a)))) / dt
        assert c["expected_value"] == pytest.approx(root, rel=1e-9)
        assert c["measured_value"] == pytest.approx(root, rel=0.02)


# The two commands below are refused before they start anything: run in this process (the command
# line's own entry point; tests/test_package.py runs the installed `dockhil` command).
def test_bad_masses_are_refused_in_one_line(capsys):
    for bad in (math.nan, math.inf, 0.0, -1.0):
        with pytest.raises(ContactModelError, match="m1"):
            ContactScenario(m1=bad, m2=1e6, kcs=3000, bcs=40)
    code = main(["launch", "launch/ideal.yaml", "m1:=nan", "--duration", "0.01", "--composed"])
    err = capsys.readouterr().err
    assert code != 0 and len(err.strip().splitlines()) == 1 and "m1" in err


def test_report_refuses_an_unwritable_out(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("")
    code = main(["report", "--quick", "--out", str(f)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "exists and is not a directory" in err
