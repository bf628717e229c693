"""The command line as docs/commands.md writes it: `name:=value` before or after the options."""

from __future__ import annotations

import pytest

from dockhil import cli


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "spring_node:Spring", "--name", "spring", "--rate", "200", "k:=50", "x0:=0.1"],
        ["run", "spring_node:Spring", "k:=50", "--name", "spring", "x0:=0.1", "--rate", "200"],
        ["run", "spring_node:Spring", "k:=50", "x0:=0.1", "--name", "spring", "--rate", "200"],
    ],
)
def test_run_takes_parameters_anywhere_on_the_line(argv):
    _, args = cli.parse(argv)
    assert args.node == "spring_node:Spring" and args.name == "spring" and args.rate == 200.0
    assert sorted(args.overrides) == ["k:=50", "x0:=0.1"]


def test_an_option_that_is_no_parameter_is_still_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        cli.parse(["run", "spring_node:Spring", "--rate", "200", "--bogus", "k:=50"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "unrecognized arguments: --bogus" in err


def test_a_launch_argument_written_with_a_plain_equals_sign_hints_at_name_colon_equals(capsys):
    with pytest.raises(SystemExit) as e:
        cli.parse(["figures", "--out", "figs", "delay=0.016"])  # a command without name:=value
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1, err
    assert "unrecognized arguments: delay=0.016; a launch argument is name:=value: did you mean delay:=0.016?" in err


def test_a_launch_override_with_a_plain_equals_sign_suggests_the_colon_equals_form():
    from dockhil.errors import LaunchError
    from dockhil.scene.launchfile import parse_overrides

    with pytest.raises(LaunchError, match=r"'delay=0.016' is not of the form name:=value; did you mean delay:=0.016\?"):
        parse_overrides(["delay=0.016"])


def test_an_ambiguous_abbreviation_of_an_option_in_another_case_names_it(capsys):
    with pytest.raises(SystemExit) as e:
        cli.parse(["stability", "--m", "750", "--b", "20", "--h", "0.016", "--k", "3"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1, err
    assert "ambiguous option: --k could match" in err and "did you mean --K? (options are case-sensitive)" in err


@pytest.mark.parametrize(
    "given, meant", [("hil", "hil.yaml"), ("ideal.yml", "ideal.yaml"), ("launch/hl.yaml", "launch/hil.yaml")]
)
def test_a_scene_name_that_is_almost_a_shipped_one_is_suggested(given, meant):
    from dockhil.errors import LaunchError
    from dockhil.scene.launchfile import find_shipped

    with pytest.raises(LaunchError, match=rf"not found: .*; did you mean {meant}\? \(shipped: "):
        find_shipped(given)
    with pytest.raises(LaunchError) as err:
        find_shipped("nothing_like_it")
    assert "did you mean" not in str(err.value) and "of that name (shipped: " in str(err.value)
