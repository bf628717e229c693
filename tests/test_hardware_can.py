"""CAN: slcan adapters on pseudo-terminals, the F/T driver against its emulator
across processes, and the driver's failure paths (missing device, stale data,
sensor faults, bus errors)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest
import serial

from dockhil.devices.can_ft import frames as ff
from dockhil.devices.can_ft.driver import FtCanDriver
from dockhil.devices.can_ft.slcan_pty import CanFrame, PtyCanBus, SlcanPort, parse_transmit
from dockhil.errors import DeviceError, LaunchError
from dockhil.node import NodeContext, Tick
from tests.conftest import VirtualFtSensor, node_process_error

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def spawn(code: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        cwd=ROOT,
        env=ENV,
        text=True,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=5)
    for stream in (proc.stdin, proc.stdout, proc.stderr):
        if stream:
            stream.close()


def ready_line(proc: subprocess.Popen, timeout: float = 10.0) -> str:
    line = []

    def read():
        line.append(proc.stdout.readline())

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout)
    if not line or not line[0]:
        raise AssertionError(
            f"process gave no ready line; stderr: {proc.stderr.read() if proc.poll() is not None else ''}"
        )
    return line[0].strip()


def open_slcan(path: str):
    return can.Bus(interface="slcan", channel=path, bitrate=1_000_000, sleep_after_open=0, timeout=0.0)


def recv(bus, timeout: float):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = bus.recv(0.0)
        if msg is not None:
            return msg
        time.sleep(0.0002)
    return None


# -- the emulated adapter --------------------------------------------------------


def test_adapter_answers_lawicel_commands_and_moves_frames(tmp_path):
    seen = []
    bus = PtyCanBus([str(tmp_path / "can0")], on_frame=lambda port, frame: seen.append(frame)).start()
    port = bus.ports[0]
    host = serial.Serial(str(tmp_path / "can0"), timeout=1.0)
    try:

        def ask(cmd: bytes) -> bytes:
            host.write(cmd + b"\r")
            reply = b""
            while not reply.endswith((b"\r", b"\a")):
                byte = host.read(1)
                assert byte, f"no reply to {cmd!r}"
                reply += byte
            return reply

        assert ask(b"V") == b"V1013\r"
        assert ask(b"t1A0811") == b"\a"  # channel closed: no transmit
        assert ask(b"S8") == b"\r" and port.bitrate_code == "S8"
        assert ask(b"O") == b"\r" and port.is_open
        assert ask(b"S4") == b"\a"  # no bitrate change while open
        assert ask(b"t1A02BEEF") == b"z\r"
        assert ask(b"T1234567F0") == b"Z\r"
        assert ask(b"t1A0") == b"\a"  # malformed
        deadline = time.monotonic() + 2
        while len(seen) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert seen == [CanFrame(0x1A0, b"\xbe\xef"), CanFrame(0x1234567F, b"", True)]
        assert port.deliver(CanFrame(0x1A1, bytes([1, 2, 3])))
        assert host.read_until(b"\r") == b"t1A13010203\r"
        assert ask(b"C") == b"\r" and not port.is_open
        assert not port.deliver(CanFrame(0x1A1, b""))  # closed: the host gets nothing
    finally:
        host.close()
        bus.stop()
    assert not (tmp_path / "can0").exists()  # the link goes with the adapter


def test_adapter_delivers_again_after_a_host_that_lagged_until_frames_dropped():
    # A host that reads nothing for a while: the pty fills, the adapter's queue fills and it drops
    # (as an adapter overruns). Once the host reads, frames must flow again, with no flush call
    # from the sender (an emulator only delivers).
    port = SlcanPort()
    host = os.open(port.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        port.is_open = True
        frame = CanFrame(0x1A0, bytes(8))
        sent = 0
        while port.dropped == 0:
            sent += port.deliver(frame)
        assert sent > 1000  # the pty and the queue held that many before the first drop

        def read_all() -> int:
            n = 0
            while True:
                try:
                    chunk = os.read(host, 65536)
                except BlockingIOError:
                    return n
                n += chunk.count(b"\r")

        assert read_all() > 0  # what the kernel held
        for _ in range(100):  # each delivery moves what is queued into the room the host made
            port.deliver(frame)
            read_all()
        marker = CanFrame(0x1A1, b"\x55")
        assert port.deliver(marker)
        got = b""
        for _ in range(20):
            try:
                got += os.read(host, 65536)
            except BlockingIOError:
                port.deliver(frame)
        assert marker.to_slcan() in got
    finally:
        os.close(host)
        port.close()


def test_transmit_parser_refuses_bad_commands():
    assert parse_transmit(b"t7FF0") == CanFrame(0x7FF, b"")
    assert parse_transmit(b"r1A08") == CanFrame(0x1A0, b"", False, True, 8)
    for bad in (b"t8000", b"t1A09" + b"00" * 9, b"t1A02AB", b"t1A01XY", b"T2000000000", b"tzzz0"):
        assert parse_transmit(bad) is None, bad


ECHO = """
import sys, can
bus = can.Bus(interface="slcan", channel=sys.argv[1], bitrate=1000000, sleep_after_open=0, timeout=0.001)
print("ready", flush=True)
n = 0
while n < int(sys.argv[2]):
    msg = bus.recv(1.0)
    if msg is None:
        continue
    bus.send(can.Message(arbitration_id=msg.arbitration_id ^ 0x100, data=msg.data[::-1],
                         is_extended_id=msg.is_extended_id))
    n += 1
