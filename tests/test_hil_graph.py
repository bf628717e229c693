"""The HIL graph of the paper, run as processes: identical to composed and to the model library,
and the paper's experiments reproduced from its summaries.

The first test holds that a multi-process run and a composed one give the same bytes; the
experiments after it run composed (the same nodes and ticks in one process, no bag to write
and read back): 15 s of the stability scene cost 1.5 s of CPU time so, 22 s as processes."""

import json

import numpy as np
import pytest

from dockhil.analysis.summary import samples_from_bag
from dockhil.bags.reader import BagReader
from dockhil.contact.hilloop import simulate_hil
from dockhil.contact.impedance import impedance_closed_form
from dockhil.contact.scenario import TABLE1
from tests.support.inprocess import launch_here_or_process, run_main


def launch(*args, timeout=180):
    """`dockhil launch ARGS`, which must succeed. A composed run needs no process of its own: it runs
    through dockhil.cli.main in this process (no interpreter start-up, the imports paid once)."""
    r = launch_here_or_process(*args, timeout=timeout)
    assert r.returncode == 0, r.stdout + r.stderr
    return r


def messages(path):
    with BagReader(path) as bag:
        return [(m.topic, m.log_time_ns, m.data) for m in bag]


def test_multiprocess_equals_composed_equals_library(tmp_path):
    a, b = tmp_path / "mp.mcap", tmp_path / "composed.mcap"
    launch("launch/hil.yaml", "--duration", "2", "--bag", a, "--quiet")
    launch("launch/hil.yaml", "--duration", "2", "--bag", b, "--composed", "--quiet")
    ma, mb = messages(a), messages(b)
    assert len(ma) == 7 * 2001 - 2 * 32  # seven topics; no delayed command and no robot pose in the first 32 ms
    assert sorted(ma) == sorted(mb)  # the same bytes on every topic at every tick
    s = samples_from_bag(a)
    lib = simulate_hil(
        m1=TABLE1.m1,
        m2=TABLE1.m2,
        k=TABLE1.k,
        impedance=impedance_closed_form(TABLE1),
        dt=1e-3,
        n_ticks=2001,
        v1=TABLE1.v1,
        delay=0.032,
    )
    assert np.array_equal(s.p, lib.x1 - lib.x2) and np.array_equal(s.pd, lib.v1 - lib.v2)
    assert np.array_equal(s.force, lib.force)


def test_fig9_from_the_graph_summary(tmp_path):
    out = {}
    for delay in ("0.0", "0.032"):
        path = tmp_path / f"s{delay}.json"
        r = launch("launch/hil.yaml", f"delay:={delay}", "--composed", "--summary", path)
        assert "peak force" in r.stdout and "ideal" in r.stdout
        out[delay] = json.loads(path.read_text())
    undelayed, delayed = out["0.0"], out["0.032"]
    for key in (
        "run_time_s",
        "sim_time_s",
        "real_time_factor",
        "peak_force_N",
        "contact_duration_s",
        "exit_velocity_mps",
        "ideal",
        "error",
    ):
        assert key in delayed
    # No delay: the hybrid loop is the ideal contact, to the sampling error.
    assert abs(undelayed["error"]["peak_force_N"]) < 0.05 and undelayed["error"]["max_force_N"] < 0.1
    assert abs(undelayed["error"]["contact_duration_s"]) < 1e-3
    # 32 ms: a higher peak and a faster exit than the ideal contact.
    assert 0.3 < delayed["error"]["peak_force_N"] < 1.5
    assert delayed["exit_velocity_mps"] < undelayed["exit_velocity_mps"] < 0


def test_ideal_scene_matches_the_closed_form(tmp_path):
    path = tmp_path / "ideal.json"
    launch("launch/ideal.yaml", "--composed", "--summary", path, "--quiet")
    s = json.loads(path.read_text())
    assert abs(s["error"]["max_force_N"]) < 1e-6 and abs(s["error"]["contact_duration_s"]) < 1e-6


@pytest.mark.parametrize("b, grows", [(20, True), (60, False)])
def test_figs11_12_from_the_graph(tmp_path, b, grows):
    path = tmp_path / "st.json"
    launch(
        "launch/stability.yaml", f"b:={b}", "x0:=0.006", "--duration", "15", "--composed", "--summary", path, "--quiet"
    )
    s = json.loads(path.read_text())
    measured, predicted = s["growth_rate_1_s"], s["predicted_growth_rate_1_s"]
    assert (measured > 0) is grows and (predicted > 0) is grows
    assert measured == pytest.approx(predicted, rel=0.2)


def test_plot_draws_fig9_from_bags(tmp_path):
    bags = []
    for delay in ("0.0", "0.032"):
        bags.append(tmp_path / f"d{delay}.mcap")
        launch("launch/hil.yaml", f"delay:={delay}", "--bag", bags[-1], "--composed", "--quiet")
    png = tmp_path / "fig9.png"
    code, _, err = run_main("plot", *bags, "--labels", "no delay", "32 ms", "--png", png)
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    code, _, err = run_main("plot", bags[0], "--labels", "a", "b", "--png", png)
    assert code == 2 and "--labels has 2 labels for 1 bags" in err
