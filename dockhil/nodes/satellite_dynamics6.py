"""satellite-dynamics, 6-DOF: two free-floating rigid bodies under the measured and virtual wrenches."""

from __future__ import annotations

from typing import Any, cast

from dockhil import physical
from dockhil.msgs import (
    BodyState,
    BodyWrenches,
    Pose,
    Quaternion,
    RobotCommand,
    SatelliteState,
    Twist,
    Vector3,
    WrenchStamped,
)
from dockhil.node import Input, Node, Output, Param, Tick
from dockhil.scene.sixdof_params import BODY_PARAMS, IDENTITY, MOUNT_PARAMS, bodies, checked


def attitude(q, rotvec, name):
    """exp(rotvec) q: a tilt given in radians on top of a quaternion (unit, checked)."""
    from dockhil.contact import rigidbody, rotations

    q = rotations.check_unit_quaternion(name.replace("attitude", "q"), q)
    return rotations.quat_multiply(rotations.quat_from_rotvec(rigidbody.check_vector(name, rotvec, unit="rad")), q)


class GapHold:
    """The robot command of max_gap: A's pose in B as it is while the interfaces are within max_gap
    along B's docking axis (x: the gap is -d_x), held still while they are farther apart.

    The gap is the distance along the docking axis, not between the interface points: the contact
    acts on d_x alone (B's face is a plane), so a pair near the plane with a large lateral offset
    can still touch, and its command must follow. Held, the whole pose stays where it was when the
    pair left: x at -max_gap, y, z and the attitude those of that tick, the twist zero. The robot
    driver checks the commanded position against its workspace box and the commanded attitude
    against max_tilt from the start; a drifting pair's lateral offset and attitude (a chaser that
    spins on for minutes) would leave both, and a pose held where the robot already was stays
    inside them. Direction-keeping (the command on the line to A, at max_gap) would still move and
    turn with the pair, and so would leave them.

    Coming back under max_gap the pair is not where it left: the command starts at the held pose
    and takes the offset between them (position difference, rotation vector) down as the gap
    closes: scaled by s = 3u^2 - 2u^3 of u = gap / (gap at the return), 1 at the return, 0 at the
    plane. It moves only as the pair closes along the axis, each tick by the pair's own step plus
    the offset times at most 1.5 times the gap's step over the gap at the return, and is the pair's
    pose again, bit for bit, from the plane on (no contact before it). Its twist is the derivative
    of that pose."""

    def __init__(self, max_gap: float):
        self.max_gap = max_gap
        self.gap = 0.0  # the last tick's gap along the docking axis
        self.parked: tuple | None = None  # the held (d, attitude)
        self.offset: tuple | None = None  # coming back: (position offset, rotation vector, gap at the return)

    def command(self, d, q, velocity, spin):
        """(d, attitude, d', angular velocity) the robot is sent, of A's pose and twist in B."""
        self.gap = gap = -d[0]
        if gap > self.max_gap:
            if self.parked is None:
                cd, cq = self._blended(d, q, velocity, spin, gap)[:2] if self.offset else (d, q)
                self.parked, self.offset = ((-self.max_gap, cd[1], cd[2]), cq), None
            return self.parked + ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        if self.parked is not None:  # back: take the offset to the pair down as the gap closes
            hd, hq = self.parked
            self.parked = None
            if gap > 0.0:
                from dockhil.contact.rotations import quat_conjugate, quat_multiply, rotvec3, sub3

                self.offset = (sub3(hd, d), rotvec3(quat_multiply(hq, quat_conjugate(q))), gap)
        if self.offset is None:
            return d, q, velocity, spin
        if gap <= 0.0:  # at the plane: the pair's pose from here on
            self.offset = None
            return d, q, velocity, spin
        return self._blended(d, q, velocity, spin, gap)

    def _blended(self, d, q, velocity, spin, gap):
        from dockhil.contact.rotations import quat_from_rotvec, quat_multiply, rotate

        dp, phi, back = cast(tuple, self.offset)  # set: called only while the offset is taken down
        # s = 3u^2 - 2u^3 of u = gap / back: its rate is 0 at both ends, so the command's velocity
        # does not step where the take-down ends, at the plane, where the contact may begin.
        u = 1.0 if gap > back else gap / back
        s, rate = u * u * (3.0 - 2.0 * u), 6.0 * u * (1.0 - u) * -velocity[0] / back
        turn = quat_from_rotvec((s * phi[0], s * phi[1], s * phi[2]))
        w = rotate(turn, spin)
        return (
            (d[0] + s * dp[0], d[1] + s * dp[1], d[2] + s * dp[2]),
            quat_multiply(turn, q),
            (velocity[0] + rate * dp[0], velocity[1] + rate * dp[1], velocity[2] + rate * dp[2]),
            (w[0] + rate * phi[0], w[1] + rate * phi[1], w[2] + rate * phi[2]),
        )


