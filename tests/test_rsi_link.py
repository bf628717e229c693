"""The RSI link's own reports: how far the setpoint leads the correction sent, the counters it closes
with, and the socket's one-line refusals. On a clock the test controls, no socket unless named."""

from __future__ import annotations

import math
import socket

import pytest

from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.kuka_rsi.link import ROUNDING_RAD, RsiLink, open_socket
from dockhil.errors import DeviceError
from dockhil.node import ManualClock

CYCLE = 0.004
START = (500.0, 0.0, 900.0, 180.0, 0.0, 180.0)
DEVICE = "robot controller (KUKA RSI 127.0.0.1 -> UDP port 49152)"


def link(clock, stale_after=0.2) -> RsiLink:
    return RsiLink(None, "127.0.0.1", CYCLE, 0.1, 0.5, stale_after, "ImFree", clock)


def answer(lk: RsiLink, clock: ManualClock, ipoc: int, host: str = "127.0.0.1", delay: int = 0):
    clock.advance(CYCLE)
    return lk.handle(rsi.build_rob(ipoc, START, delay=delay), host, clock())


def test_the_lead_is_the_setpoint_ahead_of_the_correction_sent_and_shrinks_one_step_a_cycle():
    clock = ManualClock()
    lk = link(clock)
    assert lk.lead() is None  # no setpoint: nothing to be ahead of
    turn = 0.01  # rad about z
    lk.submit((3.0, 4.0, 0.0), (0.0, 0.0, math.sin(turn / 2), math.cos(turn / 2)))
    distance, angle = lk.lead()
    assert distance == pytest.approx(0.005) and angle == pytest.approx(turn)
    answer(lk, clock, 1)
    distance, angle = lk.lead()
    # (the turn a little less where the answer's 4 decimals of A B C would make it more than the limit)
    assert distance == pytest.approx(0.005 - 0.1 * CYCLE) and angle == pytest.approx(
        turn - 0.5 * CYCLE, abs=ROUNDING_RAD
    )
    for k in range(20):
        answer(lk, clock, 2 + k)
    assert lk.lead()[0] == pytest.approx(0.0, abs=1e-12)
    assert lk.lead()[1] < 2e-6  # the orientation the answer's 4 decimals of A B C carry


def test_the_report_names_each_count_once_and_nothing_when_all_went_well():
    clock = ManualClock()
    lk = link(clock, stale_after=0.01)
    answer(lk, clock, 100)
    answer(lk, clock, 104)
    assert lk.report(DEVICE) == []
    assert answer(lk, clock, 108, host="10.0.0.9") is None  # another sender: counted, not answered
    lk.submit((1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    answer(lk, clock, 120, delay=2)  # 108 (from elsewhere), 112 and 116 never came; 2 late answers
    for k in range(3):  # the setpoint is older than stale_after from the third cycle on
        answer(lk, clock, 124 + 4 * k, delay=2)
    assert lk.report(DEVICE) == [
        f"warning: {DEVICE}: datagrams ignored: 1 from another address than the controller's",
        f"warning: {DEVICE}: 3 controller datagrams never came (gaps in the IPOC between 100 and 132)",
        f"warning: {DEVICE}: held on a stale setpoint for 2 cycles",
        f"warning: {DEVICE}: the controller counted 2 late answers while the graph ran",
    ]
    assert lk.ignored() == "1 from another address than the controller's"
    lk.delay_at_close = lk.delay  # the driver closes: what comes late now comes while the robot is held
    answer(lk, clock, 136, delay=5)
    assert lk.report(DEVICE)[-1] == (
        f"warning: {DEVICE}: the controller counted 2 late answers while the graph ran, "
        "3 while the driver closed (the robot held)"
    )


def test_a_port_in_use_or_an_unknown_host_is_refused_in_one_line_naming_the_device():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        with pytest.raises(DeviceError, match=r"cannot listen on 127\.0\.0\.1:\d+: .*another program uses the port"):
            open_socket("127.0.0.1", "127.0.0.1", port, DEVICE)
    with pytest.raises(DeviceError, match=r"^robot controller .*: cannot resolve 'no-such-host\.invalid'"):
        open_socket("no-such-host.invalid", "127.0.0.1", 0, DEVICE)
    sock, controller = open_socket("localhost", "127.0.0.1", 0, DEVICE)
    with sock:
        assert controller == "127.0.0.1" and sock.gettimeout() == pytest.approx(0.05)
