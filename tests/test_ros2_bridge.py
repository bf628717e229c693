"""The ROS 2 bridge seen from a ROS 2 network: a DDS participant of the test's own, with ROS 2's type
names and fields written here, on the loopback interface in a domain of the test's own, reads what
the bridge writes, and a ROS 2 /estop written from DDS holds the robot.

The participant that reads is a process of its own (as `ros2 topic echo` would be), so samples cross
the loopback network rather than Cyclone DDS's in-process shortcut."""

import importlib.util
import json
import random
import subprocess
import sys
import time

import pytest

from dockhil.bags.reader import BagReader
from dockhil.msgs import Header, Pose, Quaternion, RobotCommand, RobotState, Twist, Vector3
from dockhil.msgs import WrenchStamped as DockhilWrench
from dockhil.msgs.codec import decode
from dockhil.nodes.ros2_bridge import LOOPBACK_URI as LOOPBACK  # Cyclone DDS on lo only: nothing leaves this host
from dockhil.testing import NodeHarness, estop, wrench
from tests.conftest import ROOT, dockhil_cmd
from tests.support.inprocess import run_main

HAVE_DDS = importlib.util.find_spec("cyclonedds") is not None
needs_dds = pytest.mark.skipif(
    not HAVE_DDS,
    reason="the cyclonedds binding is not installed (pip install 'dockhil[ros2]'): no DDS to read the bridge with",
)

NEEDS_LINE = "the ROS 2 bridge needs the cyclonedds binding: pip install 'dockhil[ros2]'"

# ROS 2's messages as a ROS 2 node on Cyclone DDS sees them (rosidl's DDS names, fields and field types).
ROS_TYPES = """
from dataclasses import dataclass
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, uint32

@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32

@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
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
    header: Header
    wrench: Wrench

@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion

@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose

@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3

@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
    header: Header
    twist: Twist

from cyclonedds.qos import Policy, Qos

def ros2_default_qos():
    return Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile,
               Policy.History.KeepLast(10), Policy.DataRepresentation(use_cdrv0_representation=True))
"""

# A ROS 2 subscriber of rt/ft/wrench in a process of its own: prints "ready", "matched" once it has
# discovered the bridge's writer, then reads until it has
# `count` samples or nothing came for `idle` s after the first (or `limit` s passed), and prints
# [[sec, nanosec, force.x, arrival s], ...] as JSON. Keep-all history: a sample taken late is not lost
# here, so a count short of what was written is the bridge's or the network's loss.
READER = (
    ROS_TYPES
    + """
import json, sys, time
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

domain, count, idle, limit = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
dp = DomainParticipant(domain)
topic = Topic(dp, "rt/ft/wrench", WrenchStamped, qos=ros2_default_qos())
reader = DataReader(dp, topic, qos=ros2_default_qos() + Qos(Policy.History.KeepAll))
print("ready", flush=True)
end = time.monotonic() + limit
while reader.get_subscription_matched_status().current_count < 1 and time.monotonic() < end:
    time.sleep(0.005)
print("matched", flush=True)  # both sides know each other: what is written from now on is delivered
got, last = [], None
while len(got) < count and time.monotonic() < end and (last is None or time.monotonic() - last < idle):
    now = time.monotonic()
    for s in reader.take(N=4096):
        if hasattr(s, "wrench"):
            got.append([s.header.stamp.sec, s.header.stamp.nanosec, s.wrench.force.x, now])
            last = now
    time.sleep(0.002)
print(json.dumps(got), flush=True)
"""
)


@pytest.fixture
def domain(monkeypatch):
    """A ROS 2 domain of this test's own, on the loopback interface (for this process and its children)."""
    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK)
    return random.randint(1, 232)


@pytest.fixture
def ros():
    """The test's ROS 2 types and a participant factory, in this process."""
    from types import SimpleNamespace

    space: dict = {}
    exec(compile(ROS_TYPES, "<ROS_TYPES>", "exec"), space)
    return SimpleNamespace(**space)


def start_reader(domain: int, count: int, idle: float, limit: float) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", READER, str(domain), str(count), str(idle), str(limit)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
    return proc


def reader_result(proc: subprocess.Popen, timeout: float) -> list:
    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


