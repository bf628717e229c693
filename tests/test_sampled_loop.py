"""The loop a scene actually runs: its eigenvalues, the refusal of a step that does not resolve
the contact, the exit velocity after the last force, the streaming summary, growth rates.

Expected values come from closed forms or from a plain loop simulation written here, which
shares no code with the library: free bodies integrated exactly under held forces, virtual
forces from the closed-form impedance, the passive spring read through a delay line."""

import json
import math
import subprocess

import numpy as np
import pytest

from dockhil.contact.sampled import SampledLoop, characteristic_polynomial, one_tick_map, spectral_radius
from tests.conftest import dockhil_cmd

STIFF = dict(m1=2.3, m2=4.1, kcs=1e7, bcs=150.0, k=2e6, v1=0.12, v2=-0.03)  # issue 12, item 1
LATE = dict(m1=300.0, m2=1100.0, kcs=22000.0, bcs=45.0, k=9000.0, v1=0.08, v2=0.05)  # issue 12, item 2


def plain_hil(m1, m2, kcs, bcs, k, v1, v2, dt, n, delay_ticks):
    """The HIL loop in a dozen lines: tick k reads the state, computes the virtual force (closed-form
    impedance, CoM wall) and the passive force of the pose d ticks old, and holds both over the step."""
    M = m1 + m2
    k1, b1 = (kcs - k) * M / m2, bcs * M / m2
    k2, b2 = (kcs - k) * M / m1, bcs * M / m1
    x = np.array([0.0, 0.0])
    v = np.array([v1, v2])
    poses = []
    rows = []
    for _ in range(n):
        p, pd = x[0] - x[1], v[0] - v[1]
        touching = p > 0 or (p == 0 and pd > 0)
        fv = np.array([-(m2 / M) * (k1 * p + b1 * pd), (m1 / M) * (k2 * p + b2 * pd)]) if touching else np.zeros(2)
        poses.append(p)
        old = poses[-1 - delay_ticks] if len(poses) > delay_ticks else None
        fs = k * old if old is not None and old > 0 else 0.0
        f = fv + np.array([-fs, fs])
        rows.append((p, pd, -f[0], bool(np.any(f != 0))))
        a = f / np.array([m1, m2])
        x = x + v * dt + 0.5 * a * dt * dt
        v = v + a * dt
    return rows


def launch(*args, timeout=120):
    return subprocess.run(dockhil_cmd("launch", *args, "--composed"), capture_output=True, text=True, timeout=timeout)


def overrides(case, **more):
    return [f"{k}:={v}" for k, v in {**case, **more}.items()]


# -- the loop's eigenvalues ------------------------------------------------------------------------


def test_polynomial_roots_are_the_eigenvalues_of_the_tick_map_and_of_the_plain_loop():
    # Equal masses, a delayed spring and a direct damper: m = 375 kg at 1 kHz with 5 ticks of delay.
    loop = SampledLoop(m=375.0, k_direct=500.0, b_direct=30.0, k_delayed=2500.0, dt=1e-3, delay_ticks=5)
    roots = np.roots(characteristic_polynomial(loop)[::-1])
    eig = np.linalg.eigvals(one_tick_map(loop))
    assert max(abs(roots)) == pytest.approx(max(abs(eig)), abs=1e-12)
    # The plain recurrence, written here: p'' = -(kd p + bd p') / m - kh p_{k-5} / m held over a tick.
    dt, m = 1e-3, 375.0
    p, pd, hist = 1e-3, 0.0, [1e-3] * 6
    amp = []
    for _ in range(60000):
        a = -(500.0 * p + 30.0 * pd) / m - 2500.0 * hist[-6] / m
        p, pd = p + pd * dt + 0.5 * a * dt * dt, pd + a * dt
        hist = hist[1:] + [p]
        amp.append(abs(p))
    # Growth of the envelope over the last 40 s against ln(spectral radius) / dt.
    late = np.array(amp[20000:])
    peaks = [max(late[i : i + 2000]) for i in range(0, 40000, 2000)]
    measured = np.polyfit(np.arange(len(peaks)) * 2.0, np.log(peaks), 1)[0]
    assert measured == pytest.approx(math.log(spectral_radius(loop)) / dt, abs=2e-4)


