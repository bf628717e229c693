"""Datagram loss on the device links: every lost RSI datagram and RDT record is counted, and the
correction never moves more than the per-cycle limit across a gap. On a clock the test controls,
and (wall_time) the whole graph with 1 % loss injected on both links."""

from __future__ import annotations

import json
import math
import random
import re
import subprocess
from pathlib import Path

import pytest

from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.node import ManualClock
from tests.conftest import dockhil_cmd
from tests.test_hardware_netft import free_udp_and_tcp_port
from tests.test_hardware_rsi import CYCLE, START, SceneFrame, link, read_sen, rob_text, udp_port

HIL = Path(__file__).resolve().parent.parent / "launch"


def test_lost_rsi_datagrams_are_counted_and_the_correction_steps_at_most_the_limit():
    clock, rng = ManualClock(10.0), random.Random(3)
    lk = link(clock)
    lk.submit(*SceneFrame((0.0, 0.0, 0.0), START).correction((0.05, 0.0, 0.0), rsi.abc_to_quat(0.0, 0.0, 0.0)))
    lost, korrs = 0, [(0.0,) * 6]
    for k in range(600):
        clock.advance(CYCLE)
        if k % 50 == 0:
            lk.submit(*lk.target[1:])
        if k and rng.random() < 0.05:  # this cycle's datagram never reaches the driver
            lost += 1
            continue
        korrs.append(read_sen(lk.handle(rob_text(1000 + 4 * k), "127.0.0.1", clock()))[2])
    assert lost > 10 and lk.missing == lost
    steps = [math.dist(a[:3], b[:3]) for a, b in zip(korrs, korrs[1:])]
    assert max(steps) <= 0.1 * CYCLE * 1000 + 1e-3  # mm: a gap is never made up by a bigger step


def lossy_scene(tmp_path: Path, loss: float, records: Path) -> Path:
    """launch/hil.yaml with its emulators losing `loss` % of their datagrams, writing their records."""
    emulators = (HIL / "emulators.yaml").read_text()
    head = "    params: {host: 127.0.0.2, port: $(arg netft_port), "
    assert head in emulators
    emulators = emulators.replace(head, head + f"loss: {loss}, seed: 1, maxima: {records / 'netft.json'}, ")
    head = "    params: {port: $(arg rsi_port), cycle: $(arg rsi_cycle), "
    assert head in emulators
    emulators = emulators.replace(head, head + f"loss: {loss}, seed: 2, record: {records / 'rsi.json'}, ")
    (tmp_path / "emulators.yaml").write_text(emulators)
    scene = (HIL / "hil.yaml").read_text().replace("file: emulators.yaml", f"file: {tmp_path / 'emulators.yaml'}")
    path = tmp_path / "hil.yaml"
    path.write_text(scene)
    return path


MACHINE = ("fell behind real time", "missed", "started", "late")  # reasons that are the machine's, not the code's


@pytest.mark.wall_time
def test_one_percent_loss_on_both_links_is_counted_and_the_run_valid_or_held(tmp_path):
    """At 250 Hz (as the swap test: a busy machine's seven processes keep up there). The counts hold
    whatever the machine did; the run is valid, or invalid only for the machine's reasons after a
    retry, or held with one line."""
    scene = lossy_scene(tmp_path, 1.0, tmp_path)
    for _attempt in range(2):
        p = subprocess.run(
            dockhil_cmd(
                "launch",
                str(scene),
                "ft:=netft",
                "robot:=rsi",
                "emulators:=true",
                "rate:=250",
                f"netft_port:={free_udp_and_tcp_port()}",  # not the default ports: another graph may hold them
                f"rsi_port:={udp_port()}",
                "--wall-time",
                "--duration",
                "6",
            ),
            capture_output=True,
            text=True,
            timeout=90,
        )
        text = p.stdout + p.stderr
        assert "Traceback" not in text, text
        invalid = next((x for x in text.splitlines() if "INVALID:" in x), "")
        machine = p.returncode == 3 and all(any(m in r for m in MACHINE) for r in invalid.split("; "))
        if not machine:
            break
    if p.returncode == 1:  # held: one line says why
        assert any("safety stop" in x or "holding" in x for x in text.splitlines()), text
        return
    assert p.returncode == 0 or machine, text
    emulated = json.loads((tmp_path / "rsi.json").read_text())
    # Every datagram the controller lost while the driver listened is an IPOC gap the driver counts
    # (and so are slots the emulator itself skipped when it fell behind: at least as many).
    missing = re.search(r"(\d+) controller datagrams never came \(gaps in the IPOC between (\d+) and (\d+)\)", text)
    assert missing, text
    first, last = int(missing[2]), int(missing[3])
    lost = [i for i in emulated["lost_ipocs"] if first < i < last]
    assert lost and int(missing[1]) >= len(lost), (missing[0], lost)
    # Net F/T: every record the box lost before the last one it sent shows as a gap in the sequence, and
    # the driver counts exactly those; the lost ones after it no sequence can show (lost_unseen).
    box = json.loads((tmp_path / "netft.json").read_text())
    shown = box["lost"] - box["lost_unseen"]
    counted = re.search(r"Net F/T box 127\.0\.0\.2:\d+: (\d+) lost", text)
    assert shown > 0 and counted and int(counted[1]) == shown, (box, text)
    # The correction never moved more than the per-cycle limit (the driver's max_speed 0.1 m/s) between two
    # answers the controller took, also where the emulator itself fell behind and skipped slots: the driver
    # keeps each answer within one cycle's travel of every correction the controller may hold (its RSol).
    limit = 0.1 * 0.004 * 1000
    assert emulated["max_step_mm"] <= limit + 1e-9, emulated
