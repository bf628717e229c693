"""ros2_bridge: the running graph seen live on a ROS 2 network over DDS, and a ROS 2 /estop that holds it.

Each topic of `topics` is written to a ROS 2 domain (`domain_id`) as ROS 2 writes it: the DDS topic
`rt/<topic>`, the type `geometry_msgs::msg::dds_::<Type>_` with ROS 2's field names and types, plain
CDR, ROS 2's default QoS (reliable, volatile, keep last 10). So `ros2 topic echo /ft/wrench`, rviz or a
lab's own nodes read the docking run without a ROS 2 install on this side:

    dockhil message        ROS 2 topic               ROS 2 type
    WrenchStamped  /T      /T                        geometry_msgs/msg/WrenchStamped
    RobotCommand   /T      /T (pose), /T/twist       geometry_msgs/msg/PoseStamped, TwistStamped
    RobotState     /T      /T (pose), /T/twist       geometry_msgs/msg/PoseStamped, TwistStamped

The header's stamp (sim or Unix time) becomes builtin_interfaces/Time, its frame the frame_id.

It reads the ROS 2 topic /estop (std_msgs/msg/Bool): `data: true` publishes dockhil's EStop (active)
on /estop from that step on, every step, until the graph stops, so a robot driver or the simulated
robot holds and stops the graph: `ros2 topic pub --once /estop std_msgs/msg/Bool "{data: true}"`.
An e-stop once given is latched here; `false` after it releases nothing.

It observes, never holds the graph back: each step writes each message once, as it came (in wall
time the latest one), and a write never waits (max_blocking_time 0): when ROS 2 readers acknowledge
too slowly for a reliable writer's history, the sample is dropped and counted, never queued. Its
inputs have no maximum age: a quiet topic does not stop the graph.

cyclonedds (the Eclipse Cyclone DDS binding, `pip install 'dockhil[ros2]'`) is imported only in
setup; the network it uses is Cyclone DDS's own configuration (CYCLONEDDS_URI), as for ROS 2's
rmw_cyclonedds_cpp.
"""

# No `from __future__ import annotations`: cyclonedds reads the field types of the IDL structs that
# ros_types() defines in its own scope from their annotations, which must be the types, not names.
import functools
import importlib.util
import math
import re
from typing import TYPE_CHECKING, Any

from dockhil.errors import DockhilError, ParamError
from dockhil.msgs import EStop, Header, RobotCommand, RobotState, WrenchStamped
from dockhil.node import Input, Node, Output, Param, Tick

if TYPE_CHECKING:
    from cyclonedds.pub import DataWriter

NEEDS = "the ROS 2 bridge needs the cyclonedds binding: pip install 'dockhil[ros2]'"
DOMAIN_MAX = 232  # ROS 2's largest domain id: DDS ports 7400 + 250 d stay below 65536
# dockhil message types the bridge writes, by name (for `topic:Type`)
BRIDGED = {cls.__name__: cls for cls in (WrenchStamped, RobotCommand, RobotState)}
# The graph's own topics and their types; any other topic is given as `topic:Type`.
KNOWN_TOPICS = {
    "/ft/wrench": WrenchStamped,
    "/robot/command": RobotCommand,
    "/robot/command/delayed": RobotCommand,
    "/robot/state": RobotState,
}
# A CYCLONEDDS_URI that keeps DDS on this host (the loopback interface, unicast discovery on 127.0.0.1):
# tests and measurements use it, and so may a user who wants no DDS traffic on the network.
LOOPBACK_URI = (
    '<CycloneDDS><Domain Id="any"><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    '<Peers><Peer Address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>'
)
_ROS_NAME = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")  # a fully qualified ROS 2 topic name


