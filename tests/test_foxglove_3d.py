"""Foxglove's 3D panel: /tf (foxglove.FrameTransforms) and /scene (foxglove.SceneUpdate) of a run.

The transforms and entities of hand-worked states are checked number by number (positions,
quaternions applied to vectors with a rotation matrix written here, the force arrow against the
force) and validated with `jsonschema` against the official JSON Schemas of the well-known types;
a bag of a short hil.yaml and hil6.yaml run exported with --foxglove is read back with the `mcap`
library; the live bridge advertises and sends them to a real WebSocket client.
"""

import asyncio
import json
import math
import subprocess
import time

import jsonschema
import msgspec
import pytest
import websockets

from dockhil.bags import foxglove_scene as fs
from dockhil.msgs import BodyState, Header, Pose, Quaternion, RobotState, SatelliteState, Vector3, Wrench, WrenchStamped
from tests.conftest import ROOT, dockhil_cmd, free_port
from tests.support.inprocess import run_main
from tests.test_foxglove import SUBPROTOCOLS, channels, connect, message_data, subscribe, until_subscribed

OFFICIAL = {name: fs.schema(name) for name in fs.DERIVED.values()}


def validate(topic: str, value: dict) -> None:
    schema = OFFICIAL[fs.DERIVED[topic]]
    jsonschema.validators.validator_for(schema)(schema).validate(value)


def matrix(q):
    """The rotation matrix of a unit quaternion (x, y, z, w), written out."""
    x, y, z, w = q
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def apply(q, v):
    return [sum(r[j] * v[j] for j in range(3)) for r in matrix(q)]


def about_z(angle):
    return (0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2))


def state(x1, q1, x2, q2, stamp=1.25):
    return SatelliteState(
        header=Header(stamp=stamp, frame="world"),
        bodies=(
            BodyState("chaser", 750.0, Pose(Vector3(*x1), Quaternion(*q1))),
            BodyState("target", 1e6, Pose(Vector3(*x2), Quaternion(*q2))),
        ),
    )


def xyz(d):
    return [d["x"], d["y"], d["z"]]


def xyzw(d):
    return [d["x"], d["y"], d["z"], d["w"]]


