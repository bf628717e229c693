"""ATI Net F/T: the RDT codec against bytes written here from the protocol, netftapi2.xml in the
box's own format, unit conversions, the emulator answered by a raw socket client, and the
ft_netft driver against the emulator and against a minimal fake box written here (so the driver
is held to the protocol, not to our emulator). The driver is stepped with tick times the test
chooses; only the records' arrival takes real time."""

from __future__ import annotations

import json
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import urllib.request
import xml.etree.ElementTree as ET
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from dockhil.devices.ati_netft import protocol as rdt
from dockhil.devices.ati_netft.driver import FtNetFtDriver
from dockhil.devices.ati_netft.emulator import ContactModel, NetFtBox
from dockhil.errors import DeviceError, LaunchError, ParamError
from dockhil.node import NodeContext, Tick
from dockhil.runtime import ownership
from tests.conftest import dockhil_cmd, wait_for

ROOT = Path(__file__).resolve().parents[1]

# Trimmed from the page a Net F/T box serves at /netftapi2.xml (its element names and spelling).
BOX_XML = """<?xml version="1.0" encoding="utf-8"?>
<netft>
<runstat>0x00000000</runstat><runrate>7000</runrate>
<cfgnam>lab</cfgnam><cfgcalsel>0</cfgcalsel><cfgcalsn>FT12345</cfgcalsn>
<cfgfu>1</cfgfu><cfgtu>1</cfgtu>
<scfgfu>lbf</scfgfu><scfgtu>lbf-in</scfgtu>
<cfgtfx>0;0;0;0;0;0</cfgtfx><scfgtdu>in</scfgtdu><scfgtau>degrees</scfgtau>
<cfgcpf>1000000</cfgcpf><cfgcpt>1000000</cfgcpt>
<cfgmr>150;150;450;150;150;150</cfgmr>
<setuserfilter>0</setuserfilter>
<comrdte>Enabled</comrdte><comrdtrate>1000</comrdtrate><comrdtbsiz>1</comrdtbsiz>
</netft>
"""
LBF = 4.4482216152605  # N
LBF_IN = LBF * 0.0254  # N m


def request(command: int, count: int = 0) -> bytes:
    return struct.pack(">HHI", 0x1234, command, count)


def record(rdt_seq: int, ft_seq: int, status: int, counts) -> bytes:
    return struct.pack(">III6i", rdt_seq, ft_seq, status, *counts)


# -- the codec, against bytes written from the manual's description ----------------------


def test_requests_are_the_manuals_eight_bytes():
    assert rdt.encode_request(rdt.CMD_START) == bytes.fromhex("1234 0002 00000000")
    assert rdt.encode_request(rdt.CMD_STOP) == bytes.fromhex("1234 0000 00000000")
    assert rdt.encode_request(rdt.CMD_BIAS) == bytes.fromhex("1234 0042 00000000")
    assert rdt.encode_request(rdt.CMD_START, 1000) == bytes.fromhex("1234 0002 000003e8")
    assert rdt.decode_request(bytes.fromhex("1234 0002 00000010")) == (2, 16)
    for bad in (bytes.fromhex("4321 0002 00000000"), bytes.fromhex("1234 0002 000000"), b""):
        with pytest.raises(rdt.RdtError):
            rdt.decode_request(bad)


def test_records_are_the_manuals_36_bytes():
    data = bytes.fromhex(
        "00000001"
        "00000102"
        "00000000"  # rdt_sequence 1, ft_sequence 258, status 0
        "ffffffff"
        "000f4240"
        "fffffffe"  # Fx -1, Fy 1000000, Fz -2
        "7fffffff"
        "80000000"
        "00000000"
    )  # Tx, Ty the int32 extremes, Tz 0
    r = rdt.decode_record(data)
    assert (r.rdt_sequence, r.ft_sequence, r.status) == (1, 258, 0)
    assert r.counts == (-1, 1_000_000, -2, 2**31 - 1, -(2**31), 0)
    assert rdt.encode_record(1, 258, 0, r.counts) == data
    assert rdt.decode_record(bytes.fromhex("ffffffffffffffff80020000" + "00" * 24)).status == 0x80020000
    for size in (0, 35, 37, 1500):
        with pytest.raises(rdt.RdtError, match="a record is 36 bytes"):
            rdt.decode_record(bytes(size))
    assert "transducer saturation" in rdt.describe_status(0x80020000)


