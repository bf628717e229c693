"""`dockhil figures` draws the off-axis 6-DOF docking of launch/hil6.yaml: the recorded run is the
library's 6-DOF hybrid loop, the figure is drawn from that bag, and its numbers are its summary."""

import numpy as np

from dockhil.bags.reader import BagReader
from tests.test_sixdof_graph import assert_equals_library, library_run


def test_sixdof_figure_draws_the_recorded_scene_and_gives_its_summary(tmp_path):
    from dockhil.analysis.plots.figures import sixdof
    from dockhil.analysis.plots.plot6 import plot6, series6

    bag, png = tmp_path / "sixdof.mcap", tmp_path / "sixdof.png"
    seconds, delay = 1.7, 0.01
    numbers = sixdof(str(bag), delay=delay, seconds=seconds)
    n = int(round(seconds * 1000)) + 1
    run = library_run(0.05, 0.02, 0.01, delay, n)
    with BagReader(str(bag)) as reader:
        states = sorted((m for _t, _s, m in reader.decoded(["/satellite/state"])), key=lambda m: m.header.tick)
    assert_equals_library(states, run)  # the bag holds the library's run, bit for bit
    s = series6(str(bag))
    assert np.allclose(s.position, run.e[:, :3], rtol=0, atol=1e-12)
    assert np.max(np.abs(s.torque)) > 0.05 and np.max(np.abs(s.omega[:, 0, 2])) > 0.0
    # Its numbers: the summary of that run, the peak |F| of the library's total force on the chaser.
    inside = run.e[:, 0] > 0.0
    assert abs(numbers["peak_force_N"] - np.max(np.linalg.norm(run.force[inside], axis=1))) < 1e-12 * 50
    assert numbers["ideal"]["peak_force_N"] > 40.0 and numbers["exit_relative_velocity_mps"][0] < 0.0
    assert "run_time_s" not in numbers  # figures.json holds what does not depend on the machine
    plot6([str(bag)], str(png), labels=["hil6"], title="6-DOF")
    assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size > 10_000
