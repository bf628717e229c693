"""The live view: `dockhil launch ... --foxglove PORT` serves the running graph to Foxglove.

A real WebSocket client speaks the Foxglove WebSocket protocol to the server
(text ops serverInfo, advertise, subscribe; binary message data: opcode 0x01,
subscription id u32, log time u64, payload), checks the channels against the
graph built from the launch file, and validates every payload against the
channel's advertised JSON Schema with `jsonschema`. The viewer must not change
the run: a run watched (by a viewer that stops reading) gives the same bag and
summary as a run without the bridge.
"""

import asyncio
import json
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import foxglove  # noqa: F401  (a dev dependency: a broken install fails here, never skips)
import jsonschema
import pytest
import websockets

from tests.conftest import ROOT, dockhil_cmd, free_port
from tests.support.inprocess import run_main

SCENE = "launch/hil.yaml"
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]  # foxglove-sdk 0.30; older servers
MESSAGE_DATA = 0x01
DEADLINE_S = 60.0  # generous: the machine may be busy; every wait ends on its condition first


def scene_topics() -> dict[str, str]:
    """topic -> message type name of the scene, from the launch file (not from the bridge)."""
    from dockhil import msgs
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    graph = build(launchfile.load(SCENE, {}))
    return {topic: msgs.type_name(ref.type) for topic, ref in graph.publishers.items()}


def start_launch(tmp_path, *args):
    out = open(tmp_path / "launch.out", "w+")
    proc = subprocess.Popen(
        dockhil_cmd("launch", SCENE, "--quiet", *args), cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, text=True
    )
    return proc, out


def finish(proc, out, *, interrupt: bool) -> tuple[int, str]:
    try:
        if interrupt:
            proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=DEADLINE_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out.seek(0)
    return code, out.read()


def view_then_finish(view, proc, out, *, interrupt: bool):
    """Run a viewer (a coroutine) against a launch, then end the launch: (what the viewer returned, the
    launch's exit code, its output). A viewer that fails says what the launch printed."""
    try:
        got = asyncio.run(view)
    except Exception as exc:
        _code, text = finish(proc, out, interrupt=interrupt)
        raise AssertionError(f"the viewer failed ({exc!r}); the launch printed:\n{text[-3000:]}") from exc
    code, text = finish(proc, out, interrupt=interrupt)
    return got, code, text


# --------------------------------------------------------------------------- a Foxglove WebSocket client


async def connect(port: int, proc=None):
    """Connect as soon as the server listens (a launch process starts it before any node)."""
    deadline = time.monotonic() + DEADLINE_S
    while True:
        try:
            # close_timeout: the server may drop the connection without answering our close frame.
            return await websockets.connect(
                f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, max_size=None, open_timeout=10, close_timeout=0.5
            )
        except (TimeoutError, OSError, websockets.exceptions.InvalidHandshake):
            assert proc is None or proc.poll() is None, (
                f"the launch exited ({proc.returncode}) before its server was reached"
            )
            assert time.monotonic() < deadline, f"no Foxglove server on port {port}"
            await asyncio.sleep(0.05)


async def channels(ws, topics) -> dict[str, dict]:
    """serverInfo first, then advertisements until every topic is there: topic -> channel."""
    first = json.loads(await asyncio.wait_for(ws.recv(), DEADLINE_S))
    assert first["op"] == "serverInfo", first
    found = {}
    while not set(topics) <= set(found):  # other channels may be advertised first
        msg = await asyncio.wait_for(ws.recv(), DEADLINE_S)
        if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
            for channel in json.loads(msg)["channels"]:
                found[channel["topic"]] = channel
    return found


async def subscribe(ws, subscriptions: dict[int, int]) -> None:
    """subscription id -> channel id."""
    await ws.send(
        json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c} for s, c in subscriptions.items()]})
    )


async def until_subscribed(*channels) -> None:
    """Until the server has handed each channel's subscription to it (has_sinks)."""
    deadline = time.monotonic() + DEADLINE_S
    while not all(channel.has_sinks() for channel in channels):
        assert time.monotonic() < deadline, "the subscription never reached the bridge"
        await asyncio.sleep(0.01)


async def message_data(ws):
    """The next binary message-data frame: (subscription id, log time ns, payload)."""
    while True:
        msg = await asyncio.wait_for(ws.recv(), DEADLINE_S)
        if isinstance(msg, bytes):
            assert msg[0] == MESSAGE_DATA, msg[:1]
            sub_id, log_ns = struct.unpack_from("<IQ", msg, 1)
            return sub_id, log_ns, msg[13:]


