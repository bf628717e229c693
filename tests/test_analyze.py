"""`dockhil analyze RUN.mcap`: the summary of a recorded run from the bag alone gives the launch's numbers,
exactly; the recorded validity (INVALID exits 3, as the launch did); a 6-DOF bag's 6-DOF summary; a bag
without a scene says in one line what to pass, and works when it is given; `dockhil plot` reads the same."""

from __future__ import annotations

import json
import struct
import subprocess

import pytest

from dockhil.bags.reader import BagReader
from dockhil.bags.writer import BagWriter
from tests.conftest import dockhil_cmd
from tests.support.inprocess import launch_here_or_process, run_main


def launched(tmp_path, *args, name="run", code=0):
    bag, summary = tmp_path / f"{name}.mcap", tmp_path / f"{name}.json"
    r = launch_here_or_process(*args, "--bag", bag, "--summary", summary, "--quiet")
    assert r.returncode == code, r.stderr
    return bag, json.loads(summary.read_text())


def analyzed(*args, code=0) -> dict:
    got, out, err = run_main("analyze", *args, "--json")
    assert got == code, err
    return json.loads(out)


def assert_same_numbers(analysis: dict, summary: dict) -> None:
    shared = set(analysis) & set(summary)
    # What only the run knows is how long the machine took; everything else is shared.
    assert set(summary) - shared == {"run_time_s", "real_time_factor"}
    assert {k: analysis[k] for k in shared} == {k: summary[k] for k in shared}


def copy_without_metadata(src, dst) -> None:
    """A bag as dockhil recorded it before bags knew their run: the same messages, no metadata."""
    with BagReader(src) as reader, BagWriter(dst) as writer:
        for topic, type_name, log_ns, data in reader:
            writer.add_topic(topic, type_name)
            writer.write(topic, log_ns, log_ns, data)


@pytest.mark.parametrize("mode", [["--composed"], []], ids=["composed", "processes"])
def test_analyze_gives_the_launch_summary_from_the_bag_alone(tmp_path, mode):
    bag, summary = launched(tmp_path, "hil.yaml", *mode)
    assert summary["peak_force_N"] > 40 and summary["ideal"]["peak_force_N"] > 40 and "energy" in summary
    analysis = analyzed(bag)
    assert_same_numbers(analysis, summary)
    assert analysis["run"]["verdict"] == "valid" and analysis["run"]["analyzed_scene"] == "recorded"

    code, out, err = run_main("analyze", bag, "--png", tmp_path)
    assert code == 0, err
    assert (
        "scene:     recorded" in out
        and "peak force" in out
        and out.rstrip().endswith("valid (as recorded: the launch exited 0)")
    )
    png = tmp_path / "run-force-velocity.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_an_invalid_run_analyzed_says_invalid_and_exits_3(tmp_path):
    bag, summary = launched(tmp_path, "hil.yaml", "compensation:=passivity", "max_damping:=1", "--composed", code=3)
    analysis = analyzed(bag, code=3)
    assert_same_numbers(analysis, summary)
    assert analysis["valid"] is False and analysis["invalid_reasons"] == summary["invalid_reasons"]
    code, out, _ = run_main("analyze", bag)
    assert code == 3 and out.rstrip().splitlines()[-1].startswith("INVALID: the passivity controller saturated")


def test_a_sixdof_bag_gets_the_sixdof_summary_and_figure(tmp_path):
    bag, summary = launched(tmp_path, "hil6.yaml", "--duration", "2", "--composed")
    analysis = analyzed(bag)
    assert analysis["dof"] == 6 and "peak_torque_Nm" in analysis
    assert_same_numbers(analysis, summary)
    code, _, err = run_main("analyze", bag, "--png", tmp_path)
    assert code == 0, err
    assert (tmp_path / "run-6dof.png").stat().st_size > 20_000
    # `dockhil plot` knows it too: the 6-DOF figure (five panels) without --6dof.
    png = tmp_path / "plot.png"
    assert run_main("plot", bag, "--png", png)[0] == 0
    assert png_size(png)[1] > 1200


def png_size(path) -> tuple[int, int]:
    return struct.unpack(">II", path.read_bytes()[16:24])