bus.shutdown()
"""


def test_python_can_slcan_talks_across_processes_through_the_pty_bus(tmp_path):
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    bridge = subprocess.Popen(
        [sys.executable, "-m", "dockhil.devices.can_ft.slcan_pty", a, b],
        cwd=ROOT,
        env=ENV,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    echo = None
    try:
        assert ready_line(bridge).startswith(f"ready {a}=/dev/pts/")
        n = 200
        echo = spawn(ECHO, a, str(n))
        assert ready_line(echo) == "ready"
        bus = open_slcan(b)
        try:
            got = []
            for i in range(n):
                extended = i % 5 == 0
                bus.send(
                    can.Message(
                        arbitration_id=(0x1ABCDE00 + i) if extended else 0x200 + i,
                        data=bytes([i % 256, 1, 2, 3][: i % 5]),
                        is_extended_id=extended,
                    )
                )
                msg = recv(bus, 2.0)
                assert msg is not None, f"no echo for frame {i}"
                got.append(msg)
            for i, msg in enumerate(got):
                extended = i % 5 == 0
                assert msg.is_extended_id == extended
                assert msg.arbitration_id == ((0x1ABCDE00 + i) if extended else 0x200 + i) ^ 0x100
                assert bytes(msg.data) == bytes([i % 256, 1, 2, 3][: i % 5])[::-1]
        finally:
            bus.shutdown()
        echo.wait(timeout=5)
        assert echo.returncode == 0, echo.stderr.read()
    finally:
        if echo:
            stop(echo)
        bridge.terminate()
        bridge.wait(timeout=5)
        for s in (bridge.stdout, bridge.stderr):
            s.close()
    assert bridge.returncode == 0
    assert not os.path.lexists(a) and not os.path.lexists(b)


# -- the F/T driver against the emulator, across processes -------------------------

EMULATOR = """
import sys, threading, time
from dockhil.node import NodeContext, Tick
from dockhil.msgs import Header, Pose, RobotState, Vector3
from dockhil.devices.can_ft.emulator import FtSensorEmulator

em = FtSensorEmulator(NodeContext("ft_emulator", 0.001, sim_time=False), channel=sys.argv[1],
                      k=float(sys.argv[2]), bias=float(sys.argv[3]), noise=0.0)
em.setup()
x = [0.0]

def read_positions():
    for line in sys.stdin:
        x[0] = float(line)

threading.Thread(target=read_positions, daemon=True).start()
print("ready", flush=True)
t0 = time.monotonic()
k = 0
while True:
    state = RobotState(header=Header(), pose=Pose(position=Vector3(x=x[0])))
    em.step(Tick(k, time.monotonic() - t0, 0.001), {"state": state})
    k += 1
    left = t0 + k * 0.001 - time.monotonic()
    if left > 0:
        time.sleep(left)
"""


def wall_steps(node, seconds: float, t0: float, k0: int = 0):
    """Step a node in wall time at about 1 kHz; return (outputs, next tick index)."""
    outs = []
    k = k0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        out = node.step(Tick(k, time.monotonic() - t0, 0.001), {})
        if out:
            outs.append(out)
        k += 1
        time.sleep(0.001)
    return outs, k


def wall_until(node, done, t0: float, k: int, timeout: float = 30.0):
    """Step a node in wall time until done(output) for an output; return (that output, next tick index)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = node.step(Tick(k, time.monotonic() - t0, 0.001), {})
        k += 1
        if out and done(out):
            return out, k
        time.sleep(0.001)
    raise AssertionError(f"{node.ctx.name}: no such output within {timeout} s")