def bridged_topics(entries: object) -> dict[str, type]:
    """topic -> dockhil message type of the `topics` parameter, or one ParamError line."""
    where = "node type ros2_bridge parameter 'topics'"
    if not isinstance(entries, list) or not all(isinstance(e, str) for e in entries):
        raise ParamError(f"{where}: expected a list of topic names, got {entries!r}")
    out: dict[str, type] = {}
    for entry in entries:
        topic, _, type_name = entry.partition(":")
        if not _ROS_NAME.fullmatch(topic):
            raise ParamError(
                f"{where}: {topic!r} is not a ROS 2 topic name (/ and parts of letters, digits "
                f"and _, each not starting with a digit)"
            )
        if topic == "/estop":
            raise ParamError(f"{where}: /estop is the ROS 2 e-stop the bridge reads, not a topic it writes")
        if type_name:
            if type_name not in BRIDGED:
                raise ParamError(f"{where}: {entry!r}: the bridge writes {', '.join(BRIDGED)}, not {type_name!r}")
            out[topic] = BRIDGED[type_name]
        elif topic in KNOWN_TOPICS:
            out[topic] = KNOWN_TOPICS[topic]
        else:
            raise ParamError(
                f"{where}: {topic!r} is not one of the graph's topics "
                f"({', '.join(KNOWN_TOPICS)}); give its type as '{topic}:WrenchStamped', "
                f"':RobotCommand' or ':RobotState'"
            )
    return out


def ros_time(stamp: float) -> tuple[int, int]:
    """(sec, nanosec) of builtin_interfaces/Time for a header stamp [s]."""
    sec, nanosec = divmod(round(stamp * 1e9), 1_000_000_000)
    return sec, nanosec


