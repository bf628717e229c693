"""The energy account of the HIL loop and the passivity controller: the account closes against an
independent computation, compensation takes out the energy the delay makes, and the graph runs it
bit for bit like the library loop."""

import json
import subprocess

import numpy as np
import pytest

from dockhil.analysis.summary import Samples, contact_metrics, ideal_summary
from dockhil.bags.reader import BagReader
from dockhil.contact.envelope import growth_rate
from dockhil.contact.hilloop import Bodies, DelayLine, Servo, sensor_force, simulate_hil, virtual_wrench
from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.impedance import impedance_closed_form
from dockhil.contact.passivity import DEFAULT_MAX_DAMPING, ENERGY_FIELDS, Passivity, left_in_loop
from dockhil.contact.scenario import TABLE1
from tests.conftest import dockhil_cmd

DT = 1e-3
IMP = impedance_closed_form(TABLE1, warn=False)


def table1(delay, passivity=None, n_ticks=2400, energy=True):
    t = TABLE1
    return simulate_hil(
        m1=t.m1,
        m2=t.m2,
        k=t.k,
        impedance=IMP,
        dt=DT,
        n_ticks=n_ticks,
        v1=t.v1,
        delay=delay,
        passivity=passivity,
        energy=energy,
    )


def metrics(run):
    return contact_metrics(Samples(run.t, run.x1 - run.x2, run.v1 - run.v2, run.force))


def test_the_account_closes_and_its_port_energy_matches_an_independent_computation():
    t = TABLE1
    d = 32
    run = table1(d * DT)
    e = run.extra
    p, v1, v2 = run.x1 - run.x2, run.v1, run.v2
    # The sensor force, rebuilt here: the spring k against the penetration of d ticks earlier.
    fs = np.array([-t.k * p[j - d] if j >= d and p[j - d] > 0 else 0.0 for j in range(len(p))])
    work = np.concatenate(([0.0], np.cumsum(fs[:-1] * np.diff(p))))
    assert np.allclose(e["port_work_J"], work, rtol=0, atol=1e-12)
    # Energy balance of the bodies (exact integrator, forces held over a tick): the change of
    # kinetic energy is the work of the port and of the virtual impedance.
    ke = 0.5 * (t.m1 * v1**2 + t.m2 * v2**2)
    assert np.allclose(e["kinetic_J"], ke, rtol=1e-12, atol=0)
    assert np.allclose(ke - ke[0], e["port_work_J"] + e["virtual_work_J"], rtol=0, atol=1e-9)
    # Once the contact is over (nothing stored), the energy made is what the bodies carry beyond
    # a passive loop: kinetic energy at the end - at the start + what the virtual dampers took.
    made = ke[-1] - ke[0] + e["virtual_dissipated_J"][-1]
    assert fs[-1] == 0.0 and e["virtual_stored_J"][-1] == 0.0
    assert e["generated_J"][-1] == pytest.approx(made, rel=1e-9)
    # First order in h: the delay is a negative damper -k h, making k h * integral(p'^2) over the contact.
    touching = p > 0
    assert made == pytest.approx(t.k * d * DT * np.sum((v1 - v2)[touching] ** 2) * DT, rel=0.1)
    assert made > 0.02


def test_compensation_takes_out_the_energy_and_the_errors_shrink():
    t = TABLE1
    ideal = ideal_summary(m1=t.m1, m2=t.m2, kcs=t.kcs, bcs=t.bcs, v1=t.v1, v2=t.v2)
    plain, comp = metrics(table1(0.032)), table1(0.032, Passivity(t.k, 200.0))
    mc = metrics(comp)
    assert plain["restitution"] > ideal["restitution"] + 1e-3  # the delay made energy
    assert mc["restitution"] <= ideal["restitution"] + 1e-3
    for key in ("exit_velocity_mps", "peak_force_N"):
        assert abs(mc[key] - ideal[key]) < abs(plain[key] - ideal[key]) / 5
    e = comp.extra
    # The controller only dissipates, within its bound, and leaves next to nothing.
    assert np.all(e["damping_Ns_m"] >= 0.0) and np.all(e["damping_Ns_m"] <= 200.0)
    assert e["compensation_dissipated_J"][-1] == pytest.approx(e["generated_J"][-1], rel=1e-3)
    assert abs(e["net_generated_J"][-1]) < 1e-3 * np.max(e["port_spring_J"])


