"""KUKA RSI (Robot Sensor Interface), Ethernet XML over UDP: the datagrams and the angles.

Each interpolation cycle (4 ms; 12 ms on older controllers) the controller sends
one datagram and expects the answer to it within the same cycle:

    <Rob Type="KUKA">
      <RIst X="..." Y="..." Z="..." A="..." B="..." C="..."/>   actual TCP pose: mm, degrees
      <RSol X="..." Y="..." Z="..." A="..." B="..." C="..."/>   commanded TCP pose
      <Delay D="0"/>                                            late answers counted so far
      <IPOC>123456</IPOC>                                       the cycle's timestamp
    </Rob>

    <Sen Type="ImFree">
      <RKorr X="..." Y="..." Z="..." A="..." B="..." C="..."/>  Cartesian correction: mm, degrees
      <IPOC>123456</IPOC>                                       the same IPOC, echoed
    </Sen>

Which elements a datagram carries is set in the controller's Ethernet
configuration file (docs/hardware.md); a datagram may carry others (AIPos,
ASPos, Tech, Digin, ...), which are ignored here. The Sen's Type is the
configuration's SENTYPE. Some open simulators write the Rob's attribute as
TYPE; only the element name Rob is checked.

A B C are KUKA's Euler angles: Z-Y'-X'' intrinsic, R = Rz(A) Ry(B) Rx(C), in
degrees. Quaternions here are (x, y, z, w), as in dockhil.contact.rigid.

Parsing is safe by construction: a datagram is bounded (MAX_DATAGRAM bytes),
one that declares anything (`<!`: a DOCTYPE, an ENTITY, CDATA or a comment) or
an instruction other than a leading XML declaration is refused before expat
sees it, so there is no entity to expand; expat then parses at most a few KB.
What no controller sends is refused too: a count of more than 19 digits, a
position beyond a kilometre, an angle beyond +-360 degrees.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from typing import NamedTuple

MAX_DATAGRAM = 4096  # bytes: a controller's datagram with every configured element is about 1 KB
MAX_DIGITS = 19  # an IPOC or a count has at most this many digits (a 64-bit counter): longer, no controller sent it
MAX_POSITION_MM = 1e6  # |X|, |Y|, |Z| of a pose above a kilometre is no robot's pose
MAX_ANGLE_DEG = 360.0  # |A|, |B|, |C| of a pose
CARTESIAN = ("X", "Y", "Z", "A", "B", "C")
CYCLES = (0.004, 0.012)  # s: the RSI interpolation cycles (KR C4/C5; KR C2 and older RSI versions)


class RsiError(ValueError):
    """A datagram that is not a valid RSI datagram; the message says why, in a few words."""


class RobFrame(NamedTuple):
    """One controller datagram, as read."""

    ipoc: int
    rist: tuple[float, float, float, float, float, float]  # actual pose: mm, degrees
    rsol: tuple[float, float, float, float, float, float] | None  # commanded pose, if sent
    delay: int | None  # the controller's count of late answers, if sent


def _screen(data: bytes) -> None:
    if len(data) > MAX_DATAGRAM:
        raise RsiError(f"oversized datagram ({len(data)} bytes > {MAX_DATAGRAM})")
    if b"<!" in data:
        raise RsiError("datagram carries a declaration (<!...>): refused unparsed")
    head = data.lstrip()
    if head.startswith(b"<?xml"):
        end = head.find(b"?>")
        head = head[end + 2 :] if end > 0 else head
    if b"<?" in head:
        raise RsiError("datagram carries a processing instruction: refused unparsed")


def _pose(element, tag: str) -> tuple[float, float, float, float, float, float]:
    out = []
    for name in CARTESIAN:
        text = element.get(name)
        if text is None:
            raise RsiError(f"{tag} has no attribute {name}")
        try:
            value = float(text)
        except ValueError:
            raise RsiError(f"{tag} {name}={text[:20]!r} is not a number") from None
        if not math.isfinite(value):
            raise RsiError(f"{tag} {name}={text[:20]!r} is not finite")
        limit, unit = (MAX_POSITION_MM, "mm") if name in "XYZ" else (MAX_ANGLE_DEG, "degrees")
        if abs(value) > limit:
            raise RsiError(f"{tag} {name}={text[:20]!r} is outside +-{limit:g} {unit}: no robot's pose")
        out.append(value)
    return tuple(out)  # type: ignore[return-value]


def _count(text: str | None, what: str) -> int:
    text = (text or "").strip()
    if not text.isdigit() or not text.isascii():
        raise RsiError(f"{what} {text[:20]!r} is not a non-negative integer")
    if len(text) > MAX_DIGITS:
        raise RsiError(f"{what} of {len(text)} digits: no controller counts that far")
    return int(text)


def _root(data: bytes, tag: str):
    """The parsed datagram, whose root element must be `tag`."""
    _screen(data)
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise RsiError(f"malformed XML ({exc})") from None
    if root.tag != tag:
        raise RsiError(f"root element <{root.tag[:20]}>, not <{tag}>")
    return root


def _element(root, tag: str, hint: str = ""):
    element = root.find(tag)
    if element is None:
        raise RsiError(f"no {tag} element{hint}")
    return element


def parse_rob(data: bytes) -> RobFrame:
    """The controller's datagram; RsiError if it is not one this driver can act on (it needs RIst and IPOC)."""
    root = _root(data, "Rob")
    rist = _element(root, "RIst", " (add DEF_RIst to the SEND elements of the Ethernet configuration)")
    ipoc = _element(root, "IPOC")
    rsol = root.find("RSol")
    delay = root.find("Delay")
    return RobFrame(
        _count(ipoc.text, "IPOC"),
        _pose(rist, "RIst"),
        None if rsol is None else _pose(rsol, "RSol"),
        None if delay is None else _count(delay.get("D"), "Delay D"),
    )


