"""Values outside the range of docking hardware are refused in one line before anything runs, a
contact no scene rate resolves is refused naming the rate it needs, and a bug still ends in one line."""

import subprocess

import pytest

from dockhil import cli
from tests.conftest import dockhil_cmd


def launch(*args):
    return subprocess.run(
        dockhil_cmd("launch", "launch/stability.yaml", "--composed", "--duration", "0.1", *args),
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize(
    "override, said",
    [
        ("m:=1e-300", "node 'dynamics' parameter 'm1': 1e-300 kg is outside 0.01 to 1e+08 kg in magnitude"),
        ("thrust:=1e300", "node 'dynamics' parameter 'thrust': 1e+300 N is outside 0 to 1e+06 N in magnitude"),
        ("v0:=-5e3", "node 'dynamics' parameter 'v1': -5000.0 m/s is outside 0 to 5 m/s in magnitude"),
    ],
)
def test_a_value_outside_docking_hardware_is_refused_in_one_line(override, said):
    r = launch(override)
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.splitlines()) == 1 and said in r.stderr and "Traceback" not in r.stderr


def test_a_contact_no_scene_rate_resolves_is_refused_naming_the_rate_it_needs():
    # omega = sqrt(k/m) = sqrt(1e12/750) = 3.65e4 rad/s: resolving it (omega dt <= 0.025) takes more
    # than 1.46e6 Hz, past the 1e6 Hz a scene runs at, so no rate:= is offered.
    r = launch("k:=1e12")
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr
    assert "omega = 3.651e+04 rad/s" in r.stderr and "above the 1e+06 Hz a scene runs at" in r.stderr
    assert "rate:=" not in r.stderr.split("above")[1].replace("allow_coarse:=true", "")


def test_a_bug_ends_in_one_line_naming_where(monkeypatch, capsys):
    def broken(args):
        raise ValueError("Maximum allowed dimension exceeded")

    import dockhil.commands.params as params

    monkeypatch.setattr(params, "run", broken)
    monkeypatch.delenv("DOCKHIL_TRACEBACK", raising=False)
    assert cli.main(["params"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(
        "dockhil params: internal error: ValueError: Maximum allowed dimension exceeded (at test_physical_range.py:"
    )
    monkeypatch.setenv("DOCKHIL_TRACEBACK", "1")
    with pytest.raises(ValueError):
        cli.main(["params"])


@pytest.mark.parametrize(
    "argv",
    [
        ["stability", "--m", "1e-300", "--b", "20", "--h", "0.016"],
        ["stability", "map", "--m", "1e-9", "--png", "never.png"],
    ],
)
def test_the_stability_tool_holds_its_mass_to_the_same_range(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "kg is below 0.01 kg, the range of docking hardware" in err
    assert not (tmp_path / "never.png").exists()
