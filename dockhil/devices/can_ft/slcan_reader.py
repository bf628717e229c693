"""Received frames of a serial-line CAN (slcan, Lawicel ASCII) adapter, read in bulk.

python-can's slcan interface reads its serial port one byte per call: some 25 system calls for
each frame, 50,000 a second for a sensor that streams two frames a millisecond, enough to make a
driver miss its ticks on a busy 2-core machine. `SlcanReader` reads what the port holds in one
call and parses whole lines; python-can still opens, configures and closes the adapter.

Lines (each ends with CR; BEL is the adapter's error answer): tiiil<data> and Tiiiiiiiil<data>
(a data frame, 11- and 29-bit ID, l data bytes as 2l hex digits, optionally followed by a 4-digit
timestamp), riiil and Riiiiiiiil (a remote frame). Anything else (the answers to commands, z/Z
after a transmit, error answers) is no frame; a line that claims to be a frame but does not parse
is counted in `malformed` and dropped.
"""

from __future__ import annotations

from typing import Any, NamedTuple

# A line longer than the longest frame (T + 8 + 1 + 16 + 4 timestamp digits) is no frame: the
# buffer is cut there, so a port that streams garbage without a CR cannot grow it without bound.
MAX_LINE = 64


class Frame(NamedTuple):
    """The fields of a python-can Message that a driver reads."""

    arbitration_id: int
    data: bytes
    is_extended_id: bool
    is_remote_frame: bool = False
    is_error_frame: bool = False


def parse_line(line: bytes) -> Frame | None:
    """The frame of one slcan line (without its CR); None for a line that is no frame; ValueError
    for a frame line that does not parse."""
    if not line:
        return None
    kind = line[:1]
    if kind in (b"t", b"r"):
        id_len = 3
    elif kind in (b"T", b"R"):
        id_len = 8
    else:
        return None
    dlc_at = 1 + id_len
    if len(line) < dlc_at + 1:
        raise ValueError(f"{line[:MAX_LINE]!r} is too short for a frame")
    arbitration_id = int(line[1:dlc_at], 16)
    dlc = int(line[dlc_at : dlc_at + 1], 16)
    if dlc > 8:
        raise ValueError(f"{line[:MAX_LINE]!r}: data length {dlc} > 8")
    remote = kind in (b"r", b"R")
    end = dlc_at + 1 + (0 if remote else 2 * dlc)
    if len(line) not in (end, end + 4):  # the data, then an optional timestamp
        raise ValueError(f"{line[:MAX_LINE]!r}: length {len(line)} does not match data length {dlc}")
    data = b"" if remote else bytes.fromhex(line[dlc_at + 1 : end].decode("ascii"))
    return Frame(arbitration_id, data, id_len == 8, remote)


class SlcanReader:
    """recv(timeout) as python-can's Bus.recv for a non-blocking poll (timeout is not waited: the
    port is read as it is), over the adapter's serial port (a pyserial object)."""

    def __init__(self, port: Any) -> None:  # a pyserial port, or what reads as one
        self.port = port
        self.buffer = bytearray()
        self.frames: list[Frame] = []
        self.next = 0
        self.malformed = 0

    def recv(self, timeout: float | None = 0.0) -> Frame | None:
        if self.next >= len(self.frames):
            self.frames, self.next = self._read(), 0
            if not self.frames:
                return None
        frame = self.frames[self.next]
        self.next += 1
        return frame

    def _read(self) -> list[Frame]:
        waiting = self.port.in_waiting
        if waiting:
            self.buffer += self.port.read(waiting)
        if not self.buffer:
            return []
        lines = self.buffer.replace(b"\x07", b"\r").split(b"\r")
        rest = lines.pop()  # after the last CR: a line still arriving
        if len(rest) > MAX_LINE:
            self.malformed += 1
            rest = bytearray()
        self.buffer = bytearray(rest)
        frames = []
        for line in lines:
            try:
                frame = parse_line(bytes(line))
            except ValueError:
                self.malformed += 1
                continue
            if frame is not None:
                frames.append(frame)
        return frames