def test_the_unstable_sheet_stops_growing_with_compensation():
    K, b, h = 2510.0, 20.0, 0.016  # Fig. 11: unstable without compensation
    rates = {}
    for name, pc in (("none", None), ("passivity", Passivity(K, 200.0))):
        run = simulate_hil(
            m1=750.0,
            m2=0.0,
            k=K,
            impedance=VirtualImpedance(0.0, b, 0.0, 0.0),
            dt=DT,
            n_ticks=30001,
            delay=h,
            thrust=10.0,
            x1=0.006,
            passivity=pc,
        )
        rates[name] = growth_rate(run.t, run.x1 - run.x2, about=10.0 / K)
    assert rates["none"] > 0.005
    # With compensation the loop is passive: it decays like the damper alone, b / (2 m).
    assert rates["passivity"] == pytest.approx(-b / (2 * 750.0), rel=0.1)


def _sensor(p, d, k):
    """The sensor force, rebuilt here: the spring k against the penetration of d ticks earlier."""
    return np.array([k * p[j - d] if j >= d and p[j - d] > 0 else 0.0 for j in range(len(p))])


def test_the_chaser_feels_the_delay_free_spring_until_the_turn_and_no_more_than_the_force_error():
    t = TABLE1
    kv = IMP.k1 * (t.m2 / (t.m1 + t.m2)) ** 2 + IMP.k2 * (t.m1 / (t.m1 + t.m2)) ** 2  # the virtual springs on p
    for delay in (0.032, 0.5):
        d = int(round(delay / DT))
        run = table1(delay, Passivity(t.k, DEFAULT_MAX_DAMPING), n_ticks=int((2.2 + 2.5 * delay) / DT))
        p, pd = run.x1 - run.x2, run.v1 - run.v2
        F = _sensor(p, d, t.k)
        error = t.k * np.maximum(p, 0.0) - F  # what the delay takes from the delay-free spring
        added = run.extra["damping_Ns_m"] * pd  # the controller's compressive force
        sampling = (t.k + kv) * np.abs(pd) * DT  # what the held springs make over a tick, as force
        # It adds at most the force error (and the sampling's share), however long the delay: no spike.
        assert np.all(np.abs(added) <= np.abs(error) + sampling + 1e-3)
        assert np.max(np.abs(error)) > (2.0 if delay > 0.1 else 0.3)  # the delay does take force away
        # Until the bodies turn, port and controller together are the delay-free spring at mid-tick.
        turn = int(np.argmax(pd < 0.0))
        approach = slice(0, turn - 20)  # the last ticks before the turn: the damping needed grows as 1/v
        assert np.allclose((F + added)[approach], (t.k * (p + pd * DT / 2))[approach], rtol=0, atol=0.04)


@pytest.mark.parametrize("delay", [0.1, 0.3, 0.5, 0.785])
def test_up_to_half_the_contact_compensation_makes_neither_error_larger(delay):
    t = TABLE1
    ideal = ideal_summary(m1=t.m1, m2=t.m2, kcs=t.kcs, bcs=t.bcs, v1=t.v1, v2=t.v2)
    assert delay <= ideal["contact_duration_s"] / 2 + 1e-3
    n_ticks = int((2.2 + 2.5 * delay) / DT)
    plain = metrics(table1(delay, n_ticks=n_ticks))
    comp_run = table1(delay, Passivity(t.k, DEFAULT_MAX_DAMPING), n_ticks=n_ticks)
    comp = metrics(comp_run)
    for key in ("exit_velocity_mps", "peak_force_N"):
        assert abs(comp[key] - ideal[key]) < abs(plain[key] - ideal[key]) / 10, key
    left, allowed = left_in_loop(comp_run.extra)
    assert left <= allowed  # valid: the bound took out everything


def test_a_bound_below_the_damping_the_delay_needs_saturates():
    t = TABLE1
    delay = 0.3
    # The first delayed force arrives at t = h, the body still closing (the ideal p = P sin(w t)):
    # cancelling its error k p takes the damping k p / p' = k tan(w h) / w then.
    w = np.sqrt(t.kcs * (t.m1 + t.m2) / (t.m1 * t.m2))
    need = t.k * np.tan(w * delay) / w
    assert 300.0 < need < 400.0
    n_ticks = int((2.2 + 2.5 * delay) / DT)
    low = table1(delay, Passivity(t.k, need / 2), n_ticks=n_ticks)
    left, allowed = left_in_loop(low.extra)
    assert left > 10 * allowed and np.any(low.extra["at_max_damping"])
    high = table1(delay, Passivity(t.k, 10 * need), n_ticks=n_ticks)
    left, allowed = left_in_loop(high.extra)
    assert left <= allowed