# -- netftapi2.xml and units ---------------------------------------------------------------


def test_the_boxs_page_gives_counts_per_unit_and_units():
    cal = rdt.calibration_from(rdt.parse_netftapi2(BOX_XML))
    assert (cal.counts_per_force, cal.counts_per_torque, cal.force_unit, cal.torque_unit) == (1e6, 1e6, "lbf", "lbf-in")
    assert cal.newtons_per_count == pytest.approx(LBF / 1e6, rel=1e-12)
    assert cal.newton_metres_per_count == pytest.approx(LBF_IN / 1e6, rel=1e-12)
    # a page with only the units' codes (cfgfu 4 kN, cfgtu 4 N mm)
    coded = BOX_XML.replace("<scfgfu>lbf</scfgfu><scfgtu>lbf-in</scfgtu>", "").replace(
        "<cfgfu>1</cfgfu><cfgtu>1</cfgtu>", "<cfgfu>4</cfgfu><cfgtu>4</cfgtu>"
    )
    cal = rdt.calibration_from(rdt.parse_netftapi2(coded))
    assert (cal.force_unit, cal.torque_unit) == ("kN", "Nmm")
    # parameters override the page, each on its own
    cal = rdt.calibration_from(
        rdt.parse_netftapi2(BOX_XML),
        {"counts_per_force": 500.0, "torque_unit": "Nm", "counts_per_torque": 0.0, "force_unit": ""},
    )
    assert (cal.counts_per_force, cal.counts_per_torque, cal.force_unit, cal.torque_unit) == (500.0, 1e6, "lbf", "Nm")


@pytest.mark.parametrize(
    "change, words",
    [
        (("<cfgcpf>1000000</cfgcpf>", ""), "no <cfgcpf>"),
        (("<cfgcpt>1000000</cfgcpt>", "<cfgcpt>lots</cfgcpt>"), "<cfgcpt> is 'lots'"),
        (("<cfgcpf>1000000</cfgcpf>", "<cfgcpf>0</cfgcpf>"), "counts_per_force must be a finite positive number"),
        (("<cfgcpf>1000000</cfgcpf>", "<cfgcpf>nan</cfgcpf>"), "counts_per_force must be a finite positive number"),
        (("<scfgfu>lbf</scfgfu>", "<scfgfu>stone</scfgfu>"), "unknown force unit 'stone'"),
        (("<cfgcpt>1000000</cfgcpt>", "<cfgcpt>1e-300</cfgcpt>"), "not the resolution of a sensor"),
        (("</netft>", ""), "not XML"),
    ],
)
def test_a_broken_page_is_one_line(change, words):
    with pytest.raises(rdt.RdtError) as err:
        rdt.calibration_from(rdt.parse_netftapi2(BOX_XML.replace(*change)))
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(
    "unit, newtons",
    [("N", 1.0), ("lbf", LBF), ("kN", 1000.0), ("klbf", 1000 * LBF), ("kgf", 9.80665), ("gf", 0.00980665)],
)
def test_force_units(unit, newtons):
    assert rdt.force_factor(unit) == pytest.approx(newtons, rel=1e-12)


@pytest.mark.parametrize(
    "unit, newton_metres",
    [
        ("Nm", 1.0),
        ("N-m", 1.0),
        ("N mm", 0.001),
        ("Nmm", 0.001),
        ("N-mm", 0.001),
        ("lbf-in", 0.1129848290276167),
        ("in-lb", 0.1129848290276167),
        ("lbf-ft", 1.3558179483314004),
        ("kgf-cm", 0.0980665),
        ("kNm", 1000.0),
    ],
)
def test_torque_units(unit, newton_metres):
    assert rdt.torque_factor(unit) == pytest.approx(newton_metres, rel=1e-12)


