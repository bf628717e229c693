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
