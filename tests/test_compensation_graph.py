"""The compensation methods, the Hunt-Crossley target and the simulated hardware's mismatch as launch
arguments: the composed graph runs them bit for bit like the library loop, and bad arguments get
one line."""

import json

import numpy as np
import pytest

from dockhil.bags.reader import BagReader
from dockhil.contact.compensation import CompensationSettings
from dockhil.contact.comploop import ZERO, Hardware, simulate_compensated, target_frequency
from dockhil.contact.hunt_crossley import TargetContact
from dockhil.contact.hybrid import VirtualImpedance
from dockhil.contact.impedance import impedance_closed_form
from dockhil.contact.passivity import DEFAULT_MAX_DAMPING, Passivity
from dockhil.contact.scenario import TABLE1
from tests.support.inprocess import run_main

MISMATCH = ("hw_k_scale:=0.7", "hw_delay_scale:=1.2", "ft_delay:=0.002", "ft_noise:=0.2")


def chaser_positions(bag):
    with BagReader(bag) as b:
        return np.array([m.bodies[0].pose.position.x for _, _, m in b.decoded(["/satellite/state"])])


@pytest.mark.parametrize(
    "method, contact, extra",
    [
        ("predictor", "linear", ()),
        ("phase_lead", "hunt_crossley", ("kcs:=40000", "hc_alpha:=2.0")),
        ("smith", "linear", ("lag:=0.004",)),
        ("phase_lead+passivity", "linear", ()),
    ],
)
def test_the_composed_graph_is_the_library_loop(tmp_path, method, contact, extra):
    bag = tmp_path / "run.mcap"
    args = ("launch/hil.yaml", f"compensation:={method}", f"contact:={contact}", *MISMATCH, *extra)
    code, _out, err = run_main("launch", *args, "--duration", "0.8", "--quiet", "--composed", "--bag", bag)
    assert code == 0, err
    x1 = chaser_positions(bag)
    t = TABLE1
    m = t.m1 * t.m2 / (t.m1 + t.m2)
    if contact == "linear":
        target, imp = TargetContact("linear", t.kcs, t.bcs), impedance_closed_form(t, warn=False)
    else:
        target, imp = TargetContact("hunt_crossley", 40000.0, n=1.5, alpha=2.0), ZERO
    lag = 0.004 if extra == ("lag:=0.004",) else 0.0
    lib = simulate_compensated(
        m1=t.m1,
        m2=t.m2,
        k=t.k,
        impedance=imp,
        dt=1e-3,
        n_ticks=x1.size,
        delay=0.032,
        v1=t.v1,
        settings=CompensationSettings(method, t.k, 0.032, lag, target_frequency(target, m, t.v1), 0.0, 0.2),
        contact=target,
        hardware=Hardware(0.7, 1.2, 0.002, 0.2, lag),
        passivity=Passivity(t.k, DEFAULT_MAX_DAMPING),
    )
    assert np.array_equal(x1, lib.x1)


def test_stability_yaml_takes_the_methods_and_the_mismatch(tmp_path):
    bag = tmp_path / "run.mcap"
    args = ("launch/stability.yaml", "compensation:=energy", "hw_delay_scale:=0.8", "hw_k_scale:=1.3")
    code, _out, err = run_main("launch", *args, "--duration", "2", "--quiet", "--composed", "--bag", bag)
    assert code == 0, err
    x1 = chaser_positions(bag)
    lib = simulate_compensated(
        m1=750.0,
        m2=0.0,
        k=2510.0,
        impedance=VirtualImpedance(0.0, 20.0, 0.0, 0.0),
        dt=1e-3,
        n_ticks=x1.size,
        delay=0.016,
        thrust=10.0,
        settings=CompensationSettings("energy", 2510.0, 0.016),
        hardware=Hardware(1.3, 0.8),
    )
    assert np.array_equal(x1, lib.x1)