@functools.cache
def ros_types():
    """ROS 2's message types as Cyclone DDS IDL structs (ROS 2's names, fields and field types)."""
    from dataclasses import dataclass
    from types import SimpleNamespace

    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import float64, int32, uint32

    @dataclass
    class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
        sec: int32
        nanosec: uint32

    @dataclass
    class RosHeader(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
        stamp: Time
        frame_id: str

    @dataclass
    class Bool(IdlStruct, typename="std_msgs::msg::dds_::Bool_"):
        data: bool

    @dataclass
    class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
        x: float64
        y: float64
        z: float64

    @dataclass
    class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
        x: float64
        y: float64
        z: float64

    @dataclass
    class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
        x: float64
        y: float64
        z: float64
        w: float64

    @dataclass
    class Wrench(IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
        force: Vector3
        torque: Vector3

    @dataclass
    class WrenchStamped(IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
        header: RosHeader
        wrench: Wrench

    @dataclass
    class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
        position: Point
        orientation: Quaternion

    @dataclass
    class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
        header: RosHeader
        pose: Pose

    @dataclass
    class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
        linear: Vector3
        angular: Vector3

    @dataclass
    class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
        header: RosHeader
        twist: Twist

    return SimpleNamespace(
        **{
            cls.__name__: cls
            for cls in (
                Time,
                RosHeader,
                Bool,
                Vector3,
                Point,
                Quaternion,
                Wrench,
                WrenchStamped,
                Pose,
                PoseStamped,
                Twist,
                TwistStamped,
            )
        }
    )


def ros_messages(msg: WrenchStamped | RobotCommand | RobotState) -> list[tuple[str, object]]:
    """(suffix of the ROS 2 topic, ROS 2 sample) for one dockhil message."""
    t = ros_types()
    h = msg.header
    header = t.RosHeader(t.Time(*ros_time(h.stamp)), h.frame)

    def vec(v):
        return t.Vector3(v.x, v.y, v.z)

    if isinstance(msg, WrenchStamped):  # no message type derives from it
        return [("", t.WrenchStamped(header, t.Wrench(vec(msg.wrench.force), vec(msg.wrench.torque))))]
    p, q, tw = msg.pose.position, msg.pose.orientation, msg.twist
    pose = t.Pose(t.Point(p.x, p.y, p.z), t.Quaternion(q.x, q.y, q.z, q.w))
    return [
        ("", t.PoseStamped(header, pose)),
        ("/twist", t.TwistStamped(header, t.Twist(vec(tw.linear), vec(tw.angular)))),
    ]


def ros_sample_types(cls: type) -> list[tuple[str, type]]:
    """(suffix of the ROS 2 topic, ROS 2 type) that `ros_messages` makes of a message of type `cls`."""
    t = ros_types()
    if cls is WrenchStamped:
        return [("", t.WrenchStamped)]
    return [("", t.PoseStamped), ("/twist", t.TwistStamped)]


def ros2_qos():
    """ROS 2's default QoS (rmw_qos_profile_default: reliable, volatile, keep last 10) in plain CDR (XCDR1),
    as rmw_cyclonedds_cpp writes and reads it; a write never waits (max_blocking_time 0)."""
    from cyclonedds.qos import Policy, Qos

    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=0),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(10),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )


class Ros2Bridge(Node):
    """Writes chosen topics to a ROS 2 domain over DDS (ROS 2's names, types and QoS); a ROS 2 /estop holds the robot."""

    params = {
        "topics": Param(
            list,
            ["/ft/wrench", "/robot/command", "/robot/state"],
            help="topics to write to ROS 2: the graph's /ft/wrench, /robot/command, "
            "/robot/command/delayed, /robot/state, or any topic as 'topic:Type'",
        ),
        "domain_id": Param(int, 0, help="ROS 2 domain (ROS_DOMAIN_ID)", ge=0, le=DOMAIN_MAX),
    }
    outputs = {"estop": Output(EStop, "/estop", help="active from the first ROS 2 /estop data: true on")}

    @classmethod
    def ports(cls, params):
        if importlib.util.find_spec("cyclonedds") is None:  # refused before anything runs; nothing imported
            raise DockhilError(NEEDS)
        inputs = {
            topic: Input(t, topic, required=False, max_age=math.inf, help="written to ROS 2 as it comes")
            for topic, t in bridged_topics(params["topics"]).items()
        }
        return inputs, cls.outputs

    def setup(self):
        try:
            from cyclonedds.core import DDSException
            from cyclonedds.domain import DomainParticipant
            from cyclonedds.pub import DataWriter
            from cyclonedds.sub import DataReader
            from cyclonedds.topic import Topic
        except ImportError:
            raise DockhilError(NEEDS) from None
        self.DDSException = DDSException
        self.topics = bridged_topics(self.p.topics)
        try:
            self.participant = DomainParticipant(self.p.domain_id)
            qos = ros2_qos()
            self.writers: dict[str, list[DataWriter]] = {}
            for topic, cls in self.topics.items():
                self.writers[topic] = [
                    DataWriter(
                        self.participant, Topic(self.participant, f"rt{topic}{suffix}", ros_type, qos=qos), qos=qos
                    )
                    for suffix, ros_type in ros_sample_types(cls)
                ]
            self.estop_reader = DataReader(
                self.participant, Topic(self.participant, "rt/estop", ros_types().Bool, qos=qos), qos=qos
            )
        except DDSException as exc:
            raise DockhilError(
                f"node {self.ctx.name!r}: cannot join ROS 2 domain {self.p.domain_id} over DDS "
                f"({exc}); check CYCLONEDDS_URI"
            ) from None
        self.last_header: dict[str, Header] = {}
        self.written = 0
        self.dropped = 0
        self.pressed = False  # latched: an e-stop holds until the graph stops

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        for topic, writers in self.writers.items():
            msg = inputs.get(topic)
            if msg is None or self.last_header.get(topic) == msg.header:  # wall time: the latest, once
                continue
            self.last_header[topic] = msg.header
            for writer, (_, sample) in zip(writers, ros_messages(msg)):
                self._write(writer, sample)
        if not self.pressed:  # keep last 10: what came since the last step; InvalidSample has no data
            self.pressed = any(getattr(s, "data", False) is True for s in self.estop_reader.take(N=10))
            if self.pressed:
                self.log(f"ROS 2 /estop data: true on domain {self.p.domain_id}: holding the robot")
        return {"estop": EStop(header=tick.header(), active=True, reason="ROS 2 /estop")} if self.pressed else {}

    def _write(self, writer: "DataWriter", sample: object) -> None:
        try:
            writer.write(sample)
            self.written += 1
        except self.DDSException as exc:
            if exc.code != self.DDSException.DDS_RETCODE_TIMEOUT:
                raise DockhilError(f"node {self.ctx.name!r}: DDS write failed ({exc})") from None
            if not self.dropped:
                self.log("warning: ROS 2 readers acknowledge too slowly: samples are dropped, the graph runs on")
            self.dropped += 1

    def close(self):
        participant = getattr(self, "participant", None)
        if participant is None:
            return
        self.participant = None  # type: ignore[assignment]  # closed: the node holds no participant
        if self.dropped:
            self.log(
                f"warning: {self.dropped} of {self.written + self.dropped} ROS 2 samples dropped (readers too slow)"
            )
        self.writers, self.estop_reader = {}, None  # type: ignore[assignment]  # nor reader
        participant.__del__()  # now, not at garbage collection: ROS 2 readers see the writers leave
