"""The emulator's Modbus TCP server against frames written here from the protocol description (MBAP
header: transaction, protocol 0, length, unit; then the PDU), over a raw socket."""

from __future__ import annotations

import asyncio
import socket
import struct
import threading

import pytest

from dockhil.devices.modbus_robot.server import ModbusTcpServer


class Served:
    """A server on a loop of its own whose registers are a list: holding 0..9, input 0..4."""

    def __init__(self):
        self.holding = list(range(100, 110))
        self.calls: list[tuple] = []
        self.loop = asyncio.new_event_loop()
        self.server = ModbusTcpServer(self.handle, "127.0.0.1", 0, holding=10, inputs=5)
        self.port = self.loop.run_until_complete(self.server.start())
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def handle(self, function, address, count, values, connection):
        self.calls.append((function, address, count, values, connection))
        if function == 4:
            return [7, 8, 9, 10, 11][address : address + count]
        if function == 3:
            return self.holding[address : address + count]
        if address == 9:
            return 6  # the device is busy (another host owns it)
        self.holding[address : address + len(values)] = values
        return None

    def close(self):
        asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def served():
    s = Served()
    yield s
    s.close()


def frame(tid: int, pdu: bytes, unit: int = 1, protocol: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1, unit) + pdu


def connect(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def reply(sock: socket.socket) -> tuple[int, int, bytes]:
    """(transaction, unit, PDU) of the next response."""
    head = b""
    while len(head) < 7:
        head += sock.recv(7 - len(head))
    tid, protocol, length, unit = struct.unpack(">HHHB", head)
    assert protocol == 0
    pdu = b""
    while len(pdu) < length - 1:
        pdu += sock.recv(length - 1 - len(pdu))
    return tid, unit, pdu


def test_reads_and_writes_answer_as_the_protocol_says(served):
    with connect(served.port) as sock:
        sock.sendall(frame(0x1234, bytes.fromhex("04 0001 0003"), unit=7))  # read input registers 1..3
        assert reply(sock) == (0x1234, 7, bytes.fromhex("04 06 0008 0009 000a"))
        sock.sendall(frame(2, bytes.fromhex("10 0002 0002 04 abcd 0001")))  # write multiple: 2..3
        assert reply(sock) == (2, 1, bytes.fromhex("10 0002 0002"))
        sock.sendall(frame(3, bytes.fromhex("06 0004 beef")))  # write single: 4
        assert reply(sock) == (3, 1, bytes.fromhex("06 0004 beef"))
        sock.sendall(frame(4, bytes.fromhex("03 0001 0004")))  # read holding 1..4
        assert reply(sock) == (4, 1, bytes.fromhex("03 08 0065 abcd 0001 beef"))
    assert [c[:4] for c in served.calls] == [
        (4, 1, 3, None),
        (16, 2, 2, [0xABCD, 1]),
        (6, 4, 1, [0xBEEF]),
        (3, 1, 4, None),
    ]


@pytest.mark.parametrize(
    "pdu, answer",
    [
        ("2b 0e 01 00", "ab 01"),  # read device identification: not a function of this server
        ("04 0004 0002", "84 02"),  # input registers 4..5: the map has 0..4
        ("03 0000 0000", "83 03"),  # a count of 0
        ("03 0000 007e", "83 03"),  # 126 registers: more than a response holds
        ("10 0000 0002 02 0001", "90 03"),  # byte count 2 for two registers
        ("10 0009 0001 02 0001", "90 06"),  # the handler says the device is busy
        ("03 00", "83 03"),  # too short
    ],
)
def test_what_the_server_cannot_do_is_an_exception_response(served, pdu, answer):
    with connect(served.port) as sock:
        sock.sendall(frame(9, bytes.fromhex(pdu)))
        assert reply(sock) == (9, 1, bytes.fromhex(answer))


def test_requests_split_or_joined_in_the_stream_are_each_answered_in_order(served):
    with connect(served.port) as sock:
        joined = frame(1, bytes.fromhex("04 0000 0001")) + frame(2, bytes.fromhex("04 0004 0001"))
        sock.sendall(joined[:5])
        sock.sendall(joined[5:13])
        sock.sendall(joined[13:])
        assert reply(sock) == (1, 1, bytes.fromhex("04 02 0007"))
        assert reply(sock) == (2, 1, bytes.fromhex("04 02 000b"))


def test_each_connection_is_told_apart_and_a_foreign_protocol_closes_it(served):
    with connect(served.port) as a, connect(served.port) as b:
        for sock in (a, b):
            sock.sendall(frame(1, bytes.fromhex("04 0000 0001")))
            reply(sock)
        assert served.calls[0][4] != served.calls[1][4]
        a.sendall(frame(5, bytes.fromhex("04 0000 0001"), protocol=1))  # not Modbus
        assert a.recv(16) == b""  # closed: the stream cannot be trusted further
        b.sendall(frame(6, bytes.fromhex("04 0000 0001")))
        assert reply(b)[0] == 6


def test_a_burst_of_requests_is_answered_and_reading_allocates_no_large_buffer(served):
    """Reads go into the connection's own buffer: a transport that allocated 256 kB a read (asyncio's
    Protocol) had the allocator map and unmap fresh pages for every request."""
    import tracemalloc

    with connect(served.port) as sock:
        burst = b"".join(frame(tid, bytes.fromhex("03 0000 0002")) for tid in range(400))  # 4800 bytes
        tracemalloc.start()
        try:
            sock.sendall(burst)
            wrong = [tid for tid in range(400) if reply(sock) != (tid, 1, bytes.fromhex("03 04 0064 0065"))]
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert wrong == []
    assert peak < 128 * 1024, f"reading 400 requests took {peak} bytes at its peak"
