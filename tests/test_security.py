"""Only this graph commands this robot: a private runtime directory, CURVE on every endpoint,
one graph per device. Every fault is injected here: a foreign socket on a graph's ipc path,
strangers on its tcp ports, a second graph on the same controller or adapter, a runtime
directory of the wrong mode or owner."""

from __future__ import annotations

import json
import os
import re
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zmq

from dockhil import msgs
from dockhil.errors import DeviceError, DockhilError
from dockhil.msgs.codec import decode, encode
from dockhil.runtime.transport import GraphKeys, Publisher, Subscriber, runtime_dir
from tests.conftest import ROOT, dockhil_cmd, free_port, registered
from tests.support.inprocess import run_main

READY = "\x1edockhil-ready"


def env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in text, text
    return lines[0]


def mode(path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


def command(y: float, tick: int = 0) -> msgs.RobotCommand:
    return msgs.RobotCommand(header=msgs.Header(tick=tick), pose=msgs.Pose(position=msgs.Vector3(y=y)), enable=True)


# --------------------------------------------------------------------------- the runtime directory


def test_runtime_directory_is_made_private(monkeypatch, tmp_path):
    d = tmp_path / "rt"
    monkeypatch.setenv("DOCKHIL_RUNTIME_DIR", str(d))
    old = os.umask(0o022)  # a usual umask, which would leave a plain mkdir at 0755
    try:
        assert runtime_dir() == d and mode(d) == 0o700
    finally:
        os.umask(old)
    # Ours, readable by others but not writable (an older release made it so): tightened, not refused.
    d.chmod(0o755)
    runtime_dir()
    assert mode(d) == 0o700


@pytest.mark.parametrize("bad", ["group-writable", "world-writable", "other-owner", "symlink"])
def test_a_runtime_directory_others_could_write_is_refused_in_one_line(monkeypatch, tmp_path, bad):
    d = tmp_path / "rt"
    d.mkdir(mode=0o700)
    if bad == "group-writable":
        d.chmod(0o770)
        expected = f"{d} has mode 0770: other users may write to it"
    elif bad == "world-writable":
        d.chmod(0o1777)
        expected = f"{d} has mode 1777"
    elif bad == "other-owner":
        if os.getuid() != 0:
            # Without root a directory of another owner cannot be made: pretend to be someone else.
            monkeypatch.setattr(os, "getuid", lambda: os.stat(d).st_uid + 1)
        else:
            os.chown(d, 4321, -1)
        expected = "belongs to uid"
    else:
        target, d = d, tmp_path / "link"
        d.symlink_to(target)
        expected = "is not a plain directory"
    monkeypatch.setenv("DOCKHIL_RUNTIME_DIR", str(d))
    with pytest.raises(DockhilError, match=re.escape(expected)):
        runtime_dir()
    # The CLI too (in this process, so it sees the same directory and uid): one line, exit 2, nothing started.
    code, out, err = run_main("topic", "list")
    assert code == 2 and out == "" and expected.split(":")[0].replace("\\", "") in one_line(err), err
    assert "DOCKHIL_RUNTIME_DIR" in err or "chmod 700" in err


@pytest.mark.parametrize("bad", ["parent-of-another-user", "grandparent-writable-by-others"])
def test_a_runtime_directory_in_a_parent_others_could_change_is_refused_in_one_line(monkeypatch, tmp_path, bad):
    """Another user who may rename or replace a parent can swap the runtime directory mid-run."""
    top = tmp_path / "top"
    parent = top / "parent"
    parent.mkdir(parents=True, mode=0o755)
    if bad == "parent-of-another-user":
        if os.getuid() != 0:
            pytest.skip("making a directory of another user needs root")
        os.chown(parent, 65534, -1)  # nobody
        expected = f"its parent {parent} belongs to uid 65534"
    else:
        top.chmod(0o777)
        expected = f"its parent {top} has mode 0777: other users may write to it"
    d = parent / "rt"
    monkeypatch.setenv("DOCKHIL_RUNTIME_DIR", str(d))
    with pytest.raises(DockhilError, match=re.escape(expected)):
        runtime_dir()
    code, out, err = run_main("topic", "list")
    assert code == 2 and out == "" and expected in one_line(err) and "DOCKHIL_RUNTIME_DIR" in err, err
    assert not d.exists()  # refused before anything was made in it


def test_a_sticky_parent_writable_by_all_is_accepted(monkeypatch, tmp_path):
    """As /tmp: only an entry's owner may rename or remove it."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    monkeypatch.setenv("DOCKHIL_RUNTIME_DIR", str(shared / "rt"))
    assert runtime_dir() == shared / "rt" and mode(shared / "rt") == 0o700


def test_key_files_other_users_could_read_are_refused(tmp_path):
    path = GraphKeys.make().write(tmp_path / "graph.keys")
    assert mode(path) == 0o600
    GraphKeys.read(path)
    path.chmod(0o644)
    with pytest.raises(DockhilError, match=r"has mode 0644: other users can read the graph's keys; chmod 600"):
        GraphKeys.read(path)
    path.chmod(0o600)
    if os.getuid() == 0:
        os.chown(path, 4321, -1)
        with pytest.raises(DockhilError, match="belongs to uid 4321, not to you"):
            GraphKeys.read(path)
        os.chown(path, os.getuid(), -1)
    # A node started by hand with such a file says so in one line.
    path.chmod(0o640)
    spec = {
        "name": "g",
        "type_name": "tests.support.graphnodes:Gain",
        "dt": 0.01,
        "clock": "wall",
        "params": {},
        "inputs": {"x": {"topic": "/x", "endpoint": f"ipc://{tmp_path}/x", "type": "dockhil/WrenchStamped"}},
    }
    r = subprocess.run(
        [sys.executable, "-m", "dockhil.process", "--keys", str(path), json.dumps(spec)],
        capture_output=True,
        text=True,
        env=env(),
        timeout=30,
    )
    assert r.returncode == 2 and "has mode 0640" in one_line(r.stderr)


# --------------------------------------------------------------------------- endpoints


def hear(sub: Subscriber, send, seconds: float = 10.0) -> tuple[list, str]:
    """Keep `send`ing and receiving until the subscriber refuses its peer; (what it received, why it stopped)."""
    got = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        send()
        try:
            frames = sub.recv(0.05)
        except DockhilError as exc:
            return got, str(exc)
        if frames is not None:
            got.append(frames)
    return got, ""


def test_a_socket_bound_on_the_ipc_path_after_the_publisher_is_never_heard(tmp_path):
    """The hijack: libzmq replaces a bound ipc socket file, so whoever binds the path next gets the
    subscribers that connect after it. Without the graph's server key it cannot complete the
    handshake: nothing it sends arrives, not even with a CURVE key of its own, and the subscriber
    says so in one line instead of waiting in silence."""
    ctx = zmq.Context.instance()
    keys = GraphKeys.make()
    endpoint = f"ipc://{tmp_path}/robot.command"
    real = Publisher(ctx, "/robot/command", endpoint, keys=keys)
    forged = b"/robot/command\x00" + encode(command(y=0.05))
    own = ctx.socket(zmq.PUB)  # the second hijacker: CURVE, but with a key pair of its own
    own.curve_server, own.curve_secretkey = True, zmq.curve_keypair()[1]
    try:
        for hijacker in ("no keys", "own keys"):
            if hijacker == "no keys":
                sock = ctx.socket(zmq.PUB)
                sock.bind(endpoint)
            else:
                sock = own
                sock.bind(endpoint)
            driver = Subscriber(ctx)
            driver.connect(endpoint, keys=keys)
            got, why = hear(driver, lambda: sock.send(forged))  # noqa: B023 - called at once, in this pass
            driver.close()
            sock.close(linger=0)
            assert got == [], hijacker
            assert why.startswith(f"{endpoint}: the peer there failed the graph's authentication"), (hijacker, why)
        # A graph member on a path nobody took hears the real publisher.
        endpoint2 = f"ipc://{tmp_path}/robot.command2"
        real2 = Publisher(ctx, "/robot/command", endpoint2, keys=keys)
        member = Subscriber(ctx)
        member.connect(endpoint2, keys=keys)
        real2.wait_subscribers(1, 10.0)
        real2.send(encode(command(y=0.0)))
        frames = member.recv(10.0)
        assert frames is not None and decode(frames[1], msgs.RobotCommand).pose.position.y == 0.0
        member.close()
        real2.close()
    finally:
        own.close(linger=0)
        real.close()


def test_strangers_on_a_publishers_port_receive_nothing_and_are_not_counted(tmp_path):
    """In-process, so that the publisher's view is visible: a stranger's subscription never
    reaches it (sim time would otherwise count it and start early), and it hears nothing."""
    ctx = zmq.Context.instance()
    keys, other = GraphKeys.make(), GraphKeys.make()
    pub = Publisher(ctx, "/x", "tcp://127.0.0.1:0", keys=keys)
    plain = ctx.socket(zmq.SUB)
    plain.setsockopt(zmq.SUBSCRIBE, b"")
    plain.connect(pub.endpoint)
    xsub = ctx.socket(zmq.XSUB)  # sends a raw subscription frame, as a graph member would
    xsub.connect(pub.endpoint)
    xsub.send(b"\x01")
    # Knows the graph's server key (public, say) but holds another graph's client key: ZAP refuses it.
    thief = Subscriber(ctx)
    thief.connect(pub.endpoint, keys=GraphKeys(keys.server_public, b"", other.client_public, other.client_secret))
    try:
        with pytest.raises(DockhilError, match="0 of 1 subscribers joined"):
            pub.wait_subscribers(1, 1.5)
        got, why = hear(thief, lambda: pub.send(b"\x80"))
        assert got == [] and "failed the graph's authentication" in why
        assert plain.poll(0) == 0
    finally:
        for s in (plain, xsub):
            s.close(linger=0)
        thief.close()
        pub.close()


def test_publishers_opened_and_closed_in_turn_on_one_context_each_get_a_zap_handler():
    """The last publisher's close stops the context's ZAP handler, and libzmq frees its address
    later: a publisher opened right after must still start (it failed with 'Address already in use')."""
    ctx = zmq.Context.instance()
    keys = GraphKeys.make()
    for _ in range(200):
        Publisher(ctx, "/x", "tcp://127.0.0.1:0", keys=keys).close()


def test_the_zap_handler_admits_the_graphs_client_key_and_nothing_else():
    """Each ZAP request a publisher's handshake makes: only CURVE with the graph's client key gets 200."""
    from zmq.utils import z85

    from dockhil.runtime.keys import ZapHandler

    keys, other = GraphKeys.make(), GraphKeys.make()
    handler = ZapHandler(zmq.Context())
    try:
        handler.allowed.add(keys.client_public)

        def status(mechanism, *credentials, version=b"1.0"):
            reply = handler.reply([version, b"id7", b"", b"127.0.0.1", b"", mechanism, *credentials])
            assert reply[:2] == [b"1.0", b"id7"]  # answers the request it was asked
            return reply[2]

        assert status(b"CURVE", z85.decode(keys.client_public)) == b"200"
        assert status(b"CURVE", z85.decode(other.client_public)) == b"400"
        assert status(b"CURVE", z85.decode(keys.server_public)) == b"400"
        assert status(b"CURVE", z85.decode(keys.client_public), version=b"2.0") == b"400"
        assert status(b"NULL") == b"400"
        assert status(b"PLAIN", b"user", b"password") == b"400"
        assert handler.reply([b"1.0"])[2] == b"400"
    finally:
        handler.stop()


def test_socket_monitor_events_read_as_pyzmq_reads_them():
    import struct

    from zmq.utils.monitor import parse_monitor_message

    from dockhil.runtime.transport import monitor_event

    for event in (
        zmq.EVENT_HANDSHAKE_SUCCEEDED,
        zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL,
        zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL,
        zmq.EVENT_HANDSHAKE_FAILED_AUTH,
    ):
        frames = [struct.pack("=hi", event, 0x3F), b"ipc:///run/x"]
        theirs = parse_monitor_message(frames)
        assert monitor_event(frames) == (theirs["event"], theirs["endpoint"]) == (event, b"ipc:///run/x")
    with pytest.raises(DockhilError, match="unexpected socket monitor message"):
        monitor_event([b"\x00\x10"])


WALL_TCP = """
rate: 200
nodes:
  - {name: integ, node: "tests.support.graphnodes:Integrator"}
  - {name: gain, node: "tests.support.graphnodes:Gain"}
"""


@pytest.mark.wall_time
def test_a_running_graph_over_tcp_gives_nothing_to_an_unauthenticated_socket(write_launch):
    launch = subprocess.Popen(
        dockhil_cmd("launch", write_launch(WALL_TCP), "--wall-time", "--transport", "tcp"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env(),
    )
    ctx = zmq.Context.instance()
    socks = []
    try:
        info = registered(launch.pid)
        keys_path = Path(info["keys"])
        run_dir = keys_path.parent
        assert mode(run_dir) == 0o700 and mode(keys_path) == 0o600
        keys = GraphKeys.read(keys_path)
        # No key on any node's command line (every user can read /proc/PID/cmdline).
        deadline = time.monotonic() + 20
        while not all(n["pid"] for n in info["nodes"].values()) and time.monotonic() < deadline:
            time.sleep(0.05)
            info = registered(launch.pid)
        for node in info["nodes"].values():
            cmdline = Path(f"/proc/{node['pid']}/cmdline").read_bytes()
            assert keys.server_secret not in cmdline and keys.client_secret not in cmdline
            assert keys_path.name.encode() in cmdline
        endpoints = [t["endpoint"] for t in info["topics"].values()]
        assert endpoints and all(e.startswith("tcp://127.0.0.1:") for e in endpoints)  # loopback only
        strangers = []
        for e in endpoints:
            s = ctx.socket(zmq.SUB)
            s.setsockopt(zmq.SUBSCRIBE, b"")
            s.connect(e)
            strangers.append(s)
        member = Subscriber(ctx, observer=True)
        for e in endpoints:
            member.connect(e, keys=keys)
        socks = strangers
        # The graph is publishing (a member hears it) while the strangers hear nothing.
        heard = 0
        deadline = time.monotonic() + 20
        while heard < 50 and time.monotonic() < deadline:
            heard += member.recv(0.1) is not None
        member.close()
        assert heard >= 50
        assert all(s.poll(0) == 0 for s in strangers)
        # What a stranger sends (a subscription, to make sim time start early) never reaches a
        # publisher: test_strangers_on_a_publishers_port_receive_nothing_and_are_not_counted.
        assert launch.poll() is None
    finally:
        for s in socks:
            s.close(linger=0)
        launch.send_signal(signal.SIGINT)
        out = launch.communicate(timeout=30)[0]
    assert "Traceback" not in out, out


# --------------------------------------------------------------------------- one graph per device


@pytest.fixture
def controller():
    """The robot controller emulator, its heartbeat timeout 2 s instead of 0.2 s: the driver processes
    here run on the real clock, and a busy 2-core machine can pause one for longer than 0.2 s, which
    ends its claim before a test looks. The tests that need the claim to end wait for it (10 s)."""
    from dockhil.devices.modbus_robot.emulator import RobotControllerEmulator

    em = RobotControllerEmulator(port=0, tau=0.005, heartbeat_timeout=2.0)
    em.start_thread()
    yield em
    em.stop_thread()


def start_driver(port: int, run_id: str, runtime: str | None = None, **params) -> subprocess.Popen:
    spec = {
        "name": "robot",
        "type_name": "robot_modbus",
        "dt": 0.01,
        "clock": "wall",
        "run_id": run_id,
        # As the controller's heartbeat (the fixture): 1 s a request and 2 s without a step, not the lab's 0.1 s
        # and 0.2 s, which a busy 2-core machine outlasted (a lost connection, then a stall that stopped it).
        "params": {
            "port": port,
            "ft_timeout": 0.0,
            "connect_timeout": 2.0,
            "timeout": 1.0,
            "stall_timeout": 2.0,
            **params,
        },
    }
    e = env()
    if runtime:
        e["DOCKHIL_RUNTIME_DIR"] = runtime
    return subprocess.Popen(
        [sys.executable, "-m", "dockhil.process", json.dumps(spec)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=e,
    )


def wait_ready(proc: subprocess.Popen, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.rstrip("\n") == READY:
            return
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"driver did not get ready: {proc.stdout.read() if proc.poll() is not None else ''}")


def failing_driver(port: int, run_id: str, runtime: str | None = None) -> str:
    proc = start_driver(port, run_id, runtime)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 2, out
    return one_line(out)


def wait_until(cond, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def test_a_second_graph_refuses_the_controller_before_writing_anything(controller, tmp_path):
    first = start_driver(controller.port, "graph-one")
    try:
        wait_ready(first)
        servo = controller.servo
        assert wait_until(lambda: servo.owner_session != 0)
        assert servo.owner_name.startswith("graph-one@")
        held = controller.call(lambda: list(servo.holding))
        # The same host: the lock file names the owner.
        line = failing_driver(controller.port, "graph-two")
        assert f"robot controller (Modbus TCP 127.0.0.1:{controller.port}) is in use by graph graph-one" in line
        # Another host (its own runtime directory, so no common lock file): the controller's owner registers.
        other_host = tmp_path / "other-host"
        line = failing_driver(controller.port, "graph-two", str(other_host))
        assert f"robot controller (Modbus TCP 127.0.0.1:{controller.port}): owned by graph graph-one@" in line
        assert "nothing written" in line
        # Nothing was written: no write refused, the owner and the first graph's hold unchanged.
        assert servo.refused == 0 and servo.owner_name.startswith("graph-one@")
        assert controller.call(lambda: list(servo.holding))[0] == held[0] == 3  # ENABLE | HOLD
        assert first.poll() is None
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=30)
    # A clean stop lets go at once: the next graph takes the controller.
    assert servo.owner_session == 0
    second = start_driver(controller.port, "graph-two")
    try:
        wait_ready(second)
        assert wait_until(lambda: servo.owner_name.startswith("graph-two@"))
    finally:
        second.send_signal(signal.SIGTERM)
        second.communicate(timeout=30)


def test_the_controller_refuses_a_host_that_ignores_the_claim_until_the_owner_dies(controller):
    """A host that does not read the owner registers (an older driver, a script) is refused by the
    controller itself: no setpoint, no HOLD, no second claim. The claim dies with the owner's heartbeat."""
    from pymodbus.client import ModbusTcpClient

    from dockhil.devices.modbus_robot import registers as mm

    first = start_driver(controller.port, "graph-one")
    other = ModbusTcpClient("127.0.0.1", port=controller.port, timeout=1.0, retries=0)
    try:
        wait_ready(first)
        servo = controller.servo
        assert wait_until(lambda: servo.owner_session != 0)
        assert other.connect()
        setpoint = mm.encode_write(mm.CONTROL_ENABLE, 77, (0.0, 0.05) + mm.HOLD_POSE[2:])
        writes = [
            other.write_registers(0, setpoint, device_id=1),
            other.write_registers(0, mm.encode_write(mm.CONTROL_ENABLE | mm.CONTROL_HOLD, 78), device_id=1),
            other.write_register(mm.HR_CONTROL, 0, device_id=1),
            other.write_registers(mm.HR_SESSION, mm.encode_owner(1234, "intruder"), device_id=1),
        ]
        assert all(w.isError() and w.exception_code == 6 for w in writes)  # device busy
        assert servo.refused == 4 and servo.owner_name.startswith("graph-one@")
        assert controller.call(lambda: mm.decode_holding(servo.holding)).setpoint[1] == 0.0
        assert servo.position[1] == 0.0
        # The owner dies without letting go: after the heartbeat timeout the claim is gone.
        first.kill()
        first.wait(timeout=10)
        assert wait_until(lambda: servo.owner_session == 0, timeout=10.0)
        assert not other.write_registers(mm.HR_SESSION, mm.encode_owner(1234, "next"), device_id=1).isError()
        assert servo.owner_name == "next"
    finally:
        other.close()
        if first.poll() is None:
            first.kill()
            first.communicate(timeout=10)


def test_a_second_emulator_on_the_same_port_names_the_graph_that_owns_it():
    port = free_port()
    spec = {"name": "em", "type_name": "robot_emulator", "dt": 0.01, "clock": "wall", "params": {"port": port}}
    first = subprocess.Popen(
        [sys.executable, "-m", "dockhil.process", json.dumps({**spec, "run_id": "graph-one"})],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env(),
    )
    try:
        wait_ready(first)
        r = subprocess.run(
            [sys.executable, "-m", "dockhil.process", json.dumps({**spec, "run_id": "graph-two"})],
            capture_output=True,
            text=True,
            env=env(),
            timeout=30,
        )
        assert r.returncode == 2
        assert f"robot controller emulator port 127.0.0.1:{port} is in use by graph graph-one" in one_line(r.stderr)
        r = subprocess.run(
            [sys.executable, "-m", "dockhil.devices.modbus_robot.emulator", "--port", str(port)],
            capture_output=True,
            text=True,
            env=env(),
            timeout=30,
        )
        assert r.returncode == 2 and "is in use by graph graph-one" in one_line(r.stderr)
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=30)