def wait_matched(writer, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while writer.get_publication_matched_status().current_count < 1:
        assert time.monotonic() < end, "the test's ROS 2 reader never matched the bridge's writer"
        time.sleep(0.01)


def ros_ns(stamp: float) -> int:
    return round(stamp * 1e9)


# -- what the bridge writes -------------------------------------------------------------------------


@needs_dds
def test_each_topic_reaches_ros2_with_its_names_fields_and_values(domain, ros):
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    dp = DomainParticipant(domain)
    wanted = {
        "rt/ft/wrench": ros.WrenchStamped,
        "rt/robot/command": ros.PoseStamped,
        "rt/robot/command/twist": ros.TwistStamped,
        "rt/robot/state": ros.PoseStamped,
        "rt/robot/state/twist": ros.TwistStamped,
    }
    readers = {
        name: DataReader(dp, Topic(dp, name, t, qos=ros.ros2_default_qos()), qos=ros.ros2_default_qos())
        for name, t in wanted.items()
    }
    pose = Pose(Vector3(0.01, -0.02, 0.03), Quaternion(0.0, 0.0, 0.38268343236508984, 0.9238795325112867))
    twist = Twist(Vector3(0.03, 0.0, -0.001), Vector3(0.0, 0.01, 0.0))
    with NodeHarness("ros2_bridge", dt=0.001, sim_time=False, domain_id=domain) as h:
        for writers in h.node.writers.values():
            for writer in writers:
                wait_matched(writer)
        h.step(
            inputs={
                "/ft/wrench": wrench(fx=12.5, fy=-1.0, tz=0.25),
                "/robot/command": RobotCommand(Header(frame="target"), pose=pose, twist=twist),
                "/robot/state": RobotState(Header(frame="target"), pose=pose, twist=twist),
            },
            t=1.25,
        )
        got = {}
        end = time.monotonic() + 10.0
        while len(got) < len(readers) and time.monotonic() < end:
            for name, reader in readers.items():
                for sample in reader.take(N=10):
                    if hasattr(sample, "header"):
                        got[name] = sample  # the last one read
            time.sleep(0.01)
    assert set(got) == set(readers)
    w = got["rt/ft/wrench"]
    assert (w.header.stamp.sec, w.header.stamp.nanosec) == (1, 250_000_000)
    assert (w.wrench.force.x, w.wrench.force.y, w.wrench.force.z) == (12.5, -1.0, 0.0)
    assert (w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z) == (0.0, 0.0, 0.25)
    for topic in ("rt/robot/command", "rt/robot/state"):
        p = got[topic]
        assert p.header.frame_id == "target" and (p.header.stamp.sec, p.header.stamp.nanosec) == (1, 250_000_000)
        assert (p.pose.position.x, p.pose.position.y, p.pose.position.z) == (0.01, -0.02, 0.03)
        q = p.pose.orientation
        assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.38268343236508984, 0.9238795325112867)
        t = got[f"{topic}/twist"].twist
        assert (t.linear.x, t.linear.z, t.angular.y) == (0.03, -0.001, 0.01)


@needs_dds
@pytest.mark.wall_time
def test_ft_wrench_reaches_a_ros2_reader_at_the_graphs_rate_for_10_s_with_none_lost(domain):
    # The bridge steps at 1 kHz on real time for 10 s, a new wrench each tick, as in a wall-time graph;
    # a reader in another process must get every one of them, in order, while the stream runs.
    dt, n = 0.001, 10_000
    reader = start_reader(domain, n, idle=5.0, limit=120.0)
    try:
        with NodeHarness("ros2_bridge", dt=dt, sim_time=False, domain_id=domain, topics=["/ft/wrench"]) as h:
            wait_matched(h.node.writers["/ft/wrench"][0])
            assert reader.stdout.readline().strip() == "matched"
            t0 = time.monotonic()
            for k in range(n):
                ahead = t0 + k * dt - time.monotonic()
                if ahead > 0:
                    time.sleep(ahead)
                h.step(inputs={"/ft/wrench": wrench(fx=float(k))})
            elapsed = time.monotonic() - t0
            written, dropped = h.node.written, h.node.dropped
            got = reader_result(reader, timeout=60.0)
    finally:
        reader.kill()
        reader.wait()
    assert elapsed >= 10.0 - dt
    assert (written, dropped) == (n, 0)
    assert [int(s[2]) for s in got] == list(range(n)), f"lost {n - len(got)} of {n}"
    assert [s[0] * 1_000_000_000 + s[1] for s in got] == [ros_ns(k * dt) for k in range(n)]
    # Live: the reader had the samples as they were written, not in a burst at the end.
    span = got[-1][3] - got[0][3]
    assert span >= 0.9 * elapsed - 0.5, (span, elapsed)