# --------------------------------------------------------------------------- tests


@pytest.mark.parametrize("mode", [[], ["--composed"]], ids=["processes", "composed"])
def test_a_viewer_sees_every_topic_with_its_schema_and_receives_valid_wrenches(tmp_path, mode):
    # Every topic of the scene, and the 3D view's (tests/test_foxglove_3d.py)
    expected = {**scene_topics(), "/tf": "foxglove.FrameTransforms", "/scene": "foxglove.SceneUpdate"}
    port = free_port()
    # Long enough that the graph still runs when the client is done; stopped with Ctrl-C.
    proc, out = start_launch(tmp_path, "--duration", "600", "--foxglove", str(port), *mode)

    async def view():
        ws = await connect(port, proc)
        try:
            assert ws.subprotocol in SUBPROTOCOLS
            found = await channels(ws, expected)
            assert set(found) == set(expected)
            for topic, channel in found.items():
                assert channel["encoding"] == "json", channel
                assert channel["schemaEncoding"] == "jsonschema", channel
                assert channel["schemaName"] == expected[topic]
                schema = json.loads(channel["schema"])
                assert schema["type"] == "object" and "$ref" not in schema, topic  # self-contained
                jsonschema.Draft202012Validator.check_schema(schema)
            schema = json.loads(found["/ft/wrench"]["schema"])
            await subscribe(ws, {7: found["/ft/wrench"]["id"]})
            got = []
            while len(got) < 200:
                sub_id, log_ns, payload = await message_data(ws)
                assert sub_id == 7
                got.append((log_ns, json.loads(payload)))
            return schema, got
        finally:
            await ws.close()

    (schema, got), code, text = view_then_finish(view(), proc, out, interrupt=True)
    assert code == 130 and "Traceback" not in text, text
    validator = jsonschema.Draft202012Validator(schema)
    for log_ns, message in got:
        validator.validate(message)
        assert message["type"] == "dockhil/WrenchStamped"
        # Sim time t [s] is logged at t * 1e9 ns, as in bags.
        assert log_ns == round(message["header"]["stamp"] * 1e9)
    ticks = [message["header"]["tick"] for _, message in got]
    assert ticks == sorted(ticks) and len(set(ticks)) == len(ticks)
    # The schema is no blank cheque: a force that is not a number is refused.
    bad = json.loads(json.dumps(got[0][1]))
    bad["wrench"]["force"]["x"] = "12 N"
    assert not validator.is_valid(bad)


def test_a_watched_run_gives_the_same_bag_and_summary_as_an_unwatched_one(tmp_path):
    """The bridge observes: sim time does not wait for it, and a viewer that stops reading
    slows nothing. Same bag bit for bit, same summary. The unwatched run is composed (one process,
    a quarter of the CPU time): a multi-process run gives a composed run's bytes (test_hil_graph.py
    holds that), so the watched multi-process run must give them too."""
    from dockhil.bags.reader import BagReader

    args = ["--duration", "1.5"]
    plain = subprocess.run(
        dockhil_cmd(
            "launch",
            SCENE,
            "--quiet",
            *args,
            "--composed",
            "--bag",
            tmp_path / "plain.mcap",
            "--summary",
            tmp_path / "plain.json",
        ),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=DEADLINE_S,
    )
    assert plain.returncode == 0, plain.stderr
    port = free_port()
    proc, out = start_launch(
        tmp_path,
        *args,
        "--bag",
        tmp_path / "watched.mcap",
        "--summary",
        tmp_path / "watched.json",
        "--foxglove",
        str(port),
    )
    topics = scene_topics()

    async def view():
        ws = await connect(port, proc)
        try:
            found = await channels(ws, topics)
            await subscribe(ws, {i: found[t]["id"] for i, t in enumerate(sorted(found))})
            await message_data(ws)  # the bridge serves the run...
            while proc.poll() is None:  # ...and the viewer stops reading until the run is over
                await asyncio.sleep(0.05)
        finally:
            await ws.close()

    _, code, text = view_then_finish(view(), proc, out, interrupt=False)
    assert code == 0, text
    assert "[foxglove] served" in text

    def messages(name):
        with BagReader(tmp_path / name) as bag:
            return sorted((m[0], m[2], bytes(m[3])) for m in bag)

    reference = messages("plain.mcap")
    assert len(reference) > 6 * 1000
    assert messages("watched.mcap") == reference

    def science(name):
        out = json.loads((tmp_path / name).read_text())
        return {k: v for k, v in out.items() if k not in ("run_time_s", "real_time_factor")}

    assert science("watched.json") == science("plain.json")