def test_a_second_slcan_adapter_or_driver_on_the_same_path_is_refused(tmp_path):
    from dockhil.devices.can_ft.slcan_pty import PtyCanBus
    from dockhil.runtime import ownership

    link = str(tmp_path / "ft.slcan")
    ownership.set_graph("graph-one")
    try:
        bus = PtyCanBus([link])
    finally:
        ownership.set_graph("")
    try:
        target = os.readlink(link)
        r = subprocess.run(
            [sys.executable, "-m", "dockhil.devices.can_ft.slcan_pty", link],
            capture_output=True,
            text=True,
            env=env(),
            timeout=30,
        )
        assert r.returncode == 2 and f"slcan adapter {link} is in use by graph graph-one" in one_line(r.stderr)
        assert os.readlink(link) == target  # the first adapter keeps its link
        # The F/T driver side: the adapter path is claimed by one graph's driver at a time.
        held = ownership.claim(f"can-slcan-{os.path.abspath(link)}", "F/T adapter")
        try:
            spec = {
                "name": "ft",
                "type_name": "ft_can",
                "dt": 0.01,
                "clock": "wall",
                "run_id": "graph-two",
                "params": {"channel": link, "open_timeout": 0.5},
            }
            r = subprocess.run(
                [sys.executable, "-m", "dockhil.process", json.dumps(spec)],
                capture_output=True,
                text=True,
                env=env(),
                timeout=30,
            )
            assert r.returncode == 2 and f"F/T adapter (slcan {link}) is in use by process pid" in one_line(r.stderr)
        finally:
            held.release()
    finally:
        bus.stop()
    # A dead owner's claim is gone with it.
    PtyCanBus([link]).stop()


