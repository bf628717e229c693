"""One verdict on the loop files of bench/calibrate.py's draws: calibrated on emulated hardware hiding a robot
delay, lag, stiffness, noise and bias (RSI and Modbus, both controller timings), each file holds
`dockhil calibrate`'s verdict for the scene it was calibrated for (`dockhil calibrate --bag RUN.mcap SCENE
... --out`); `dockhil stability --scene` and the launch's scene check (`dockhil graph`, which refuses an
unstable hardware scene without allow_unstable:=true) say the same, in the same words.

The files were written by `python3 bench/calibrate.py --keep DIR` (each draw's bag) and then
`dockhil calibrate --bag DIR/ROBOT-TIMING-SEED.mcap SCENE ARGS --out tests/data/loops/NAME.yaml`; a change
to the verdict's words is a change to what calibrate writes: write them again so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dockhil.analysis.scenecheck import scene_check
from dockhil.cli import main
from dockhil.scene import boundedyaml, launchfile
from dockhil.scene.graph import build

LOOPS = Path(__file__).parent / "data" / "loops"
RSI = ["robot:=rsi", "ft:=netft", "emulators:=true"]
MODBUS = ["robot:=modbus", "ft:=can", "emulators:=true"]
FIG11_LAB = ["stability.yaml", "m:=50", "b:=20", "rate:=250"]

CASES = [
    ("rsi-ours-0-hil.yaml", ["hil.yaml", *RSI]),
    ("rsi-immediate-1-stability.yaml", [*FIG11_LAB, *RSI]),
    ("modbus-ours-1-hil-kcs6000.yaml", ["hil.yaml", "kcs:=6000", *MODBUS]),
    ("modbus-immediate-0-stability.yaml", [*FIG11_LAB, *MODBUS]),
    ("modbus-ours-1-hil-bcs400.yaml", ["hil.yaml", "bcs:=400", *MODBUS]),
    ("rsi-immediate-1-stability-b60.yaml", ["stability.yaml", "m:=50", "b:=60", "rate:=250", *RSI]),
]


def calibrates_verdict(path: Path) -> dict:
    data, _root = boundedyaml.load(path.read_text(), str(path))
    return data["verdict"]


@pytest.mark.parametrize("name, scene", CASES)
def test_the_three_verdicts_on_a_draws_loop_file_are_one(name, scene, capsys):
    loop = LOOPS / name
    verdict = calibrates_verdict(loop)
    line = verdict["line"]
    assert main(["stability", "--scene", *scene, f"loop:={loop}", "--json"]) == 0
    said = json.loads(capsys.readouterr().out)["verdict"]
    graph = build(launchfile.load(scene[0], launchfile.parse_overrides([*scene[1:], f"loop:={loop}"])))
    checked = scene_check(graph, refuse=False)["loop"]["verdict"]
    assert said == line and checked == line, (line, said, checked)
    # the launch: an unstable hardware loop refused in one line that says it, a stable one runs
    code = main(["graph", *scene, f"loop:={loop}"])
    err = capsys.readouterr().err
    if verdict["stable"]:
        assert code == 0 and "UNSTABLE" not in err, err
    else:
        assert code == 2 and line in err and "allow_unstable:=true" in err, err
        assert main(["graph", *scene, f"loop:={loop}", "allow_unstable:=true"]) == 0


def test_the_draws_cover_both_verdicts():
    """The files are not all of one kind: at least one loop the verdict calls stable and one it does not."""
    kinds = {calibrates_verdict(LOOPS / name)["stable"] for name, _scene in CASES}
    assert kinds == {True, False}, kinds
