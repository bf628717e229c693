"""A Modbus TCP server for the robot controller emulator: MBAP framing and the register functions the
driver uses (3 read holding, 4 read input, 6 write single, 16 write multiple), as the Modbus
Application Protocol v1.1b3 and the Modbus Messaging on TCP/IP Implementation Guide v1.0b describe them.

Each request is answered in the callback that received it, on the emulator's event loop, with no task of
its own (pymodbus's server made one per request: the emulated controller of a 1 kHz graph, reading and
writing each cycle, took 46 % of a core with it, 30 % with this server).

Unknown functions answer exception 1, a register range outside the map exception 2, a count or byte count
out of the protocol's bounds exception 3; a frame whose protocol identifier is not 0 or whose length is
outside 2..254 closes the connection (the stream cannot be re-synchronised).

`handle(function, address, count, values, connection)` decides: for a read, the registers (or None:
zeros); for a write, None; an int is an exception code. `connection` numbers each TCP connection.
"""

from __future__ import annotations

import asyncio
import itertools
import struct
from collections.abc import Callable
from typing import cast

ILLEGAL_FUNCTION = 1
ILLEGAL_ADDRESS = 2
ILLEGAL_VALUE = 3
DEVICE_BUSY = 6

READ_HOLDING, READ_INPUT, WRITE_SINGLE, WRITE_MULTIPLE = 3, 4, 6, 16
MAX_READ = 125  # registers in one read (the PDU's 253 bytes)
MAX_WRITE = 123  # registers in one write multiple

Handle = Callable[[int, int, int, "list[int] | None", int], "list[int] | int | None"]

_MBAP = struct.Struct(">HHHB")  # transaction, protocol (0), length (unit + PDU), unit
READ_SIZE = 4096  # bytes read at most at once; a frame is 260 at most, so one always fits after what is left


class _Connection(asyncio.BufferedProtocol):
    """Reads into one buffer made with the connection: a Protocol's transport allocated 256 kB for each
    read, which the allocator mapped and unmapped every time (at 2000 requests a second, 4000 page faults
    a second on the emulator's thread, each ~9 us on a virtual machine and milliseconds at worst)."""

    def __init__(self, server: ModbusTcpServer, number: int):
        self.server = server
        self.number = number
        self.buffer = bytearray(READ_SIZE)
        self.filled = 0  # bytes of self.buffer received and not yet answered (less than a frame)
        self.transport: asyncio.Transport  # set by connection_made, before anything reads it

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)  # a stream server's: TCP
        self.server.connections.add(self)

    def connection_lost(self, exc: Exception | None) -> None:
        self.server.connections.discard(self)

    def get_buffer(self, sizehint: int) -> memoryview:
        return memoryview(self.buffer)[self.filled :]

    def buffer_updated(self, nbytes: int) -> None:
        buf, end, start = self.buffer, self.filled + nbytes, 0
        while end - start >= 7:
            tid, protocol, length, unit = _MBAP.unpack_from(buf, start)
            if protocol != 0 or not 2 <= length <= 254:
                self.transport.close()
                self.filled = 0
                return
            if end - start < 6 + length:
                break
            pdu = bytes(buf[start + 7 : start + 6 + length])
            start += 6 + length
            reply = self.server.answer(pdu, self.number)
            self.transport.write(_MBAP.pack(tid, 0, len(reply) + 1, unit) + reply)
        buf[: end - start] = buf[start:end]  # the part of a frame still to come stays at the front
        self.filled = end - start


class ModbusTcpServer:
    """Listens on host:port; `handle` answers each request (see the module's text)."""

    def __init__(self, handle: Handle, host: str, port: int, holding: int, inputs: int):
        self.handle = handle
        self.host, self.port = host, port
        self.sizes = {READ_HOLDING: holding, READ_INPUT: inputs, WRITE_SINGLE: holding, WRITE_MULTIPLE: holding}
        self.connections: set[_Connection] = set()
        self._numbers = itertools.count(1)
        self._server: asyncio.base_events.Server | None = None

    async def start(self) -> int:
        """Listen; the port (useful with port 0). OSError when the address cannot be had."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: _Connection(self, next(self._numbers)), self.host, self.port, reuse_address=True
        )
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            for c in list(self.connections):
                c.transport.close()
            await self._server.wait_closed()

    def answer(self, pdu: bytes, connection: int) -> bytes:
        """The response PDU to a request PDU."""
        function = pdu[0]
        if function not in self.sizes:
            return bytes((function | 0x80, ILLEGAL_FUNCTION))
        if len(pdu) < 5:
            return bytes((function | 0x80, ILLEGAL_VALUE))
        address, count = struct.unpack_from(">HH", pdu, 1)
        values = None
        if function == WRITE_SINGLE:
            values, count = [count], 1
        elif function == WRITE_MULTIPLE:
            if not 1 <= count <= MAX_WRITE or len(pdu) != 6 + 2 * count or pdu[5] != 2 * count:
                return bytes((function | 0x80, ILLEGAL_VALUE))
            values = list(struct.unpack_from(f">{count}H", pdu, 6))
        elif not 1 <= count <= MAX_READ:
            return bytes((function | 0x80, ILLEGAL_VALUE))
        if address + count > self.sizes[function]:
            return bytes((function | 0x80, ILLEGAL_ADDRESS))
        out = self.handle(function, address, count, values, connection)
        if isinstance(out, int):
            return bytes((function | 0x80, out))
        if values is None:  # a read
            registers = list(out or ())
            registers += [0] * (count - len(registers))  # what the map leaves out reads 0
            return struct.pack(f">BB{count}H", function, 2 * count, *registers)
        return pdu[:5]  # a write: the request's function, address and count (or value), echoed
