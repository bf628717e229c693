"""ATI Net F/T: the RDT protocol over UDP and the box's netftapi2.xml.

As ATI's Net F/T manual publishes it (all fields big-endian):

    request  (host -> box UDP port 49152), 8 bytes   >HHI
             header 0x1234, command, sample count (0: until stopped)
             commands: 0x0000 stop streaming, 0x0002 start high-speed real-time
             streaming, 0x0042 set software bias
    record   (box port 49152 -> the requester's address and port), 36 bytes   >III6i
             rdt_sequence  position of the record in this stream, from 1; a gap is a lost datagram
             ft_sequence   the box's internal sample number (7000 a second): the same
                           number twice is the same sample
             status        0 healthy; any bit set is a fault the box reports
             Fx Fy Fz Tx Ty Tz   counts

Counts per force and per torque unit, and the units, are on the box's web
server: http://HOST/netftapi2.xml, elements cfgcpf, cfgcpt, scfgfu (N, lbf,
kN, ...) and scfgtu (Nm, Nmm, lbf-in, ...), or their codes cfgfu and cfgtu.

Axes: Fx is the force on the probe along the sensor's +x, which the scene
mounts along the docking axis (x > 0 is penetration), so a compressive
contact reads negative Fx: the convention of /ft/wrench (the force on the chaser).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

RDT_PORT = 49152
HEADER = 0x1234
CMD_STOP = 0x0000
CMD_START = 0x0002  # high-speed real-time streaming
CMD_BIAS = 0x0042  # software bias: the box subtracts its present reading from what follows
COMMANDS = {CMD_STOP: "stop", CMD_START: "start", CMD_BIAS: "bias"}
INTERNAL_RATE = 7000.0  # [Hz] the box's own sample rate; ft_sequence counts these samples
MAX_RDT_RATE = 7000.0

REQUEST = struct.Struct(">HHI")
RECORD = struct.Struct(">III6i")
INT32 = (-(2**31), 2**31 - 1)
SEQ_MOD = 2**32

# Newtons per unit, by the names the box and the open drivers write (normalised: lower case,
# without '-', ' ', '.', '*' and the middle dot) and by the codes of cfgfu / cfgtu.
LBF = 4.4482216152605
FORCE_UNITS = {"n": 1.0, "lbf": LBF, "klbf": 1000.0 * LBF, "kn": 1000.0, "kgf": 9.80665, "gf": 0.00980665}
FORCE_CODES = {1: "lbf", 2: "N", 3: "klbf", 4: "kN", 5: "kgf", 6: "gf"}
TORQUE_UNITS = {
    "nm": 1.0,
    "nmm": 0.001,
    "lbfin": LBF * 0.0254,
    "lbfft": LBF * 0.3048,
    "kgfcm": 0.0980665,
    "knm": 1000.0,
}
TORQUE_ALIASES = {
    "inlb": "lbfin",
    "inlbf": "lbfin",
    "lbin": "lbfin",
    "ftlb": "lbfft",
    "ftlbf": "lbfft",
    "lbft": "lbfft",
    "kgcm": "kgfcm",
}
TORQUE_CODES = {1: "lbf-in", 2: "lbf-ft", 3: "Nm", 4: "Nmm", 5: "kgf-cm", 6: "kNm"}

# Status bits as the manual names them (the ones a run is likeliest to meet first).
STATUS_BITS = {
    31: "error",
    30: "CPU or RAM error",
    29: "digital board error",
    28: "analog board error",
    27: "serial link error",
    26: "program memory error",
    25: "halted by configuration errors",
    24: "settings validation error",
    23: "configuration incompatible with calibration",
    22: "network failure",
    20: "RDT communication error",
    17: "transducer saturation or A/D error",
    16: "monitor condition latched",
    14: "watchdog timeout",
    9: "excessive strain gage excitation",
    8: "insufficient strain gage excitation",
    2: "internal temperature error",
}
STATUS_SATURATED = (1 << 31) | (1 << 17)

MAX_XML_BYTES = 1 << 20  # the real page is a few kB
FORCE_FULL_SCALE = (1.0, 1e5)  # N: the force of the largest count, from a nano sensor to the largest ATI makes
TORQUE_FULL_SCALE = (0.01, 1e4)  # N m: the same for torque


class RdtError(ValueError):
    """A request, record or configuration page that breaks the protocol; one line."""


class Unreachable(RdtError):
    """The box's web server did not answer (yet): refused, timed out, no route."""


@dataclass(frozen=True)
class Record:
    rdt_sequence: int
    ft_sequence: int
    status: int
    counts: tuple[int, int, int, int, int, int]


def encode_request(command: int, count: int = 0) -> bytes:
    return REQUEST.pack(HEADER, command, count)


def decode_request(data: bytes) -> tuple[int, int]:
    """(command, sample count) of a request; RdtError if it is not one."""
    if len(data) != REQUEST.size:
        raise RdtError(f"a request is {REQUEST.size} bytes, got {len(data)}")
    header, command, count = REQUEST.unpack(data)
    if header != HEADER:
        raise RdtError(f"request header {header:#06x}, not {HEADER:#06x}")
    return command, count