def wall_ctx(name: str, logs: list) -> NodeContext:
    return NodeContext(name, 0.001, sim_time=False, log=logs.append)


@pytest.mark.wall_time
def test_driver_reads_the_emulated_sensor_across_processes(tmp_path):
    link = str(tmp_path / "ft.slcan")
    em = spawn(EMULATOR, link, "1000.0", "2.5")
    logs: list[str] = []
    # stale_timeout 1 s: a busy machine may stall either process for a while (stale data is tested
    # on the tick clock below); lost samples are counted, not failed on, for the same reason.
    node = FtCanDriver(wall_ctx("ft", logs), channel=link, tare_samples=50, stale_timeout=1.0)
    try:
        assert ready_line(em) == "ready"
        t = time.monotonic()
        node.setup()
        assert time.monotonic() - t < 15.0  # open + tare within seconds, even on a loaded machine
        assert node.bias_force == pytest.approx((2.5, 0.0, 0.0))  # the tare found the emulated bias
        assert any("tared over 50 samples" in line for line in logs)
        t0 = time.monotonic()
        out, k = wall_until(node, lambda o: True, t0, 0)
        assert out["wrench"].wrench.force.x == pytest.approx(0.0, abs=1e-9)

        em.stdin.write("0.012\n")  # 12 mm into a 1000 N/m compliance
        em.stdin.flush()
        # Force on the chaser pushes it back: -k x, to the sensor's 0.01 N resolution.
        out, k = wall_until(node, lambda o: o["wrench"].wrench.force.x < -1.0, t0, k)
        w = out["wrench"]
        assert w.wrench.force.x == pytest.approx(-12.0, abs=0.006)
        assert (w.wrench.force.y, w.wrench.force.z) == (0.0, 0.0)

        em.stdin.write("-0.02\n")  # apart: a compliance does not pull
        em.stdin.flush()
        out, k = wall_until(node, lambda o: o["wrench"].wrench.force.x > -1.0, t0, k)
        assert out["wrench"].wrench.force.x == pytest.approx(0.0, abs=1e-9)
        assert node.bad_frames == 0

        em.kill()  # the sensor goes away mid-run
        em.wait(timeout=5)
        with pytest.raises(DeviceError) as err:  # stale data after 0.1 s, or the bus error at once
            wall_steps(node, 30.0, t0, k)
        text = str(err.value)
        assert "\n" not in text and text.startswith(f"F/T sensor (slcan {link}, CAN ID 0x1a0): ")
        assert "bus error" in text or "stale data" in text
    finally:
        node.close()
        stop(em)


# -- missing devices --------------------------------------------------------------


def test_adapter_link_replaces_only_a_stale_link_of_its_own_kind(tmp_path):
    """The link path is replaced only where an earlier emulated adapter left its link (to a
    pseudo-terminal): a file, or a link to anything else (a real adapter's /dev/serial/by-id
    name), is refused in one line and left as it was."""
    precious = tmp_path / "summary.json"
    precious.write_text("keep me")
    real = tmp_path / "by-id-link"
    real.symlink_to("/dev/ttyACM0")
    for path, kind in ((precious, "a regular file"), (real, "a link to /dev/ttyACM0")):
        with pytest.raises(DeviceError) as err:
            SlcanPort(str(path))
        text = str(err.value)
        assert "\n" not in text
        assert text.startswith(f"slcan adapter {path}: ") and kind in text, text
    assert precious.read_text() == "keep me"
    assert os.readlink(real) == "/dev/ttyACM0"
    # a stale link from an earlier run (its pseudo-terminal gone) is replaced
    stale = tmp_path / "stale.slcan"
    stale.symlink_to("/dev/pts/987654")
    port = SlcanPort(str(stale))
    try:
        assert os.readlink(stale) == port.path and port.path.startswith("/dev/pts/")
    finally:
        port.close()
    assert not os.path.lexists(stale)
    # and the claim was let go: the refused paths can be claimed once they are free
    precious.unlink()
    SlcanPort(str(precious)).close()


def test_emulator_process_refuses_to_replace_a_file_in_one_line(tmp_path):
    precious = tmp_path / "data.csv"
    precious.write_text("1,2,3\n")
    proc = subprocess.run(
        [sys.executable, "-m", "dockhil.devices.can_ft.slcan_pty", str(precious)],
        cwd=ROOT,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"slcan_pty: error: slcan adapter {precious}: ")
    assert precious.read_text() == "1,2,3\n"


