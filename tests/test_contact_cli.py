"""`dockhil params` and `dockhil stability`: JSON outputs, tables, the Fig. 7
map, and one-line refusals of bad input (exit code 2)."""

import json
import subprocess
import sys

import pytest

from dockhil.cli import main

TABLE1_ARGS = ["--m1", "750", "--m2", "1e6", "--kcs", "3000", "--bcs", "40", "--k", "1000"]


def run_json(capsys, argv):
    assert main(argv) == 0
    out = capsys.readouterr().out
    return json.loads(out)


def test_params_json_reproduces_table1(capsys):
    result = run_json(capsys, ["params", *TABLE1_ARGS, "--v1", "0.03", "--v2", "0", "--json"])
    assert result["k1"] == pytest.approx(2001.5, rel=1e-3)
    assert result["b1"] == pytest.approx(40.03, rel=1e-3)
    assert result["k2"] == pytest.approx(2668700.0, rel=1e-3)
    assert result["b2"] == pytest.approx(53373.0, rel=1e-3)
    assert result["agrees_with_closed_form"] is True
    assert result["max_relative_deviation"] < 1e-12
    assert result["closed_form"]["k2"] == pytest.approx(result["k2"], rel=1e-12)
    assert result["states"] == "exact" and "Eqs. 5-6" in result["method"]
    assert 0 < result["t1"] < result["t2"] < result["contact_duration"]
    assert result["warnings"] == []


def test_params_table1_preset_and_velocity_independence(capsys):
    a = run_json(capsys, ["params", "--table1", "--json"])
    b = run_json(capsys, ["params", "--table1", "--v1", "0.5", "--v2", "0.2", "--t1", "0.2", "--t2", "1.3", "--json"])
    for name in ("k1", "b1", "k2", "b2"):
        assert b[name] == pytest.approx(a[name], rel=1e-8)
    assert (b["t1"], b["t2"]) == (0.2, 1.3)


def test_params_table_and_warning(capsys):
    assert main(["params", "--table1", "--kcs", "500"]) == 0
    captured = capsys.readouterr()
    assert "k1" in captured.out and "closed form" in captured.out and "agree" in captured.out
    assert "warning: kcs = 500 N/m is below the passive stiffness k = 1000 N/m" in captured.err
    result = run_json(capsys, ["params", "--table1", "--kcs", "500", "--json"])
    assert result["k1"] < 0 and result["warnings"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["params", "--table1", "--m1", "-750"], "--m1 must be > 0 kg, got -750.0"),
        (["params", "--table1", "--m2", "0"], "--m2 must be > 0 kg"),
        (["params", "--table1", "--kcs", "nan"], "--kcs must be a finite number"),
        (["params", "--m1", "750"], "missing --m2"),
        (["params", "--table1", "--t1", "0.5", "--t2", "0.5"], "t1 = t2 = 0.5 s"),
        (["params", "--table1", "--t1", "0.5", "--t2", "3"], "outside the contact"),
        (["params", "--table1", "--v1", "0"], "--v1 = 0 m/s must exceed --v2"),
        (["stability", "--m", "-1", "--b", "20", "--h", "0.016"], "--m must be > 0 kg"),
        (["stability", "--m", "750", "--b", "20", "--h", "-0.016"], "--h must be >= 0 s"),
        (["stability", "--m", "750", "--b", "20", "--h", "0"], "--h must be > 0 s"),
        (["stability", "--m", "750", "--b", "nan", "--h", "0.016"], "--b must be a finite number"),
        (["stability", "--m", "750", "--b", "20", "--h", "0.016", "--K", "inf"], "--K must be a finite number"),
        (["stability", "--m", "750", "--h", "0.016"], "missing --b"),
        (["stability", "map", "--m", "0", "--png", "x.png"], "--m must be > 0 kg"),
        (["stability", "map", "--m", "750", "--h-range", "0.03", "0.01", "--png", "x.png"], "--h-range needs LO < HI"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_stability_json_paper_numbers(capsys):
    b20 = run_json(capsys, ["stability", "--m", "750", "--b", "20", "--h", "0.016", "--K", "2510", "--json"])
    assert b20["pade1"] == pytest.approx(1250.0, abs=0.5)
    assert b20["exact"] == pytest.approx(1249.822, rel=1e-6)
    assert b20["stable"] is False and b20["growth_rate"] > 0
    b60 = run_json(capsys, ["stability", "--m", "750", "--b", "60", "--h", "0.016", "--K", "2510", "--json"])
    assert b60["pade1"] == pytest.approx(3748.8, abs=0.05)
    assert b60["stable"] is True and b60["growth_rate"] < 0
    without_k = run_json(capsys, ["stability", "--m", "750", "--b", "60", "--h", "0.016", "--json"])
    assert "stable" not in without_k and "growth_rate" not in without_k


def test_stability_json_no_stabilizing_k(capsys):
    r = run_json(capsys, ["stability", "--m", "1", "--b", "110", "--h", "0.016", "--K", "100", "--json"])
    assert r["exact"] is None
    assert r["reason"].startswith("no stiffness K > 0 stabilizes this loop")
    assert r["pade1"] > 0  # Eq. 12 would have allowed it
    assert r["stable"] is False
    u = run_json(capsys, ["stability", "--m", "1", "--b", "110", "--h", "0.016", "--damper", "undelayed", "--json"])
    assert u["exact"] > 0 and u["damper"] == "undelayed"


def test_stability_table_and_pade_order(capsys):
    assert main(["stability", "--m", "750", "--b", "20", "--h", "0.016", "--K", "2510", "--pade-order", "3"]) == 0
    out = capsys.readouterr().out
    assert "Eq. 12" in out and "exact" in out and "Pade 3" in out and "UNSTABLE" in out


def test_stability_map_writes_png(capsys, tmp_path):
    png = tmp_path / "fig7.png"
    r = run_json(capsys, ["stability", "map", "--m", "750", "--png", str(png), "--json"])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert r["grid"] == [200, 200] and r["compute_seconds"] < 0.5
    assert r["pade1_min"] > r["exact_min"] > 0 and r["points_without_stable_K"] == 0


def test_library_import_is_light_and_cli_runs_as_a_process():
    code = (
        "import sys, dockhil.contact;"
        "heavy = [m for m in ('scipy', 'zmq', 'matplotlib') if m in sys.modules];"
        "print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    proc = subprocess.run(
        [sys.executable, "-m", "dockhil.cli", "params", "--table1", "--json"], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["k1"] == pytest.approx(2001.5)
