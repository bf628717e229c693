"""`dockhil stability` on the hybrid loop m s^2 + b_d s + k_d + (k_h + b_h s) e^{-sh} = 0, exact and
sampled. Expected values come from a direct solve of the characteristic equation on the imaginary
axis (scipy), a simulation of the delay equation, and one-tick matrices written here."""

import json
import math
import subprocess

import numpy as np
import pytest
from scipy.optimize import brentq

from dockhil.cli import main
from tests.conftest import dockhil_cmd

# Equal masses m1 = m2 = 1500 kg (m = 750 kg), Table 1's contact, passive k = 1000 N/m, h = 32 ms.
M, KCS, BCS, K, H = 750.0, 3000.0, 40.0, 1000.0, 0.032
HYB = ["--m", "750", "--k-direct", str(KCS - K), "--b-direct", str(BCS), "--k-delayed", str(K), "--h", str(H)]


def run_json(capsys, argv):
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def simulate_delay_equation(m, kd, bd, kh, h, t_end, dt=1e-3):
    """Method of steps with RK4 and linear interpolation in the history (written here)."""
    n_delay = h / dt
    n = int(t_end / dt)
    p = np.zeros(n + 1)
    v = np.zeros(n + 1)
    p[0], v[0] = 1e-3, 0.0

    def past(i_float):
        if i_float <= 0:
            return 1e-3  # constant history
        i = int(i_float)
        f = i_float - i
        return p[i] * (1 - f) + p[min(i + 1, n)] * f

    for i in range(n):

        def acc(x, xd, s, i=i):
            return -(kd * x + bd * xd + kh * past(i + s - n_delay)) / m

        k1x, k1v = v[i], acc(p[i], v[i], 0.0)
        k2x, k2v = v[i] + 0.5 * dt * k1v, acc(p[i] + 0.5 * dt * k1x, v[i] + 0.5 * dt * k1v, 0.5)
        k3x, k3v = v[i] + 0.5 * dt * k2v, acc(p[i] + 0.5 * dt * k2x, v[i] + 0.5 * dt * k2v, 0.5)
        k4x, k4v = v[i] + dt * k3v, acc(p[i] + dt * k3x, v[i] + dt * k3v, 1.0)
        p[i + 1] = p[i] + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
        v[i + 1] = v[i] + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return np.arange(n + 1) * dt, p


def test_equal_masses_the_paper_loop_grows_but_the_hybrid_loop_decays(capsys):
    old = run_json(capsys, ["stability", "--m", "750", "--b", str(BCS), "--h", str(H), "--K", str(KCS), "--json"])
    new = run_json(capsys, ["stability", *HYB, "--json"])
    assert old["growth_rate"] > 0 and old["stable"] is False  # what the Eq. 12 loop says
    assert new["stable"] is True and new["growth_rate"] < 0
    # The delay equation itself, simulated: the envelope decays at the rightmost root's rate (fitted
    # over 20-60 s to a few parts per million of it).
    t, p = simulate_delay_equation(M, KCS - K, BCS, K, H, t_end=60.0)
    peaks = [i for i in range(1, len(p) - 1) if abs(p[i]) > abs(p[i - 1]) and abs(p[i]) >= abs(p[i + 1])]
    late = [i for i in peaks if t[i] > 20.0]
    measured = np.polyfit(t[late], np.log(np.abs(p[late])), 1)[0]
    assert measured == pytest.approx(new["growth_rate"], rel=0.01)