def test_high_degree_loop_is_solved_without_the_companion_matrix(monkeypatch):
    # 1600 ticks of delay: the Newton path with the argument-principle check, no companion matrix.
    monkeypatch.setattr(np, "roots", lambda *a: pytest.fail("fell back to the companion matrix"))
    loop = SampledLoop(m=750.0, k_direct=0.0, b_direct=60.0, k_delayed=2510.0, dt=1e-5, delay_ticks=1600)
    from dockhil.contact.hybrid_stability import hybrid_roots

    s = hybrid_roots(750.0, 0.0, 60.0, 2510.0, 0.0, 0.016, count=3)
    guesses = [np.exp(r * 1e-5) for r in s]
    from dockhil.contact.sampled import sampled_roots

    fast = sampled_roots(loop, guesses)[0]
    # At 100 kHz the sampled loop is the delay equation with h + dt/2 to within a part in 10^4.
    assert math.log(abs(fast)) / 1e-5 == pytest.approx(s[0].real, rel=2e-3)


@pytest.mark.parametrize("guess", [0.5, 0.999 + 0.05j])
def test_a_wrong_newton_guess_is_caught_and_the_dominant_root_still_found(monkeypatch, guess):
    from dockhil.contact import sampled

    monkeypatch.setattr(sampled, "DENSE_DEGREE", 5)  # force the Newton path on a small loop
    loop = SampledLoop(m=375.0, k_direct=500.0, b_direct=30.0, k_delayed=2500.0, dt=1e-3, delay_ticks=20)
    rho = max(abs(np.linalg.eigvals(one_tick_map(loop))))
    assert abs(sampled.sampled_roots(loop, [guess])[0]) == pytest.approx(rho, rel=1e-12)


# -- item 1: a step that does not resolve the contact is refused --------------------------------------


def stiff_numbers():
    m = STIFF["m1"] * STIFF["m2"] / (STIFF["m1"] + STIFF["m2"])
    omega = math.sqrt(STIFF["kcs"] / m)  # |s| of an underdamped pole
    zeta = STIFF["bcs"] / (2 * math.sqrt(STIFF["kcs"] * m))
    duration = math.pi / (omega * math.sqrt(1 - zeta * zeta))  # p = v0/wd e^{-zeta w t} sin(wd t) returns to 0
    return m, omega, duration


@pytest.mark.parametrize("scene", ["launch/hil.yaml", "launch/ideal.yaml"])
def test_stiff_contact_at_1khz_is_refused_in_one_line_naming_the_numbers(scene):
    args = {k: v for k, v in STIFF.items() if not (scene.endswith("ideal.yaml") and k == "k")}
    r = launch(scene, *overrides(args), "delay:=0" if "hil" in scene else "rate:=1000", "--duration", "0.026")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    _, omega, duration = stiff_numbers()
    assert f"omega*dt = {omega * 1e-3:.3g}" in lines[0]
    assert f"{duration / 1e-3:.3g} samples per contact" in lines[0]
    # The rate that would work: omega*dt <= 0.025, rounded up to two digits.
    assert "rate:=110000" in lines[0] and "allow_coarse:=true" in lines[0]


def test_stiff_contact_at_the_named_rate_matches_the_closed_form(tmp_path):
    out = tmp_path / "s.json"
    r = launch(
        "launch/hil.yaml",
        *overrides(STIFF),
        "delay:=0",
        "rate:=110000",
        "--duration",
        "0.006",
        "--quiet",
        "--summary",
        out,
    )
    assert r.returncode == 0, r.stderr
    s = json.loads(out.read_text())
    # Closed form of Eq. 1: peak of kcs p + bcs p' along p = v0/wd e^{-zeta w t} sin(wd t).
    m, omega, duration = stiff_numbers()
    v0 = STIFF["v1"] - STIFF["v2"]
    t = np.linspace(0, duration, 200001)
    zeta = STIFF["bcs"] / (2 * math.sqrt(STIFF["kcs"] * m))
    wd = omega * math.sqrt(1 - zeta * zeta)
    p = v0 / wd * np.exp(-zeta * omega * t) * np.sin(wd * t)
    pd = v0 * np.exp(-zeta * omega * t) * (np.cos(wd * t) - zeta * omega / wd * np.sin(wd * t))
    peak = float(np.max(STIFF["kcs"] * p + STIFF["bcs"] * pd))
    exit_v = -v0 * math.exp(-zeta * omega * duration)
    assert peak == pytest.approx(559.0, abs=0.5)  # the right value
    assert s["peak_force_N"] == pytest.approx(peak, rel=0.015)
    assert s["exit_velocity_mps"] == pytest.approx(exit_v, rel=0.025)
    assert s["warnings"] == []