def test_the_frames_and_the_force_arrow_of_a_tilted_6dof_contact():
    theta = 0.3  # the chaser turned about z; the sensor turned 90 deg about z in B
    sensor_q = about_z(math.pi / 2)
    geometry = fs.Geometry((1.0, 0.0, 0.0), (0, 0, 0, 1), (-2.0, 0.0, 0.0), (0, 0, 0, 1), (0.0, 0.0, 0.1), sensor_q)
    target_q = about_z(-0.2)
    s = state((-1.0, 0.05, 0.0), about_z(theta), (2.0, 0.0, 0.0), target_q)
    # On the target, in the sensor's axes: -30 N along the sensor's y, which is B's -x... turned by the target.
    wrench = WrenchStamped(header=Header(stamp=1.25, frame="ft_sensor"), wrench=Wrench(Vector3(0.0, -30.0, 4.0)))
    robot = RobotState(
        header=Header(stamp=1.25, frame="target_interface"),
        pose=Pose(Vector3(0.002, 0.01, 0.0), Quaternion(*about_z(0.01))),
    )
    out = fs.views(s, wrench, robot, geometry)
    assert set(out) == {"/tf", "/scene"}
    for topic, value in out.items():
        validate(topic, value)

    tf = {(t["parent_frame_id"], t["child_frame_id"]): t for t in out["/tf"]["transforms"]}
    assert set(tf) == {
        ("world", "chaser"),
        ("world", "target"),
        ("chaser", "probe"),
        ("target", "target_interface"),
        ("target_interface", "ft_sensor"),
        ("target_interface", "robot_probe"),
    }
    for t in tf.values():
        assert t["timestamp"] == {"sec": 1, "nsec": 250_000_000}
    assert xyz(tf["world", "chaser"]["translation"]) == [-1.0, 0.05, 0.0]
    assert xyzw(tf["world", "chaser"]["rotation"]) == pytest.approx(about_z(theta), abs=1e-15)
    assert xyzw(tf["world", "target"]["rotation"]) == pytest.approx(target_q, abs=1e-15)
    assert xyz(tf["chaser", "probe"]["translation"]) == [1.0, 0.0, 0.0]
    assert xyz(tf["target", "target_interface"]["translation"]) == [-2.0, 0.0, 0.0]
    assert xyz(tf["target_interface", "ft_sensor"]["translation"]) == [0.0, 0.0, 0.1]
    assert xyzw(tf["target_interface", "ft_sensor"]["rotation"]) == pytest.approx(sensor_q)
    assert xyz(tf["target_interface", "robot_probe"]["translation"]) == [0.002, 0.01, 0.0]

    entities = {e["id"]: e for e in out["/scene"]["entities"]}
    assert {"chaser", "target", "probe", "drogue", "contact_force"} <= set(entities)
    assert entities["probe"]["frame_id"] == "probe" and entities["drogue"]["frame_id"] == "target_interface"
    cone = entities["probe"]["cylinders"][0]
    assert (cone["bottom_scale"], cone["top_scale"]) == (1.0, 0.0)
    # The cone's axis (its z) is A's +x, and its tip (centre + z * length/2) is A's origin.
    axis = apply(xyzw(cone["pose"]["orientation"]), [0.0, 0.0, 1.0])
    assert axis == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)
    tip = [c + a * cone["size"]["z"] / 2 for c, a in zip(xyz(cone["pose"]["position"]), axis)]
    assert tip == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)

    force = entities["contact_force"]
    assert force["frame_id"] == "world" and len(force["arrows"]) == 1
    arrow = force["arrows"][0]
    # The probe tip in the world: the chaser's CoM plus its turned interface offset.
    assert xyz(arrow["pose"]["position"]) == pytest.approx([-1.0 + math.cos(theta), 0.05 + math.sin(theta), 0.0])
    # The force on the chaser, in the world: minus the target's R_target R_B R_sensor f.
    on_target = apply(target_q, apply(sensor_q, [0.0, -30.0, 4.0]))
    expected = [-f for f in on_target]
    magnitude = math.sqrt(30.0**2 + 4.0**2)
    assert arrow["shaft_length"] + arrow["head_length"] == pytest.approx(magnitude * fs.FORCE_SCALE)
    direction = apply(xyzw(arrow["pose"]["orientation"]), [1.0, 0.0, 0.0])
    assert direction == pytest.approx([f / magnitude for f in expected], abs=1e-12)
    assert expected[0] < -29  # pushed back, against its approach along +x
    assert force["texts"][0]["text"] == f"{magnitude:.1f} N"


def test_a_1dof_state_has_its_interfaces_at_the_coms_and_the_force_along_x():
    s = state((0.004, 0.0, 0.0), (0, 0, 0, 1), (0.0, 0.0, 0.0), (0, 0, 0, 1), stamp=0.5)
    wrench = WrenchStamped(header=Header(stamp=0.5, frame="probe"), wrench=Wrench(Vector3(-12.0)))
    out = fs.views(s, wrench)
    for topic, value in out.items():
        validate(topic, value)
    tf = {t["child_frame_id"]: t for t in out["/tf"]["transforms"]}
    assert "robot_probe" not in tf  # no robot state yet
    assert xyz(tf["probe"]["translation"]) == [0.0, 0.0, 0.0]
    assert xyz(tf["target_interface"]["translation"]) == [0.0, 0.0, 0.0]
    arrow = next(e for e in out["/scene"]["entities"] if e["id"] == "contact_force")["arrows"][0]
    assert xyz(arrow["pose"]["position"]) == [0.004, 0.0, 0.0]
    assert arrow["shaft_length"] + arrow["head_length"] == pytest.approx(0.12)
    assert apply(xyzw(arrow["pose"]["orientation"]), [1, 0, 0]) == pytest.approx([-1.0, 0.0, 0.0], abs=1e-12)
    # Out of contact the force entity is still sent, empty: it replaces the arrow, which goes away.
    apart = fs.views(s, WrenchStamped(header=Header(frame="probe")))
    force = next(e for e in apart["/scene"]["entities"] if e["id"] == "contact_force")
    assert force["arrows"] == [] and force["texts"] == []


