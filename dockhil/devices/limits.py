"""What the robot drivers (robot_modbus, robot_rsi) check a command and a reading with: a message's
identity, a command's values, the distance and turn toward a setpoint, the angle between two
orientations (of the smallest rotation, 2 atan2(|v|, |w|) of q1 q0*, so q and -q are one
orientation), a non-finite field, and what a unit quaternion is."""

from __future__ import annotations

import math

from dockhil.contact.rotations import quat_conjugate, quat_from_rotvec, quat_multiply, rotvec3
from dockhil.msgs import Quaternion, RobotCommand, Vector3

# |q| of an orientation may differ from 1 by this much: the Modbus map's 1e-9 counts round a unit
# quaternion to within ~2e-9 of unit length; more is not a rotation.
UNIT_TOLERANCE = 1e-6

# A pose and twist as 13 floats: position(3), quaternion(4), linear(3), angular(3).
PoseTwist = tuple[float, ...]


def message_key(msg) -> tuple:
    """Identifies one published message; the runtime may hand the same one again."""
    h = msg.header
    return (h.stamp, h.tick, h.seq)


def vector_norm(v: Vector3) -> float:
    return math.sqrt(v.x * v.x + v.y * v.y + v.z * v.z)


def quat_tuple(q: Quaternion) -> tuple[float, float, float, float]:
    return (q.x, q.y, q.z, q.w)


def quat_norm(q) -> float:
    return math.sqrt(sum(c * c for c in q))


def angle_between(q0, q1) -> float:
    """Angle [rad, 0..pi] of the smallest rotation that turns q0 into q1 (q and -q are one rotation;
    the ratio of the parts makes it independent of |q|)."""
    x, y, z, w = quat_multiply(q1, quat_conjugate(q0))
    return 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))


def command_values(cmd: RobotCommand) -> PoseTwist:
    p, q, lin, ang = cmd.pose.position, cmd.pose.orientation, cmd.twist.linear, cmd.twist.angular
    return (p.x, p.y, p.z, q.x, q.y, q.z, q.w, lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)


def toward(origin, target, travel: float) -> tuple[float, ...]:
    """The point at most `travel` from origin on the straight line to target."""
    d = math.sqrt(sum((b - a) ** 2 for a, b in zip(origin, target)))
    if d <= travel:
        return tuple(target)
    f = travel / d
    return tuple(a + f * (b - a) for a, b in zip(origin, target))


def turn_toward(origin, target, angle: float) -> tuple[float, ...]:
    """The orientation at most `angle` [rad] from origin on the shortest rotation to target."""
    rotvec = rotvec3(quat_multiply(target, quat_conjugate(origin)))
    turn = math.sqrt(sum(c * c for c in rotvec))
    if turn <= angle:
        return tuple(target)
    f = angle / turn
    return tuple(quat_multiply(quat_from_rotvec(tuple(f * c for c in rotvec)), origin))


def non_finite(*named: tuple[str, object]) -> str:
    """'position.x = nan' for the first NaN/Inf field of the named vectors, else ''."""
    for name, vec in named:
        for axis in ("x", "y", "z", "w"):
            v = getattr(vec, axis, None)
            if v is not None and not math.isfinite(v):
                return f"{name}.{axis} = {v}"
    return ""


def toward_within(origin, target, travel: float, held, reach=None) -> tuple[float, ...]:
    """The point toward `target` from `origin`, at most `travel` from origin and within reach of every point
    of `held` (each of which a device may hold: whichever it holds, the step to the answer is at most its
    reach; `reach`: one per point, default `travel`). Origin must be within reach of each; the answer is the
    farthest such point on the straight line."""
    goal = toward(origin, target, travel)
    u = [b - a for a, b in zip(origin, goal)]
    uu = sum(c * c for c in u)
    if uu == 0.0:
        return tuple(origin)
    t = 1.0
    for i, c in enumerate(held):
        r = travel if reach is None else reach[i]
        d = [a - b for a, b in zip(origin, c)]
        du = sum(a * b for a, b in zip(d, u))
        dd = sum(a * a for a in d)
        if dd + 2.0 * du + uu <= r * r:
            continue  # the whole step stays within reach of this one
        # |d + t u| = r: the larger root (t = 0 is within reach)
        root = (-du + math.sqrt(max(0.0, du * du - uu * (dd - r * r)))) / uu
        t = min(t, max(0.0, root))
    return tuple(a + t * c for a, c in zip(origin, u))


def turn_within(origin, target, angle: float, held, reach=None) -> tuple[float, ...]:
    """The orientation toward `target` from `origin`, at most `angle` [rad] from origin and within reach of
    every orientation of `held` (`reach`: one per orientation, default `angle`; bounded through origin: what
    it is from each, plus the turn)."""
    spare = min(
        ((angle if reach is None else reach[i]) - angle_between(c, origin) for i, c in enumerate(held)), default=angle
    )
    return turn_toward(origin, target, max(0.0, min(angle, spare)))