def test_a_bag_without_its_scene_says_what_to_pass_and_works_when_given(tmp_path):
    bag, summary = launched(tmp_path, "hil.yaml", "--composed")
    old = tmp_path / "old.mcap"
    copy_without_metadata(bag, old)
    proc = subprocess.run(dockhil_cmd("analyze", old), capture_output=True, text=True, timeout=120)
    line = proc.stderr.strip()
    assert proc.returncode == 2 and proc.stdout == "" and len(line.splitlines()) == 1, proc.stderr
    assert "holds no run metadata" in line and "--scene FILE" in line and "--kcs --bcs --m1" in line

    # The ideal contact given (the shipped defaults here), or the scene: the launch's numbers again.
    for given in (["--kcs", "3000", "--bcs", "40"], ["--scene", "hil.yaml"]):
        analysis = analyzed(old, *given)
        assert_same_numbers(analysis, summary)
        assert analysis["run"]["verdict"] == "not recorded"
    code, out, _ = run_main("analyze", old, "--m1", "750")
    assert code == 0 and out.rstrip().endswith(
        "(no verdict recorded: the bag holds no run metadata (recorded by an older dockhil, or another writer))"
    )
    # Another ideal contact: other reference numbers, the same run.
    other = analyzed(old, "--kcs", "2000", "--bcs", "40")
    assert other["peak_force_N"] == summary["peak_force_N"] and other["ideal"] != summary["ideal"]
    # A scene at another rate would misplace every sample: refused in one line.
    code, _, err = run_main("analyze", old, "--scene", "hil.yaml", "rate:=500")
    assert code == 2 and "ticks are 1 ms apart, the scene's 2 ms" in err and "rate:=1000" in err


def test_an_ideal_model_bag_is_plotted_with_its_recorded_force(tmp_path):
    """The ideal model publishes no force: the recorded scene's kcs and bcs give it, without --kcs/--bcs."""
    from dockhil.analysis.plots.runplot import bag_graph, load_samples
    from dockhil.analysis.summary import scene_reference

    bag, summary = launched(tmp_path, "ideal.yaml", "--composed")
    graph = bag_graph(str(bag))
    samples = load_samples(str(bag), scene_reference(graph)["ideal_force"], graph.scene.dt)
    assert samples.force.max() == summary["peak_force_N"]
    assert run_main("plot", bag, "--png", tmp_path / "ideal.png")[0] == 0
    assert analyzed(bag)["peak_force_N"] == summary["peak_force_N"]


@pytest.mark.parametrize(
    "args, says",
    [
        (["nothing.mcap"], "nothing.mcap: no such file"),
        (["{bag}", "--png", "{bag}/figures"], "cannot create the folder (Not a directory)"),
        (["{bag}", "--kcs", "1", "kcs:=2"], "kcs is given twice"),
        (["{bag}", "nope:=1"], "unknown arg 'nope'"),
    ],
)
def test_refusals_are_one_line(tmp_path, args, says):
    bag = tmp_path / "b.mcap"
    with BagWriter(bag) as w:
        w.add_topic("/satellite/state", "dockhil/SatelliteState")
    if "nope:=1" in args or "--png" in args:  # these need a scene: the recorded one
        r = launch_here_or_process(
            "ideal.yaml", "--duration", "0.05", "--bag", tmp_path / "s.mcap", "--quiet", "--composed"
        )
        assert r.returncode == 0, r.stderr
        bag = tmp_path / "s.mcap"
    code, out, err = run_main("analyze", *[a.format(bag=bag, tmp=tmp_path) for a in args])
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and says in err, err


def test_png_makes_its_folder_as_figures_out_does(tmp_path):
    r = launch_here_or_process(
        "ideal.yaml", "--duration", "0.05", "--bag", tmp_path / "s.mcap", "--quiet", "--composed"
    )
    assert r.returncode == 0, r.stderr
    code, out, err = run_main("analyze", tmp_path / "s.mcap", "--png", tmp_path / "new" / "figures")
    assert code == 0, err
    # A bag does not know the run's wall time: the simulated time alone, not "simulated 0.05 s in -".
    assert "\nsimulated 0.05 s\n" in out, out
    assert (tmp_path / "new" / "figures" / "s-force-velocity.png").stat().st_size > 1000


def test_a_recorded_scene_that_does_not_rebuild_here_is_one_line(tmp_path):
    """A node type of a package not installed here: analyze says so in one line (exit 2); plot draws the
    bag as one without its scene, and says why."""
    from dockhil.bags import runinfo

    bag, _ = launched(tmp_path, "ideal.yaml", "--duration", "0.5", "--composed")
    moved = tmp_path / "moved.mcap"
    scene = str(tmp_path / "lab.yaml")
    with BagReader(bag) as reader, BagWriter(moved) as writer:
        run = dict(runinfo.read(reader).run, scene=scene, args="{}")
        runinfo.write_start(writer, run, {scene: "nodes:\n  - {name: dyn, node: 'lab_package.nodes:Dynamics'}\n"})
        for topic, type_name, log_ns, data in reader:
            writer.add_topic(topic, type_name)
            writer.write(topic, log_ns, log_ns, data)
    code, out, err = run_main("analyze", moved)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "recorded scene" in err and "lab_package" in err
    code, _, err = run_main("plot", moved, "--kcs", "3000", "--bcs", "40", "--png", tmp_path / "p.png")
    assert code == 0 and "drawn without its recorded scene" in err