class SatelliteDynamics6(Node):
    """Integrates two rigid bodies under the F/T wrench and the virtual wrenches; publishes states and A's pose in B.

    The sensor's wrench (sensor frame, on the target) is moved to both CoMs with the mounting pose
    (dockhil.contact.hybrid6.held_wrench) and held over the tick; dockhil.contact.rigid integrates."""

    inputs = {
        "ft": Input(
            WrenchStamped,
            "/ft/wrench",
            feedthrough=False,
            help="wrench on the target measured by the F/T sensor, in the sensor frame",
        ),
        "impedance": Input(
            BodyWrenches,
            "/impedance/wrench",
            feedthrough=False,
            help="virtual wrenches on chaser, target (world, about each CoM)",
        ),
    }
    outputs = {
        "state": Output(
            SatelliteState,
            "/satellite/state",
            help="chaser, target: CoM pose (body-frame attitude) and twist (world angular velocity)",
        ),
        "command": Output(
            RobotCommand,
            "/robot/command",
            help="chaser interface A relative to target interface B: pose and twist in B",
        ),
    }
    params = {
        **BODY_PARAMS,
        "x1": Param(list, [-1.0, 0.0, 0.0], unit="m", help="chaser CoM, world", scale=physical.DISTANCE),
        "x2": Param(list, [2.0, 0.0, 0.0], unit="m", help="target CoM, world", scale=physical.DISTANCE),
        "q1": Param(list, IDENTITY, help="chaser attitude, body -> world (x, y, z, w)"),
        "q2": Param(list, IDENTITY, help="target attitude, body -> world (x, y, z, w)"),
        "attitude1": Param(
            list,
            [0.0, 0.0, 0.0],
            unit="rad",
            help="chaser attitude change as a rotation vector, applied after q1 (world axes)",
            scale=physical.ANGLE,
        ),
        "attitude2": Param(
            list,
            [0.0, 0.0, 0.0],
            unit="rad",
            help="target attitude change as a rotation vector, applied after q2 (world axes)",
            scale=physical.ANGLE,
        ),
        "v1": Param(list, [0.03, 0.0, 0.0], unit="m/s", help="chaser CoM velocity, world", scale=physical.SPEED),
        "v2": Param(list, [0.0, 0.0, 0.0], unit="m/s", help="target CoM velocity, world", scale=physical.SPEED),
        "w1": Param(
            list, [0.0, 0.0, 0.0], unit="rad/s", help="chaser angular velocity, body axes", scale=physical.ANGULAR_SPEED
        ),
        "w2": Param(
            list, [0.0, 0.0, 0.0], unit="rad/s", help="target angular velocity, body axes", scale=physical.ANGULAR_SPEED
        ),
        **MOUNT_PARAMS,
        "order": Param(int, 4, help="integrator order (2 or 4)", choices=(2, 4)),
        "max_gap": Param(
            float,
            0.0,
            unit="m",
            help="the robot command follows the interfaces' gap along B's docking axis up to this distance and "
            "waits there, its whole pose held, while they are farther apart (no contact can happen there; it "
            "keeps a long run in the robot's workspace); 0: follows everywhere",
            ge=0.0,
            le=physical.DISTANCE[1],
        ),
    }

    def setup(self):
        from dockhil.contact import hybrid6, rigid, rigidbody

        p = self.p

        def build():
            b1, b2 = bodies(p)
            s1 = rigidbody.BodyState(p.x1, attitude(p.q1, p.attitude1, "attitude1"), p.v1, p.w1)
            s2 = rigidbody.BodyState(p.x2, attitude(p.q2, p.attitude2, "attitude2"), p.v2, p.w2)
            return (
                b1,
                b2,
                rigid.Motion.from_state(b1, s1),
                rigid.Motion.from_state(b2, s2),
                hybrid6.sensor_mount_in_body(b2, p.sensor_position, p.sensor_orientation),
            )

        self.b1, self.b2, self.m1, self.m2, self.mount = checked(self.ctx.name, build)
        self.lib, self.rigid = hybrid6, rigid
        self.started = False
        self.hold = GapHold(p.max_gap) if p.max_gap else None

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        if not self.started:
            # Wall time with hardware: the simulated clock starts when the sensor answers (as the 1-DOF node).
            self.started = self.ctx.sim_time or inputs.get("ft") is not None
            if not self.started:
                return {"command": self._publish(tick)["command"]}
        elif tick.index > 0:
            ft, imp = inputs.get("ft"), inputs.get("impedance")
            zero = (0.0, 0.0, 0.0)
            if ft is not None:
                f, t = ft.wrench.force, ft.wrench.torque
                force, torque = (f.x, f.y, f.z), (t.x, t.y, t.z)
            else:
                force, torque = zero, zero
            if imp is not None and len(imp.wrenches) >= 2:
                w1, w2 = imp.wrenches[0], imp.wrenches[1]
                f1, t1, f2, t2 = w1.force, w1.torque, w2.force, w2.torque
                virtual = ((f1.x, f1.y, f1.z), (t1.x, t1.y, t1.z), (f2.x, f2.y, f2.z), (t2.x, t2.y, t2.z))
            else:
                virtual = (zero, zero, zero, zero)
            wrench = self.lib.held_wrench(self.m1, self.m2, self.mount, force, torque, virtual)
            self.rigid.step(self.m1, self.m2, wrench, tick.dt, self.p.order)
        return self._publish(tick)

    def _publish(self, tick):
        lib = self.lib
        pub1, pub2 = lib.published_body(self.m1), lib.published_body(self.m2)
        (d, q_rel, d_rate, w_rel), touching = lib.robot_command(self.b1, pub1, self.b2, pub2)
        if self.hold is not None:
            held = self.hold.parked
            d, q_rel, d_rate, w_rel = self.hold.command(d, q_rel, d_rate, w_rel)
            if self.hold.parked and not held:
                self.log(
                    f"interfaces {self.hold.gap:.3g} m apart along the docking axis: the robot waits at the gap "
                    f"max_gap = {self.hold.max_gap:g} m, its pose held"
                )
        x1, q1, v1, w1 = pub1
        x2, q2, v2, w2 = pub2
        # The library's values are plain floats already (tuples): they go into the messages as they are.
        state = SatelliteState(
            header=tick.header("world"),
            bodies=(
                BodyState("chaser", self.p.m1, Pose(Vector3(*x1), Quaternion(*q1)), Twist(Vector3(*v1), Vector3(*w1))),
                BodyState("target", self.p.m2, Pose(Vector3(*x2), Quaternion(*q2)), Twist(Vector3(*v2), Vector3(*w2))),
            ),
            in_contact=touching,
        )
        command = RobotCommand(
            header=tick.header("target_interface"),
            pose=Pose(Vector3(*d), Quaternion(*q_rel)),
            twist=Twist(Vector3(*d_rate), Vector3(*w_rel)),
        )
        return {"state": state, "command": command}
