"""Validity from the device cycles: a run whose device went longer than its tolerance without taking a
command (or the sensor without a fresh reading), or whose robot left the commanded path, is INVALID with
the node and the reason named; each driver keeps that account on a clock the test controls. And (wall_time)
a node or an emulator stopped mid-contact (SIGSTOP) never gives a valid run."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from dockhil.devices.kuka_rsi.link import RsiLink
from dockhil.node import ManualClock
from dockhil.runtime import validity
from tests.conftest import dockhil_cmd
from tests.test_hardware_rsi import read_sen, rob_text
from tests.test_validity import figures

CYCLE = 0.004
ROOT = Path(__file__).resolve().parents[1]


def robot(**device) -> dict:
    base = {
        "what": "robot controller (KUKA RSI 127.0.0.1 -> UDP port 49152)",
        "gap_is": "taking a command",
        "longest_gap_s": 0.008,
        "gap_limit_s": 0.05,
        "path_error_m": 0.001,
        "path_error_limit_m": 0.005,
    }
    return figures(node="robot", device={**base, **device})


def test_a_device_that_kept_the_loop_is_valid_and_one_that_stalled_is_not():
    assert validity.node_reasons(robot(), 0.004) == []
    assert validity.node_reasons(robot(longest_gap_s=0.3), 0.004) == [
        "node 'robot': robot controller (KUKA RSI 127.0.0.1 -> UDP port 49152) went 0.300 s without taking a "
        "command (> 0.05 s): the device stalled, or the loop did, and the loop that ran was not the scene's"
    ]
    assert validity.node_reasons(robot(path_error_m=0.0123), 0.004) == [
        "node 'robot': the robot's actual path left the commanded one by 0.0123 m (> following-error tolerance 0.005 m)"
    ]
    # an emulated device's own schedule is not judged, a driver's account of it is
    assert validity.wall_time_reasons({"robot": robot(longest_gap_s=1.0)}, {"robot": False}, 0.004)


def test_the_rsi_link_counts_the_cycles_its_controller_did_not_take_while_moving():
    clock = ManualClock()
    lk = RsiLink(None, "127.0.0.1", CYCLE, 0.1, 0.5, 10.0, "ImFree", clock)
    ipoc = 1000

    def cycle(step: int = 4, delay: int = 0, moved: float = CYCLE) -> None:
        nonlocal ipoc
        ipoc += step
        clock.advance(moved)
        assert read_sen(lk.handle(rob_text(ipoc, delay=delay), "127.0.0.1", clock())) is not None

    for _ in range(5):  # no command yet: nothing is missed
        cycle(step=40, moved=0.04)
    assert lk.longest_gap_s == 0.0
    lk.submit((20.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    for _ in range(10):
        cycle()
    cycle(delay=1)  # one answer late: a cycle not taken, within any tolerance
    cycle(delay=1)
    assert lk.longest_gap_s == pytest.approx(CYCLE)
    cycle(step=4 * 76, delay=1, moved=0.304)  # the controller stopped 0.3 s: 75 cycles never came
    assert lk.longest_gap_s == pytest.approx(75 * CYCLE)


# -- wall time: a node or an emulator stopped mid-contact ----------------------------------------------


def children(pid: int) -> dict[str, int]:
    """The graph's node processes under the launch `pid`, by node name."""
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) != pid or b"dockhil.process" not in cmdline:
            continue
        m = re.search(rb'"name":"([^"]+)"', b" ".join(cmdline))
        if m:
            out[m.group(1).decode()] = int(entry.name)
    return out


def stopped_run(tmp_path: Path, robot: str, node: str, seconds: float) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = dockhil_cmd(
        "launch", ROOT / "launch" / "hil.yaml", "ft:=netft", f"robot:={robot}", "emulators:=true", "--wall-time"
    )
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 30.0
        pids: dict[str, int] = {}
        while node not in pids and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
            pids = children(proc.pid)
        assert node in pids, f"no node {node!r} under the launch: {pids}"
        time.sleep(1.5)  # mid-contact: the scene starts touching and its contact lasts ~1.6 s after setup
        try:
            os.kill(pids[node], signal.SIGSTOP)
            time.sleep(seconds)
            os.kill(pids[node], signal.SIGCONT)
        except ProcessLookupError:
            pass  # the graph stopped before (a busy machine's stale input): the run says why
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out


@pytest.mark.wall_time
@pytest.mark.parametrize(
    "robot, node, seconds, named",
    [
        ("rsi", "rsi_emulator", 0.3, "robot controller (KUKA RSI 127.0.0.1 -> UDP port 49152) went"),
        ("modbus", "robot_emulator", 0.3, "robot controller (Modbus TCP 127.0.0.1:5020)"),
        # A second's stop outlasts the driver's controller_timeout (0.5 s): the line that names the
        # controller says it went without a cycle, or that it stopped sending, whichever the driver saw first.
        ("rsi", "rsi_emulator", 1.0, "robot controller (KUKA RSI 127.0.0.1 -> UDP port 49152)"),
        ("rsi", "ft", 0.3, "'ft'"),
        ("modbus", "robot", 1.0, "stall"),
    ],
)
def test_a_node_or_emulator_stopped_mid_contact_is_never_a_valid_run_and_is_named(
    tmp_path, robot, node, seconds, named
):
    """Whatever else a busy machine makes of the run, it is not valid, and a line names what stopped: the
    driver of the emulated device (its account of the device's cycles), the stopped node itself, or the
    robot driver's safety stop (a stall of its own)."""
    code, out = stopped_run(tmp_path, robot, node, seconds)
    assert code != 0, out[-3000:]
    said = [line for line in out.splitlines() if "INVALID" in line or "safety stop" in line or "error" in line]
    assert any(named in line for line in said), out[-3000:]
