"""Bad input at the device edge: what no controller or box sends is refused in one line and never
stops a thread. RSI datagrams on a clock the test controls; the Net F/T page from a server written here."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from dockhil.devices.ati_netft import protocol as rdt
from dockhil.devices.ati_netft.driver import FtNetFtDriver
from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.kuka_rsi.link import RsiLink, open_socket
from dockhil.errors import DeviceError
from dockhil.node import ManualClock, NodeContext
from tests.test_hardware_netft import BOX_XML
from tests.test_hardware_rsi import rob_text

CYCLE = 0.004


def link(clock) -> RsiLink:
    return RsiLink(None, "127.0.0.1", CYCLE, 0.1, 0.5, 0.2, "ImFree", clock)


def rob(ipoc: str, rist=("500", "0", "900", "180", "0", "180")) -> bytes:
    x, y, z, a, b, c = rist
    return f'<Rob Type="KUKA"><RIst X="{x}" Y="{y}" Z="{z}" A="{a}" B="{b}" C="{c}"/><IPOC>{ipoc}</IPOC></Rob>'.encode()


@pytest.mark.parametrize(
    "data, words",
    [
        (rob("1" * 400), "IPOC of 400 digits: no controller counts that far"),
        (rob("10", ("1e308", "0", "900", "180", "0", "180")), "RIst X='1e308' is outside +-1e+06 mm"),
        (rob("10", ("500", "-2e6", "900", "180", "0", "180")), "RIst Y='-2e6' is outside"),
        (rob("10", ("500", "0", "900", "1e300", "0", "180")), "RIst A='1e300' is outside +-360 degrees"),
        (rob("10", ("500", "0", "900", "180", "360.5", "180")), "RIst B='360.5' is outside +-360 degrees"),
    ],
)
def test_a_datagram_no_controller_sends_is_refused_in_a_few_words(data, words):
    with pytest.raises(rsi.RsiError) as err:
        rsi.parse_rob(data)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_an_implausible_ipoc_is_counted_once_and_the_controllers_next_datagram_is_answered():
    clock = ManualClock()
    lk = link(clock)
    lk.submit((10.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert lk.handle(rob_text(1000), "127.0.0.1", clock()) is not None
    for ipoc in ("1" * 400, str(1000 + 10**12), str(1000 + 4 * 30)):  # far beyond what 4 ms allow
        clock.advance(CYCLE)
        assert lk.handle(rob(ipoc), "127.0.0.1", clock()) is None
    assert lk.counted["malformed"] == 3 and lk.last_ipoc == 1000
    notes = lk.take_notes()
    assert len(notes) == 1 and "IPOC" in notes[0] and "\n" not in notes[0]
    clock.advance(CYCLE)
    assert lk.handle(rob_text(1016), "127.0.0.1", clock()) is not None  # the real controller goes on
    # a jump the time since allows (the controller, or this link, was stopped for a second) is no fault
    clock.advance(1.0)
    assert lk.handle(rob_text(2020), "127.0.0.1", clock()) is not None


def test_no_datagram_stops_the_answering_thread():
    """Against the link's own socket: a 400-digit IPOC, absurd poses and a datagram that breaks the
    handler are counted; the controller's next datagram is answered."""
    clock = ManualClock(100.0)
    sock, controller = open_socket("127.0.0.1", "127.0.0.1", 0, "robot controller")
    lk = RsiLink(sock, controller, CYCLE, 0.1, 0.5, 10.0, "ImFree", clock)
    real_handle = lk.handle

    def breaking(data, host, now, port=None):
        if b"BREAK" in data:
            raise OverflowError("int too large to convert to float")
        return real_handle(data, host, now, port)

    lk.handle = breaking  # type: ignore[method-assign]
    lk.start()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ctl:
        ctl.bind(("127.0.0.1", 0))
        ctl.settimeout(2.0)
        port = sock.getsockname()[1]
        try:
            ctl.sendto(rob_text(1000), ("127.0.0.1", port))
            ctl.recv(4096)
            for data in (rob("1" * 400), rob("1004", ("1e308",) * 6), rob_text(1004, extra="<BREAK/>")):
                ctl.sendto(data, ("127.0.0.1", port))
            clock.advance(CYCLE)
            ctl.sendto(rob_text(1008), ("127.0.0.1", port))
            assert b"<IPOC>1008</IPOC>" in ctl.recv(4096)
            assert lk.is_alive() and lk.fatal is None and lk.counted["malformed"] == 3
        finally:
            lk.stop()