def encode_record(rdt_sequence: int, ft_sequence: int, status: int, counts) -> bytes:
    return RECORD.pack(rdt_sequence % SEQ_MOD, ft_sequence % SEQ_MOD, status, *counts)


def decode_record(data: bytes) -> Record:
    if len(data) != RECORD.size:
        raise RdtError(f"a record is {RECORD.size} bytes, got {len(data)}")
    rdt, ft, status, *counts = RECORD.unpack(data)
    return Record(rdt, ft, status, tuple(counts))


def describe_status(word: int) -> str:
    names = [name for bit, name in STATUS_BITS.items() if word >> bit & 1]
    other = word & ~sum(1 << bit for bit in STATUS_BITS)
    if other:
        names.append(f"bits {other:#010x}")
    return ", ".join(names) or "healthy"


def _normal(unit: str) -> str:
    return "".join(c for c in unit.strip().lower() if c not in "- .*·_")


def force_factor(unit: str) -> float:
    """Newtons per `unit` (N, lbf, klbf, kN, kgf, gf); RdtError for anything else."""
    factor = FORCE_UNITS.get(_normal(unit))
    if factor is None:
        raise RdtError(f"unknown force unit {unit!r} (known: {', '.join(FORCE_CODES.values())})")
    return factor


def torque_factor(unit: str) -> float:
    """Newton metres per `unit` (Nm, Nmm, lbf-in, lbf-ft, kgf-cm, kNm); RdtError for anything else."""
    name = _normal(unit)
    factor = TORQUE_UNITS.get(TORQUE_ALIASES.get(name, name))
    if factor is None:
        raise RdtError(f"unknown torque unit {unit!r} (known: {', '.join(TORQUE_CODES.values())})")
    return factor


