"""`dockhil stability multi`: the multi-axis delayed loop from the command line."""

import json
import math
import subprocess

import pytest
from scipy.optimize import brentq

from tests.conftest import dockhil_cmd


def cli(*args):
    return subprocess.run(dockhil_cmd("stability", "multi", *args), capture_output=True, text=True, timeout=120)


def critical_stiffness(m, b, h):
    """1-DOF m s^2 + (K + b s) e^{-sh} = 0 on the imaginary axis: b h / m = theta sin theta,
    K = m theta^2 cos theta / h^2 (the paper's exact bound, solved here independently)."""
    theta = brentq(lambda th: th * math.sin(th) - b * h / m, 1e-12, math.pi / 2)
    return m * theta**2 * math.cos(theta) / h**2


def test_planar_decoupled_case_is_limited_by_the_weaker_axis():
    m, inertia, k, b, kr, br, h = 750.0, 500.0, 2510.0, 60.0, 300.0, 20.0, 0.016
    r = cli(
        "--planar",
        "--m",
        m,
        "--inertia",
        inertia,
        "--lever",
        0,
        "--k-normal",
        k,
        "--b-normal",
        b,
        "--k-rot",
        kr,
        "--b-rot",
        br,
        "--h",
        h,
        "--json",
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    per_axis = {"x": critical_stiffness(m, b, h) / k, "rz": critical_stiffness(inertia, br, h) / kr}
    limiting = min(per_axis, key=per_axis.get)
    assert out["limiting_axis"] == limiting
    assert out["stiffness_margin"] == pytest.approx(per_axis[limiting], rel=1e-5)
    assert out["decoupled_modes"] and out["stable"] == (per_axis[limiting] > 1.0)


def test_scene_margin_names_its_axis_and_agrees_with_the_root():
    r = cli("--scene", "launch/hil6.yaml", "delay:=0.016", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["h_s"] == 0.016 and out["limiting_axis"] in out["axes"]
    assert out["stable"] == (out["stiffness_margin"] > 1.0)


@pytest.mark.parametrize(
    "args, line",
    [
        ((), "give either --scene FILE"),
        (("--planar", "--m", "750", "--h", "0.016"), "--planar needs --inertia"),
        (("--scene", "launch/hil.yaml"), "not a 6-DOF hybrid scene"),
    ],
)
def test_bad_input_one_line(args, line):
    r = cli(*args)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    lines = [s for s in r.stderr.splitlines() if s.strip()]
    assert len(lines) == 1 and line in lines[0], r.stderr