def test_the_official_schemas_refuse_what_foxglove_would_not_read():
    out = fs.views(state((0, 0, 0), (0, 0, 0, 1), (0, 0, 0), (0, 0, 0, 1)))
    bad = json.loads(json.dumps(out["/scene"]))
    del bad["entities"][0]["frame_locked"]
    with pytest.raises(jsonschema.ValidationError):
        validate("/scene", bad)
    bad = json.loads(json.dumps(out["/tf"]))
    bad["transforms"][0]["timestamp"]["nsec"] = 1_000_000_000
    with pytest.raises(jsonschema.ValidationError):
        validate("/tf", bad)


def test_the_geometry_of_a_scene_is_its_dynamics_node_mounting():
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    six = fs.geometry_of(build(launchfile.load("launch/hil6.yaml", {})))
    assert six == fs.Geometry.six_dof_defaults()
    assert six.interface1 == (1.0, 0.0, 0.0) and six.interface2 == (-2.0, 0.0, 0.0)
    assert fs.geometry_of(build(launchfile.load("launch/hil.yaml", {}))) == fs.Geometry()


# --------------------------------------------------------------------------- bags


@pytest.mark.parametrize("scene", ["launch/hil.yaml", "launch/hil6.yaml"])
def test_an_exported_bag_has_tf_and_scene_channels_whose_messages_validate(tmp_path, scene):
    from mcap.reader import make_reader

    bag, copy = tmp_path / "run.mcap", tmp_path / "fox.mcap"
    run = subprocess.run(
        dockhil_cmd("launch", scene, "--quiet", "--composed", "--duration", "0.2", "--bag", bag),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    code, out, err = run_main("bag", "export", bag, "--foxglove", copy, "--scene", scene)
    assert code == 0, err

    def read(path):
        with open(path, "rb") as f:
            return [
                (
                    channel.topic,
                    schema.name,
                    schema.encoding,
                    json.loads(schema.data) if schema.data else None,
                    channel.message_encoding,
                    message.log_time,
                    message.data,
                )
                for schema, channel, message in make_reader(f).iter_messages(log_time_order=False)
            ]

    original, exported = read(bag), read(copy)
    derived = [m for m in exported if m[0] in ("/tf", "/scene")]
    # The run's own messages are copied as they are, in their order.
    assert [m for m in exported if m[0] not in ("/tf", "/scene")] == original
    states = [m[5] for m in original if m[0] == "/satellite/state"]
    assert len(states) == 201
    for topic in ("/tf", "/scene"):
        got = [m for m in derived if m[0] == topic]
        assert [m[5] for m in got] == states  # one at each state, at its log time
        _, name, encoding, schema, message_encoding, _, _ = got[0]
        assert (name, encoding, message_encoding) == (fs.DERIVED[topic], "jsonschema", "json")
        assert schema == OFFICIAL[name]
        for m in got:
            validate(topic, json.loads(m[6]))
    # The docking starts in contact: a force arrow is drawn, as long as the measured force says.
    wrenches = [json.loads(m[6])["wrench"]["force"] for m in original if m[0] == "/ft/wrench"]
    last = json.loads([m for m in derived if m[0] == "/scene"][-1][6])
    arrow = next(e for e in last["entities"] if e["id"] == "contact_force")["arrows"][0]
    f = wrenches[-1]
    assert arrow["shaft_length"] + arrow["head_length"] == pytest.approx(
        math.sqrt(f["x"] ** 2 + f["y"] ** 2 + f["z"] ** 2) * fs.FORCE_SCALE
    )
    assert "messages and 402 /tf and /scene messages written" in out


def test_export_refusals_are_one_line(tmp_path):
    from dockhil.bags.writer import BagWriter

    bag = tmp_path / "no_state.mcap"
    with BagWriter(bag) as w:
        w.add_topic("/ft/wrench", "dockhil/WrenchStamped")
    code, _, err = run_main("bag", "export", bag, "--foxglove", tmp_path / "out.mcap")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "no /satellite/state" in err, err
    code, _, err = run_main("bag", "export", bag, "--csv", tmp_path / "x.csv", "--scene", "launch/hil.yaml")
    assert code == 2 and "--scene is for --foxglove" in err, err


# --------------------------------------------------------------------------- the live bridge


def test_a_viewer_that_connects_while_the_bridge_starts_can_subscribe_to_every_channel_it_is_told_of(monkeypatch):
    """A viewer that connects the moment the server listens: each channel advertised to it is one its
    session knows (a server that listened while its channels were still being added told viewers of some
    it then refused to subscribe them to, 'Unknown channel ID'). Each channel here takes 3 ms to make, as
    on a busy machine."""
    import threading

    import foxglove

    from dockhil.bags.foxglove import FoxgloveBridge

    make_channel = foxglove.Channel

    def slow_channel(*args, **kwargs):
        time.sleep(0.003)
        return make_channel(*args, **kwargs)

    monkeypatch.setattr(foxglove, "Channel", slow_channel)

    topics = {
        "/satellite/state": "dockhil/SatelliteState",
        "/ft/wrench": "dockhil/WrenchStamped",
        "/robot/state": "dockhil/RobotState",
        "/robot/command": "dockhil/RobotCommand",
    }

    async def view(port: int, starter):
        starter.start()
        while True:  # at once, as a viewer retrying does
            try:
                ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, max_size=None)
                break
            except (OSError, websockets.exceptions.InvalidHandshake):
                await asyncio.sleep(0.0005)
        try:
            found = await channels(ws, [*topics, "/tf", "/scene"])
            await subscribe(ws, {i: channel["id"] for i, channel in enumerate(found.values())})
            try:
                return json.loads(await asyncio.wait_for(ws.recv(), 0.3))  # a refusal comes at once
            except TimeoutError:
                return None
        finally:
            await ws.close()

    for _ in range(12):
        port = free_port()
        started: list = []
        starter = threading.Thread(
            target=lambda p=port, out=started: out.append(FoxgloveBridge(topics, sim=True, port=p, log=lambda _: None))
        )
        refused = asyncio.run(view(port, starter))
        starter.join()
        started[0].close()
        assert refused is None, refused


