"""The F/T driver's own safety: a restarted driver keeps the graph's first tare (it may come back in
contact), a tare whose samples spread beyond the noise band is refused, a CAN channel that another
user could plant or replace is refused before a sample is read, and every parameter has a range."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import threading
import time

import pytest

from dockhil.devices import tare
from dockhil.devices.can_ft.driver import FtCanDriver
from dockhil.devices.can_ft.emulator import FtSensorEmulator
from dockhil.devices.can_ft.slcan_pty import SlcanPort
from dockhil.devices.device_path import private_link, untrusted
from dockhil.errors import DeviceError, ParamError
from dockhil.node import NodeContext, Tick
from dockhil.runtime import ownership
from tests.conftest import ROOT, VirtualFtSensor, node_process_error

OTHER = 65534  # nobody: another local user
OFFSET = (1.5, -0.25, 0.5)  # the unloaded sensor's offset
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def ctx(logs: list) -> NodeContext:
    return NodeContext("ft", 0.001, sim_time=False, log=logs.append)


@pytest.fixture
def in_graph():
    ownership.set_graph("graph-ft")
    yield ownership.graph_dir()
    ownership.set_graph("")


@pytest.fixture
def sensor(request):
    s = VirtualFtSensor(f"ft-{request.node.name}")
    yield s
    s.close()


def start(sensor, logs, force, **params):
    """A driver started while the sensor reads `force`; its first tick (t = 0) taken."""
    sensor.force = force
    sensor.stream()
    node = FtCanDriver(ctx(logs), interface="virtual", channel=sensor.channel, tare_samples=20, **params)
    try:
        node.setup()
    finally:
        sensor.quiet()
    node.step(Tick(0, 0.0, 0.001), {})  # take what the stream left
    return node


# -- the tare ------------------------------------------------------------------------------------


def test_a_driver_restarted_mid_contact_keeps_the_graphs_first_tare(sensor, in_graph):
    logs: list[str] = []
    first = start(sensor, logs, OFFSET)
    assert first.bias_force == pytest.approx(OFFSET)
    kept = in_graph / "tare-ft.json"
    assert stat.S_IMODE(kept.stat().st_mode) == 0o600 and kept.stat().st_uid == os.getuid()
    first.close()  # the driver dies mid-contact: the probe now carries 10.5 N on top of its offset
    loaded = (OFFSET[0] + 10.5, OFFSET[1], OFFSET[2])
    again = start(sensor, logs, loaded)
    try:
        assert again.bias_force == pytest.approx(OFFSET)  # not the contact force
        sensor.send(force=loaded)
        w = again.step(Tick(1, 0.001, 0.001), {})["wrench"]
        assert w.wrench.force.x == pytest.approx(10.5) and w.wrench.force.y == pytest.approx(0.0)
        line = next(m for m in logs if "): restarted: " in m)
        assert "kept the graph's first tare" in line and "reads 10.50 N from it now" in line
    finally:
        again.close()


def test_another_graph_and_a_driver_outside_a_graph_tare_anew(sensor, in_graph):
    """The first tare is the graph's: it goes with the graph, never to the next one."""
    logs: list[str] = []
    start(sensor, logs, OFFSET).close()
    for graph in ("graph-next", ""):
        ownership.set_graph(graph)
        node = start(sensor, logs, (2.0, 0.0, 0.0))
        assert node.bias_force == pytest.approx((2.0, 0.0, 0.0))
        node.close()


def test_a_tare_spread_beyond_the_noise_band_is_refused_in_one_line(sensor):
    logs: list[str] = []
    sensor.force = OFFSET
    sensor.stream()
    stop = threading.Event()

    def press():  # someone leans on the probe while it tares: 0 to 12 N and back
        k = 0
        while not stop.is_set():
            sensor.force = (OFFSET[0] + (12.0 if k % 20 < 10 else 0.0), OFFSET[1], OFFSET[2])
            k += 1
            time.sleep(0.001)

    presser = threading.Thread(target=press, daemon=True)
    presser.start()
    node = FtCanDriver(ctx(logs), interface="virtual", channel=sensor.channel, tare_samples=100)
    try:
        with pytest.raises(DeviceError) as err:
            node.setup()
    finally:
        stop.set()
        presser.join()
        sensor.quiet()
    text = str(err.value)
    assert "\n" not in text and "tare: force spread" in text and "> max_tare_spread 2 N" in text, text
    assert "free the probe" in text


