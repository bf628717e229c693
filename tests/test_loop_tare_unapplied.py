"""A loop file's tare where the scene does not ask for it (no ft_bias argument): the rest of the file holds,
and one line says the tare is not applied and why; where the scene asks for it, or the command line gives
ft_bias, no such line."""

from __future__ import annotations

from dockhil.cli import main
from dockhil.scene import launchfile

LOOP = (
    "args:\n  delay: 0.036\n  lag: 0.01\n  k: 1000.0\n"
    'tare: {"force_N": [0.31, -0.12, 1.05], "torque_Nm": [0.011, -0.004, 0.002]}\n'
)
# a scene of its own with a loop:= but no ft_bias (a lab's, written before the tare)
SCENE = """\
description: a delayed contact without ft_bias
rate: 1000.0
duration: 0.01
args:
  loop: {default: "", help: "loop file"}
  delay: {default: 0.016, help: "robot delay [s]"}
  k: {default: 2510.0, help: "stiffness [N/m]"}
nodes:
  - name: dynamics
    node: satellite_dynamics
    params: {model: ideal, m1: 750.0, m2: 1000000.0, kcs: $(arg k)}
"""


def files(tmp_path):
    loop, scene = tmp_path / "loop.yaml", tmp_path / "scene.yaml"
    loop.write_text(LOOP)
    scene.write_text(SCENE)
    return loop, scene


def test_a_tare_the_scene_does_not_ask_for_is_named_in_one_line(tmp_path, capsys):
    loop, scene = files(tmp_path)
    assert main(["graph", str(scene), f"loop:={loop}"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    said = [line for line in err if "tare" in line]
    assert len(said) == 1, err
    line = said[0]
    assert f"loop file {loop}" in line and "not applied" in line and "no ft_bias argument" in line, line
    assert "warning:" in line and str(scene) in line, line
    # the rest of the file holds
    s = launchfile.load(str(scene), {"loop": str(loop)})
    assert s.values["delay"] == 0.036 and s.values["k"] == 1000.0


def test_no_line_where_the_scene_takes_the_tare_or_the_command_line_gives_ft_bias(tmp_path, capsys):
    loop, _scene = files(tmp_path)
    assert main(["graph", "hil.yaml", "ft:=can", "robot:=modbus", f"loop:={loop}", "allow_unstable:=true"]) == 0
    assert "tare" not in capsys.readouterr().err
    assert (
        main(["graph", "hil.yaml", "ft:=can", "robot:=modbus", f"loop:={loop}", "ft_bias:=[]", "allow_unstable:=true"])
        == 0
    )
    assert "tare" not in capsys.readouterr().err