def test_missing_serial_port_fails_fast_with_one_line(tmp_path):
    node = FtCanDriver(wall_ctx("ft", []), channel=str(tmp_path / "nothing"), open_timeout=0.5)
    t = time.monotonic()
    with pytest.raises(DeviceError) as err:
        node.setup()
    assert time.monotonic() - t < 1.5
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"F/T sensor (slcan {tmp_path / 'nothing'}, CAN ID 0x1a0): cannot open: ")
    assert "No such file or directory" in text


def test_silent_adapter_fails_fast_naming_the_ids(tmp_path):
    port = SlcanPort(str(tmp_path / "quiet"))  # an adapter with no sensor on its bus
    try:
        node = FtCanDriver(wall_ctx("ft", []), channel=port.link, open_timeout=0.5)
        t = time.monotonic()
        with pytest.raises(DeviceError, match=r"no F/T frames on CAN IDs 0x1a0/0x1a1 within 0.5 s") as err:
            node.setup()
        assert time.monotonic() - t < 1.5
        assert "\n" not in str(err.value)
    finally:
        port.close()


def test_unknown_interface_is_refused_at_once():
    node = FtCanDriver(wall_ctx("ft", []), interface="no-such-interface", channel="x", open_timeout=5.0)
    t = time.monotonic()
    with pytest.raises(DeviceError, match=r"cannot open: Unknown interface type"):
        node.setup()
    assert time.monotonic() - t < 1.0


def test_sim_time_is_refused():
    node = FtCanDriver(NodeContext("ft", 0.001, sim_time=True))
    with pytest.raises(LaunchError, match="runs only in wall time"):
        node.setup()


def test_node_process_exits_non_zero_with_one_line_when_the_sensor_is_missing(tmp_path):
    spec = {
        "name": "ft",
        "type_name": "ft_can",
        "dt": 0.001,
        "clock": "wall",
        "params": {"channel": str(tmp_path / "ttyACM9"), "open_timeout": 0.5},
    }
    line = node_process_error(spec, ENV)
    assert "F/T sensor (slcan" in line and "ttyACM9" in line


