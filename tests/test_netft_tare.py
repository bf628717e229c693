"""The Net F/T driver's tare is the graph's, as the CAN driver's (dockhil/devices/tare.py): a
driver restarted mid-contact keeps the graph's first tare, a tare over a moving probe is refused,
and another graph tares anew. Against the fake box of tests/test_hardware_netft.py."""

from __future__ import annotations

import os
import stat

import pytest

from dockhil.devices.ati_netft.driver import FtNetFtDriver
from dockhil.errors import DeviceError
from dockhil.node import Tick
from dockhil.runtime import ownership
from tests.test_hardware_netft import LBF, FakeBox, arrive, ctx, record

MILLION = 1_000_000  # counts per lbf of the fake box's page


@pytest.fixture
def in_graph():
    ownership.set_graph("graph-netft")
    yield ownership.graph_dir()
    ownership.set_graph("")


@pytest.fixture
def start():
    """A driver started while the box streams `counts` (each record's six counts, in turn)."""
    opened = []

    def make(logs: list, counts, n=20, **params):
        box = FakeBox()
        box.on_start = [record(i + 1, 10 * (i + 1), 0, counts[i % len(counts)]) for i in range(n)]
        driver = FtNetFtDriver(
            ctx(logs), host="127.0.0.1", port=box.port, http_port=box.http_port, tare_samples=20, **params
        )
        opened.append((box, driver))
        driver.setup()
        return box, driver

    yield make
    for box, driver in opened:
        driver.close()
        box.close()


def test_a_driver_restarted_mid_contact_keeps_the_graphs_first_tare(start, in_graph):
    logs: list[str] = []
    _, first = start(logs, [(MILLION, 0, 0, 0, 0, 0)])  # unloaded: 1 lbf of offset
    assert first.bias_force == pytest.approx((LBF, 0.0, 0.0))
    kept = in_graph / "tare-ft.json"
    assert stat.S_IMODE(kept.stat().st_mode) == 0o600 and kept.stat().st_uid == os.getuid()
    first.close()  # the driver dies mid-contact: the probe now carries 10 lbf on top of its offset
    box, again = start(logs, [(11 * MILLION, 0, 0, 0, 0, 0)], n=1)
    assert again.bias_force == pytest.approx((LBF, 0.0, 0.0))  # not the contact force
    box.send(record(2, 20, 0, (11 * MILLION, 0, 0, 0, 0, 0)))
    arrive(again, 2)
    force = again.step(Tick(0, 0.0, 0.001), {})["wrench"].wrench.force
    assert force.x == pytest.approx(10 * LBF) and force.y == pytest.approx(0.0)
    line = next(m for m in logs if ": restarted: " in m)
    assert "kept the graph's first tare" in line and f"reads {10 * LBF:.2f} N from it now" in line


def test_another_graph_tares_anew(start, in_graph):
    logs: list[str] = []
    start(logs, [(MILLION, 0, 0, 0, 0, 0)])
    ownership.set_graph("graph-netft-next")
    _, driver = start(logs, [(2 * MILLION, 0, 0, 0, 0, 0)])
    assert driver.bias_force == pytest.approx((2 * LBF, 0.0, 0.0))
    assert sum("tared over 20 records" in line for line in logs) == 2


def test_a_tare_over_a_moving_probe_is_refused_in_one_line(start):
    logs: list[str] = []
    with pytest.raises(DeviceError) as err:  # someone leans on the probe while it tares: 0 and 3 lbf in turn
        start(logs, [(0, 0, 0, 0, 0, 0), (3 * MILLION, 0, 0, 0, 0, 0)])
    text = str(err.value)
    assert "\n" not in text and "tare: force spread 6.67 N over 20 samples > max_tare_spread 2 N" in text, text