def test_another_graphs_emulator_cannot_join_the_can_bus_a_driver_reads(request):
    """A CAN bus (python-can interface and channel) read by one graph's F/T driver takes that graph's
    emulator (hil.yaml with emulators:=true on a virtual bus), never another graph's: it would stream
    forged frames with the sensor's IDs, and the robot would move on them."""
    from dockhil.devices.can_ft.driver import FtCanDriver
    from dockhil.devices.can_ft.emulator import FtSensorEmulator
    from dockhil.node import NodeContext
    from dockhil.runtime import ownership
    from tests.conftest import VirtualFtSensor

    channel = f"bus-{request.node.name}"
    sensor = VirtualFtSensor(channel).stream()
    ctx = lambda name: NodeContext(name, 0.001, sim_time=False, log=lambda line: None)  # noqa: E731
    ownership.set_graph("graph-one")
    try:
        driver = FtCanDriver(ctx("ft"), interface="virtual", channel=channel, open_timeout=5.0)
        driver.setup()
    finally:
        ownership.set_graph("")
        sensor.quiet()
        sensor.bus.shutdown()
    try:
        ownership.set_graph("graph-two")
        try:
            stranger = FtSensorEmulator(ctx("ft_emulator"), interface="virtual", channel=channel)
            with pytest.raises(DeviceError) as err:
                stranger.setup()
        finally:
            ownership.set_graph("")
        text = str(err.value)
        assert "\n" not in text
        assert text.startswith(f"CAN bus virtual {channel} is in use by graph graph-one (pid {os.getpid()} "), text
        # a process that belongs to no graph is a stranger too
        with pytest.raises(DeviceError, match="is in use by graph graph-one"):
            FtSensorEmulator(ctx("ft_emulator"), interface="virtual", channel=channel).setup()
        # the graph's own emulator shares the bus with its driver
        ownership.set_graph("graph-one")
        try:
            own = FtSensorEmulator(ctx("ft_emulator"), interface="virtual", channel=channel)
            own.setup()
        finally:
            ownership.set_graph("")
        own.close()
    finally:
        driver.close()
    # once graph one has let go, another graph may use the bus
    ownership.set_graph("graph-two")
    try:
        later = FtSensorEmulator(ctx("ft_emulator"), interface="virtual", channel=channel)
        later.setup()
        later.close()
    finally:
        ownership.set_graph("")