def test_measure_and_refusal():
    quiet = [((1.0 + 0.1 * (-1) ** i, 0.0, 0.0), (0.0, 0.0, 0.01 * (-1) ** i)) for i in range(10)]
    bias = tare.measure(quiet)
    assert bias.force == pytest.approx((1.0, 0.0, 0.0)) and bias.force_spread == pytest.approx(0.1)
    assert bias.torque_spread == pytest.approx(0.01) and bias.samples == 10
    assert tare.refusal(bias, tare.TareLimits()) is None
    pressed = [((10.0 * (i % 2), 0.0, 0.0), (0.0, 0.0, 0.0)) for i in range(4)]
    why = tare.refusal(tare.measure(pressed), tare.TareLimits())
    assert why.startswith("force spread 5.00 N over 4 samples > max_tare_spread 2 N")
    assert tare.refusal(tare.measure(pressed), tare.TareLimits(max_spread=0.0)) is None  # 0: off
    twisted = [((0.0, 0.0, 0.0), (0.0, 0.0, 0.5 * (i % 2))) for i in range(4)]
    assert tare.refusal(tare.measure(twisted), tare.TareLimits()).startswith("torque spread 0.250 N m")
    with pytest.raises(ValueError):
        tare.measure([])


def test_the_kept_tare_is_refused_unless_a_plain_file_of_ours_of_mode_0600(tmp_path):
    store = tare.TareStore(tmp_path, "ft")
    assert store.load() is None
    bias = tare.Bias((1.0, 2.0, 3.0), (0.1, 0.2, 0.3), 0.01, 0.001, 100)
    store.save(bias)
    assert store.load() == bias and stat.S_IMODE(store.path.stat().st_mode) == 0o600
    os.chown(store.path, OTHER, OTHER)
    for words in ("uid 65534", "mode 0644", "damaged", "Too many levels of symbolic links"):
        if words == "mode 0644":
            os.chown(store.path, os.getuid(), os.getgid())
            os.chmod(store.path, 0o644)
        elif words == "damaged":
            os.chmod(store.path, 0o600)
            store.path.write_text(json.dumps({"force": [1, 2], "torque": [0, 0, 0]}))
        elif words.startswith("Too many"):
            store.path.unlink()
            (tmp_path / "elsewhere.json").write_text("{}")
            store.path.symlink_to(tmp_path / "elsewhere.json")
        with pytest.raises(DeviceError) as err:
            store.load()
        text = str(err.value)
        assert "\n" not in text and text.startswith(f"tare file {store.path}") and words in text, text


# -- device paths --------------------------------------------------------------------------------


def shared_dir(path, mode):
    path.mkdir()
    os.chmod(path, mode)
    return path


def test_device_paths_others_could_plant_or_replace_are_untrusted(tmp_path):
    master, slave = os.openpty()
    try:
        pty = os.ttyname(slave)  # ours, in root's /dev/pts
        assert untrusted("/dev/null") is None and untrusted(pty) is None
        sticky = shared_dir(tmp_path / "tmp", 0o1777)  # like /tmp
        ours = sticky / "ours.slcan"
        ours.symlink_to(pty)
        assert untrusted(str(ours)) is None  # our link in a sticky directory: nobody else may replace it
        assert untrusted(str(sticky / "not-yet")) is None  # its directories are safe; checked again when open

        planted = sticky / "planted.slcan"
        planted.symlink_to(pty)
        os.lchown(planted, OTHER, OTHER)
        assert untrusted(str(planted)) == f"{planted} belongs to uid {OTHER}, not to you or root"

        foreign = tmp_path / "foreign-device"
        foreign.touch()
        os.chown(foreign, OTHER, OTHER)
        to_foreign = sticky / "to-foreign"
        to_foreign.symlink_to(os.path.relpath(foreign, sticky))  # our link, their target
        assert untrusted(str(to_foreign)) == f"{foreign} belongs to uid {OTHER}, not to you or root"

        open_dir = shared_dir(tmp_path / "open", 0o777)  # no sticky bit: anyone may replace our link
        (open_dir / "ft.slcan").symlink_to(pty)
        why = untrusted(str(open_dir / "ft.slcan"))
        assert why == (
            f"directory {open_dir} (mode 0777) is writable by others without the sticky bit: "
            f"anyone may replace what is in it"
        )
        via = tmp_path / "via"
        via.symlink_to(open_dir)
        assert untrusted(str(via / "ft.slcan")) == why  # a directory reached through a link counts too

        theirs = shared_dir(tmp_path / "theirs", 0o755)
        os.chown(theirs, OTHER, OTHER)
        assert untrusted(str(theirs / "ft.slcan")) == f"{theirs} belongs to uid {OTHER}, not to you or root"

        group = shared_dir(tmp_path / "group", 0o775)
        os.chown(group, os.getuid(), OTHER)  # writable by a group of other users
        assert "writable by others" in untrusted(str(group / "x"))
        os.chown(group, os.getuid(), os.getgid())  # our own group
        assert untrusted(str(group / "x")) is None

        loop = tmp_path / "loop"
        loop.symlink_to(loop)
        assert "too many levels of symbolic links" in untrusted(str(loop))
    finally:
        os.close(master)
        os.close(slave)


