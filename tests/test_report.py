"""`dockhil report` on its small configuration, and each stiff or extreme case on its own,
with its expectation recomputed here from the model."""

import contextlib
import io
import json

import numpy as np
import pytest

from dockhil.progress import TaskProgress

from dockhil import report as R
from dockhil.cli import main
from dockhil.contact import stability
from dockhil.contact.ideal import ideal_contact_summary, ideal_trajectory
from dockhil.contact.integrators import LinearSecondOrderSystem, max_stable_step, simulate_contact
from dockhil.contact.scenario import TABLE1, ContactScenario

QUICK = R.ReportConfig.quick_config()
SCENARIO_KEYS = ("m1", "m2", "kcs", "bcs", "k", "v1", "v2")


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    err = io.StringIO()
    runtime = tmp_path_factory.mktemp("rt")
    # Module scope runs before conftest's per-test runtime directory: give the launches their own.
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stderr(err), \
            contextlib.redirect_stdout(io.StringIO()):
        mp.setenv("DOCKHIL_RUNTIME_DIR", str(runtime))
        code = main(["report", "--quick", "--out", str(out)])
    return code, out, err.getvalue()


def test_report_writes_json_markdown_and_plots(quick_report):
    code, out, _ = quick_report
    assert code == 0
    data = json.loads((out / "report.json").read_text())
    for key in ("work_precision", "work_precision_summary", "reference", "graph_cost", "energy_drift",
                "stiff_cases", "lean", "plots", "run_time_s"):
        assert key in data, key
    for name in data["plots"].values():
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "report.md").read_text()
    for heading in ("## Error against run time", "## The graph's cost", "## Energy over a long run",
                    "## Stiff and extreme cases", "## Lean scenes"):
        assert heading in md
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


def test_work_precision_entries(quick_report):
    _, out, _ = quick_report
    entries = json.loads((out / "report.json").read_text())["work_precision"]
    models = {e["model"] for e in entries}
    assert models == {"ideal", "ideal_stiff", "hybrid_delay"}
    for e in entries:
        assert ("step_s" in e) != ("rtol" in e), e
        assert {"model", "method", "max_error_N", "run_time_s"} <= set(e)
        if "refused" not in e:
            assert e["max_error_N"] >= 0 and e["run_time_s"] > 0
    methods = {e["method"] for e in entries}
    assert {"exact", "rk4", "symplectic_euler", "euler"} <= methods
    assert any(m.startswith("solve_ivp") for m in methods)

    def error(model, method, dt):
        return next(e["max_error_N"] for e in entries if e["model"] == model and e["method"] == method
                    and e.get("step_s") == dt)

    # The exact step reproduces the closed form to round-off; explicit Euler is first order.
    assert error("ideal", "exact", 1e-3) < 1e-9
    assert 5 < error("ideal", "euler", 1e-3) / error("ideal", "euler", 1e-4) < 20
    # Explicit Euler on the stiff contact is refused above its stability limit, which the entry names.
    stiff = R.IDEAL_MODELS["ideal_stiff"][0]
    limit = max_stable_step(LinearSecondOrderSystem.ideal_contact(stiff), "euler")
    refused = [e for e in entries if e["model"] == "ideal_stiff" and e["method"] == "euler" and "refused" in e]
    assert refused and all(e["step_s"] > limit for e in refused)
    assert all(e["largest_stable_step_s"] == pytest.approx(limit, rel=1e-5) for e in refused)
    ran = [e for e in entries if e["model"] == "ideal_stiff" and e["method"] == "euler" and "refused" not in e]
    assert all(e["step_s"] <= limit for e in ran)
    # The sampled HIL loop converges to the continuous delay reference at first order.
    assert 5 < error("hybrid_delay", "exact", 1e-3) / error("hybrid_delay", "exact", 1e-4) < 20


def test_graph_modes_are_bit_identical(quick_report):
    _, out, _ = quick_report
    g = json.loads((out / "report.json").read_text())["graph_cost"]
    assert g["composed_equals_library"] is True
    assert g["multiprocess_equals_library"] is True
    assert {m["mode"] for m in g["modes"]} == {"library", "composed", "multiprocess"}
    assert all(m["run_time_s"] > 0 for m in g["modes"])