@pytest.mark.parametrize(
    "args, words",
    [
        (("compensation:=wave",), "compensation"),
        (("contact:=hunt_crossley", "hc_n:=0.5"), "hc_n"),
        (("hw_k_scale:=0",), "k_scale"),
        (("ft_delay:=-1",), "delay"),
        (("compensation:=phase_lead", "delay:=0.9"), "cannot advance"),
        (("compensation:=smith", "k:=0"), "needs the passive stiffness k > 0"),
    ],
)
def test_bad_arguments_give_one_line(args, words):
    code, _out, err = run_main("launch", "launch/hil.yaml", *args, "--duration", "0.1", "--composed", "--quiet")
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and words in lines[0], err


def test_the_scene_check_judges_the_simulated_hardwares_true_loop():
    # 32 ms told, 1.5 x that and 10 ms of sensor delay true, a compliance twice as stiff: 58 ticks of a 2000 N/m port.
    code, out, err = run_main(
        "stability", "--scene", "launch/hil.yaml", "hw_delay_scale:=1.5", "ft_delay:=0.01", "hw_k_scale:=2", "--json"
    )
    r = json.loads(out)
    assert code == 0, err
    assert r["h"] == pytest.approx(0.058) and r["k_delayed"] == pytest.approx(2000.0)
    # A scale written as 1 (the robot then delays the command itself) is the told delay, as the default.
    for scale in ("hw_delay_scale:=1", "hw_delay_scale:=1.0"):
        code, out, err = run_main("stability", "--scene", "launch/hil.yaml", scale, "--json")
        assert code == 0 and json.loads(out)["h"] == pytest.approx(0.032), err


def test_a_hunt_crossley_target_is_checked_as_its_linear_equivalent():
    from dockhil.contact.comploop import linear_equivalent
    from dockhil.contact.hunt_crossley import restitution as hc_restitution

    params = {"kcs": 40000.0, "hc_n": 1.5, "hc_alpha": 2.0, "v_close": 0.03}
    m = TABLE1.m1 * TABLE1.m2 / (TABLE1.m1 + TABLE1.m2)
    k, b = linear_equivalent(params, m)
    from dockhil.contact.hunt_crossley import ideal_relative_run

    linear = ideal_relative_run(TargetContact("linear", k, b), m, 0.03, 1e-3, 3000)
    assert linear.restitution == pytest.approx(hc_restitution(2.0, 0.03), abs=1e-6)
    code, _out, err = run_main(
        "launch",
        "launch/hil.yaml",
        "contact:=hunt_crossley",
        "kcs:=40000",
        "hc_alpha:=2",
        "--composed",
        "--duration",
        "0.5",
        "--quiet",
    )
    assert code == 0, err


def test_the_predictor_reads_the_robot_alike_as_processes_and_composed(tmp_path):
    import subprocess

    from tests.conftest import dockhil_cmd

    args = ("launch", "launch/hil.yaml", "compensation:=predictor", *MISMATCH, "--duration", "0.6", "--quiet")
    bags = []
    for extra in ((), ("--composed",)):
        bag = tmp_path / f"run{len(bags)}.mcap"
        r = subprocess.run(dockhil_cmd(*args, *extra, "--bag", bag), capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        with BagReader(bag) as b:
            bags.append(sorted((m.topic, m.log_time_ns, m.data) for m in b))
    assert bags[0] == bags[1]


def test_a_robot_that_delays_itself_by_the_told_delay_is_the_delay_injectors_loop(tmp_path):
    runs = []
    for scale in ("hw_delay_scale:=1.0", "hw_delay_scale:=1"):  # the injector's branch, and robot_sim's own delay
        bag = tmp_path / f"{len(runs)}.mcap"
        code, _out, err = run_main(
            "launch",
            "launch/hil.yaml",
            scale,
            "compensation:=smith",
            "--duration",
            "0.5",
            "--quiet",
            "--composed",
            "--bag",
            bag,
        )
        assert code == 0, err
        runs.append(chaser_positions(bag))
    assert np.array_equal(runs[0], runs[1])
