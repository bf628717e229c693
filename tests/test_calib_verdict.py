"""One verdict: `dockhil calibrate`, `dockhil stability --scene` and the launch's scene check judge the same
loop (the scene's own placement of each force, the identified delay end to end with the lag) and say it in
the same words, on the loop files of a few calibrations; a hardware scene the verdict calls unstable is
refused at launch without allow_unstable:=true."""

from __future__ import annotations

import json

import pytest

from dockhil.analysis.scenecheck import scene_check
from dockhil.bags.writer import BagWriter
from dockhil.cli import main
from dockhil.msgs import type_name
from dockhil.msgs.codec import encode
from dockhil.scene import launchfile
from dockhil.scene.graph import build
from tests.test_calib_device import _identification_messages
from tests.test_calibrate import Truth, simulate

HARDWARE = ["robot:=rsi", "ft:=netft", "emulators:=true"]


def loop_file(tmp_path, truth: Truth, scene: list[str], capsys) -> tuple[str, dict]:
    """A recorded identification run of `truth` calibrated for `scene`: the loop file and calibrate's JSON."""
    rec, _f, _v = simulate(truth, 1)
    bag = tmp_path / "run.mcap"
    with BagWriter(bag) as writer:
        topics = set()
        for topic, msg in _identification_messages(rec):
            if topic not in topics:
                writer.add_topic(topic, type_name(type(msg)))
                topics.add(topic)
            ns = round(msg.header.stamp * 1e9)
            writer.write(topic, ns, ns, encode(msg))
    out = tmp_path / "loop.yaml"
    assert main(["calibrate", "--bag", str(bag), *scene, "--json", "--out", str(out)]) == 0
    found = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    return str(out), found


def three_verdicts(scene: list[str], loop: str, capsys) -> tuple[str, str]:
    """What `dockhil stability --scene` and the scene check say of the scene at the loop file."""
    assert main(["stability", "--scene", scene[0], *scene[1:], *HARDWARE, f"loop:={loop}", "--json"]) == 0
    said = json.loads(capsys.readouterr().out)["verdict"]
    graph = build(launchfile.load(scene[0], launchfile.parse_overrides([*scene[1:], *HARDWARE, f"loop:={loop}"])))
    checked = scene_check(graph, refuse=False)["loop"]["verdict"]
    return said, checked


@pytest.mark.parametrize(
    "truth, scene",
    [
        (Truth(delay=0.032, lag=0.004, k=1000.0, noise=0.1), ["hil.yaml"]),
        (Truth(delay=0.061, lag=0.012, k=800.0, b=10.0), ["hil.yaml", "kcs:=6000"]),
        (Truth(delay=0.023, lag=0.0, k=400.0, noise=0.2), ["stability.yaml", "m:=50", "b:=20", "rate:=250"]),
    ],
)
def test_calibrate_stability_and_the_scene_check_say_the_same_of_a_loop_file(tmp_path, capsys, truth, scene):
    loop, found = loop_file(tmp_path, truth, scene, capsys)
    line = found["verdict"]["line"]
    said, checked = three_verdicts(scene, loop, capsys)
    assert said == line and checked == line, (line, said, checked)
    assert found["stable"] is found["verdict"]["stable"] and ("is stable" in line) is found["stable"]


def test_a_hardware_scene_the_verdict_calls_unstable_is_refused_without_allow_unstable(tmp_path, capsys):
    """Figs. 11-12's loop on the lab: m 50 kg, b 20 N s/m, a sheet of 1000 N/m behind 23 ms is unstable
    (the bound is about 600 N/m): `dockhil graph` (the launch's check) refuses it in one line naming the
    verdict, and runs it with allow_unstable:=true; the simulated scene only warns."""
    scene = ["stability.yaml", "m:=50", "b:=20", "rate:=250"]
    loop, found = loop_file(tmp_path, Truth(delay=0.023, k=1000.0), scene, capsys)
    assert found["stable"] is False and found["kcs_max_N_per_m"] < 1000.0
    assert main(["graph", *scene, *HARDWARE, f"loop:={loop}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "refused" in err and found["verdict"]["line"] in err, err
    assert "allow_unstable:=true" in err
    assert main(["graph", *scene, *HARDWARE, f"loop:={loop}", "allow_unstable:=true"]) == 0
    capsys.readouterr()
    assert main(["graph", *scene, "delay:=0.023", "k:=1000"]) == 0  # simulated: a warning, as Fig. 11's
