"""The same scene on real-protocol drivers: CAN F/T over UDP multicast on loopback (and over a
pseudo-terminal slcan adapter, can_interface:=pty), robot over Modbus TCP on 127.0.0.1, both
emulated; missing devices and safety through the launcher.

True wall-time end-to-end runs (marked wall_time): they assert outcomes, and wait for
conditions with deadlines. The F/T watchdog is widened to 1 s where it is not what a
test is about, so a busy machine's scheduling gaps do not stop the run; the watchdog
itself is tested on the tick clock (test_hardware_safety.py, test_nodes_hardware.py)."""

import json
import subprocess
import time
from pathlib import Path

import pytest

from tests.conftest import Lines, dockhil_cmd, free_port, kill_child_and_expect_the_graph_to_stop

pytestmark = pytest.mark.wall_time


def hardware_args(tmp_path, emulators=True, can_interface="auto"):
    tmp_path.mkdir(exist_ok=True)
    return [
        "ft:=can",
        "robot:=modbus",
        f"emulators:={'true' if emulators else 'false'}",
        f"can_interface:={can_interface}",
        f"can_channel:={tmp_path / 'ft.slcan'}",
        f"modbus_port:={free_port()}",
        "ft_timeout:=1.0",
    ]


def contact_ended(summary) -> bool:
    """The run's summary has the whole contact (its duration is None while the contact goes on)."""
    return summary.exists() and json.loads(summary.read_text())["contact_duration_s"] is not None


def wall_run(tmp_path, *args, done, attempts=3) -> subprocess.CompletedProcess:
    """Launch the hardware scene in wall time until the run gives the outcome `done(run)` is about.

    On a busy machine a driver may stop a run early: stale sensor data, a watchdog. That is
    the safety doing its job, not this test's outcome: such a run must stop non-zero with
    one line saying why, and is tried again (a fresh port and adapter each time). A run whose
    loop skipped so many ticks that its simulated time ended before the contact did says so in
    its summary's note, and is tried again too."""
    for attempt in range(attempts):
        r = subprocess.run(
            dockhil_cmd(
                "launch", "launch/hil.yaml", *hardware_args(tmp_path / str(attempt)), "--wall-time", *args, "--quiet"
            ),
            capture_output=True,
            text=True,
            timeout=120,
        )
        out = r.stdout + r.stderr
        assert "Traceback" not in out, out
        if done(r):
            return r
        why = [line for line in out.splitlines() if " error: " in line or "safety stop" in line or "INVALID" in line]
        if r.returncode == 0 and "--summary" in args:
            note = json.loads(Path(args[args.index("--summary") + 1]).read_text())["note"] or ""
            assert note.startswith("the contact had not ended"), (
                out
            )  # a valid run: only a cut-short contact is tried again
            why = [note]
        else:
            assert r.returncode != 0 and why, out
    pytest.fail(f"{attempts} runs stopped early, the last one: {why[0]}")