def test_energy_drift_per_integrator(quick_report):
    _, out, _ = quick_report
    runs = {r["method"]: r for r in json.loads((out / "report.json").read_text())["energy_drift"]["runs"]}
    assert abs(runs["exact"]["final_relative_drift"]) < 1e-9
    assert runs["rk4"]["final_relative_drift"] < 0  # RK4 damps an undamped oscillation
    assert "refused" in runs["euler"] and runs["euler"]["largest_stable_step_s"] == 0.0


def _scenario(params):
    return ContactScenario(**{k: params[k] for k in SCENARIO_KEYS})


def test_each_case_expectation_is_the_models(quick_report):
    """Recompute every case's expectation here from its recorded parameters."""
    _, out, _ = quick_report
    cases = json.loads((out / "report.json").read_text())["stiff_cases"]
    assert all({"name", "expected", "measured", "passed"} <= set(c) for c in cases)
    checked = 0
    for c in cases:
        p = c["params"]
        if c["expected"].startswith("refuses, names"):
            system = LinearSecondOrderSystem.ideal_contact(_scenario(p))
            assert c["expected_value"] == pytest.approx(max_stable_step(system, p["method"]), rel=1e-12)
            checked += 1
        elif c["group"] == "mass ratio m2/m1":
            assert c["expected_value"] == pytest.approx(ideal_contact_summary(_scenario(p)).peak_force, rel=1e-12)
            checked += 1
        elif c["group"] == "exact stability boundary":
            h_eff = p["h"] + p["dt"] / 2
            assert c["expected_value"] == pytest.approx(
                stability.growth_rate(p["m"], p["K"], p["b"], h_eff, "undelayed"), rel=1e-6)
            checked += 1
        elif "exit" in c["expected"] and "m1" in p and "kcs" in p and "gap" in p:
            want = ideal_contact_summary(_scenario(p)).exit_relative_velocity
            assert c["expected_value"] == pytest.approx(want, rel=1e-12)
            checked += 1
    assert checked >= 15
    groups = {c["group"] for c in cases}
    assert len(groups) >= 8


def test_stiff_graph_runs_are_the_library_loop_and_refuse_rk4(quick_report):
    _, out, _ = quick_report
    cases = {c["name"]: c for c in json.loads((out / "report.json").read_text())["stiff_cases"]}
    assert cases["multi-process graph equals the library loop"]["passed"]
    assert cases["multi-process graph, method rk4"]["passed"]


# -- each case on its own ---------------------------------------------------------------------


@pytest.mark.parametrize("method", R.EXPLICIT)
def test_explicit_method_refuses_and_names_the_largest_stable_step(method):
    case = R.explicit_refusal_case("t", R.STIFF, method, 1e-3)
    limit = max_stable_step(LinearSecondOrderSystem.ideal_contact(R.STIFF), method)
    assert case["passed"] and case["expected_value"] == limit and case["measured_value"] == pytest.approx(limit, rel=1e-5)
    # Just inside the named step the method runs.
    simulate_contact(R.STIFF, method=method, dt=0.99 * limit, t_end=0.99 * limit)


@pytest.mark.parametrize("method", R.EXPLICIT)
def test_named_step_separates_decay_from_growth(method):
    limit = max_stable_step(LinearSecondOrderSystem.ideal_contact(R.STIFF), method)
    assert R.energy_growth(R.STIFF, method, 0.9 * limit) <= 0.0 < R.energy_growth(R.STIFF, method, 1.1 * limit)


def _by_name(cases):
    return {c["name"]: c for c in cases}


def test_stiff_contact_inside_one_step_at_every_onset_phase():
    case = _by_name(R.stiff_contact_cases(R.ReportConfig(graph=False)))["exact step, onset at tenths of a step"]
    assert case["passed"], case["measured"]


def test_stiff_contact_implicit_solvers_match_the_closed_form():
    cases = R.stiff_contact_cases(R.ReportConfig(graph=False))
    want = ideal_contact_summary(R.STIFF).exit_relative_velocity
    implicit = [c for c in cases if c["name"].startswith("solve_ivp")]
    assert len(implicit) == 2
    for c in implicit:
        assert c["passed"] and c["measured_value"] == pytest.approx(want, rel=1e-6)


def test_overdamped_contact_far_below_the_step():
    cases = R.overdamped_cases(QUICK)
    assert all(c["passed"] for c in cases), [c for c in cases if not c["passed"]]
    exact = _by_name(cases)["exact step against the closed form"]
    scn = _scenario(exact["params"])
    assert exact["params"]["fast_time_constant_s"] == pytest.approx(scn.reduced_mass / scn.bcs)
    assert exact["params"]["fast_time_constant_s"] < 1e-3 * exact["params"]["dt"]