def test_an_unknown_unit_parameter_is_refused_before_anything_runs():
    with pytest.raises(ParamError, match=r"parameter 'force_unit': unknown force unit 'newtons'"):
        FtNetFtDriver(ctx([]), force_unit="newtons")
    with pytest.raises(ParamError, match=r"parameter 'torque_unit': unknown torque unit 'N'"):
        FtNetFtDriver(ctx([]), torque_unit="N")
    with pytest.raises(ParamError, match=r"parameter 'counts_per_force': 1e-300 is outside 0.001 to 1e\+12"):
        FtNetFtDriver(ctx([]), counts_per_force=1e-300)


def test_sequence_gaps_late_records_repeats_and_restarts_are_told_apart():
    s = rdt.SequenceCheck()
    used = [n for n in (1, 2, 5, 3, 3, 6, 6, 2) if s.accept(n)]
    assert used == [1, 2, 5, 6]
    assert (s.lost, s.reordered, s.duplicates) == (1, 1, 3)  # 4 never came; 3 came late; 3, 6, 2 again
    s = rdt.SequenceCheck()
    assert [s.accept(n) for n in (2**32 - 2, 2**32 - 1, 1)] == [True, True, True]  # wraps: 0 was lost
    assert s.lost == 1
    assert s.accept(5_000) and s.accept(1) and s.restarts == 1  # a new stream starts again at 1
    assert s.accept(2) and s.accept(3_000) and s.accept(2_990) is False  # 10 behind: a late one


# -- the emulator, answered by a raw client ------------------------------------------------


@pytest.fixture
def box():
    boxes = []

    def make(k=1000.0, position=None, **kw):
        model = ContactModel(k, kw.pop("b", 0.0), kw.pop("bias", 0.0), kw.pop("noise", 0.0))
        model.set_pose(position)
        b = NetFtBox(model, port=0, http_port=0, **kw).start_thread()
        boxes.append(b)
        return b

    yield make
    for b in boxes:
        b.stop_thread()


def client() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(2.0)
    return s


def test_emulator_streams_the_counted_records_to_the_requester_and_serves_its_page(box):
    b = box(
        k=1000.0,
        position=0.004,
        rate=1000.0,
        force_unit="kN",
        counts_per_force=1_000_000.0,
        torque_unit="Nmm",
        counts_per_torque=1000.0,
    )
    with client() as c:
        c.sendto(request(0x0002, 10), ("127.0.0.1", b.port))
        got = []
        for _ in range(10):
            data, sender = c.recvfrom(100)
            assert sender == ("127.0.0.1", b.port) and len(data) == 36
            got.append(struct.unpack(">III6i", data))
        c.settimeout(0.2)
        with pytest.raises(socket.timeout):
            c.recvfrom(100)  # ten asked for, ten sent
    assert [g[0] for g in got] == list(range(1, 11))
    assert {got[i + 1][1] - got[i][1] for i in range(9)} == {7}  # 7000 internal samples a second, 1000 records
    assert all(g[2] == 0 for g in got)
    # -k x = -4 N on the probe, in counts of 1e6 per kN
    assert {g[3:] for g in got} == {(-4000, 0, 0, 0, 0, 0)}
    url = f"http://127.0.0.1:{b.http_port}/netftapi2.xml"
    page = ET.fromstring(urllib.request.urlopen(url, timeout=5).read())
    assert page.tag == "netft"
    assert [page.findtext(t) for t in ("cfgcpf", "cfgcpt", "scfgfu", "scfgtu", "comrdtrate")] == [
        "1e+06",
        "1000",
        "kN",
        "Nmm",
        "1000",
    ]
    with pytest.raises(urllib.error.HTTPError, match="404"):
        urllib.request.urlopen(f"http://127.0.0.1:{b.http_port}/index.html", timeout=5)


