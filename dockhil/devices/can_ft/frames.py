"""CAN frame layout of the 6-axis force/torque sensor.

The sensor streams one sample as two classic CAN frames with 11-bit IDs,
8 data bytes each, sent back to back:

    ID base + 0  FORCE   bytes 0-1 Fx, 2-3 Fy, 4-5 Fz   int16 little-endian [counts]
                         byte 6 status, byte 7 sequence
    ID base + 1  TORQUE  bytes 0-1 Tx, 2-3 Ty, 4-5 Tz   int16 little-endian [counts]
                         byte 6 status, byte 7 sequence

    base         0x1A0 by default (a parameter: one base per sensor on a bus)
    force        counts * force_resolution  [N]      (default 0.01 N/count, +-327.67 N)
    torque       counts * torque_resolution [N m]    (default 0.001 N m/count, +-32.767 N m)
    status       bit 0 OVERRANGE: a gauge saturated, the sample is clipped
                 bit 1 FAULT: the sensor reports an internal fault
                 bits 2-7 reserved, sent as 0, ignored on receive
    sequence     sample counter 0..255, wraps; both frames of one sample carry
                 the same value, which pairs them and shows lost or stuck data

Axes are those of the probe frame (x along the docking axis, x > 0 is
penetration) and the values are the wrench the contact exerts on the
chaser's probe, the convention of /ft/wrench.

Frames with other IDs belong to other devices and are not ours to judge;
a frame on one of our IDs that breaks this layout raises FrameError.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

DEFAULT_BASE_ID = 0x1A0
FORCE_OFFSET = 0
TORQUE_OFFSET = 1
MAX_STANDARD_ID = 0x7FF


def frame_params() -> dict:
    """The node parameters of this frame layout, shared by the driver and the emulator
    so the two ends of the bus cannot disagree on a default."""
    from dockhil.node import Param

    return {
        "can_id": Param(
            int,
            DEFAULT_BASE_ID,
            help="base CAN ID: force frame = base, torque frame = base + 1",
            ge=0,
            le=MAX_STANDARD_ID - 1,
        ),
        "force_resolution": Param(float, 0.01, unit="N/count", help="force per count", gt=0.0, le=10.0),
        "torque_resolution": Param(float, 0.001, unit="N m/count", help="torque per count", gt=0.0, le=1.0),
    }


STATUS_OVERRANGE = 0x01
STATUS_FAULT = 0x02

FRAME_LENGTH = 8
_LAYOUT = struct.Struct("<hhhBB")
_INT16_MIN, _INT16_MAX = -32768, 32767

FORCE = "force"
TORQUE = "torque"


class FrameError(ValueError):
    """A frame on one of the sensor's IDs that does not follow the layout."""


@dataclass(frozen=True)
class FtScaling:
    """Physical value of one count."""

    force_resolution: float = 0.01  # N per count
    torque_resolution: float = 0.001  # N m per count

    def __post_init__(self):
        for name in ("force_resolution", "torque_resolution"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")

    def resolution(self, kind: str) -> float:
        return self.force_resolution if kind == FORCE else self.torque_resolution


@dataclass(frozen=True)
class FtHalf:
    """One decoded frame: the force or the torque half of a sample."""

    kind: str  # FORCE or TORQUE
    values: tuple[float, float, float]  # N or N m
    counts: tuple[int, int, int]
    status: int
    seq: int


@dataclass(frozen=True)
class FtSample:
    """A complete sample: both halves with the same sequence number."""

    force: tuple[float, float, float]  # N
    torque: tuple[float, float, float]  # N m
    status: int
    seq: int


def check_base_id(base_id: int) -> int:
    if not 0 <= base_id <= MAX_STANDARD_ID - TORQUE_OFFSET:
        raise ValueError(
            f"CAN base ID {base_id:#x} out of range: the sensor uses base and base+1, "
            f"both 11-bit (0x000..{MAX_STANDARD_ID - TORQUE_OFFSET:#x})"
        )
    return base_id


def to_counts(values: Sequence[float], resolution: float) -> tuple[tuple[int, int, int], bool]:
    """Counts for three physical values, clipped to int16; True if any was clipped."""
    counts = []
    clipped = False
    for v in values:
        if not math.isfinite(v):
            raise ValueError(f"cannot encode {v!r}: sensor values must be finite")
        c = round(v / resolution)
        if c < _INT16_MIN or c > _INT16_MAX:
            clipped = True
            c = min(max(c, _INT16_MIN), _INT16_MAX)
        counts.append(c)
    return (counts[0], counts[1], counts[2]), clipped


def encode_sample(
    force: Sequence[float],
    torque: Sequence[float],
    seq: int,
    scaling: FtScaling = FtScaling(),
    base_id: int = DEFAULT_BASE_ID,
    status: int = 0,
) -> list[tuple[int, bytes]]:
    """[(arbitration_id, data)] for one sample: the force frame, then the torque frame.

    If either half saturates, both frames carry OVERRANGE: the sample as a
    whole is clipped.
    """
    check_base_id(base_id)
    f_counts, f_clip = to_counts(force, scaling.force_resolution)
    t_counts, t_clip = to_counts(torque, scaling.torque_resolution)
    if f_clip or t_clip:
        status |= STATUS_OVERRANGE
    status &= 0xFF
    seq &= 0xFF
    return [
        (base_id + FORCE_OFFSET, _LAYOUT.pack(*f_counts, status, seq)),
        (base_id + TORQUE_OFFSET, _LAYOUT.pack(*t_counts, status, seq)),
    ]


def decode_frame(
    arbitration_id: int,
    data: bytes | bytearray,
    base_id: int = DEFAULT_BASE_ID,
    scaling: FtScaling = FtScaling(),
    *,
    is_extended_id: bool = False,
    is_remote_frame: bool = False,
) -> FtHalf | None:
    """The half a frame carries, None for a frame of another device, FrameError if malformed."""
    if is_extended_id or arbitration_id not in (base_id + FORCE_OFFSET, base_id + TORQUE_OFFSET):
        return None
    kind = FORCE if arbitration_id == base_id + FORCE_OFFSET else TORQUE
    where = f"F/T {kind} frame {arbitration_id:#05x}"
    if is_remote_frame:
        raise FrameError(f"{where}: remote frame where data was expected")
    if len(data) != FRAME_LENGTH:
        raise FrameError(f"{where}: {len(data)} data bytes, expected {FRAME_LENGTH} ({bytes(data).hex()})")
    x, y, z, status, seq = _LAYOUT.unpack(bytes(data))
    res = scaling.resolution(kind)
    return FtHalf(kind, (x * res, y * res, z * res), (x, y, z), status, seq)


class SampleAssembler:
    """Pairs force and torque frames into samples by their sequence number.

    A torque frame completes the force frame with the same sequence number;
    anything else (a torque frame with no matching force frame, a force
    frame replaced before its torque arrived) is counted as an orphan.
    """

    def __init__(self) -> None:
        self._force: FtHalf | None = None
        self.orphans = 0

    def add(self, half: FtHalf) -> FtSample | None:
        if half.kind == FORCE:
            if self._force is not None:
                self.orphans += 1
            self._force = half
            return None
        force = self._force
        if force is None or force.seq != half.seq:
            self.orphans += 1
            return None
        self._force = None
        return FtSample(force.values, half.values, force.status | half.status, half.seq)


def describe_status(status: int) -> str:
    names = []
    if status & STATUS_OVERRANGE:
        names.append("overrange")
    if status & STATUS_FAULT:
        names.append("fault")
    return ", ".join(names) or "ok"
