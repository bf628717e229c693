"""The bulk slcan reader against lines written here from the Lawicel protocol's description."""

from __future__ import annotations

import pytest

from dockhil.devices.can_ft.slcan_reader import MAX_LINE, Frame, SlcanReader, parse_line


class FakePort:
    """A serial port that holds what the test wrote, handed out in the chunks the test chose."""

    def __init__(self, *chunks: bytes):
        self.chunks = list(chunks)

    @property
    def in_waiting(self) -> int:
        return len(self.chunks[0]) if self.chunks else 0

    def read(self, n: int) -> bytes:
        chunk = self.chunks.pop(0)
        assert n == len(chunk)
        return chunk


def drain(reader: SlcanReader) -> list[Frame]:
    out = []
    while (frame := reader.recv(0.0)) is not None:
        out.append(frame)
    return out


@pytest.mark.parametrize(
    "line, frame",
    [
        (b"t1A08" + b"0102030405060708", Frame(0x1A0, bytes(range(1, 9)), False)),
        (b"t7FF0", Frame(0x7FF, b"", False)),
        (b"T1234567830A0B0C", Frame(0x12345678, b"\x0a\x0b\x0c", True)),
        (b"t1A12FFEE" + b"1F2E", Frame(0x1A1, b"\xff\xee", False)),  # with a 4-digit timestamp
        (b"r1232", Frame(0x123, b"", False, True)),
        (b"R000000FF0", Frame(0xFF, b"", True, True)),
    ],
)
def test_frame_lines_parse_to_id_data_and_kind(line, frame):
    assert parse_line(line) == frame


@pytest.mark.parametrize("line", [b"", b"z", b"Z", b"V1013", b"N0001", b"F00"])
def test_answers_to_commands_are_no_frame(line):
    assert parse_line(line) is None


@pytest.mark.parametrize("line", [b"t1A", b"t1A09" + b"00" * 9, b"t1A02AB", b"t1A02ABCDE", b"tXYZ1AB", b"t1A01GG"])
def test_frame_lines_that_do_not_parse_are_refused(line):
    with pytest.raises(ValueError):
        parse_line(line)


def test_frames_split_across_reads_come_out_whole_and_in_order():
    port = FakePort(b"t1A0211", b"22\rt1A", b"123344\r\x07z\rt1A", b"2155\r")
    reader = SlcanReader(port)
    got = []
    for _ in range(4):
        got.extend(drain(reader))
    assert got == [Frame(0x1A0, b"\x11\x22", False), Frame(0x1A1, b"\x33\x44", False), Frame(0x1A2, b"\x55", False)]
    assert reader.malformed == 0


def test_malformed_lines_and_endless_garbage_are_counted_and_dropped():
    port = FakePort(b"t1A0ZZ\rt1A1100\r", b"x" * (MAX_LINE + 1), b"\rt1A2100\r")
    reader = SlcanReader(port)
    got = drain(reader) + drain(reader) + drain(reader)
    assert [f.arbitration_id for f in got] == [0x1A1, 0x1A2]
    assert reader.malformed == 2  # the bad hex, and the line longer than any frame
    assert len(reader.buffer) == 0