def test_emulator_biases_stops_and_ignores_what_is_not_a_request(box):
    b = box(k=1000.0, position=0.002, rate=2000.0, bias=3.0)
    with client() as c:
        c.sendto(b"\x43\x21\x00\x02\x00\x00\x00\x00", ("127.0.0.1", b.port))  # wrong header
        c.sendto(request(0x0002)[:7], ("127.0.0.1", b.port))  # short
        c.sendto(request(0x0042), ("127.0.0.1", b.port))  # software bias: the present reading becomes 0
        c.sendto(request(0x0002), ("127.0.0.1", b.port))
        first = struct.unpack(">III6i", c.recvfrom(100)[0])
        assert first[0] == 1 and first[3:] == (0, 0, 0, 0, 0, 0)  # -2 N + 3 N bias, biased away
        c.sendto(request(0x0000), ("127.0.0.1", b.port))
        time.sleep(0.05)
        c.settimeout(0.05)
        try:
            while True:
                c.recvfrom(100)  # what was under way
        except TimeoutError:
            pass
        c.settimeout(0.2)
        with pytest.raises(socket.timeout):
            c.recvfrom(100)  # stopped
    assert b.counts["bad_requests"] == 2 and b.counts["biases"] == 1 and b.counts["stops"] == 1


def test_emulator_loss_is_seeded_and_counted(box):
    b = box(rate=5000.0, loss=10.0, seed=7)
    with client() as c:
        c.sendto(request(0x0002, 2000), ("127.0.0.1", b.port))
        seqs = []
        c.settimeout(0.5)
        deadline = time.monotonic() + 60  # a busy machine may pause the box's thread: wait until it is done
        while time.monotonic() < deadline:
            try:
                seqs.append(struct.unpack(">III6i", c.recvfrom(100)[0])[0])
            except TimeoutError:
                if b.counts["records"] == 2000:
                    break
    assert b.counts["records"] == 2000
    assert len(seqs) == 2000 - b.counts["lost"] and 120 < b.counts["lost"] < 280  # 10 % of 2000, seeded
    assert seqs == sorted(seqs) and seqs[-1] <= 2000


def test_emulator_process_writes_its_maxima_when_terminated(tmp_path):
    maxima = tmp_path / "maxima.json"
    help_ = subprocess.run(
        [sys.executable, "-m", "dockhil.devices.ati_netft.emulator", "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert help_.returncode == 0 and "--loss" in help_.stdout
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dockhil.devices.ati_netft.emulator",
            "--port",
            "0",
            "--http-port",
            "0",
            "--position",
            "0.01",
            "--k",
            "2000",
            "--maxima",
            str(maxima),
        ],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline().split()
        assert line[:2] == ["listening", "udp"], line
        port = int(line[2].rsplit(":", 1)[1])
        with client() as c:
            c.sendto(request(0x0002, 5), ("127.0.0.1", port))
            counts = [struct.unpack(">III6i", c.recvfrom(100)[0])[3] for _ in range(5)]
        assert counts == [-20_000_000] * 5  # 2000 N/m x 10 mm = 20 N, 1e6 counts/N
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)
    stats = json.loads(maxima.read_text())
    assert stats["max_abs_force_N"] == [20.0, 0.0, 0.0] and stats["records"] == 5


# -- a minimal fake box, independent of the emulator ----------------------------------------


class FakeBox:
    """A few lines of socket code that answer as the manual says: records go to the address the
    start request came from. The test decides what each record says."""

    def __init__(self, xml=BOX_XML):
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.bind(("127.0.0.1", 0))
        self.udp.settimeout(0.05)
        self.port = self.udp.getsockname()[1]
        self.requests, self.client, self.on_start = [], None, []

        class Page(BaseHTTPRequestHandler):
            def do_GET(self):
                body = xml.encode()
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *a):
                pass

        self.http = ThreadingHTTPServer(("127.0.0.1", 0), Page)
        self.http_port = self.http.server_address[1]
        self.running = True
        self.threads = [
            threading.Thread(target=self._serve, daemon=True),
            threading.Thread(target=self.http.serve_forever, daemon=True),
        ]
        for t in self.threads:
            t.start()

    def _serve(self):
        while self.running:
            try:
                data, addr = self.udp.recvfrom(100)
            except TimeoutError:
                continue
            self.requests.append(struct.unpack(">HHI", data))
            if data == request(0x0002):
                self.client = addr
                for packet in self.on_start:
                    self.udp.sendto(packet, addr)

    def send(self, packet: bytes):
        self.udp.sendto(packet, self.client)

    def close(self):
        self.running = False
        self.http.shutdown()
        self.http.server_close()
        for t in self.threads:
            t.join(5)
        self.udp.close()