def test_the_damping_stays_below_what_reverses_the_relative_velocity_within_a_tick():
    # A 2 kg body: m / dt = 2000 N s/m, far below the default bound.
    m, K, b = 2.0, 1000.0, 2.0
    run = simulate_hil(
        m1=m,
        m2=0.0,
        k=K,
        impedance=VirtualImpedance(0.0, b, 0.0, 0.0),
        dt=DT,
        n_ticks=3000,
        v1=0.03,
        delay=0.05,
        passivity=Passivity(K, DEFAULT_MAX_DAMPING),
    )
    assert np.max(run.extra["damping_Ns_m"]) == pytest.approx(m / DT)
    ideal = ideal_summary(m1=m, m2=1e15, kcs=K, bcs=b, v1=0.03, v2=0.0)
    plain = simulate_hil(
        m1=m, m2=0.0, k=K, impedance=VirtualImpedance(0.0, b, 0.0, 0.0), dt=DT, n_ticks=3000, v1=0.03, delay=0.05
    )
    assert metrics(plain)["restitution"] > ideal["restitution"] + 0.1  # 50 ms is a third of this contact
    assert metrics(run)["restitution"] <= ideal["restitution"] + 1e-3


def test_the_scenes_and_the_node_share_the_default_bound():
    import yaml

    from dockhil.nodes.virtual_impedance import VirtualImpedance as Node

    assert Node.params["max_damping"].default == DEFAULT_MAX_DAMPING
    for scene in ("launch/hil.yaml", "launch/stability.yaml"):
        with open(scene) as f:
            assert float(yaml.safe_load(f)["args"]["max_damping"]["default"]) == DEFAULT_MAX_DAMPING, scene


def _loop_as_published(*, m1, m2, k, impedance, dt, n_ticks, delay, v1):
    """The HIL loop as it was before the energy account (the paper's experiments)."""
    bodies = Bodies(m1, m2, 0.0, 0.0, v1, 0.0, "exact")
    line, servo = DelayLine(int(round(delay / dt))), Servo(0.0, dt)
    out = np.empty((6, n_ticks))
    f1 = f2 = 0.0
    for tick in range(n_ticks):
        if tick > 0:
            bodies.step(f1, f2, dt)
        a1, a2, b1, b2 = bodies.positions()
        fv1, fv2 = virtual_wrench(a1, a2, b1, b2, m1, m2, impedance)
        cmd = line.push((a1 - a2, b1 - b2))
        fs = sensor_force(None if cmd is None else servo.step(*cmd)[0], k)
        f1, f2 = fs + fv1, -fs + fv2
        out[:, tick] = (tick * dt, a1, a2, b1, b2, -(fs + fv1))
    return out


def test_without_compensation_the_loop_is_bit_identical_to_the_published_one():
    t = TABLE1
    ref = _loop_as_published(m1=t.m1, m2=t.m2, k=t.k, impedance=IMP, dt=DT, n_ticks=1800, delay=0.032, v1=t.v1)
    for energy in (False, True):  # the energy account only watches
        run = table1(0.032, n_ticks=1800, energy=energy)
        for row, arr in zip(ref, (run.t, run.x1, run.x2, run.v1, run.v2, run.force)):
            assert np.array_equal(row, arr)


def launch(*args, expect=0):
    r = subprocess.run(dockhil_cmd("launch", *args), capture_output=True, text=True, timeout=180)
    assert r.returncode == expect, r.stdout + r.stderr
    return r


def test_saturation_marks_the_run_invalid(tmp_path):
    # 100 ms needs about k tan(w h) / w = 101 N s/m: a bound of 40 leaves the energy in the loop.
    path = tmp_path / "s.json"
    r = launch(
        "launch/hil.yaml",
        "delay:=0.1",
        "compensation:=passivity",
        "max_damping:=40",
        "--composed",
        "--duration",
        "2.5",
        "--summary",
        path,
        expect=3,
    )
    s = json.loads(path.read_text())
    assert s["valid"] is False and s["energy"]["saturated"] is True
    assert "saturated at max_damping 40" in s["invalid_reasons"][0]
    assert "[launch] INVALID: the passivity controller saturated" in r.stderr
    ok = tmp_path / "ok.json"
    launch("launch/hil.yaml", "compensation:=passivity", "--composed", "--duration", "2", "--summary", ok)
    s = json.loads(ok.read_text())
    assert s["valid"] is True and s["energy"]["saturated"] is False and s["invalid_reasons"] == []


@pytest.mark.parametrize(
    "args, words",
    [
        (("launch/stability.yaml", "compensation:=passivity", "k:=0"), "needs the passive stiffness k > 0"),
        (("launch/hil.yaml", "compensation:=passivity", "max_damping:=0"), "needs max_damping > 0"),
        (("launch/hil.yaml", "compensation:=passivity", "max_damping:=-5"), "max_damping': -5.0 is out of range"),
    ],
)
def test_bad_parameters_give_one_line(args, words):
    r = subprocess.run(dockhil_cmd("launch", *args, "--duration", "0.1"), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], r.stderr