def test_allow_coarse_runs_and_the_summary_carries_the_warning(tmp_path):
    out = tmp_path / "s.json"
    r = launch(
        "launch/ideal.yaml",
        *overrides({k: v for k, v in STIFF.items() if k != "k"}),
        "allow_coarse:=true",
        "--duration",
        "0.026",
        "--quiet",
        "--summary",
        out,
    )
    assert r.returncode == 0, r.stderr
    s = json.loads(out.read_text())
    assert len(s["warnings"]) == 1 and "rate:=110000" in s["warnings"][0]
    assert r.stderr.count("warning:") == 1  # warned once
    assert s["loop"]["omega_dt"] == pytest.approx(stiff_numbers()[1] * 1e-3, rel=1e-12)


def test_coarse_but_resolved_step_warns_with_the_peak_error_estimate(tmp_path):
    # Table 1 stiffened to 3e6 N/m: omega = 63 rad/s, omega*dt = 0.063 at 1 kHz (coarse, not refused).
    out = tmp_path / "s.json"
    r = launch("launch/ideal.yaml", "kcs:=3e6", "--duration", "0.1", "--quiet", "--summary", out)
    assert r.returncode == 0, r.stderr
    s = json.loads(out.read_text())
    omega = math.sqrt(3e6 / (750 * 1e6 / (750 + 1e6)))
    assert s["loop"]["omega_dt"] == pytest.approx(omega * 1e-3, rel=1e-9)
    assert len(s["warnings"]) == 1 and s["warnings"][0].startswith("coarse step")


def test_table1_scenes_run_without_warning(tmp_path):
    for scene in ("launch/hil.yaml", "launch/ideal.yaml"):
        out = tmp_path / "s.json"
        r = launch(scene, "--duration", "0.05", "--quiet", "--summary", out)
        assert r.returncode == 0 and json.loads(out.read_text())["warnings"] == [], r.stderr


def test_sampling_instability_is_refused_even_when_omega_dt_looks_fine():
    # At 20 kHz omega*dt = 0.13 (resolved), but the held virtual forces make the loop grow while the
    # delay equation (here an ordinary spring-dashpot, h = 0) decays. The test's plain loop shows it.
    dt = 1 / 20000
    m = STIFF["m1"] * STIFF["m2"] / (STIFF["m1"] + STIFF["m2"])
    loop = SampledLoop(m=m, k_direct=STIFF["kcs"] - STIFF["k"], b_direct=STIFF["bcs"], k_delayed=STIFF["k"], dt=dt)
    # Without delay the passive spring reads this tick's pose: one 2x2 map of [p, p'], built here.
    kd, bd, kh = STIFF["kcs"] - STIFF["k"], STIFF["bcs"], STIFF["k"]
    acc = -np.array([kd + kh, bd]) / m
    a = np.array([[1 + 0.5 * dt * dt * acc[0], dt + 0.5 * dt * dt * acc[1]], [dt * acc[0], 1 + dt * acc[1]]])
    rho = max(abs(np.linalg.eigvals(a)))
    assert rho > 1 and spectral_radius(loop) == pytest.approx(rho, rel=1e-12)
    r = launch("launch/hil.yaml", *overrides(STIFF), "delay:=0", "rate:=20000", "--duration", "0.01")
    assert r.returncode == 2 and "the sampled loop grows" in r.stderr and "rate:=" in r.stderr


# -- item 2: the exit velocity once no force acts ----------------------------------------------------