def ctx(logs: list) -> NodeContext:
    return NodeContext("ft", 0.001, sim_time=False, log=logs.append)


@pytest.fixture
def fake():
    boxes, drivers, logs = [], [], []

    def make(tare=((1, 0, 0, 0, 0, 0),), **params):
        b = FakeBox()
        boxes.append(b)
        # the tare's records: lbf and lbf-in, 1e6 counts each
        b.on_start = [record(i + 1, 10 * (i + 1), 0, tare[i % len(tare)]) for i in range(20)]
        d = FtNetFtDriver(ctx(logs), host="127.0.0.1", port=b.port, http_port=b.http_port, tare_samples=20, **params)
        drivers.append(d)
        d.setup()
        return b, d

    yield make, logs
    for d in drivers:
        d.close()
    for b in boxes:
        b.close()


def arrive(d, n: int):
    """Wait until the driver's receiver has had n records of the box in all."""
    wait_for(lambda: d.receiver.records >= n, what=f"{n} records")


def test_driver_follows_the_protocol_of_an_independent_box(fake):
    make, logs = fake
    b, d = make(tare=[(1_000_000, -500_000, 0, 0, 0, 250_000)])
    assert b.requests[0] == (0x1234, 0x0002, 0)  # the start request, as the manual writes it
    assert d.calibration.force_unit == "lbf" and d.calibration.torque_unit == "lbf-in"  # read from its page
    assert d.bias_force == pytest.approx((LBF, -LBF / 2, 0.0)) and d.bias_torque[2] == pytest.approx(LBF_IN / 4)
    assert any("tared over 20 records" in line for line in logs)
    # three records in one tick: their mean, less the bias, in N and N m
    for i, fx in enumerate((-1_000_000, -3_000_000, -5_000_000)):
        b.send(record(21 + i, 210 + 10 * i, 0, (fx, -500_000, 0, 0, 0, 250_000)))
    arrive(d, 23)
    w = d.step(Tick(0, 0.0, 0.001), {})["wrench"]
    assert w.wrench.force.x == pytest.approx(-4 * LBF, rel=1e-12)  # mean -3 lbf, less the +1 lbf bias
    assert (w.wrench.force.y, w.wrench.force.z, w.wrench.torque.z) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert w.header.frame == "probe"
    assert d.step(Tick(1, 0.001, 0.001), {}) == {}  # nothing new: nothing published
    d.close()
    wait_for(lambda: b.requests[-1] == (0x1234, 0x0000, 0), what="stop request")  # the box stops streaming


def test_sign_flips_force_and_torque(fake):
    make, _ = fake
    b, d = make(tare=[(0, 0, 0, 0, 0, 0)], sign=-1.0)
    b.send(record(21, 210, 0, (-2_000_000, 0, 0, 0, 0, 1_000_000)))
    arrive(d, 21)
    w = d.step(Tick(0, 0.0, 0.001), {})["wrench"].wrench
    assert (w.force.x, w.torque.z) == pytest.approx((2 * LBF, -LBF_IN))


def test_lost_repeated_reordered_and_repeated_samples_are_counted_never_used(fake):
    make, logs = fake
    b, d = make(tare=[(0, 0, 0, 0, 0, 0)])
    d.step(Tick(0, 0.0, 0.001), {})
    sent = [(21, 210, -1), (24, 240, -4), (23, 230, 99), (24, 240, 99), (25, 240, 99), (26, 260, -6)]
    for seq, ft, lbf in sent:
        b.send(record(seq, ft, 0, (lbf * 1_000_000, 0, 0, 0, 0, 0)))
    arrive(d, 20 + len(sent))
    w = d.step(Tick(1, 0.001, 0.001), {})["wrench"]
    assert w.wrench.force.x == pytest.approx(-11 / 3 * LBF)  # only 21, 24 and 26: the others are older or repeats
    c = d.counters()
    assert (c["lost"], c["reordered"], c["duplicates"], c["repeated"]) == (1, 1, 1, 1)  # 22; 23; 24; 25 is ft 240
    d.close()
    assert any("1 lost, 1 reordered, 1 duplicates, 1 repeated" in line for line in logs), logs


