"""The stability verdict proven on the run: on emulated hardware (a KUKA RSI controller whose hidden delay
is not a whole number of its 4 ms cycles, with a lag, and a noisy Net F/T sensor), `dockhil calibrate
launch/stability.yaml` gives the largest stable sheet stiffness for m 50 kg, b 20 N s/m at 250 Hz; the
scene then runs in wall time with the emulated sheet at 0.75 and 1.35 times it: the first contact's
oscillation decays, the second grows, with either timing of the emulated controller. The calibration is
held to the run it had on the way (the RSI half of tests/test_calibrate.py's live calibrations)."""

from __future__ import annotations

import pytest

# Wall time of each run [s]. Calibrated at load 12, the bound fell to 436 N/m (loop delay 34 ms): at 0.75
# times it the contact swings at 0.4 Hz, so 10 s hold 7 peaks of its envelope (the fit needs 4); a
# second's late start on a busy machine costs a tenth of the ticks the run must have.
# Fitted over the first 6, 7.5 and 10 s of 15 s runs, the growth rates stayed within 10 % of the whole
# run's and as clearly signed: about -0.055 (ours) and -0.023 (immediate) per second at 0.75 times the
# bound, +0.07 and +0.11 at 1.35 times it.
SECONDS = 10.0


DELAY, LAG, CYCLE, NOISE = 0.0231, 0.004, 0.004, 0.2  # the emulated robot's hidden delay and lag, its cycle
SHEET = 2510.0  # N/m: stability.yaml's sheet, the passive compliance the calibration presses


@pytest.mark.wall_time
@pytest.mark.parametrize("timing", ["ours", "immediate"])
def test_below_the_calibrated_bound_the_contact_decays_above_it_grows(timing, tmp_path):
    """Also the live calibration on the KUKA RSI emulator at its 4 ms cycle, with either timing: it uses
    the driver's device cycles (no fallback to the ticks); RSI does not say which cycle took a correction,
    so the robot's own delay and the link are not identified apart and the hidden delay lies in the range
    given; the loop's delay, the verdict's, is the run's own end to end (bench/calibrate.py's reading of
    the bag, code of its own): within a cycle of it and never below the hidden delay."""
    from bench.calibrate import run_end_to_end
    from bench.stability_run import calibrate, hardware, run

    args = hardware("rsi", timing, DELAY, LAG, NOISE)
    bag = tmp_path / "calibration.mcap"
    found = calibrate(args, bag_out=str(bag))
    assert found["timing"] == "device cycles" and found["fit"]["split_not_identified"], found
    assert found["delay_s"] is None and found["link_s"] is None
    low, high = found["delay_range_s"]
    assert low <= DELAY <= high, found["delay_range_s"]
    e2e = run_end_to_end(str(bag), LAG)
    loop = found["loop_delay_s"] + found["lag_s"]  # a lag under a cycle or two trades with the delay
    assert abs(loop - e2e["p95_s"] - LAG) <= CYCLE and found["loop_delay_s"] >= DELAY, (found, e2e)
    assert abs(found["lag_s"] - LAG) <= 2.0 * CYCLE and abs(found["k_N_per_m"] / SHEET - 1.0) < 0.05, found

    bound = found["kcs_max_N_per_m"]
    assert bound is not None and found["loop_delay_s"] >= DELAY
    below, above = run(args, 0.75 * bound, SECONDS), run(args, 1.35 * bound, SECONDS)
    for r in (below, above):
        assert r.get("growth_rate_1_s") is not None and r["states"] > 0.8 * SECONDS * 250.0, r
    assert below["growth_rate_1_s"] < 0.0 < above["growth_rate_1_s"], (bound, below, above)