def test_critical_delay_is_where_the_characteristic_equation_has_an_imaginary_root(capsys):
    r = run_json(capsys, ["stability", *HYB, "--json"])
    kd, bd, kh = KCS - K, BCS, K
    # Independent: |kd - m w^2 + j bd w| = kh has the crossing frequency as its root (brentq on w).
    w = brentq(lambda w: (kd - M * w * w) ** 2 + (bd * w) ** 2 - kh * kh, math.sqrt(kd / M), 10.0)
    # Then e^{-j w h} = -(kd - m w^2 + j bd w) / kh fixes h in [0, 2 pi / w).
    e = -complex(kd - M * w * w, bd * w) / kh
    h = (-math.atan2(e.imag, e.real)) % (2 * math.pi) / w
    assert r["critical_frequency"] == pytest.approx(w, rel=1e-10)
    assert r["critical_delay"] == pytest.approx(h, rel=1e-10)
    # The characteristic function vanishes there.
    s = 1j * w
    assert abs(M * s * s + bd * s + kd + kh * np.exp(-s * h)) < 1e-9 * kh
    # First-order Pade is close but not exact.
    assert r["pade1_critical_delay"] == pytest.approx(h, rel=2e-3) and r["pade1_critical_delay"] != h
    # The rightmost root crosses zero there: just below stable, just above not.
    below = run_json(capsys, [*["stability"], *HYB[:-1], str(0.99 * h), "--json"])
    above = run_json(capsys, [*["stability"], *HYB[:-1], str(1.01 * h), "--json"])
    assert below["stable"] and not above["stable"]


def sampled_radius(m, kd, bd, kh, dt, d):
    """Spectral radius of the held-force loop, from a one-tick matrix built here."""
    n = 2 * (d + 1)
    a = np.zeros((n, n))
    a[0, 0] = 1 - 0.5 * dt * dt * kd / m
    a[0, 1] = dt - 0.5 * dt * dt * bd / m
    a[1, 0] = -dt * kd / m
    a[1, 1] = 1 - dt * bd / m
    a[0, 2 * d] += -0.5 * dt * dt * kh / m
    a[1, 2 * d] += -dt * kh / m
    a[2:, : 2 * d] = np.eye(2 * d)
    return max(abs(np.linalg.eigvals(a)))


def test_sampled_loop_at_the_scene_rate(capsys):
    r = run_json(capsys, ["stability", *HYB, "--rate", "1000", "--json"])["sampled"]
    rho = sampled_radius(M, KCS - K, BCS, K, 1e-3, 32)
    assert r["delay_ticks"] == 32 and r["spectral_radius"] == pytest.approx(rho, rel=1e-12)
    assert r["growth_rate"] == pytest.approx(math.log(rho) * 1000, rel=1e-6)
    ticks = next(d for d in range(0, 200) if sampled_radius(M, KCS - K, BCS, K, 1e-3, d) > 1)
    assert r["critical_delay_ticks"] == ticks


