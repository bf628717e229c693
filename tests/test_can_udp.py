"""The emulated CAN F/T sensor of hil.yaml over python-can's udp_multicast on loopback: a group drawn for
each graph, kept to its own group and to this host, claimed by its graph, refused in one line where
it cannot be joined; the pseudo-terminal slcan adapter stays selectable."""

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from dockhil.devices.can_ft import multicast as can_multicast
from dockhil.devices.can_ft.emulator import FtSensorEmulator
from dockhil.errors import DeviceError
from dockhil.node import NodeContext
from dockhil.runtime import ownership
from dockhil.scene import launchfile
from dockhil.scene.graph import build
from tests.support.inprocess import run_main

HIL = Path(__file__).resolve().parent.parent / "launch" / "hil.yaml"
ROOT = HIL.parent.parent


def ft_nodes(**args):
    """(driver params, emulator params or None) of hil.yaml resolved with `args`, through the graph check."""
    graph = build(launchfile.load(HIL, {"ft": "can", "robot": "modbus", **args}))
    emulator = graph.nodes.get("ft_emulator")
    return graph.nodes["ft"].params, emulator.params if emulator else None


def test_emulated_can_is_udp_multicast_on_a_group_of_the_graphs_own():
    groups = set()
    for _ in range(3):
        driver, emulator = ft_nodes(emulators=True)
        assert driver["interface"] == emulator["interface"] == "udp_multicast"
        assert driver["channel"] == emulator["channel"]  # one group for the scene and its include
        assert driver["loopback"] and emulator["loopback"]
        assert can_multicast.check_group(driver["channel"]) is None and driver["channel"].startswith("239.74.")
        groups.add(driver["channel"])
    assert len(groups) > 1  # each resolution draws its own (three equal: 1 in 4e9)


def test_dockhil_graph_shows_the_drawn_group():
    code, out, err = run_main("graph", str(HIL), "ft:=can", "robot:=modbus", "emulators:=true")
    assert code == 0, err
    lines = [line for line in out.splitlines() if "interface='udp_multicast'" in line]
    assert len(lines) == 2 and lines[0] == lines[1], out  # the driver's and the emulator's
    assert "channel='239.74." in lines[0]


def test_the_labs_adapter_and_the_pseudo_terminal_stay_as_they_were():
    driver, emulator = ft_nodes(emulators=False)
    assert (driver["interface"], driver["channel"], emulator) == ("slcan", "", None)
    driver, _ = ft_nodes(emulators=False, can_interface="socketcan", can_channel="can0")
    assert (driver["interface"], driver["channel"]) == ("socketcan", "can0")
    driver, emulator = ft_nodes(emulators=True, can_interface="pty")
    assert (driver["interface"], driver["channel"]) == ("pty", "")
    assert (emulator["interface"], emulator["channel"]) == ("pty", "")


def test_a_driver_off_its_emulators_bus_is_refused_in_one_line():
    code, _, err = run_main("graph", str(HIL), "ft:=can", "robot:=modbus", "emulators:=true", "can_interface:=slcan")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "node 'ft' (ft_can) reads CAN slcan ''" in err and "give can_interface:=auto or pty" in err


def test_a_udp_multicast_channel_that_is_no_group_is_refused_before_anything_runs():
    code, _, err = run_main("graph", str(HIL), "ft:=can", "robot:=modbus", "can_interface:=udp_multicast")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "node 'ft' parameter 'channel': '' is not an IPv4 address; give a group such as 239.74.1.2" in err


def test_the_built_in_group_is_one_per_scene_and_a_declared_name_wins(tmp_path):
    (tmp_path / "inner.yaml").write_text(
        "nodes:\n  - {name: b, node: ft_sim, params: {frame: $(var multicast_group)}}\n"
    )
    (tmp_path / "outer.yaml").write_text(
        "nodes:\n  - {name: a, node: ft_sim, params: {frame: $(var multicast_group)}}\ninclude:\n  - file: inner.yaml\n"
    )
    scene = launchfile.load(tmp_path / "outer.yaml")
    a, b = (n.params["frame"] for n in scene.nodes)
    assert a == b and can_multicast.check_group(a) is None
    (tmp_path / "own.yaml").write_text(
        "args:\n  multicast_group: {default: mine}\n"
        "nodes:\n  - {name: a, node: ft_sim, params: {frame: $(var multicast_group)}}\n"
    )
    assert launchfile.load(tmp_path / "own.yaml").nodes[0].params["frame"] == "mine"