@dataclass(frozen=True)
class Calibration:
    """How counts become newtons and newton metres."""

    counts_per_force: float
    counts_per_torque: float
    force_unit: str
    torque_unit: str

    def __post_init__(self):
        for name in ("counts_per_force", "counts_per_torque"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise RdtError(f"{name} must be a finite positive number, got {value!r}")
        # a full-scale count must stay a number: 1e-300 counts per N would make it infinite
        for name, scale in (
            ("counts_per_force", self.newtons_per_count),
            ("counts_per_torque", self.newton_metres_per_count),
        ):
            if not 0.0 < scale * 2.0**31 < 1e15:
                raise RdtError(
                    f"{name} {getattr(self, name)!r}: a count would be {scale:g} N or N m, "
                    f"not the resolution of a sensor"
                )

    @property
    def newtons_per_count(self) -> float:
        return force_factor(self.force_unit) / self.counts_per_force

    @property
    def newton_metres_per_count(self) -> float:
        return torque_factor(self.torque_unit) / self.counts_per_torque

    def full_scale_problem(self) -> str | None:
        """Why the largest count (2**31 - 1) is no sensor's full scale, or None: outside FORCE_FULL_SCALE
        (newtons) or TORQUE_FULL_SCALE (newton metres) the sensor would never see a contact, or see
        noise as one."""
        for name, scale, (lo, hi), unit in (
            ("counts_per_force", self.newtons_per_count, FORCE_FULL_SCALE, "N"),
            ("counts_per_torque", self.newton_metres_per_count, TORQUE_FULL_SCALE, "N m"),
        ):
            full = scale * INT32[1]
            if not lo <= full <= hi:
                return (
                    f"{name} {getattr(self, name):g} makes the full scale {full:.3g} {unit}, outside "
                    f"{lo:g} to {hi:g} {unit}: not a sensor's (check the counts per unit and the units)"
                )
        return None

    def describe(self) -> str:
        return (
            f"{self.counts_per_force:g} counts/{self.force_unit}, {self.counts_per_torque:g} counts/{self.torque_unit}"
        )


def parse_netftapi2(text: str | bytes) -> dict[str, str]:
    """The box's configuration page as {element: text} (cfgcpf, scfgfu, comrdtrate, ...); RdtError
    if it is not XML. Elements are found at any depth, names compared in lower case."""
    import xml.etree.ElementTree as ET

    if len(text) > MAX_XML_BYTES:
        raise RdtError(f"netftapi2.xml is {len(text)} bytes, more than a Net F/T page")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RdtError(f"netftapi2.xml is not XML ({exc})") from None
    found: dict[str, str] = {}
    for element in root.iter():
        tag = element.tag.rsplit("}", 1)[-1].lower() if isinstance(element.tag, str) else ""
        if tag and tag not in found and element.text is not None:
            found[tag] = element.text.strip()
    return found


def calibration_from(fields: dict[str, str], override: dict | None = None) -> Calibration:
    """The Calibration of a parsed netftapi2.xml, each of its four values replaced by `override`'s
    where that gives one (counts_per_force, counts_per_torque, force_unit, torque_unit)."""
    override = {k: v for k, v in (override or {}).items() if v}
    values = {}
    for name, tag in (("counts_per_force", "cfgcpf"), ("counts_per_torque", "cfgcpt")):
        if name in override:
            values[name] = float(override[name])
            continue
        text = fields.get(tag)
        if text is None:
            raise RdtError(f"netftapi2.xml has no <{tag}> (counts per unit)")
        try:
            values[name] = float(text)
        except ValueError:
            raise RdtError(f"netftapi2.xml <{tag}> is {text!r}, not a number") from None
    for name, tag, codes in (("force_unit", "scfgfu", FORCE_CODES), ("torque_unit", "scfgtu", TORQUE_CODES)):
        if name in override:
            values[name] = override[name]
        elif fields.get(tag):
            values[name] = fields[tag]
        elif fields.get(tag[1:], "").strip().isdigit() and int(fields[tag[1:]]) in codes:
            values[name] = codes[int(fields[tag[1:]])]  # only the unit's code (cfgfu / cfgtu)
        else:
            raise RdtError(f"netftapi2.xml has no <{tag}> (the {name.replace('_', ' ')})")
    try:
        return Calibration(**values)
    except RdtError as exc:
        raise RdtError(f"netftapi2.xml: {exc}") from None


def fetch_netftapi2(host: str, http_port: int, timeout: float) -> dict[str, str]:
    """GET http://host:http_port/netftapi2.xml and parse it; RdtError (one line) when it fails. The whole
    exchange, from connecting to the last byte, takes at most `timeout` and MAX_XML_BYTES: a server that
    trickles or floods the page is refused, never waited for. No proxy: the box is on the lab's own
    network, whatever a proxy variable says. HTTP/1.0, so the page ends when the box closes."""
    import socket
    import time

    url = f"http://{host}:{http_port}/netftapi2.xml"
    deadline = time.monotonic() + timeout
    data = bytearray()
    try:
        with socket.create_connection((host, http_port), timeout=timeout) as sock:
            sock.sendall(f"GET /netftapi2.xml HTTP/1.0\r\nHost: {host}\r\n\r\n".encode())
            while True:
                left = deadline - time.monotonic()
                try:
                    if left <= 0:
                        raise TimeoutError
                    sock.settimeout(left)
                    chunk = sock.recv(65536)
                except TimeoutError:
                    if not data:
                        raise
                    raise RdtError(
                        f"{url}: the page took more than {timeout:g} s (http_timeout); {len(data)} bytes came"
                    ) from None
                if not chunk:
                    break
                data += chunk
                if len(data) > MAX_XML_BYTES + 65536:
                    raise RdtError(f"{url}: more than {MAX_XML_BYTES} bytes, not a Net F/T page")
    except RdtError:
        raise
    except TimeoutError:
        raise Unreachable(f"{url}: no answer within {timeout:g} s") from None
    except OSError as exc:
        raise Unreachable(f"{url}: {exc.strerror or exc}") from None
    head, sep, body = bytes(data).partition(b"\r\n\r\n")
    status = head.split(b"\r\n", 1)[0].split(None, 2)
    if not sep or len(status) < 2 or not status[0].startswith(b"HTTP/"):
        raise RdtError(f"{url}: not an HTTP answer")
    if status[1] != b"200":
        raise RdtError(f"{url}: HTTP {b' '.join(status[1:]).decode('latin-1')}")
    try:
        return parse_netftapi2(body)
    except RdtError as exc:
        raise RdtError(f"{url}: {exc}") from None


class SequenceCheck:
    """Judges each record's rdt_sequence against the stream so far: only newer records are used.

    A gap counts its records as lost; one that turns up late fills its gap (reordered, then not
    lost) and is not used, being older than one already used; a number seen before is a
    duplicate. A number far behind (more than WINDOW), or 1 (the first record of a stream), is a
    new stream (the box restarted it): counted, and followed from there."""

    WINDOW = 1024

    def __init__(self):
        self.last: int | None = None
        self.lost = 0
        self.reordered = 0
        self.duplicates = 0
        self.restarts = 0
        self._missing: dict[int, None] = {}  # recent gaps, oldest first, at most WINDOW

    def accept(self, seq: int) -> bool:
        if self.last is None:
            self.last = seq
            return True
        ahead = (seq - self.last) % SEQ_MOD
        if ahead == 0:
            self.duplicates += 1
            return False
        if ahead < SEQ_MOD // 2:
            for missed in range(max(1, ahead - self.WINDOW), ahead):
                self._missing[(self.last + missed) % SEQ_MOD] = None
            self.lost += ahead - 1
            while len(self._missing) > self.WINDOW:
                del self._missing[next(iter(self._missing))]
            self.last = seq
            return True
        if SEQ_MOD - ahead > self.WINDOW or seq == 1:  # far behind, or a stream's first record
            self.restarts += 1
            self._missing.clear()
            self.last = seq
            return True
        if seq in self._missing:
            del self._missing[seq]
            self.lost -= 1
            self.reordered += 1
        else:
            self.duplicates += 1
        return False