def test_scene_values_are_read_from_the_launch_file(capsys):
    r = run_json(capsys, ["stability", "--scene", "launch/hil.yaml", "delay:=0.1", "rate:=500", "--json"])
    m = 750 * 1e6 / (750 + 1e6)
    assert r["m"] == pytest.approx(m, rel=1e-12) and r["h"] == 0.1
    assert r["k_direct"] == pytest.approx(2000.0, rel=1e-9) and r["k_delayed"] == 1000.0
    assert r["b_direct"] == pytest.approx(40.0, rel=1e-9)
    assert r["sampled"]["rate"] == 500.0 and r["sampled"]["delay_ticks"] == 50


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--m", "750", "--b", "20", "--h", "1e308"], "--h must be at most 10 s"),
        (["--m", "750", "--b", "20", "--h", "nan"], "--h must be a finite number"),
        (["--m", "0", "--k-delayed", "1", "--h", "0.01"], "--m must be > 0 kg"),
        (["--m", "-3", "--b", "20", "--h", "0.01"], "--m must be > 0 kg"),
        (["--m", "750", "--k-delayed", "inf", "--h", "0.01"], "--k-delayed must be a finite number"),
        (["--m", "750", "--k-delayed", "1", "--h", "0.01", "--rate", "0"], "--rate must be > 0 Hz"),
        (["--m", "750", "--b", "20", "--h", "0.016", "--K", "1e308"], "--K must be at most"),
        (["--scene", "launch/hil.yaml", "--m", "3"], "--m and --scene do not go together"),
        (["--scene", "launch/hil.yaml", "bogus:=1"], "unknown arg 'bogus'"),
        # a real robot's delay is the hardware's: the scene does not know it, so no verdict at h = 0
        (["--scene", "launch/hil.yaml", "robot:=modbus"], "the robot's delay is the hardware's"),
        (["--scene", "launch/hil.yaml", "robot:=modbus", "emulators:=true"], "give it with --h"),
        # 15 s (15000 ticks, whose roots the scene check could not verify): milliseconds given for seconds
        (["--scene", "launch/hil.yaml", "delay:=15"], "delay:=15 is 15 s: a robot delay is a few ms"),
        (["map", "--m", "750", "--h-range", "0.01", "1e308", "--png", "x.png"], "--h-range HI must be at most 10 s"),
        (["map", "--m", "750", "--b-range", "0", "1e308", "--png", "x.png"], "--b-range HI must be at most"),
        (["map", "--m", "750", "--kcs", "3000", "--png", "x.png"], "needs both --kcs and --bcs"),
        (
            ["map", "--m", "750", "--kcs", "3000", "--bcs", "40", "--h-range", "0.01", "1", "--png", "x.png"],
            "1000 ticks of delay",
        ),
    ],
)
def test_bad_input_gives_one_line_and_exit_2(argv, message):
    r = subprocess.run(dockhil_cmd("stability", *argv), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.count("\n") == 1 and message in r.stderr and "Traceback" not in r.stderr


def test_the_launch_scene_check_says_a_hardware_robots_delay_is_not_in_its_numbers():
    from dockhil.analysis.scenecheck import scene_check
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    def check(*overrides):
        return scene_check(build(launchfile.load("launch/hil.yaml", launchfile.parse_overrides(list(overrides)))))

    assert "note" not in check()["loop"]
    hw = check("robot:=modbus")["loop"]
    assert hw["note"] == "the robot's delay is the hardware's: the loop is analysed without it"
    assert hw["delay_ticks"] == 0


def test_hybrid_map_draws_both_regions(capsys, tmp_path):
    png = tmp_path / "hyb.png"
    r = run_json(
        capsys,
        [
            "stability",
            "map",
            "--m",
            "750",
            "--kcs",
            "3000",
            "--bcs",
            "40",
            "--n",
            "8",
            "--h-range",
            "0.004",
            "0.06",
            "--png",
            str(png),
            "--json",
        ],
    )
    assert png.read_bytes()[:4] == b"\x89PNG"
    # k = 0: everything direct, stable at every delay; so some but not all of the grid is stable.
    assert 0 < r["exact_stable_fraction"] < 1 and r["sampled_disagrees_fraction"] <= 0.1
    # Eq. 12 on the paper's loop: kcs = 3000 is stable only while h is below its Pade bound's crossing.
    hs = np.linspace(0.004, 0.06, 8)
    eq12 = [40 * (4 * 750 - 2 * 40 * h) / (h * (4 * 750 - 40 * h)) for h in hs]  # b (4m - 2bh) / (h (4m - bh))
    assert r["eq12_stable_delays"] == pytest.approx(np.mean([3000 < k for k in eq12]))


@pytest.mark.parametrize("theta", [0.2, 0.7, 1.3])
def test_critical_delay_of_the_papers_loop_from_its_closed_form(capsys, theta):
    # m s^2 + (K + b s) e^{-sh} = 0 crosses at s = j theta / h when b h / m = theta sin(theta) and
    # K h^2 / m = theta^2 cos(theta): choose theta and h, derive b and K, find h back.
    m, h = 750.0, 0.016
    b, K = theta * math.sin(theta) * m / h, theta**2 * math.cos(theta) * m / h**2
    r = run_json(
        capsys, ["stability", "--m", "750", "--k-delayed", repr(K), "--b-delayed", repr(b), "--h", "0.01", "--json"]
    )
    assert r["critical_delay"] == pytest.approx(h, rel=1e-9)
    assert r["critical_frequency"] == pytest.approx(theta / h, rel=1e-9)