def parse_sen(data: bytes) -> tuple[int, tuple[float, float, float, float, float, float]]:
    """The sensor's answer: (IPOC, RKorr); RsiError if it is not one (the emulator's side)."""
    root = _root(data, "Sen")
    korr = _element(root, "RKorr")
    return _count(_element(root, "IPOC").text, "IPOC"), _pose(korr, "RKorr")


def _check_type(value: str) -> str:
    if not value or not all(c.isalnum() or c in "_-" for c in value) or not value.isascii():
        raise ValueError(f"RSI type {value!r}: letters, digits, _ and - only")
    return value


class SenWriter:
    """Builds the answers for one SENTYPE: one %-format of a prebuilt template, no XML library."""

    def __init__(self, sentype: str = "ImFree"):
        self._template = (
            f'<Sen Type="{_check_type(sentype)}"><RKorr X="%.4f" Y="%.4f" Z="%.4f" '
            f'A="%.4f" B="%.4f" C="%.4f"/><IPOC>%d</IPOC></Sen>'
        ).encode()

    def __call__(self, korr, ipoc: int) -> bytes:
        """The answer carrying correction `korr` (X Y Z mm, A B C degrees, all finite) for cycle `ipoc`."""
        return self._template % (*korr, ipoc)


def build_rob(ipoc: int, rist, rsol=None, delay: int | None = None, rob_type: str = "KUKA") -> bytes:
    """A controller's datagram (the emulator's side)."""
    parts = [f'<Rob Type="{_check_type(rob_type)}">', _pose_text("RIst", rist)]
    if rsol is not None:
        parts.append(_pose_text("RSol", rsol))
    if delay is not None:
        parts.append(f'<Delay D="{int(delay)}"/>')
    parts.append(f"<IPOC>{int(ipoc)}</IPOC></Rob>")
    return "".join(parts).encode()


def _pose_text(tag: str, pose) -> str:
    return f"<{tag} " + " ".join(f'{n}="{v:.4f}"' for n, v in zip(CARTESIAN, pose)) + "/>"


# -- KUKA A B C <-> quaternion --------------------------------------------------------


def abc_to_quat(a: float, b: float, c: float) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of KUKA angles A B C [degrees]: R = Rz(A) Ry(B) Rx(C)."""
    ha, hb, hc = math.radians(a) / 2, math.radians(b) / 2, math.radians(c) / 2
    ca, sa, cb, sb, cc, sc = math.cos(ha), math.sin(ha), math.cos(hb), math.sin(hb), math.cos(hc), math.sin(hc)
    return (
        ca * cb * sc - sa * sb * cc,
        ca * sb * cc + sa * cb * sc,
        sa * cb * cc - ca * sb * sc,
        ca * cb * cc + sa * sb * sc,
    )


def quat_to_abc(q) -> tuple[float, float, float]:
    """KUKA angles A B C [degrees] of a unit quaternion (x, y, z, w); A and C in (-180, 180],
    B in [-90, 90]. At B = +-90 (gimbal lock) only A - C (B = 90) or A + C (B = -90) is defined:
    C is 0 there."""
    x, y, z, w = q
    r00 = 1 - 2 * (y * y + z * z)
    r10 = 2 * (x * y + z * w)
    r20 = 2 * (x * z - y * w)
    r21 = 2 * (y * z + x * w)
    r22 = 1 - 2 * (x * x + y * y)
    cos_b = math.hypot(r00, r10)
    b = math.atan2(-r20, cos_b)
    if cos_b > 1e-9:
        a = math.atan2(r10, r00)
        c = math.atan2(r21, r22)
    else:
        r01 = 2 * (x * y - z * w)
        r11 = 1 - 2 * (x * x + z * z)
        a = math.atan2(-r01, r11)
        c = 0.0
    return math.degrees(a), math.degrees(b), math.degrees(c)


def claim_port(port: int):
    """Claim the RSI port for this graph: its driver and its emulator may share it, another graph may not
    (its driver would answer our controller's datagrams, its emulator would send ours its own)."""
    from dockhil.runtime import ownership

    return ownership.claim_for_graph(f"kuka-rsi-port-{port}", f"KUKA RSI port {port}")