def test_exit_velocity_is_read_after_the_last_force_through_the_delay(tmp_path):
    out = tmp_path / "s.json"
    r = launch("launch/hil.yaml", *overrides(LATE), "delay:=0.1", "--duration", "0.7", "--quiet", "--summary", out)
    assert r.returncode == 0, r.stderr
    s = json.loads(out.read_text())
    rows = plain_hil(**LATE, dt=1e-3, n=701, delay_ticks=100)
    last = max(i for i, row in enumerate(rows) if row[3])
    expected = rows[last + 1][1]  # the relative velocity after the last force has acted
    separated = next(i for i, row in enumerate(rows) if i > 0 and row[0] <= 0 and row[1] < 0)
    assert last > separated + 50  # the delayed spring pushes long after the bodies part
    assert expected == pytest.approx(-0.04936, abs=5e-6)  # the right value
    assert s["exit_velocity_mps"] == pytest.approx(expected, rel=1e-9)
    assert s["entry_velocity_mps"] == pytest.approx(LATE["v1"] - LATE["v2"], rel=1e-12)
    assert s["restitution"] == pytest.approx(-expected / (LATE["v1"] - LATE["v2"]), rel=1e-9)
    # The ideal model's coefficient: exp(-zeta pi / sqrt(1 - zeta^2)).
    m = LATE["m1"] * LATE["m2"] / (LATE["m1"] + LATE["m2"])
    zeta = LATE["bcs"] / (2 * math.sqrt(LATE["kcs"] * m))
    assert s["ideal"]["restitution"] == pytest.approx(math.exp(-zeta * math.pi / math.sqrt(1 - zeta * zeta)), rel=1e-9)


def test_exit_velocity_is_withheld_while_a_force_still_acts():
    from dockhil.analysis.summary import Samples, contact_metrics

    rows = plain_hil(**LATE, dt=1e-3, n=400, delay_ticks=100)  # stops while the delayed spring pushes
    p, pd, f, acting = (np.array(c) for c in zip(*rows))
    m = contact_metrics(Samples(np.arange(400) * 1e-3, p, pd, f, acting))
    assert m["exit_velocity_mps"] is None and "still acted" in m["note"]


def test_a_run_stopped_inside_the_contact_reports_no_peak_force_error():
    from dockhil.analysis.summary import Samples, summarize

    # The ideal contact of Table 1 (m1 750, m2 1e6, kcs 3000, bcs 40, 0.03 m/s), written out: a
    # damped oscillation of the reduced mass from p = 0 (overlap until pi/wd), stopped at 0.2 s.
    m, kcs, bcs, v0 = 750.0 * 1e6 / (750.0 + 1e6), 3000.0, 40.0, 0.03
    sigma, wd = bcs / (2 * m), math.sqrt(kcs / m - (bcs / (2 * m)) ** 2)

    def contact(t):
        p = v0 / wd * np.exp(-sigma * t) * np.sin(wd * t)
        pd = v0 * np.exp(-sigma * t) * (np.cos(wd * t) - sigma / wd * np.sin(wd * t))
        return p, pd, kcs * p + bcs * pd

    peak = float(np.max(contact(np.linspace(0, math.pi / wd, 100001))[2]))
    t = np.arange(0, 0.2, 1e-3)
    p, pd, f = contact(t)
    s = summarize(
        Samples(t, p, pd, f),
        ideal={
            "peak_force_N": peak,
            "contact_duration_s": math.pi / wd,
            "exit_velocity_mps": -v0 * math.exp(-sigma * math.pi / wd),
            "restitution": None,
        },
    )
    assert s["peak_force_N"] == pytest.approx(float(np.max(kcs * p + bcs * pd))) and s["peak_force_N"] < 0.5 * peak
    assert s["error"]["peak_force_N"] is None and s["error"]["contact_duration_s"] is None
    assert "had not ended" in s["note"] and "run longer" in s["note"]


# -- the summary streams ------------------------------------------------------------------------------


def test_summary_collector_keeps_bounded_buffers_over_a_long_run():
    from dockhil.analysis.summary import ContactMeter, SummaryCollector, TickMatcher
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    graph = build(launchfile.load("launch/stability.yaml", {"b": "60"}))
    collect = SummaryCollector(graph)
    sizes = []
    g = ComposedGraph(
        graph,
        log=lambda n, m: None,
        taps=[
            collect,
            lambda topic, msg: sizes.append(
                (len(collect.match.pending), len(collect.match.ft), len(collect.match.virtual))
            ),
        ],
    )
    g.setup()
    try:
        g.run(5001)  # 5 s: 20 windows, so a buffer that grows with the run would hold thousands
    finally:
        g.close()
    s = collect.summary()
    assert max(x[0] for x in sizes) <= TickMatcher.WINDOW + 1
    assert max(max(x[1], x[2]) for x in sizes) <= TickMatcher.WINDOW + 2
    assert isinstance(collect.meter, ContactMeter) and s["sim_time_s"] == pytest.approx(5.0)