def bus(group: str):
    import can

    b = can.Bus(interface="udp_multicast", channel=group)
    can_multicast.on_loopback(b, group)
    return b


def test_a_bus_reads_its_own_group_alone():
    """python-can binds the port on every address, and Linux hands such a socket every group joined on
    the host (IP_MULTICAST_ALL): two graphs on two groups read each other's frames until on_loopback."""
    import can

    mine, other = launchfile.draw_group(), launchfile.draw_group()
    while other == mine:
        other = launchfile.draw_group()
    reader, sender, stranger = bus(mine), bus(mine), bus(other)
    try:
        stranger.send(can.Message(arbitration_id=0x1A0, data=b"x", is_extended_id=False))
        sender.send(can.Message(arbitration_id=0x7, data=b"y", is_extended_id=False))  # after the stranger's
        got = []
        while 0x7 not in got:
            msg = reader.recv(5.0)
            assert msg is not None, got
            got.append(msg.arbitration_id)
        assert got == [0x7]
    finally:
        for b in (reader, sender, stranger):
            b.shutdown()


def ctx(name):
    return NodeContext(name, 0.001, sim_time=False, log=lambda line: None)


def test_a_second_graph_naming_the_same_group_is_refused_naming_the_owner():
    group = launchfile.draw_group()
    ownership.set_graph("graph-one")
    try:
        first = FtSensorEmulator(ctx("ft_emulator"), interface="udp_multicast", channel=group)
        first.setup()
    finally:
        ownership.set_graph("")
    try:
        ownership.set_graph("graph-two")
        try:
            with pytest.raises(DeviceError) as err:
                FtSensorEmulator(ctx("ft_emulator"), interface="udp_multicast", channel=group).setup()
        finally:
            ownership.set_graph("")
        text = str(err.value)
        assert "\n" not in text
        assert text.startswith(f"CAN bus udp_multicast {group} is in use by graph graph-one (pid {os.getpid()} "), text
    finally:
        first.close()


JOIN = """
import sys
from dockhil.errors import DeviceError
from dockhil.node import NodeContext
from dockhil.devices.can_ft.{module} import {cls}
node = {cls}(NodeContext("ft", 0.001, sim_time=False, log=print), interface="udp_multicast", channel="239.74.1.2")
try:
    node.setup()
except DeviceError as exc:
    print(exc)
    sys.exit(2)
"""


@pytest.mark.skipif(shutil.which("unshare") is None, reason="needs unshare(1)")
@pytest.mark.parametrize("module, cls", [("driver", "FtCanDriver"), ("emulator", "FtSensorEmulator")])
def test_a_group_without_a_route_is_refused_in_one_line_saying_what_to_do(tmp_path, module, cls):
    """In a network namespace of its own the host has loopback alone, and no route for the group."""
    if subprocess.run(["unshare", "-rn", "true"], capture_output=True).returncode != 0:
        pytest.skip("unprivileged network namespaces are not allowed here")
    code = shlex.quote(JOIN.format(module=module, cls=cls))
    script = f"ip link set lo up 2>/dev/null; exec {shlex.quote(sys.executable)} -c {code}"
    env = {**os.environ, "DOCKHIL_RUNTIME_DIR": str(tmp_path)}
    r = subprocess.run(
        ["unshare", "-rn", "sh", "-c", script], capture_output=True, text=True, env=env, timeout=60, cwd=ROOT
    )
    lines = r.stdout.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, (r.stdout, r.stderr)
    assert (
        "cannot join multicast group 239.74.1.2 on loopback (No such device): this host has no route for it" in lines[0]
    )
    assert "launch with can_interface:=pty" in lines[0]