def _bag(path):
    with BagReader(path) as bag:
        return [(m.topic, m.log_time_ns, m.data) for m in bag]


def test_graph_equals_library_with_compensation(tmp_path):
    a, b = tmp_path / "mp.mcap", tmp_path / "composed.mcap"
    common = ("launch/hil.yaml", "compensation:=passivity", "delay:=0.064", "--duration", "1", "--quiet")
    launch(*common, "--bag", a)
    launch(*common, "--bag", b, "--composed")
    ma = _bag(a)
    assert sorted(ma) == sorted(_bag(b))
    t = TABLE1
    lib = simulate_hil(
        m1=t.m1,
        m2=t.m2,
        k=t.k,
        impedance=IMP,
        dt=DT,
        n_ticks=1001,
        v1=t.v1,
        delay=0.064,
        passivity=Passivity(t.k, DEFAULT_MAX_DAMPING),
    )
    with BagReader(a) as bag:
        got = {"state": [], "energy": []}
        for topic, _t, msg in bag.decoded(["/satellite/state", "/energy"]):
            if topic == "/satellite/state":
                got["state"].append((msg.bodies[0].pose.position.x, msg.bodies[1].pose.position.x))
            else:
                got["energy"].append(tuple(getattr(msg, f) for f in ENERGY_FIELDS))
    assert np.array_equal(np.array(got["state"]), np.stack([lib.x1, lib.x2], axis=1))
    energy = np.array(got["energy"], dtype=float)
    for i, name in enumerate(ENERGY_FIELDS):
        assert np.array_equal(energy[:, i], lib.extra[name].astype(float)), name
    assert lib.extra["compensation_dissipated_J"][-1] > 0.01  # the damping acted


def test_below_the_deadband_an_apart_port_is_unloaded_and_the_controller_does_not_act():
    from dockhil.contact.passivity import EnergyMonitor

    rng = np.random.default_rng(1)
    monitor = EnergyMonitor(750.0, 0.0, 1000.0, VirtualImpedance(0.0, 20.0, 0.0, 0.0), Passivity(1000.0, 200.0, 0.5))
    x = -0.01  # apart, flying away, with sensor noise of 0.1 N
    for _ in range(2000):
        x -= 0.03 * DT
        fc, e = monitor.step(x, 0.0, -0.03, 0.0, float(rng.normal(0.0, 0.1)), 0.0, 0.0, DT)
        assert fc == 0.0 and not e.port_loaded
    assert e.compensation_dissipated_J == 0.0
    # Without the deadband the same noise keeps the controller busy.
    monitor = EnergyMonitor(750.0, 0.0, 1000.0, VirtualImpedance(0.0, 20.0, 0.0, 0.0), Passivity(1000.0, 200.0))
    x, acted = -0.01, 0
    for _ in range(2000):
        x -= 0.03 * DT
        fc, e = monitor.step(x, 0.0, -0.03, 0.0, float(rng.normal(0.0, 0.1)), 0.0, 0.0, DT)
        acted += fc != 0.0
    assert acted > 0 and e.compensation_dissipated_J > 0.0


def test_stability_measures_the_compensated_loop(capsys):
    from dockhil.cli import main

    # The measurement in this process; the refusal below as a command.
    assert (
        main(
            [
                "stability",
                "--m",
                "750",
                "--b",
                "20",
                "--h",
                "0.016",
                "--K",
                "2510",
                "--compensation",
                "passivity",
                "--json",
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out)
    assert report["growth_rate"] > 0  # Fig. 11 without compensation
    at_k = next(row for row in report["passivity"]["runs"] if row["label"] == "--K")
    assert at_k["growth_rate"] < 0 and at_k["saturated"] is False
    assert report["passivity"]["largest_decaying_K"] >= 3 * report["exact"] * 0.999
    r = subprocess.run(
        dockhil_cmd(
            "stability", "--m", 750, "--b", 20, "--h", 0.016, "--compensation", "passivity", "--max-damping", -1
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0 and r.stderr.strip().splitlines() == [r.stderr.strip()] and "--max-damping" in r.stderr


def test_the_report_section_compares_each_delay_with_and_without_compensation():
    from dockhil.analysis.report.compute import passivity_compensation

    out = passivity_compensation()
    rows = {(r["delay_s"], r["compensation"]): r for r in out["rows"]}
    for delay in {r["delay_s"] for r in out["rows"]}:
        plain, comp = rows[(delay, "none")], rows[(delay, "passivity")]
        for key in ("exit_velocity_error_mps", "peak_force_error_N"):
            assert abs(comp[key]) < abs(plain[key])
        assert comp["restitution"] <= out["ideal_restitution"] + 1e-3 < plain["restitution"]
    assert set(out["energy_32ms"]) == {"none", "passivity"}
