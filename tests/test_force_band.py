"""Whether a measured force acts is judged against the sensor's noise band: a noisy, biased or tared
sensor still gives the contact's exit velocity and restitution. A contact played here: the bodies meet
at 0.03 m/s, a spring contact turns them round, and the measured force follows through the robot's
delay; the sensor adds noise, a bias or a tare's rounding residue."""

from __future__ import annotations

import math
import random

import pytest

from dockhil.analysis.summary.common import BAND_SIGMAS, ContactMeter, ForceBand, TickMatcher, force_band
from dockhil.msgs import Header
from dockhil.testing import satellite_state, wrench

DT = 0.001
V = 0.03  # m/s at contact
KCS, M = 3000.0, 750.0
W = math.sqrt(KCS / M)
DELAY = 0.032  # s: the measured force lags the bodies by the robot's delay


def penetration(t: float) -> tuple[float, float]:
    """(p, p') of a contact from t = 0 that lasts pi / W, free flight before and after (restitution 1)."""
    if t < 0.0:
        return V * t, V
    if t < math.pi / W:
        return V / W * math.sin(W * t), V * math.cos(W * t)
    return -V * (t - math.pi / W), -V


def run(noise: float = 0.0, bias: float = 0.0, residue: float = 0.0, before: float = 0.5, band=None) -> dict:
    rng = random.Random(7)
    meter = ContactMeter()
    match = TickMatcher(meter.add, dt=DT, expect={"/ft/wrench"}, band=band)
    n0, n = int(before / DT), int((before + 2.0) / DT)
    for k in range(n):
        t = (k - n0) * DT
        p, pd = penetration(t)
        seen = penetration(t - DELAY)[0]  # the compliance pushes as the robot was DELAY ago
        fs = -KCS * max(seen, 0.0) + rng.gauss(0.0, noise) + bias + (residue if seen <= 0.0 else 0.0)
        header = Header(k * DT, k, k, "")
        state = satellite_state(x1=p, v1=pd)
        match("/satellite/state", type(state)(header=header, bodies=state.bodies))
        w = wrench(fs)
        match("/ft/wrench", type(w)(header=header, wrench=w.wrench))
    match.flush()
    return meter.result()


def test_an_exact_sensor_gives_the_restitution_of_the_contact():
    out = run()
    assert out["restitution"] == pytest.approx(1.0, abs=1e-9) and "note" not in out


@pytest.mark.parametrize(
    "sensor",
    [
        dict(noise=0.2),  # the band measured from the readings before the contact
        dict(bias=2.0),  # an untared bias: the band is centred on it
        dict(noise=0.2, bias=2.0),
        dict(residue=2e-15, before=0.0),  # a tare's rounding residue, no reading before the contact
    ],
)
def test_a_noisy_biased_or_tared_sensor_gives_the_restitution_too(sensor):
    out = run(**sensor)
    assert out["restitution"] == pytest.approx(1.0, abs=1e-9), out
    assert out["exit_velocity_mps"] == pytest.approx(-V, abs=1e-12)


def test_without_readings_at_rest_the_band_is_the_scenes_noise():
    # the contact from the first tick (as hil.yaml's robot starts touching): only the scene's numbers
    out = run(noise=0.2, before=0.0, band=ForceBand(BAND_SIGMAS * 0.2))
    assert out["restitution"] == pytest.approx(1.0, abs=1e-9)
    # a band narrower than the noise finds a force acting to the end, and says so
    out = run(noise=0.2, before=0.0)
    assert out["restitution"] is None and "a force still acted" in out["note"]


def test_the_band_of_a_scene_is_its_deadband_or_its_sensors_noise_and_bias():
    class Node:
        def __init__(self, type_name, **params):
            self.type_name, self.params = type_name, params

    class Graph:
        def __init__(self, *nodes):
            self.nodes = {str(i): n for i, n in enumerate(nodes)}

    band = force_band(Graph(Node("ft_sim", noise=0.2, bias=2.0), Node("virtual_impedance", force_deadband=0.5)))
    assert band.half_width == pytest.approx(1.0) and band.centre == 2.0
    band = force_band(Graph(Node("netft_emulator", noise=0.0), Node("virtual_impedance", force_deadband=0.5)))
    assert band.half_width == 0.5 and band.centre == 0.0
    band = force_band(Graph(Node("satellite_dynamics")))
    assert band.half_width == pytest.approx(1e-6) and not band.acting(2e-15) and band.acting(1e-3)
    assert band.acting(math.nan)