def test_a_non_zero_status_word_holds(fake):
    make, _ = fake
    b, d = make(tare=[(0, 0, 0, 0, 0, 0)])
    b.send(record(21, 210, 0x80020000, (123_000_000, 0, 0, 0, 0, 0)))
    arrive(d, 21)
    with pytest.raises(DeviceError) as err:
        d.step(Tick(0, 0.0, 0.001), {})
    text = str(err.value)
    assert "\n" not in text and text.startswith(f"Net F/T box 127.0.0.1:{b.port}: the box reports status 0x80020000")
    assert "transducer saturation" in text and "holding" in text


def test_a_foreign_sender_is_ignored_and_counted_and_bad_datagrams_dropped(fake):
    make, logs = fake
    b, d = make(tare=[(0, 0, 0, 0, 0, 0)])
    me = d.sock.getsockname()[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        stranger.bind(("127.0.0.1", 0))
        for _ in range(3):  # a well-formed record with a huge force, from the wrong sender
            stranger.sendto(record(21, 210, 0, (900_000_000, 0, 0, 0, 0, 0)), ("127.0.0.1", me))
    for size in (0, 8, 35, 37, 1400):  # short and oversized, from the box
        b.send(bytes(range(256))[:size] if size <= 256 else b"\x7f" * size)
    b.send(record(21, 210, 0, (-2_000_000, 0, 0, 0, 0, 0)))
    arrive(d, 21)
    wait_for(lambda: d.counters()["foreign datagrams"] == 3 and d.counters()["bad datagrams"] == 5)
    w = d.step(Tick(0, 0.0, 0.001), {})["wrench"]
    assert w.wrench.force.x == pytest.approx(-2 * LBF)  # only the box's record
    warned = [line for line in logs if "ignoring datagrams from 127.0.0.1" in line]
    assert len(warned) == 1 and warned[0].startswith("warning: ")
    d.step(Tick(1, 0.001, 0.001), {})
    assert len([line for line in logs if "ignoring datagrams" in line]) == 1  # one line, not one per datagram


def test_stale_data_stops_after_the_timeout_on_the_tick_clock(fake):
    make, _ = fake
    b, d = make(tare=[(0, 0, 0, 0, 0, 0)], stale_timeout=0.05)
    assert d.step(Tick(0, 0.0, 0.001), {}) == {}
    assert d.step(Tick(30, 0.03, 0.001), {}) == {}
    with pytest.raises(DeviceError, match=r"stale data: no new record for 0.051 s \(stale_timeout 0.05 s\)"):
        d.step(Tick(51, 0.051, 0.001), {})


def test_a_loaded_probe_at_start_is_refused_not_tared_away(fake):
    make, _ = fake
    with pytest.raises(DeviceError) as err:
        make(tare=[(15_000_000, 0, 0, 0, 0, 0)])  # 15 lbf = 66.7 N pressing the probe
    text = str(err.value)
    assert "\n" not in text and "tare: bias force |F| = 66.7 N > max_bias 50 N" in text and "free the probe" in text


def test_a_silent_box_and_a_box_without_a_page_fail_fast_in_one_line():
    b = FakeBox()
    try:  # answers its page, never streams
        d = FtNetFtDriver(ctx([]), host="127.0.0.1", port=b.port, http_port=b.http_port, open_timeout=0.3)
        t = time.monotonic()
        with pytest.raises(DeviceError, match=r"no RDT records within 0.3 s of the start request"):
            d.setup()
        assert time.monotonic() - t < 2.0
        assert len([r for r in b.requests if r == (0x1234, 2, 0)]) >= 1
    finally:
        b.close()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens there
    d = FtNetFtDriver(ctx([]), host="127.0.0.1", port=49152, http_port=port, open_timeout=0.3)
    with pytest.raises(DeviceError) as err:
        d.setup()
    assert f"http://127.0.0.1:{port}/netftapi2.xml: " in str(err.value) and "\n" not in str(err.value)


def test_node_process_exits_non_zero_with_one_line_when_the_box_is_missing():
    from tests.conftest import node_process_error

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    spec = {
        "name": "ft",
        "type_name": "ft_netft",
        "dt": 0.001,
        "clock": "wall",
        "params": {"host": "127.0.0.1", "http_port": port, "open_timeout": 0.3},
    }
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    line = node_process_error(spec, env)
    assert "Net F/T box 127.0.0.1:49152" in line and "netftapi2.xml" in line, line


def test_sim_time_is_refused():
    with pytest.raises(LaunchError, match="runs only in wall time"):
        FtNetFtDriver(NodeContext("ft", 0.001, sim_time=True)).setup()


def test_a_second_graph_naming_the_same_box_is_refused(fake):
    make, _ = fake
    ownership.set_graph("graph-one")
    try:
        b, d = make(tare=[(0, 0, 0, 0, 0, 0)])
    finally:
        ownership.set_graph("")
    ownership.set_graph("graph-two")
    try:
        other = FtNetFtDriver(ctx([]), host="127.0.0.1", port=b.port, http_port=b.http_port)
        with pytest.raises(DeviceError) as err:
            other.setup()
    finally:
        ownership.set_graph("")
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"Net F/T box 127.0.0.1:{b.port} is in use by graph graph-one (pid {os.getpid()} "), text
    assert b.requests == [(0x1234, 2, 0)]  # the refused driver sent nothing