def wrench(k: int) -> bytes:
    """The wire bytes of a wrench at tick k of a 1 kHz graph, force x = k newtons."""
    import msgspec

    from dockhil.msgs import Header, Vector3, Wrench, WrenchStamped

    return msgspec.msgpack.encode(
        WrenchStamped(header=Header(stamp=k * 0.001, tick=k, seq=k), wrench=Wrench(force=Vector3(x=float(k))))
    )


def test_the_bridge_joins_a_publisher_as_an_observer_and_serves_what_it_sends():
    """Sim time never waits for the bridge: its subscription is a topic prefix, which the
    publisher's start barrier does not count. Each message reaches the viewer once, in
    order, at its sim time; an empty tick does not; bytes that are not a message are counted."""
    import zmq

    from dockhil.bags.foxglove import FoxgloveBridge
    from dockhil.errors import DockhilError
    from dockhil.runtime.transport import OBSERVED, GraphKeys, Publisher, ipc_endpoint, new_run_dir

    keys = GraphKeys.make()
    endpoint = ipc_endpoint(new_run_dir("fox"), "/ft/wrench")
    pub = Publisher(zmq.Context.instance(), "/ft/wrench", endpoint, keys=keys)
    lines = []
    port = free_port()
    bridge = FoxgloveBridge({"/ft/wrench": "dockhil/WrenchStamped"}, sim=True, port=port, log=lines.append)
    n = 50

    async def view():
        ws = await connect(port)
        try:
            found = await channels(ws, ["/ft/wrench"])
            await subscribe(ws, {3: found["/ft/wrench"]["id"]})
            # The bridge subscribes once a viewer wants the topic: what reaches the publisher is its prefix.
            deadline = time.monotonic() + DEADLINE_S
            while not pub.observers.poll(50):  # observers have a socket of their own
                assert time.monotonic() < deadline, "the bridge never subscribed"
                await asyncio.sleep(0)
            assert pub.observers.recv() == b"\x01/ft/wrench" + OBSERVED
            pub.watchers += 1  # as `look` would have, had it read the subscription
            with pytest.raises(DockhilError, match="0 of 1 subscribers"):
                pub.wait_subscribers(1, timeout=0.3)
            pub.observers.send(b"/ft/wrench" + OBSERVED + (0).to_bytes(8, "little") + b"not msgpack")
            for k in range(n):
                pub.send(wrench(k))
                pub.send_empty(k)
            return [await message_data(ws) for _ in range(n)]
        finally:
            await ws.close()

    try:
        bridge.observe({"/ft/wrench": endpoint}, keys)
        got = asyncio.run(view())
    finally:
        bridge.close()
        pub.close()
    assert [(sub_id, log_ns) for sub_id, log_ns, _ in got] == [(3, k * 1_000_000) for k in range(n)]
    assert [json.loads(payload)["wrench"]["force"]["x"] for _, _, payload in got] == list(range(n))
    assert (bridge.sent, bridge.unencodable, bridge.dropped) == (n, 1, 0)
    assert lines[-1] == f"[foxglove] served {n} messages; 1 not encodable as JSON"


def test_a_bridge_that_falls_behind_drops_the_oldest_and_counts_them():
    from dockhil.bags.foxglove import FoxgloveBridge

    lines = []
    port = free_port()
    bridge = FoxgloveBridge({"/ft/wrench": "dockhil/WrenchStamped"}, sim=True, port=port, log=lines.append, burst=4)

    async def view():
        ws = await connect(port)
        try:
            found = await channels(ws, ["/ft/wrench"])
            await subscribe(ws, {1: found["/ft/wrench"]["id"]})
            await until_subscribed(bridge.channels["/ft/wrench"])
            bridge.serve([[b"/ft/wrench", wrench(k)] for k in range(10)])  # one pass found 10 waiting
            return [await message_data(ws) for _ in range(4)]
        finally:
            await ws.close()

    try:
        got = asyncio.run(view())
    finally:
        bridge.close()
    assert [json.loads(payload)["header"]["tick"] for _, _, payload in got] == [6, 7, 8, 9]  # the newest
    assert (bridge.sent, bridge.dropped) == (4, 6)
    assert lines[-1] == "[foxglove] served 4 messages; dropped 6 it could not keep up with"