@needs_dds
@pytest.mark.wall_time
def test_a_wall_time_hil_run_with_ros2_true_writes_every_wrench_it_published(domain, tmp_path):
    # The shipped scene, composed, in wall time: every /ft/wrench the graph published (its bag) after the
    # reader matched reaches the reader, in order, with the header's stamp.
    bag = tmp_path / "run.mcap"
    reader = start_reader(domain, 10**6, idle=3.0, limit=120.0)
    try:
        run = subprocess.run(
            dockhil_cmd(
                "launch",
                ROOT / "launch/hil.yaml",
                "--wall-time",
                "--composed",
                "--quiet",
                "--duration",
                "5",
                "--bag",
                bag,
                "ros2:=true",
                f"ros_domain_id:={domain}",
            ),
            capture_output=True,
            text=True,
            timeout=180,
            cwd=str(ROOT),
        )
        got = reader_result(reader, timeout=60.0)
    finally:
        reader.kill()
        reader.wait()
    assert run.returncode in (0, 3), run.stderr  # 3: INVALID (fell behind real time on a busy machine)
    with BagReader(str(bag)) as r:
        published = [
            ros_ns(decode(data, DockhilWrench).header.stamp) for topic, _, _, data in r if topic == "/ft/wrench"
        ]
    received = [s[0] * 1_000_000_000 + s[1] for s in got]
    assert len(published) > 1000 and received, (len(published), len(received))
    first = published.index(received[0])  # before the reader matched, a volatile topic sends nothing
    assert received == published[first:], f"lost {len(published) - first - len(received)} after the match"
    assert first < len(published) // 2


# -- the ROS 2 /estop ----------------------------------------------------------------------------------


def estop_writer(ros, domain):
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    dp = DomainParticipant(domain)
    return dp, DataWriter(dp, Topic(dp, "rt/estop", ros.Bool, qos=ros.ros2_default_qos()), qos=ros.ros2_default_qos())


@needs_dds
def test_a_ros2_estop_true_is_dockhils_active_estop_from_then_on_and_false_releases_nothing(domain, ros):
    _, writer = estop_writer(ros, domain)
    with NodeHarness("ros2_bridge", dt=0.001, sim_time=False, domain_id=domain, topics=[]) as h:
        wait_matched(writer)
        writer.write(ros.Bool(False))
        time.sleep(0.2)
        assert h.step() == {}  # false alone holds nothing
        writer.write(ros.Bool(True))
        end = time.monotonic() + 10.0
        out = h.step()
        while "estop" not in out:
            assert time.monotonic() < end, "the bridge never turned the ROS 2 /estop into an EStop"
            time.sleep(0.005)
            out = h.step()
        assert out["estop"].active and out["estop"].reason == "ROS 2 /estop"
        writer.write(ros.Bool(False))
        time.sleep(0.2)
        assert all(h.step()["estop"].active for _ in range(3))  # latched: every step, until the graph stops
        assert any("ROS 2 /estop" in line for line in h.logs)


@pytest.mark.parametrize("node", ["robot_sim", "robot_sim6"])
def test_the_simulated_robot_holds_on_an_active_estop_with_the_drivers_line(node):
    from dockhil.errors import SafetyStop

    with NodeHarness(node, dt=0.001) as h:
        command = RobotCommand(Header(), pose=Pose(Vector3(0.001)))
        assert "state" in h.step(inputs={"command": command, "estop": estop(active=False)})
        h.step(inputs={"command": command, "estop": estop(reason="ROS 2 /estop")})  # read one tick later
        with pytest.raises(SafetyStop) as stop:
            h.step(inputs={"command": command})
    assert str(stop.value) == "safety stop: estop: e-stop active (ROS 2 /estop); simulated robot held"
    assert stop.value.limit == "estop"