def test_net_ft_counts_that_make_the_full_scale_meaningless_are_refused_at_start_in_one_line():
    good = rdt.Calibration(1e6, 1e6, "N", "Nm")
    assert good.full_scale_problem() is None
    for calibration, words in (
        (rdt.Calibration(1e20, 1e6, "N", "Nm"), "counts_per_force 1e+20 makes the full scale 2.15e-11 N"),
        (rdt.Calibration(1e3, 1e6, "N", "Nm"), "full scale 2.15e+06 N, outside 1 to 100000 N"),
        (rdt.Calibration(1e6, 1e12, "N", "Nm"), "counts_per_torque 1e+12 makes the full scale 0.00215 N m"),
        (rdt.Calibration(1e6, 1e3, "N", "kNm"), "outside 0.01 to 10000 N m"),
    ):
        problem = calibration.full_scale_problem()
        assert problem is not None and words in problem, problem
    d = FtNetFtDriver(
        NodeContext("ft", 0.001, sim_time=False, log=lambda line: None),
        host="127.0.0.1",
        counts_per_force=1e12,
        counts_per_torque=1e6,
        force_unit="N",
        torque_unit="Nm",
    )
    with pytest.raises(DeviceError) as err:
        d.setup()
    text = str(err.value)
    assert "\n" not in text and text.startswith("Net F/T box 127.0.0.1:49152: counts_per_force 1e+12 makes"), text


class Page:
    """A web server written here that serves netftapi2.xml as told: trickled a byte at a time, or huge."""

    def __init__(self, body: bytes, byte_every: float = 0.0):
        self.body, self.byte_every = body, byte_every
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(4)
        self.server.settimeout(0.1)
        self.port = self.server.getsockname()[1]
        self.running = True
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while self.running:
            try:
                conn, _ = self.server.accept()
            except OSError:
                continue
            with conn:
                try:
                    conn.recv(4096)
                    data = b"HTTP/1.0 200 OK\r\nContent-Type: text/xml\r\n\r\n" + self.body
                    if not self.byte_every:
                        conn.sendall(data)
                        continue
                    for i in range(len(data)):
                        if not self.running:
                            break
                        conn.sendall(data[i : i + 1])
                        time.sleep(self.byte_every)
                except OSError:
                    pass

    def close(self) -> None:
        self.running = False
        self.thread.join(timeout=2.0)
        self.server.close()


def test_the_boxs_page_is_read_in_bounded_time_and_size():
    page = Page(BOX_XML.encode())
    try:  # the page served at once is read
        assert rdt.fetch_netftapi2("127.0.0.1", page.port, 2.0)["cfgcpf"] == "1000000"
    finally:
        page.close()
    page = Page(BOX_XML.encode(), byte_every=0.02)  # 50 bytes a second: each read is quick, the page is not
    try:
        t = time.monotonic()
        with pytest.raises(rdt.RdtError) as err:
            rdt.fetch_netftapi2("127.0.0.1", page.port, 0.5)
        assert time.monotonic() - t < 1.5
        assert "the page took more than 0.5 s (http_timeout)" in str(err.value) and "\n" not in str(err.value)
        assert not isinstance(err.value, rdt.Unreachable)  # not asked again: the box answers, too slowly
    finally:
        page.close()
    page = Page(b"<netft>" + b"<x>0</x>" * (rdt.MAX_XML_BYTES // 4) + b"</netft>")
    try:
        with pytest.raises(rdt.RdtError, match=f"more than {rdt.MAX_XML_BYTES} bytes, not a Net F/T page"):
            rdt.fetch_netftapi2("127.0.0.1", page.port, 5.0)
    finally:
        page.close()