# -- the driver against the emulator -------------------------------------------------------


@pytest.mark.parametrize(
    "fault, box_count, driver_count",
    [
        ("loss", "lost", "lost"),
        ("duplicate", "duplicated", "duplicates"),
        ("reorder", "reordered", "reordered"),
        ("late", "late", "reordered"),
    ],
)
def test_driver_counts_what_the_emulator_injected(box, fault, box_count, driver_count):
    # A run in which the kernel dropped datagrams (the receive thread starved on a busy machine and
    # its socket buffer overflowed) counts those as lost too; it is tried again, for exact counts.
    for attempt in range(3):
        b = box(k=1000.0, position=0.01, rate=2000.0, seed=11 + attempt, bias=1.5, **{fault: 5.0})
        d = FtNetFtDriver(ctx([]), host="127.0.0.1", port=b.port, http_port=b.http_port, stale_timeout=1.0)
        d.setup()
        try:
            assert d.bias_force == pytest.approx((-8.5, 0.0, 0.0))  # the contact's -10 N was there at start too
            forces = []
            for k in range(1, 200):  # the box streams in real time; the ticks are the test's
                time.sleep(0.002)
                out = d.step(Tick(k, k * 0.001, 0.001), {})
                if out:
                    forces.append(out["wrench"].wrench.force.x)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
                c.sendto(request(0x0000), ("127.0.0.1", b.port))  # any client may stop the box
            wait_for(lambda b=b: b.counts["stops"] == 1, what="stop")
            time.sleep(0.1)  # the datagrams under way
            stats, counters = b.stats(), d.counters()
        finally:
            d.close()
        if counters["records"] == stats["sent"]:
            break
    else:
        pytest.fail(f"the kernel dropped datagrams in 3 runs: {counters}, {stats}")
    # a record lost after the last one sent leaves no gap a receiver could see
    assert counters[driver_count] == stats[box_count] - (stats["lost_unseen"] if fault == "loss" else 0) > 0, (
        counters,
        stats,
    )
    others = {"lost", "duplicates", "reordered"} - {driver_count}
    assert all(counters[o] == 0 for o in others), counters
    assert forces and all(f == pytest.approx(0.0, abs=1e-9) for f in forces)  # tared, constant contact
    assert d.averaged > 1.5 * d.ticks_with_data  # 2 records a ms, several a tick