def test_the_live_bridge_announces_and_sends_tf_and_scene():
    from dockhil.bags.foxglove import FoxgloveBridge

    topics = {
        "/satellite/state": "dockhil/SatelliteState",
        "/ft/wrench": "dockhil/WrenchStamped",
        "/robot/state": "dockhil/RobotState",
    }
    port = free_port()
    lines = []
    bridge = FoxgloveBridge(topics, sim=True, port=port, log=lines.append, geometry=fs.Geometry.six_dof_defaults())
    s = state((-1.0, 0.05, 0.0), about_z(0.02), (2.0, 0.0, 0.0), (0, 0, 0, 1), stamp=0.003)
    wrench = WrenchStamped(header=Header(stamp=0.003, tick=3, frame="ft_sensor"), wrench=Wrench(Vector3(25.0)))

    async def view():
        ws = await connect(port)
        try:
            found = await channels(ws, ["/tf", "/scene", *topics])
            for topic, name in fs.DERIVED.items():
                assert (found[topic]["schemaName"], found[topic]["schemaEncoding"], found[topic]["encoding"]) == (
                    name,
                    "jsonschema",
                    "json",
                )
                assert json.loads(found[topic]["schema"]) == OFFICIAL[name]
            # Only the 3D view is watched: the bridge still reads its sources.
            await subscribe(ws, {1: found["/tf"]["id"], 2: found["/scene"]["id"]})
            await until_subscribed(*bridge.derived.values())
            assert bridge._wanted() == set(topics)
            # Multi-process: wire bytes as they come off the bus; composed: the message itself.
            bridge.serve(
                [[b"/ft/wrench", msgspec.msgpack.encode(wrench)], [b"/satellite/state", msgspec.msgpack.encode(s)]]
            )
            first = [await message_data(ws) for _ in range(2)]
            bridge.tap("/satellite/state", msgspec.structs.replace(s, header=Header(stamp=0.004, tick=4)))
            return first + [await message_data(ws) for _ in range(2)]
        finally:
            await ws.close()

    try:
        got = asyncio.run(view())
    finally:
        bridge.close()
    by_sub = {1: "/tf", 2: "/scene"}
    assert sorted((sub, log_ns) for sub, log_ns, _ in got) == [
        (1, 3_000_000),
        (1, 4_000_000),
        (2, 3_000_000),
        (2, 4_000_000),
    ]
    expected = fs.views(s, wrench, None, fs.Geometry.six_dof_defaults())
    for sub, log_ns, payload in got:
        value = json.loads(payload)
        validate(by_sub[sub], value)
        if log_ns == 3_000_000:
            assert value == expected[by_sub[sub]]  # the same computation as the bag's
    assert "and /tf, /scene" in lines[0]
    assert bridge.sent == 4 and bridge.unencodable == 0  # the raw topics had no viewer: none sent