# -- item 4: growth rates about the true equilibrium ----------------------------------------------------


@pytest.mark.parametrize("b", [20.0, 60.0])
def test_growth_rate_matches_the_sampled_loop_root_within_one_percent(b):
    from dockhil.analysis.plots.figures import fig11_12

    case = next(c for c in fig11_12(dampers=(b,))["cases"])
    # The sampled loop built here: a body on a sheet, damper on the current velocity, spring 16 ticks late.
    dt, d, m, K = 1e-3, 16, 750.0, 2510.0
    n = 2 + 2 * d + 2
    a = np.zeros((n, n))
    acc_v, acc_late = -b / m, -K / m
    a[0, 0], a[0, 1] = 1.0, dt + 0.5 * dt * dt * acc_v
    a[1, 1] = 1.0 + dt * acc_v
    a[0, 2 * d], a[1, 2 * d] = 0.5 * dt * dt * acc_late, dt * acc_late
    a[2 : 2 * (d + 1), : 2 * d] = np.eye(2 * d)
    root = math.log(max(abs(np.linalg.eigvals(a)))) / dt
    assert case["predicted_growth_rate_1_s"] == pytest.approx(root, rel=1e-9)
    assert case["growth_rate_1_s"] == pytest.approx(root, rel=0.01)


def test_substeps_integrate_the_ideal_contact_more_finely(tmp_path):
    # kcs = 3e6 N/m: 63 rad/s; RK4's error against Eq. 1 falls as (dt / n)^4 with n sub-steps.
    errors = []
    for n in (1, 4):
        out = tmp_path / f"s{n}.json"
        r = launch(
            "launch/ideal.yaml",
            "kcs:=3e6",
            "method:=rk4",
            f"substeps:={n}",
            "--duration",
            "0.1",
            "--quiet",
            "--summary",
            out,
        )
        assert r.returncode == 0, r.stderr
        errors.append(json.loads(out.read_text())["error"]["max_force_N"])
    assert 4**4 / 2 < errors[0] / errors[1] < 4**4 * 2


def test_a_delay_rounded_to_whole_ticks_is_warned(tmp_path):
    out = tmp_path / "s.json"
    r = launch("launch/stability.yaml", "b:=60", "rate:=300", "--duration", "0.1", "--quiet", "--summary", out)
    assert r.returncode == 0, r.stderr
    w = json.loads(out.read_text())["warnings"]
    # 16 ms at 300 Hz is 4.8 ticks: it runs as 5 ticks, 16.67 ms.
    assert len(w) == 1 and "runs as 5 ticks = 0.0166667 s" in w[0] and r.stderr.count("warning:") == 1


def test_all_roots_of_a_long_delay_are_refused_not_computed():
    """Degree 5001 without guesses would be a 5001 x 5001 companion matrix: refused at once."""
    from dockhil.contact.sampled import DENSE_FALLBACK_DEGREE, RootsNotResolved, SampledLoop, sampled_roots

    loop = SampledLoop(750.0, 2000.0, 40.0, 1000.0, 0.0, dt=1e-3, delay_ticks=5000)
    with pytest.raises(RootsNotResolved, match=f"beyond the {DENSE_FALLBACK_DEGREE}"):
        sampled_roots(loop)
    short = SampledLoop(750.0, 2000.0, 40.0, 1000.0, 0.0, dt=1e-3, delay_ticks=32)
    assert len(sampled_roots(short)) == 32 + 3  # below the bound: every root, as before


def test_a_contact_no_rate_resolves_gets_advice_that_changes_something():
    """kcs 3e9 N/m on hil.yaml: with its delay no rate makes the sampled loop agree with the delay
    equation; the advice names what would help, not the method the scene already uses (it said
    'use method:=exact' to a scene using it)."""
    from tests.support.inprocess import run_main

    code, out, err = run_main("launch", "launch/hil.yaml", "--composed", "kcs:=3e9")
    assert code == 2
    assert "fixes it with method 'exact': give a softer contact or heavier bodies" in err