def test_driver_publishes_what_the_simulated_sensor_does_for_the_same_contact(box):
    from dockhil.msgs import Header, Pose, RobotState, Vector3
    from dockhil.nodes.ft_sim import FtSensorSim

    b = box(k=1500.0, rate=2000.0, jitter=0.002, seed=5)  # no pose yet: no contact while the driver tares
    d = FtNetFtDriver(ctx([]), host="127.0.0.1", port=b.port, http_port=b.http_port, stale_timeout=1.0)
    d.setup()
    try:
        for k, x in enumerate((0.012, -0.003, 0.0004)):  # pressed, apart, barely touching
            b.model.set_pose(x)
            time.sleep(0.05)
            d.step(Tick(2 * k, k * 0.1, 0.001), {})  # the records of the pose before
            time.sleep(0.05)
            got = d.step(Tick(2 * k + 1, k * 0.1 + 0.05, 0.001), {})["wrench"]
            sim = FtSensorSim(NodeContext("sim", 0.001), k=1500.0)
            sim.setup()
            want = sim.step(Tick(0, 0.0, 0.001), {"robot": RobotState(header=Header(), pose=Pose(Vector3(x=x)))})
            assert got.wrench.force.x == pytest.approx(want["wrench"].wrench.force.x, abs=1e-6)
            assert got.header.frame == want["wrench"].header.frame == "probe"
        c = d.counters()
        assert (c["lost"], c["reordered"], c["duplicates"]) == (0, 0, 0)  # jitter delays, never reorders
    finally:
        d.close()


def test_emulator_status_fault_reaches_the_driver(box):
    b = box(rate=1000.0, fault_after=0.3)
    d = FtNetFtDriver(ctx([]), host="127.0.0.1", port=b.port, http_port=b.http_port, tare_samples=20, stale_timeout=5.0)
    d.setup()
    try:
        with pytest.raises(DeviceError, match=r"the box reports status 0x80020000"):
            for k in range(5000):
                time.sleep(0.001)
                d.step(Tick(k, k * 0.001, 0.001), {})
    finally:
        d.close()


# -- launch files and one true wall-time run -------------------------------------------------


def graph_text(*args) -> str:
    r = subprocess.run(
        dockhil_cmd("graph", "launch/hil.yaml", *args), cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_hil_yaml_points_the_driver_at_the_box_or_at_its_emulator():
    real = graph_text("ft:=netft")
    assert "ft [ft_netft]" in real and "host=" not in real and "netft_emulator [" not in real  # the default box
    emulated = graph_text("ft:=netft", "emulators:=true", "netft_port:=50123")
    assert "ft [ft_netft]" in emulated and "netft_emulator [netft_emulator]" in emulated
    assert "host='127.0.0.2'" in emulated and "port=50123" in emulated


def free_udp_and_tcp_port() -> int:
    for _ in range(50):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            u.bind(("127.0.0.1", 0))
            port = u.getsockname()[1]
            with socket.socket() as t:
                try:
                    t.bind(("127.0.0.1", port))
                except OSError:
                    continue
                return port
    raise AssertionError("no port free for both UDP and TCP")


@pytest.mark.wall_time
def test_hil_scene_runs_on_the_emulated_box(tmp_path):
    # 250 Hz: the loop a busy 2-core machine keeps in real time. A run a busy machine stopped early
    # (stale data: the safety doing its job) says why in one line, and is tried again.
    for attempt in range(3):
        summary = tmp_path / f"hw{attempt}.json"
        r = subprocess.run(
            dockhil_cmd(
                "launch",
                "launch/hil.yaml",
                "ft:=netft",
                "emulators:=true",
                "rate:=250",
                f"netft_port:={free_udp_and_tcp_port()}",
                "--wall-time",
                "--duration",
                "5",
                "--summary",
                summary,
                "--quiet",
            ),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=120,
        )
        out = r.stdout + r.stderr
        assert "Traceback" not in out, out
        if r.returncode == 0:
            break
        assert [line for line in out.splitlines() if " error: " in line or "INVALID" in line], out
    else:
        pytest.fail(f"3 runs stopped early, the last: {out}")
    assert "tared over 100 records" in r.stderr and "records averaged over" in r.stderr, r.stderr
    s = json.loads(summary.read_text())
    assert s["valid"] is True and 20.0 < s["peak_force_N"] < 60.0, s
