"""The scene check judges the sampled loop against the delay equation with the robot's servo lag
counted as delay: an identified loop (delay 36 ms, lag 10 ms) is not refused as if the sampling made
the growth its lag makes."""

from __future__ import annotations

import pytest

from dockhil.cli import main


@pytest.mark.parametrize("delay, lag", [(0.036, 0.010), (0.032, 0.010), (0.036, 0.005)])
def test_a_lagged_loop_that_grows_as_its_delay_equation_is_warned_not_refused(tmp_path, capsys, delay, lag):
    loop = tmp_path / "loop.yaml"
    loop.write_text(
        f"args:\n  delay: {delay}\n  lag: {lag}\n  k: 1000.0\n  ft_noise: 0.2\n"
        'tare: {"force_N": [0.31, -0.12, 1.05], "torque_Nm": [0.011, -0.004, 0.002]}\n'
    )
    assert main(["graph", "hil.yaml", f"loop:={loop}"]) == 0
    err = capsys.readouterr().err
    assert "refused" not in err and "the loop is unstable" in err and "as the delay equation predicts" in err, err


def test_the_lag_free_loop_at_the_same_delay_stays_quiet(capsys):
    assert main(["graph", "hil.yaml", "delay:=0.036", "lag:=0"]) == 0
    assert "warning" not in capsys.readouterr().err
