"""The identification run's path tolerance: its moves at half max_speed behind a robot as slow as calibrate
is specified for (120 ms of delay, 20 ms of lag, 10 ms of link) are that far behind the command, so the
robot driver's max_path_error in the identification graph is the scene's plus that distance (a robot
of 106 ms read 5.5-5.9 mm behind, past the scene's 5 mm, and every such run was INVALID)."""

from __future__ import annotations

import pytest

from dockhil.commands.calibrate import calibration_scene
from dockhil.scene import launchfile


@pytest.mark.parametrize("robot", ["rsi", "modbus"])
def test_the_identification_allows_the_slowest_robots_lag_behind_its_moves(robot):
    args = [f"robot:={robot}", "ft:=can", "emulators:=true"]
    scene = launchfile.load("hil.yaml", launchfile.parse_overrides(args))
    node = next(n for n in calibration_scene(scene).nodes if n.name == "robot")
    given = next(n for n in scene.nodes if n.name == "robot").params.get("max_path_error", 0.005)
    # max_speed 0.1 m/s (the drivers' default): the profile moves at 0.05 m/s, 0.15 s behind: 7.5 mm more
    assert node.params["max_path_error"] == pytest.approx(given + 0.0075)
    # the scene itself keeps its own tolerance
    assert next(n for n in scene.nodes if n.name == "robot").params.get("max_path_error", 0.005) == given