# --------------------------------------------------------------------------- the layout


def test_the_layout_has_a_3d_panel_on_tf_and_scene_and_the_raw_topics():
    code, out, err = run_main("foxglove", "layout")
    assert code == 0, err
    layout = json.loads(out)

    def panels(node):
        return [node] if isinstance(node, str) else panels(node["first"]) + panels(node["second"])

    shown = panels(layout["layout"])
    assert sorted(shown) == sorted(layout["configById"])
    three_d = [p for p in shown if p.startswith("3D!")]
    assert len(three_d) == 1
    config = layout["configById"][three_d[0]]
    assert config["followTf"] == "world"
    assert {"/tf", "/scene"} <= {t for t, c in config["topics"].items() if c["visible"]}
    raw = [layout["configById"][p] for p in shown if p.startswith("RawMessages!")]
    assert raw and raw[0]["topicPath"] == "/ft/wrench"
    plotted = {path["value"] for p in shown if p.startswith("Plot!") for path in layout["configById"][p]["paths"]}
    assert "/ft/wrench.wrench.force.x" in plotted and "/satellite/state.bodies[0].twist.linear.x" in plotted


def test_a_launched_6dof_run_serves_the_3d_view_to_a_viewer_of_tf_alone(tmp_path):
    """Multi-process: the bridge reads the state and the robot state for a viewer who only asked
    for /tf, and draws with the scene's mounting (hil6.yaml's)."""
    from tests.test_foxglove import view_then_finish

    port = free_port()
    out = open(tmp_path / "launch.out", "w+")
    proc = subprocess.Popen(
        dockhil_cmd("launch", "launch/hil6.yaml", "--quiet", "--duration", "600", "--foxglove", str(port)),
        cwd=ROOT,
        stdout=out,
        stderr=subprocess.STDOUT,
        text=True,
    )

    async def view():
        ws = await connect(port, proc)
        try:
            found = await channels(ws, ["/tf"])
            await subscribe(ws, {5: found["/tf"]["id"]})
            # Until the robot's state has come too: it starts after the robot's 32 ms delay, and the
            # bridge's subscription to it may reach its publisher after the one to the state.
            got, deadline = [], time.monotonic() + 60
            while len(got) < 20 or "robot_probe" not in got[-1][2].decode():
                assert time.monotonic() < deadline, "no /tf with robot_probe"
                got.append(await message_data(ws))
            return got
        finally:
            await ws.close()

    got, code, text = view_then_finish(view(), proc, out, interrupt=True)
    assert code == 130 and "Traceback" not in text, text
    ticks = []
    for _, log_ns, payload in got:
        value = json.loads(payload)
        validate("/tf", value)
        tf = {t["child_frame_id"]: t for t in value["transforms"]}
        assert tf["chaser"]["timestamp"] == {"sec": log_ns // 10**9, "nsec": log_ns % 10**9}
        assert xyz(tf["probe"]["translation"]) == [1.0, 0.0, 0.0]  # hil6.yaml: A 1 m ahead of the CoM
        assert xyz(tf["target_interface"]["translation"]) == [-2.0, 0.0, 0.0]
        ticks.append(log_ns)
    assert ticks == sorted(ticks) and len(set(ticks)) == len(ticks)
    # The robot state was read too: A in B where the robot has it.
    assert "robot_probe" in {t["child_frame_id"] for t in json.loads(got[-1][2])["transforms"]}