def test_a_planted_channel_is_refused_before_a_sample_is_read(tmp_path):
    """Another user's emulated adapter in a sticky, world-writable directory, streaming forged forces."""
    sticky = shared_dir(tmp_path / "tmp", 0o1777)
    link = str(sticky / "dockhil-ft.slcan")
    port = SlcanPort(link)
    os.lchown(link, OTHER, OTHER)
    try:
        node = FtCanDriver(ctx([]), channel=link, open_timeout=0.5)
        with pytest.raises(DeviceError) as err:
            node.setup()
        text = str(err.value)
        assert "\n" not in text and text.startswith(
            f"F/T sensor (slcan {link}, CAN ID 0x1a0): refused: {link} belongs to uid {OTHER}, not to you or root"
        ), text
        port.read_host()
        assert not port.is_open and port.bitrate_code is None  # the driver never spoke to it
        spec = {
            "name": "ft",
            "type_name": "ft_can",
            "dt": 0.001,
            "clock": "wall",
            "params": {"channel": link, "open_timeout": 0.5},
        }
        line = node_process_error(spec, ENV)
        assert f"refused: {link} belongs to uid {OTHER}" in line
    finally:
        port.close()


def test_a_channel_in_a_directory_anyone_may_write_is_refused_and_no_adapter_is_made_there(tmp_path):
    open_dir = shared_dir(tmp_path / "open", 0o777)
    link = str(open_dir / "ft.slcan")
    em = FtSensorEmulator(ctx([]), channel=link)
    with pytest.raises(
        DeviceError,
        match=rf"^slcan adapter {link}: refused: directory {open_dir} \(mode 0777\) "
        rf"is writable by others",
    ):
        em.setup()
    assert not os.path.lexists(link)
    proc = subprocess.run(
        [sys.executable, "-m", "dockhil.devices.can_ft.slcan_pty", link],
        cwd=ROOT,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert proc.stderr.startswith(f"slcan_pty: error: slcan adapter {link}: refused: directory {open_dir}")
    node = FtCanDriver(ctx([]), channel=link, open_timeout=0.5)
    with pytest.raises(DeviceError, match=r"refused: directory .* writable by others without the sticky bit"):
        node.setup()


def test_the_default_channel_is_the_emulators_link_in_the_graphs_private_run_directory(in_graph):
    logs: list[str] = []
    em = FtSensorEmulator(ctx(logs))
    em.setup()
    link = str(in_graph / "ft.slcan")
    assert em.p.channel == link == private_link("ft.slcan") and os.path.islink(link)
    assert stat.S_IMODE(in_graph.stat().st_mode) == 0o700
    running = threading.Event()
    running.set()

    def stream():
        k = 0
        while running.is_set():
            em.step(Tick(k, k * 0.001, 0.001), {})
            k += 1
            time.sleep(0.001)

    streamer = threading.Thread(target=stream, daemon=True)
    streamer.start()
    node = FtCanDriver(ctx(logs), tare_samples=10, open_timeout=10.0)
    try:
        node.setup()
        assert node.p.channel == link and any(f"(slcan {link}," in m and "tared over 10" in m for m in logs)
    finally:
        node.close()
        running.clear()
        streamer.join()
        em.close()


# -- parameters ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "node, name, value",
    [
        (FtCanDriver, "bitrate", 2_000_000),
        (FtCanDriver, "tare_samples", -1),
        (FtCanDriver, "max_tare_spread", -0.5),
        (FtCanDriver, "max_tare_spread_torque", float("nan")),
        (FtCanDriver, "stale_timeout", 60.0),
        (FtCanDriver, "open_timeout", 0.0),
        (FtCanDriver, "force_resolution", 0.0),
        (FtCanDriver, "torque_resolution", 5.0),
        (FtCanDriver, "max_bias", 1e6),
        (FtCanDriver, "open_delay", -1.0),
        (FtCanDriver, "max_bus_errors", 0),
        (FtSensorEmulator, "k", -1.0),
        (FtSensorEmulator, "noise", 1e4),
        (FtSensorEmulator, "bias", 5000.0),
        (FtSensorEmulator, "seed", -1),
        (FtSensorEmulator, "bitrate", 0),
    ],
)
def test_every_parameter_out_of_its_range_is_refused(node, name, value):
    with pytest.raises(ParamError) as err:
        node(ctx([]), **{name: value})
    assert "\n" not in str(err.value) and name in str(err.value)


def test_a_node_process_with_a_parameter_out_of_range_exits_2_in_one_line():
    spec = {"name": "ft", "type_name": "ft_can", "dt": 0.001, "clock": "wall", "params": {"bitrate": 2_000_000}}
    proc = subprocess.run(
        [sys.executable, "-m", "dockhil.process", json.dumps(spec)],
        cwd=ROOT,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "bitrate" in proc.stderr, proc.stderr