def test_modules_do_not_import_python_can_until_setup():
    code = (
        "import sys, dockhil.devices.can_ft.driver, dockhil.devices.can_ft.emulator, dockhil.devices.can_ft.slcan_pty; "
        "print(sorted(m for m in ('can', 'serial', 'pymodbus') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=30)
    assert out.stdout.strip() == "[]", out.stderr


# -- driver behaviour on a virtual bus (in process, ticks with chosen times) -----------


@pytest.fixture
def virtual(request):
    channel = f"ft-{request.node.name}"
    sensor = VirtualFtSensor(channel)
    logs: list[str] = []
    nodes = []

    def make(**params):
        node = FtCanDriver(wall_ctx("ft", logs), interface="virtual", channel=channel, **params)
        nodes.append(node)
        return node

    yield sensor, make, logs
    for node in nodes:
        node.close()
    sensor.close()


def started(sensor, make, **params):
    sensor.force = (1.5, -0.25, 0.5)  # the unloaded sensor's offset
    sensor.stream()
    node = make(tare_samples=20, **params)
    node.setup()
    sensor.quiet()
    node.step(Tick(0, 0.0, 0.001), {})  # take what the stream left
    return node


def test_tare_removes_the_offset_and_sign_flips(virtual):
    sensor, make, _ = virtual
    node = started(sensor, make, sign=-1.0)
    assert node.bias_force == pytest.approx((1.5, -0.25, 0.5))
    sensor.send(force=(11.5, -0.25, 0.5), torque=(0.0, 0.0, 0.125))
    w = node.step(Tick(1, 0.001, 0.001), {})["wrench"]
    assert (w.wrench.force.x, w.wrench.force.y, w.wrench.force.z) == pytest.approx((-10.0, 0.0, 0.0))
    assert w.wrench.torque.z == pytest.approx(-0.125)
    assert w.header.tick == 1 and w.header.stamp == 0.001


@pytest.mark.parametrize(
    "force, torque, params, words",
    [
        # a probe pressed at start: taring it away would hide a 150 N contact from every force limit
        ((150.0, 0.0, 0.0), (0.0, 0.0, 0.0), {}, "tare: bias force |F| = 150.0 N > max_bias 50 N"),
        ((0.0, 30.0, 40.1), (0.0, 0.0, 0.0), {}, "tare: bias force |F| = 50.1 N > max_bias 50 N"),
        ((0.0, 0.0, 0.0), (3.0, 0.0, 4.001), {}, "tare: bias torque |T| = 5.00 N m > max_bias_torque 5 N m"),
        ((30.0, 0.0, 0.0), (0.0, 0.0, 0.0), {"max_bias": 20.0}, "tare: bias force |F| = 30.0 N > max_bias 20 N"),
    ],
)
def test_a_loaded_probe_at_start_is_refused_not_tared_away(virtual, force, torque, params, words):
    sensor, make, _ = virtual
    sensor.force = force
    sensor.torque = torque
    sensor.stream()
    node = make(tare_samples=20, **params)
    try:
        with pytest.raises(DeviceError) as err:
            node.setup()
    finally:
        sensor.quiet()
    text = str(err.value)
    assert "\n" not in text and text.startswith("F/T sensor (virtual ") and words in text, text
    assert "free the probe" in text


def test_a_heavy_tools_offset_passes_with_a_raised_bound_or_none(virtual):
    sensor, make, _ = virtual
    sensor.force = (0.0, 0.0, -49.05 * 2)  # a 10 kg tool on the sensor
    sensor.stream()
    try:
        for bound in (100.0, 0.0):  # 0: the check is off
            node = make(tare_samples=20, max_bias=bound)
            node.setup()
            assert node.bias_force == pytest.approx((0.0, 0.0, -98.1))
            node.close()
    finally:
        sensor.quiet()


def test_newest_sample_wins_and_lost_samples_are_counted(virtual):
    sensor, make, logs = virtual
    node = started(sensor, make)
    sensor.send(force=(2.5, 0, 0))
    sensor.send(force=(3.5, 0, 0), seq=sensor.seq + 3)  # three samples never arrived
    w = node.step(Tick(1, 0.001, 0.001), {})["wrench"]
    assert w.wrench.force.x == pytest.approx(2.0)
    assert node.lost == 3
    node.close()
    assert any("3 samples lost" in line for line in logs)


def test_stale_data_is_an_error_after_the_timeout(virtual):
    sensor, make, _ = virtual
    node = started(sensor, make, stale_timeout=0.05)
    assert node.step(Tick(1, 0.03, 0.001), {}) == {}  # nothing new: nothing published
    with pytest.raises(DeviceError, match=r"stale data: no new sample for 0.051 s \(stale_timeout 0.05 s\)"):
        node.step(Tick(2, 0.051, 0.001), {})


def test_a_stuck_sensor_repeating_itself_is_stale(virtual):
    sensor, make, _ = virtual
    node = started(sensor, make, stale_timeout=0.05)
    for k in range(1, 60):
        sensor.send(seq=(sensor.seq - 1) & 0xFF, advance=False)  # the last sample, again and again
        if k * 0.001 <= 0.05:
            assert node.step(Tick(k, k * 0.001, 0.001), {}) == {}
        else:
            with pytest.raises(DeviceError, match="stale data"):
                node.step(Tick(k, k * 0.001, 0.001), {})
            break
    assert node.repeated > 40


@pytest.mark.parametrize("status, word", [(ff.STATUS_FAULT, "fault"), (ff.STATUS_OVERRANGE, "overrange")])
def test_sensor_fault_and_overrange_are_errors(virtual, status, word):
    sensor, make, _ = virtual
    node = started(sensor, make)
    sensor.send(status=status)
    with pytest.raises(DeviceError, match=rf"sensor reports {word} \(raw force"):
        node.step(Tick(1, 0.001, 0.001), {})


def test_bad_frames_are_dropped_counted_and_logged(virtual):
    sensor, make, logs = virtual
    node = started(sensor, make)
    sensor.bus.send(can.Message(arbitration_id=0x1A0, data=bytes(4), is_extended_id=False))
    sensor.bus.send(can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False))  # another device
    sensor.send(force=(4.5, -0.25, 0.5))
    w = node.step(Tick(1, 0.001, 0.001), {})["wrench"]
    assert w.wrench.force.x == pytest.approx(3.0)
    assert node.bad_frames == 1
    assert any("dropped a bad frame: F/T force frame 0x1a0: 4 data bytes" in line for line in logs)


def test_error_frames_in_a_row_are_a_bus_error(virtual):
    sensor, make, _ = virtual
    node = started(sensor, make, max_bus_errors=3)
    for _ in range(2):
        sensor.bus.send(can.Message(is_error_frame=True))
    sensor.send()
    node.step(Tick(1, 0.001, 0.001), {})  # a valid sample resets the run
    for _ in range(3):
        sensor.bus.send(can.Message(is_error_frame=True))
    with pytest.raises(DeviceError, match="bus error: 3 error frames in a row"):
        node.step(Tick(2, 0.002, 0.001), {})
    assert node.error_frames == 5