def test_a_busy_port_is_refused_in_one_line_before_any_node_starts(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        # In this process: a refusal needs no interpreter of its own.
        code, out, err = run_main("launch", SCENE, "--foxglove", port)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert f"127.0.0.1:{port}" in lines[0] and "in use" in lines[0] and "--foxglove PORT" in lines[0]
    assert "[impedance]" not in out + err  # no node ran


@pytest.mark.parametrize(
    "args, says",
    [
        (["--foxglove-host", "0.0.0.0"], "--foxglove-host needs --foxglove"),
        (["--foxglove", "70000"], "not a port number"),
        (["--foxglove", "delay:=0.01"], "put --foxglove after the launch arguments"),
        (["--foxglove", "1", "--foxglove-host", "no-such-host.invalid"], "no-such-host.invalid"),
    ],
)
def test_bad_live_view_options_get_one_line(args, says):
    code, _, err = run_main("launch", SCENE, *args)
    assert code == 2
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1 and says in errors[0], err


def test_a_launch_without_the_live_view_does_not_import_foxglove():
    code = (
        "import sys; from dockhil.commands import launch; from dockhil import session; "
        "from dockhil.runtime import launcher, composed; "
        "print('foxglove' in sys.modules)"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=DEADLINE_S)
    assert r.stdout.strip() == "False", r.stderr


def _resolve(schema: dict, fields: list[str]) -> dict:
    """The schema of a field path such as ["bodies[0]", "pose", "position", "x"]."""
    for field in fields:
        name, _, index = field.partition("[")
        assert name in schema.get("properties", {}), f"no field {name!r}"
        schema = schema["properties"][name]
        if index:
            assert index.rstrip("]").isdigit() and schema["type"] == "array", field
            schema = schema["items"]
    return schema


def test_the_shipped_layout_plots_numbers_the_scene_publishes():
    """The layout `dockhil foxglove layout` prints is a Foxglove layout (configById, layout tree,
    globalVariables, userNodes) whose every plotted message path is a number field of a topic of
    launch/hil.yaml (its 3D panel: tests/test_foxglove_3d.py)."""
    from dockhil import msgs
    from dockhil.bags.writer import channel_schema

    code, out, err = run_main("foxglove", "layout")
    assert code == 0, err
    layout = json.loads(out)
    assert {"configById", "layout", "globalVariables", "userNodes"} <= set(layout)

    def panels(node):
        if isinstance(node, str):
            return [node]
        assert node["direction"] in ("row", "column")
        return panels(node["first"]) + panels(node["second"])

    shown = panels(layout["layout"])
    assert sorted(shown) == sorted(layout["configById"])
    topics = scene_topics()
    plotted = set()
    for panel_id in [p for p in shown if p.startswith("Plot!")]:
        config = layout["configById"][panel_id]
        assert config["xAxisVal"] == "timestamp" and config["paths"]
        for path in config["paths"]:
            topic, *fields = path["value"].split(".")
            assert topic in topics, path["value"]
            leaf = _resolve(channel_schema(msgs.type_by_name(topics[topic])), fields)
            assert leaf["type"] == "number", path["value"]
            plotted.add(path["value"])
    assert "/ft/wrench.wrench.force.x" in plotted
    assert {"/satellite/state.bodies[0].pose.position.x", "/satellite/state.bodies[0].twist.linear.x"} <= plotted


def test_the_end_of_a_run_does_not_wait_for_a_viewer_that_stopped_reading():
    """The server's stop waits for every viewer to take its close; one that stopped reading is given up only
    after about 40 s (foxglove-sdk 0.30). The bridge waits STOP_WAIT_S for it and says so in its last line."""
    from dockhil.bags import foxglove as fg

    lines = []
    bridge = fg.FoxgloveBridge({"/ft/wrench": "dockhil/WrenchStamped"}, sim=True, port=free_port(), log=lines.append)
    server, released = bridge._server, threading.Event()

    class Stalled:  # the SDK's stop with a viewer that never takes its close
        def stop(self):
            released.wait(30.0)

    bridge._server = Stalled()
    began = time.monotonic()
    try:
        bridge.close()
        took = time.monotonic() - began
    finally:
        released.set()
        server.stop()
    assert took < fg.STOP_WAIT_S + 5.0  # the wait, and a busy machine's slack; not the viewer's 30 s
    assert lines[-1].startswith("[foxglove] served 0 messages")
    assert lines[-1].endswith(f"; a viewer that stopped reading was not waited for ({fg.STOP_WAIT_S:g} s)")