def test_a_graph_claim_is_shared_within_its_graph_across_processes_and_dies_with_them():
    from dockhil.runtime import ownership

    code = (
        "import time; from dockhil.runtime import ownership; ownership.set_graph('graph-one'); "
        "ownership.claim_for_graph('bus', 'the bus'); print('held', flush=True); time.sleep(60)"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env())
    try:
        assert holder.stdout.readline().strip() == "held"
        for graph in ("graph-two", ""):
            ownership.set_graph(graph)
            try:
                with pytest.raises(DeviceError, match=r"^the bus is in use by graph graph-one \(pid \d+ on "):
                    ownership.claim_for_graph("bus", "the bus")
            finally:
                ownership.set_graph("")
        ownership.set_graph("graph-one")
        try:
            ownership.claim_for_graph("bus", "the bus").release()  # another process of the same graph
        finally:
            ownership.set_graph("")
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    ownership.set_graph("graph-two")
    try:
        ownership.claim_for_graph("bus", "the bus").release()
    finally:
        ownership.set_graph("")


def _fake_graph(name: str, **entry) -> Path:
    graphs = runtime_dir() / "graphs"
    graphs.mkdir(mode=0o700, parents=True, exist_ok=True)
    path = graphs / f"{name}.json"
    path.write_text(
        json.dumps(
            {
                "run_id": name,
                "pid": os.getpid(),
                "file": "hil.yaml",
                "clock": "wall",
                "nodes": {},
                "keys": "",
                "topics": {},
                **entry,
            }
        )
    )
    return path


