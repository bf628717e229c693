"""Modbus register map of the robot controller (Modbus TCP, one device).

All addresses are 0-based protocol addresses. Registers are 16-bit; a
32-bit value takes two registers, high word first (big-endian, "ABCD").

Holding registers (the host writes them; FC 3, 6, 16, 23)

    0      CONTROL     bit 0 ENABLE  drives on, follow the setpoint
                       bit 1 HOLD    stop and stay at the actual pose; the setpoint is ignored
                       bit 2 RESET   clear a latched fault (the controller clears the bit)
    1      HEARTBEAT   u16, the host changes it on every write cycle; when it
                       stops changing for the controller's heartbeat timeout,
                       the controller holds and sets HEARTBEAT_LOST
    2..27  SETPOINT    pose and twist block (below)
    28..29 SESSION     u32, the host's session id (nonzero) when it claims the
                       controller, 0 when it lets go (ownership, below)
    30..45 OWNER_NAME  32 bytes of ASCII, NUL-padded: who the claiming host is
                       (graph run id and host name), for other hosts to read

Input registers (the controller writes them; FC 4)

    0      MAGIC       0x4448 ("DH"): this register map
    1      VERSION     1
    2      STATUS      bit 0 ENABLED, bit 1 HOLDING, bit 2 FAULT,
                       bit 3 HEARTBEAT_LOST, bit 4 FOLLOWING (tracking the setpoint)
    3      HEARTBEAT   the last heartbeat value the controller accepted
    4      CYCLE       u16 servo cycle counter, wraps: a changing value shows
                       the actual pose is fresh
    5..30  ACTUAL      pose and twist block (below)
    31..32 OWNER       u32 session id of the host that owns the controller; 0: nobody
    33..48 OWNER_NAME  the owner's name as it wrote it

Pose and twist block: 13 int32 (26 registers), in the frame of
RobotCommand/RobotState (pose of the chaser's probe relative to the
target's interface, x > 0 is penetration):

    +0   position x, y, z          [1e-6 m per count]     range +-2147 m
    +6   orientation qx, qy, qz, qw [1e-9 per count]      unit quaternion
    +14  linear velocity x, y, z   [1e-6 m/s per count]
    +20  angular velocity x, y, z  [1e-6 rad/s per count]

The full pose goes both ways: a setpoint commands position and orientation,
the actual block reports both, with the measured twist. The orientation is a
unit quaternion, scalar last, the rotation of the probe frame relative to the
target's interface frame; its length must be 1 within UNIT_TOLERANCE (1e-6:
whole 1e-9 counts round a unit quaternion to within 2e-9 of it). A controller
refuses a setpoint whose quaternion is not unit (FAULT, hold until RESET):
such a quaternion is no rotation. The angular velocity, like the linear one,
is expressed in the target's interface frame (the rate of the rotation vector
that carries the orientation on).

The velocities of a setpoint are a feed-forward the controller may use.
One FC 16 write of registers 0..27 sets control, heartbeat and setpoint in
one transaction, so the controller never sees a half-written setpoint.

Ownership: one host commands the controller at a time. A host reads OWNER
first and, if it is not 0, writes nothing. It claims the controller by one
FC 16 write of SESSION and OWNER_NAME (registers 28..45). While the claim is
alive the controller answers every write to its holding registers from
any other connection with exception 6 (device busy), a second claim
included; only the owner's session may claim again (its driver
reconnecting). Without a live claim nothing moves the robot: a write of
CONTROL, HEARTBEAT or SETPOINT (registers 0..27) from a connection that holds
no live claim (a host that never claimed, or the owner after its claim
lapsed) is refused with exception 6 too, and counted; a host claims first.
The claim dies when the owner writes SESSION 0, or when its heartbeat has
not changed for the heartbeat timeout (the owner died or lost the link):
then the controller holds and another host may claim it.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from dockhil.devices.limits import UNIT_TOLERANCE, PoseTwist

MAGIC = 0x4448
VERSION = 1

# Holding registers
HR_CONTROL = 0
HR_HEARTBEAT = 1
HR_SETPOINT = 2
BLOCK_VALUES = 13
BLOCK_REGISTERS = 2 * BLOCK_VALUES
HR_COUNT = HR_SETPOINT + BLOCK_REGISTERS  # 28

CONTROL_ENABLE = 0x0001
CONTROL_HOLD = 0x0002
CONTROL_RESET = 0x0004

# Ownership block (holding: the host's claim; input: the controller's owner)
HR_SESSION = 28
HR_OWNER_NAME = 30
OWNER_NAME_REGISTERS = 16  # 32 ASCII bytes
HR_CLAIM_COUNT = 2 + OWNER_NAME_REGISTERS  # registers 28..45
HR_END = HR_SESSION + HR_CLAIM_COUNT  # 46 holding registers in all

# Input registers
IR_MAGIC = 0
IR_VERSION = 1
IR_STATUS = 2
IR_HEARTBEAT = 3
IR_CYCLE = 4
IR_ACTUAL = 5
IR_COUNT = IR_ACTUAL + BLOCK_REGISTERS  # 31

IR_OWNER = 31
IR_OWNER_NAME = 33
IR_OWNER_COUNT = 2 + OWNER_NAME_REGISTERS  # registers 31..48
IR_END = IR_OWNER + IR_OWNER_COUNT  # 49 input registers in all

STATUS_ENABLED = 0x0001
STATUS_HOLDING = 0x0002
STATUS_FAULT = 0x0004
STATUS_HEARTBEAT_LOST = 0x0008
STATUS_FOLLOWING = 0x0010

# Counts per SI unit. Decoding divides by these integers, so that a value
# written in whole counts (0.1 m = 100000 counts) reads back exactly.
POSITION_COUNTS = 1_000_000  # per m
QUATERNION_COUNTS = 1_000_000_000  # per 1
LINEAR_COUNTS = 1_000_000  # per m/s
ANGULAR_COUNTS = 1_000_000  # per rad/s

FIELDS = (
    ("position.x", POSITION_COUNTS, "m"),
    ("position.y", POSITION_COUNTS, "m"),
    ("position.z", POSITION_COUNTS, "m"),
    ("orientation.x", QUATERNION_COUNTS, ""),
    ("orientation.y", QUATERNION_COUNTS, ""),
    ("orientation.z", QUATERNION_COUNTS, ""),
    ("orientation.w", QUATERNION_COUNTS, ""),
    ("linear.x", LINEAR_COUNTS, "m/s"),
    ("linear.y", LINEAR_COUNTS, "m/s"),
    ("linear.z", LINEAR_COUNTS, "m/s"),
    ("angular.x", ANGULAR_COUNTS, "rad/s"),
    ("angular.y", ANGULAR_COUNTS, "rad/s"),
    ("angular.z", ANGULAR_COUNTS, "rad/s"),
)

_INT32 = struct.Struct(">i")
_WORDS = struct.Struct(">HH")
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


class RegisterError(ValueError):
    """A value that does not fit the map, or registers that are not this map."""


HOLD_POSE: PoseTwist = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def int32_to_registers(value: int) -> tuple[int, int]:
    return _WORDS.unpack(_INT32.pack(value))


def registers_to_int32(high: int, low: int) -> int:
    return _INT32.unpack(_WORDS.pack(high, low))[0]


def encode_block(values: PoseTwist, what: str = "setpoint") -> list[int]:
    """26 registers for a pose and twist; RegisterError names a value that does not fit."""
    if len(values) != BLOCK_VALUES:
        raise RegisterError(f"{what}: expected {BLOCK_VALUES} values, got {len(values)}")
    regs: list[int] = []
    for (name, per_unit, unit), v in zip(FIELDS, values):
        if not math.isfinite(v):
            raise RegisterError(f"{what} {name} = {v!r}: not a finite number")
        counts = round(v * per_unit)
        if not _INT32_MIN <= counts <= _INT32_MAX:
            limit = _INT32_MAX / per_unit
            raise RegisterError(
                f"{what} {name} = {v:g} {unit}".rstrip() + f" does not fit the register map (|value| <= {limit:.4g})"
            )
        regs.extend(int32_to_registers(counts))
    return regs


def decode_block(regs: Sequence[int]) -> PoseTwist:
    if len(regs) != BLOCK_REGISTERS:
        raise RegisterError(f"pose block: expected {BLOCK_REGISTERS} registers, got {len(regs)}")
    return tuple(registers_to_int32(regs[2 * i], regs[2 * i + 1]) / FIELDS[i][1] for i in range(BLOCK_VALUES))


def encode_write(control: int, heartbeat: int, setpoint: PoseTwist | None = None) -> list[int]:
    """Holding registers from 0: control and heartbeat, plus the setpoint if given."""
    regs = [control & 0xFFFF, heartbeat & 0xFFFF]
    if setpoint is not None:
        regs.extend(encode_block(setpoint))
    return regs


@dataclass(frozen=True)
class HostWrite:
    """The holding registers as the controller sees them."""

    control: int
    heartbeat: int
    setpoint: PoseTwist


def decode_holding(regs: Sequence[int]) -> HostWrite:
    if len(regs) != HR_COUNT:
        raise RegisterError(f"holding registers: expected {HR_COUNT}, got {len(regs)}")
    return HostWrite(regs[HR_CONTROL], regs[HR_HEARTBEAT], decode_block(regs[HR_SETPOINT:HR_COUNT]))


@dataclass(frozen=True)
class ControllerReading:
    """The input registers as the host sees them."""

    status: int
    heartbeat: int
    cycle: int
    actual: PoseTwist


def encode_inputs(status: int, heartbeat: int, cycle: int, actual: PoseTwist) -> list[int]:
    return [MAGIC, VERSION, status & 0xFFFF, heartbeat & 0xFFFF, cycle & 0xFFFF] + encode_block(actual, "actual")


def decode_inputs(regs: Sequence[int]) -> ControllerReading:
    """Decode input registers 0..30; RegisterError if they are not this map."""
    if len(regs) != IR_COUNT:
        raise RegisterError(f"input registers: expected {IR_COUNT}, got {len(regs)}")
    if regs[IR_MAGIC] != MAGIC or regs[IR_VERSION] != VERSION:
        raise RegisterError(
            f"not a dockhil robot controller: input registers 0-1 read {regs[IR_MAGIC]:#06x} {regs[IR_VERSION]}, "
            f"expected {MAGIC:#06x} {VERSION}"
        )
    return ControllerReading(
        regs[IR_STATUS], regs[IR_HEARTBEAT], regs[IR_CYCLE], decode_block(regs[IR_ACTUAL:IR_COUNT])
    )


def describe_status(status: int) -> str:
    """A short word for RobotState.status: the most important condition first."""
    if status & STATUS_FAULT:
        return "fault"
    if status & STATUS_HEARTBEAT_LOST:
        return "heartbeat-lost"
    if not status & STATUS_ENABLED:
        return "disabled"
    if status & STATUS_HOLDING:
        return "holding"
    return "ok"


def encode_owner(session: int, name: str) -> list[int]:
    """SESSION (u32, high word first) and OWNER_NAME: a claim (holding 28..45) or the owner (input 31..48)."""
    if not 0 <= session <= 0xFFFF_FFFF:
        raise RegisterError(f"session id {session} does not fit 32 bits")
    raw = name.encode("ascii", "replace")[: 2 * OWNER_NAME_REGISTERS].ljust(2 * OWNER_NAME_REGISTERS, b"\0")
    return [session >> 16, session & 0xFFFF] + [int.from_bytes(raw[i : i + 2], "big") for i in range(0, len(raw), 2)]


def decode_owner(regs: Sequence[int]) -> tuple[int, str]:
    """(session id, name) from an ownership block; session 0: nobody."""
    if len(regs) != HR_CLAIM_COUNT:
        raise RegisterError(f"ownership block: expected {HR_CLAIM_COUNT} registers, got {len(regs)}")
    raw = b"".join(int(r).to_bytes(2, "big") for r in regs[2:])
    return (regs[0] << 16) | regs[1], raw.rstrip(b"\0").decode("ascii", "replace")


def start_orientation(reading: ControllerReading) -> tuple[float, float, float, float]:
    """The actual orientation at connect, the reference of max_tilt; RegisterError if it is no rotation."""
    q = reading.actual[3:7]
    n = math.sqrt(sum(c * c for c in q))
    if abs(n - 1.0) > UNIT_TOLERANCE:
        raise RegisterError(
            f"the controller reports an actual orientation with |q| = {n:.9g}, not a unit "
            f"quaternion; check its orientation registers (input {IR_ACTUAL + 6}-"
            f"{IR_ACTUAL + 13})"
        )
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n