def test_swap_runs_the_scene_through_the_drivers_and_lands_near_the_simulated_run(tmp_path):
    sim, hw = tmp_path / "sim.json", tmp_path / "hw.json"
    # 250 Hz, for both: the loop a 2-core machine keeps in real time also while other work runs
    # (at 1 kHz seven processes on a busy machine fall behind, and the run rightly says so).
    r = subprocess.run(
        dockhil_cmd("launch", "launch/hil.yaml", "rate:=250", "--composed", "--summary", sim, "--quiet"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    # 2.5 s of wall time: the 1.57 s contact ends within it also when a busy machine skips some ticks
    # (a run that skipped so many that it did not is tried again).
    r = wall_run(
        tmp_path,
        "rate:=250",
        "--duration",
        "2.5",
        "--summary",
        hw,
        done=lambda r: r.returncode == 0 and contact_ended(hw),
    )
    assert "tared over 100 samples" in r.stderr and "listening on 127.0.0.1" in r.stderr
    s, h = json.loads(sim.read_text()), json.loads(hw.read_text())
    # Real protocols and wall-clock scheduling add a little delay on top of the emulated 32 ms.
    assert h["peak_force_N"] == pytest.approx(s["peak_force_N"], abs=2.0)
    assert h["contact_duration_s"] == pytest.approx(s["contact_duration_s"], abs=0.05)
    assert h["exit_velocity_mps"] == pytest.approx(s["exit_velocity_mps"], abs=0.003)


def test_passivity_compensation_works_through_the_drivers(tmp_path):
    # Through the real protocols the robot answers 32 ms late plus what the links and a busy
    # machine add; uncompensated, the bodies leave faster than the ideal contact lets them
    # (restitution 0.993 against 0.959, README). The controller takes out the energy those delays
    # make, whatever made it: the bodies leave no faster than ideal, to the links' jitter.
    hw = tmp_path / "hw.json"
    wall_run(
        tmp_path,
        "rate:=250",
        "compensation:=passivity",
        "--duration",
        "2.5",
        "--summary",
        hw,
        done=lambda r: r.returncode == 0 and contact_ended(hw),
    )
    h = json.loads(hw.read_text())
    assert h["valid"] is True and h["energy"]["compensation"] == "passivity"
    assert h["energy"]["generated_J"] > 0 and h["energy"]["net_generated_J"] <= 1e-3 * h["energy"]["generated_J"]
    assert h["restitution"] < h["ideal"]["restitution"] + 0.02, (h["restitution"], h["ideal"]["restitution"])


def test_missing_devices_fail_fast_with_one_line_each(tmp_path):
    t0 = time.monotonic()
    r = subprocess.run(
        dockhil_cmd(
            "launch",
            "launch/hil.yaml",
            *hardware_args(tmp_path, emulators=False),
            "--wall-time",
            "--duration",
            "30",
            "--quiet",
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0
    assert time.monotonic() - t0 < 25  # fails at start, long before the 30 s run would end
    out = r.stdout + r.stderr
    errors = [line for line in out.splitlines() if " error: " in line]
    assert any(line.startswith("[robot] error: robot controller (Modbus TCP") for line in errors), out
    assert any(line.startswith("[ft] error: F/T sensor (slcan") for line in errors), out
    assert "Traceback" not in out


def test_a_safety_limit_stops_the_graph_naming_limit_and_value(tmp_path):
    # The sensor measures the passive compliance alone: k v / omega, about 15 N at its peak here.
    # 250 Hz, as in the swap test: at 1 kHz a busy machine's seven processes fall behind and a run stops
    # on a stale input before the contact (three times in a row, seen with other work on the machine).
    r = wall_run(
        tmp_path,
        "rate:=250",
        "max_force:=10",
        "--duration",
        "3",
        done=lambda r: "safety stop: max_force" in r.stdout + r.stderr,
    )
    assert r.returncode != 0
    out = r.stdout + r.stderr
    trip = [line for line in out.splitlines() if "safety stop: max_force" in line]
    assert len(trip) == 1 and "> 10 N" in trip[0].replace("10.0", "10"), out
    assert "robot held" in trip[0] and "Traceback" not in out


@pytest.mark.parametrize("can_interface", ["auto", "pty"])
def test_a_dead_device_stops_the_graph(tmp_path, can_interface):
    """The sensor's CAN adapter (the emulator, on UDP multicast or an slcan pseudo-terminal) dies
    mid-run: the launcher stops the graph, non-zero.
    The driver's own watchdog and hold are tested in test_hardware_safety.py."""
    args = hardware_args(tmp_path, can_interface=can_interface)
    p = subprocess.Popen(
        dockhil_cmd("launch", "launch/hil.yaml", *args, "--wall-time", "--duration", "20", "--quiet"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines = Lines(p)
    started = lines.wait_for("tared over")  # running: the driver reads the emulated sensor
    assert f"F/T sensor ({'slcan' if can_interface == 'pty' else 'udp_multicast'} " in started, started
    out = kill_child_and_expect_the_graph_to_stop(p, "ft_emulator", dependent="ft", lines=lines)
    # Either way the sensor's loss is named: the dead adapter, or the driver's bus error.
    assert "'ft_emulator' was killed by SIGKILL" in out or "bus error" in out or "stale data" in out