@needs_dds
@pytest.mark.wall_time
def test_one_ros2_estop_line_holds_the_robot_of_a_running_hil_scene(domain, ros):
    # `ros2 topic pub --once /estop std_msgs/msg/Bool "{data: true}"`, as one DDS write of the test's own.
    launch = subprocess.Popen(
        dockhil_cmd(
            "launch",
            ROOT / "launch/hil.yaml",
            "--wall-time",
            "--composed",
            "--duration",
            "60",
            "ros2:=true",
            f"ros_domain_id:={domain}",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=str(ROOT),
    )
    try:
        _, writer = estop_writer(ros, domain)
        wait_matched(writer, timeout=60.0)
        time.sleep(0.5)  # the run is under way
        pressed = time.monotonic()
        writer.write(ros.Bool(True))
        out, err = launch.communicate(timeout=30)
        took = time.monotonic() - pressed
    finally:
        launch.kill()
        launch.wait()
    assert launch.returncode == 1, err
    lines = [line for line in err.splitlines() if "estop" in line]
    assert any("safety stop: estop: e-stop active (ROS 2 /estop); simulated robot held" in line for line in lines), err
    assert took < 20.0


# -- refusals and leanness -------------------------------------------------------------------------


def test_without_the_binding_ros2_true_is_refused_in_one_line_before_anything_runs(monkeypatch):
    monkeypatch.setitem(sys.modules, "cyclonedds", None)  # as if not installed: find_spec and import fail
    for argv in (
        ("launch", ROOT / "launch/hil.yaml", "--composed", "--duration", "0.01", "ros2:=true"),
        ("graph", ROOT / "launch/hil6.yaml", "ros2:=true"),
    ):
        code, out, err = run_main(*argv)
        assert code == 2, (argv, err)
        assert err.strip().splitlines() == [f"dockhil {argv[0]}: error: {NEEDS_LINE}"], err
    code, _, err = run_main("launch", ROOT / "launch/hil.yaml", "--composed", "--quiet", "--duration", "0.01")
    assert code == 0, err  # without ros2:=true the scene needs no binding


@pytest.mark.skipif(not HAVE_DDS, reason="the parameters are checked after the binding")
@pytest.mark.parametrize(
    "override, says",
    [
        ("ros_domain_id:=233", "'domain_id': 233 is out of range, must be <= 232"),
        ("ros_domain_id:=-1", "'domain_id': -1 is out of range, must be >= 0"),
    ],
)
def test_a_domain_outside_ros2s_range_is_refused(override, says):
    code, _, err = run_main("graph", ROOT / "launch/hil.yaml", "ros2:=true", override)
    assert code == 2 and says in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize(
    "topics, says",
    [
        (["/ft/wrench", "/satellite/state"], "'/satellite/state' is not one of the graph's topics"),
        (["ft/wrench"], "'ft/wrench' is not a ROS 2 topic name"),
        (["/my/force:BodyWrenches"], "the bridge writes WrenchStamped, RobotCommand, RobotState, not 'BodyWrenches'"),
        (["/estop"], "/estop is the ROS 2 e-stop the bridge reads"),
        ("/ft/wrench", "expected list"),
    ],
)
def test_a_topic_the_bridge_cannot_write_is_refused_in_one_line(topics, says):
    from dockhil.errors import DockhilError
    from dockhil.nodes.ros2_bridge import Ros2Bridge, bridged_topics

    with pytest.raises(DockhilError) as err:
        Ros2Bridge.resolve_params("ros2", {"topics": topics})
        bridged_topics(topics)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_topic_of_another_name_is_written_with_the_type_given():
    from dockhil.nodes.ros2_bridge import bridged_topics

    assert bridged_topics(["/lab/ft:WrenchStamped", "/robot/state"]) == {
        "/lab/ft": DockhilWrench,
        "/robot/state": RobotState,
    }


@needs_dds
def test_the_bridge_loads_cyclonedds_at_setup_and_within_a_nodes_memory_budget():
    from dockhil.analysis import leanness
    from tests.test_lean_imports import NODE_BUDGET_MB

    with __import__("tempfile").TemporaryDirectory() as tmp:
        spec = leanness.setup_specs(tmp)["ros2_bridge"]
    row = leanness.measure("ros2_bridge", spec)
    bare = leanness.measure("module:json")
    assert row["setup"] == "ok", row
    assert "cyclonedds" not in row["after_import"] and "cyclonedds" in row["after_setup"], row
    assert row["rss_mb"] - bare["rss_mb"] <= NODE_BUDGET_MB, row