@pytest.mark.parametrize(
    "entry, words",
    [
        # a second publisher of a graph's topic: the graph's subscribers never connect to it
        (
            {
                "topics": {
                    "/x": {"type": "dockhil/WrenchStamped", "endpoint": "ipc:///nowhere", "publisher": "dynamics"}
                }
            },
            ["topic /x is published by graph lab-graph (node 'dynamics')", "-r x:=/TOPIC"],
        ),
        # an input the launch left unconnected (an e-stop nobody published) does not start listening later
        (
            {"unconnected": {"/x": ["robot.estop"]}},
            ["graph lab-graph left input robot.estop (/x) unconnected at launch", "would not hear"],
        ),
    ],
)
def test_a_node_run_alone_never_publishes_what_a_running_graph_would_not_hear(entry, words):
    """`dockhil run` outputs are new topics: one that a running graph publishes, or that a node of it
    reads but was left unconnected (the robot driver's /estop), is refused in one line; an e-stop sent
    that way would never reach the driver, while the operator believes it would."""

    reg = _fake_graph("lab-graph", **entry)
    try:  # a refusal: in this process, no interpreter of its own
        code, out, err = run_main("run", "tests.support.graphnodes:Source", "--rate", "100", "--duration", "0.05")
    finally:
        reg.unlink()
    assert code == 2, out + err
    line = one_line(err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for word in words:
        assert word in line, line


def test_a_device_lock_dies_with_its_process(tmp_path):
    from dockhil.runtime import ownership

    code = (
        "import time; from dockhil.runtime import ownership; ownership.set_graph('graph-one'); "
        "ownership.claim('dev', 'the device'); print('held', flush=True); time.sleep(60)"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env())
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(DeviceError, match=r"the device is in use by graph graph-one \(pid \d+ on "):
            ownership.claim("dev", "the device")
    finally:
        holder.kill()
        holder.wait()
    ownership.claim("dev", "the device").release()


def test_a_driver_stalled_past_its_claim_does_not_resume_on_a_controller_taken_over(controller):
    """SIGSTOP the owner past the heartbeat timeout: the controller holds and lets the claim go; another
    host claims it. On SIGCONT the first driver's writes and its re-claim are refused; it stops in one line."""
    from pymodbus.client import ModbusTcpClient

    from dockhil.devices.modbus_robot import registers as mm

    first = start_driver(controller.port, "graph-one")
    other = ModbusTcpClient("127.0.0.1", port=controller.port, timeout=1.0, retries=0)
    try:
        wait_ready(first)
        servo = controller.servo
        assert wait_until(lambda: servo.owner_session != 0)
        os.kill(first.pid, signal.SIGSTOP)
        assert wait_until(lambda: servo.owner_session == 0, timeout=10.0)
        assert other.connect()
        assert not other.write_registers(
            mm.HR_SESSION, mm.encode_owner(99, "graph-two@elsewhere"), device_id=1
        ).isError()
        refused_before = servo.refused
        os.kill(first.pid, signal.SIGCONT)
        out, _ = first.communicate(timeout=30)
        assert first.returncode == 2, out
        # Whichever the driver notices first, its own stall or the new owner, it stops in one line.
        assert "owned by graph graph-two@elsewhere" in out or "safety stop: stall" in out, out
        assert "Traceback" not in out
        assert servo.refused > refused_before  # it tried, and the controller said no
    finally:
        other.close()
        if first.poll() is None:
            os.kill(first.pid, signal.SIGCONT)
            first.kill()
            first.communicate(timeout=10)


def test_a_respawned_driver_takes_its_own_graphs_claim_back_at_once(controller):
    """Killed without letting go, a driver's claim outlives it by the heartbeat timeout; its own graph's
    restarted driver (same run id and node) has the same session and may claim again at once."""
    first = start_driver(controller.port, "graph-one")
    try:
        wait_ready(first)
        servo = controller.servo
        assert wait_until(lambda: servo.owner_session != 0)
        session = servo.owner_session
        servo.heartbeat_timeout = 30.0  # the claim would outlive the test: only the session can take it back
        first.kill()
        first.wait(timeout=10)
        assert servo.owner_session == session
        line = failing_driver(controller.port, "graph-two")
        assert "owned by graph graph-one@" in line
        second = start_driver(controller.port, "graph-one")
        try:
            wait_ready(second)
            assert servo.owner_session == session and servo.refused == 0
        finally:
            second.send_signal(signal.SIGTERM)
            second.communicate(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
            first.communicate(timeout=10)


def test_a_remote_node_that_could_not_reach_a_loopback_bind_is_refused_before_anything_starts(write_launch):
    """Publishers bind the one address this machine is reached by, never 0.0.0.0: if that address is
    loopback, a node on a real other machine could never connect; say so instead of hanging."""
    import socket

    here = socket.gethostname()
    if not socket.gethostbyname(here).startswith("127."):
        pytest.skip(f"{here} resolves to a network address here")
    scene = write_launch(
        'nodes:\n  - {name: integ, node: "tests.support.graphnodes:Integrator"}\n'
        '  - {name: gain, node: "tests.support.graphnodes:Gain", host: 192.0.2.7}\n'
    )
    code, out, err = run_main("launch", scene, "--duration", "0.1")  # a refusal: no process of its own
    assert code == 2 and out == ""
    assert f"node 'gain' runs on 192.0.2.7 (192.0.2.7), but this machine's name '{here}' resolves to " in one_line(err)