def test_zero_damping_keeps_energy():
    cases = R.zero_damping_cases(QUICK)
    assert all(c["passed"] for c in cases), [c for c in cases if not c["passed"]]
    by = _by_name(cases)
    assert by["unilateral contact, exact step: restitution"]["expected_value"] == pytest.approx(1.0, abs=1e-12)
    rk4 = next(c for c in cases if c["name"].startswith("rk4"))
    # RK4's predicted loss is rho^(2n) - 1 of its own step map: recompute rho here.
    scn = R.undamped_scenario()
    system = LinearSecondOrderSystem.ideal_contact(scn)
    from dockhil.contact.integrators import step_matrices

    basis = system.flexible_basis()
    rho = np.max(np.abs(np.linalg.eigvals(basis.T @ step_matrices(system, "rk4", rk4["params"]["dt"])[0] @ basis)))
    n = round(rk4["params"]["t_end"] / rk4["params"]["dt"])
    assert rk4["expected_value"] == pytest.approx(rho ** (2 * n) - 1.0, rel=1e-9) and rk4["expected_value"] < 0


def test_mass_ratios_from_1e_minus_6_to_1e9():
    cases = R.mass_ratio_cases(QUICK)
    assert [c["params"]["m2"] / c["params"]["m1"] for c in cases] == pytest.approx(list(R.MASS_RATIOS))
    assert all(c["passed"] for c in cases), [c for c in cases if not c["passed"]]


def test_delay_zero_and_delay_far_beyond_the_contact():
    cases = R.delay_cases(QUICK)
    assert all(c["passed"] for c in cases), [c for c in cases if not c["passed"]]
    soft = ideal_contact_summary(TABLE1.replace(kcs=TABLE1.kcs - TABLE1.k))
    long_delay = next(c for c in cases if "virtual part only" in c["name"])
    assert long_delay["expected_value"] == pytest.approx(soft.peak_force, rel=1e-12)
    assert long_delay["params"]["delay"] > 3 * soft.duration


def test_negative_virtual_stiffness_warns_and_matches_the_ideal():
    cases = R.negative_stiffness_cases(QUICK)
    assert all(c["passed"] for c in cases), [c for c in cases if not c["passed"]]
    assert cases[0]["expected_value"] < 0


def test_just_inside_and_just_outside_the_exact_boundary():
    cases = R.stability_boundary_cases(QUICK)
    assert [c["expected_value"] < 0 for c in cases] == [True, False]
    assert all(c["passed"] for c in cases), cases
    p = cases[0]["params"]
    k_max = stability.exact_bound(p["m"], p["b"], p["h"] + p["dt"] / 2, "undelayed").k_max
    assert p["K_max"] == pytest.approx(k_max)


def test_nan_inf_and_non_positive_masses_are_refused_in_one_line():
    cases = R.refusal_cases(QUICK)
    assert len(cases) >= 14
    assert all(c["passed"] for c in cases), [c for c in cases if not c["passed"]]


# -- the references ------------------------------------------------------------------------------


def test_continuous_run_without_delay_is_the_closed_form():
    run = R.DelayedContactRun(TABLE1, t_end=2.0, rtol=1e-12, atol=1e-16)
    t = np.linspace(0.0, 2.0, 401)
    s, ref = run.sample(t), ideal_trajectory(TABLE1, t)
    assert np.max(np.abs((s["x1"] - s["x2"]) - ref.penetration)) < 1e-12
    assert run.events[0] == pytest.approx(ref.exit, abs=1e-9)


def test_delayed_reference_agrees_across_methods():
    cfg = R.ReportConfig(contact_t_end=2.0, min_timing_s=0.0)
    ref = R.hybrid_reference(cfg)
    assert R.hybrid_ivp("RK45", 1e-10, cfg, ref)["max_error_N"] < 1e-7
    # The delay raises the peak force over the ideal contact's (Fig. 9).
    t = np.linspace(0.0, 2.0, 2001)
    s = ref.sample(t)
    p, pd = s["x1"] - s["x2"], s["v1"] - s["v2"]
    force = R.compared_force(TABLE1, ref.impedance, p, pd, s["touching"], s["touching"], s["fs"])
    rise = np.max(force) - ideal_contact_summary(TABLE1).peak_force
    assert 0.3 < rise < 1.5
