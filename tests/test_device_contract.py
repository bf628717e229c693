"""The contract every device driver keeps, each clause run against every driver and its emulator
(tests/support/devices.py: ft_can + ft_emulator on a python-can virtual bus, ft_netft + NetFtBox,
robot_modbus + the robot_emulator node, robot_rsi + RsiControllerEmulator). The drivers step on a
ManualClock, one period a step, so every timeout is decided on the test's clock; only the devices'
own streams take real time, and the tests wait for them with deadlines.

A new device is one more rig in tests/support/devices.py; what a device cannot show of a clause is
said in the clause's docstring, with the nearest equivalent it tests instead."""

from __future__ import annotations

import math
import os
import re
import time

import pytest

from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.emulator import FOLLOW, HOLD
from dockhil.errors import DeviceError
from tests.conftest import wait_for
from tests.support.devices import DT, GRAPH, OTHER_GRAPH, RIGS, STALE, in_graph

FT_RIGS = ("ft_can", "ft_netft")


@pytest.fixture(params=list(RIGS))
def rig(request):
    """The device's emulator running and its driver set up in graph GRAPH; all closed after."""
    made = RIGS[request.param]()
    try:
        yield made.start()
    finally:
        made.close()


def measured(rig, out: dict) -> float:
    """What the published message says along x: the force [N], or the robot's position [m]."""
    msg = out[rig.published]
    return msg.pose.position.x if rig.robot else msg.wrench.force.x


def start_moving(rig) -> None:
    """A robot at rest at the scene's x = 0 (the first command anchors RSI there), then commanded 10 mm
    along x; returns once the link has sent the first step toward it (the limits make it take many)."""
    rig.until(lambda o: rig.published in o)
    rig.target = 0.01
    rig.until(lambda o: rig.sent_x() > 0.0)
    assert rig.sent_x() < 0.005


def test_starts_steps_and_stops_and_the_device_is_free_again(rig):
    """Setup, steps on the test's clock publishing what the device measures, close; then a second
    driver claims the device and reads it."""
    out = rig.until(lambda o: rig.published in o)
    assert measured(rig, out) == pytest.approx(0.0, abs=1e-6)  # at rest (the F/T offset tared away)
    for _ in range(5):
        rig.step()
    rig.driver.close()
    with in_graph(GRAPH):
        second = rig.build()
        rig.setup(second)
    rig.driver = second
    out = rig.until(lambda o: rig.published in o)
    assert measured(rig, out) == pytest.approx(0.0, abs=1e-6)
    second.close()


def test_malformed_and_foreign_input_is_counted_and_never_applied(rig):
    """A malformed datagram or frame and a well-formed one from a foreign sender, each saying the
    probe is pushed with 300-900 N or the robot stands 50 mm away: counted, and the published wrench,
    the published pose and what the robot is commanded stay where the device's own data put them.

    Nearest equivalents: RSI's foreign sender is another address (RSI configures the sensor's
    IP_NUMBER and PORT, not the controller's source port, so the driver tells its controller by
    address, and by the port its first datagram came from: a well-formed datagram from another port
    is foreign too, a malformed one malformed); on a CAN bus the foreign sender is another device's CAN ID; the bus carries
    other devices' frames by design, so ft_can skips them without counting them. Over Modbus TCP the
    driver is the client: the malformed and the foreign request reach the controller (a write whose
    byte count disagrees with its register count; a setpoint write from another connection, which
    holds no claim), which refuses them with exception 3 and 6; the controller counts the foreign one
    (`unclaimed`) and answers, but does not count, the malformed one."""
    rig.until(lambda o: rig.published in o)
    before = rig.rejected()
    rig.send_malformed()
    rig.send_foreign()
    after = before
    seen: list[dict] = []

    def counted(out) -> bool:
        nonlocal after
        after = rig.rejected()
        return all(after[kind] == before[kind] + 1 for kind in after if after[kind] is not None)

    rig.until(counted, seen=seen)
    for _ in range(20):  # what was under way
        seen.append(rig.step())
        time.sleep(0.001)
    assert after == rig.rejected()  # one each, counted once
    published = [measured(rig, out) for out in seen if rig.published in out]
    assert published and all(x == pytest.approx(0.0, abs=1e-6) for x in published), published
    if rig.name == "robot_modbus":
        assert rig.answers == [bytes((0x90, 3)), bytes((0x90, 6))]
        assert rig.holding().setpoint[0] == 0.0 and rig.servo("max_position")[0] <= 1e-9
    if rig.name == "robot_rsi":
        applied = rig.controller.applied
        assert applied and all(abs(v) < 1e-9 for korr in applied for v in korr), applied[-3:]
        assert rig.driver.link.korr[0] == (0.0, 0.0, 0.0)


def test_stale_input_stops_in_one_line_naming_the_device_and_the_robot_holds(rig):
    """The device falls silent: once nothing came for its timeout on the driver's clock, a step stops
    with one DeviceError line naming the device. A robot driver holds: when the controller comes back,
    all it is sent is a hold (RSI: the correction where it stopped, short of the command; Modbus: a
    hold and no setpoint).

    Nearest equivalents: a Modbus controller that falls silent is a lost connection
    (reconnect_timeout); an F/T driver has no robot to hold (the robot driver's ft_timeout holds it,
    tests/test_hardware_safety.py)."""
    if rig.robot:
        start_moving(rig)
    else:
        rig.until(lambda o: rig.published in o)
    rig.silence()
    time.sleep(0.05)  # what was under way arrives
    rig.step()
    held = rig.sent_x() if rig.name == "robot_rsi" else None  # the correction no datagram moves any more
    k0 = rig.k
    with pytest.raises(DeviceError) as err:
        for _ in range(round(STALE / DT) + 2):
            rig.step()
    steps = rig.k - k0 + 1  # the one that raised too
    text = str(err.value)
    assert "\n" not in text and text.startswith(rig.driver.device + ": "), text
    if not rig.robot:
        age = rig.clock() - rig.fresh_at
        assert age > STALE and age - DT <= STALE + 1e-9  # the first step past the timeout
        what = "record" if rig.name == "ft_netft" else "sample"
        assert text.endswith(f": stale data: no new {what} for {age:.3f} s (stale_timeout {STALE:g} s)"), text
        return
    assert steps > round(STALE / DT) // 2  # the timeout, not the first steps after the silence
    if rig.name == "robot_rsi":
        assert re.search(rf"no datagram for 0\.3\d\d s > controller_timeout {STALE:g} s", text), text
        assert rig.driver.link.hold_latched
        # RSI started again (from another port, its IPOC 100 s on): its correction starts from nothing, so
        # the correction held would be a jump; the driver reads no other sender than the controller it had
        rig.start_emulator(ipoc0=rig.controller.ipoc + 100_000)
        wait_for(lambda: rig.controller.stats["cycles"] >= 10, what="the controller's cycles")
        assert rig.controller.answers == [] and rig.controller.applied == [], rig.controller.answers
        assert 0.0 < held < 0.005
    else:
        assert re.search(rf"connection lost for 0\.3 s \(reconnect_timeout {STALE:g} s\)", text), text
        rig.start_emulator(port=rig.controller.port)  # the controller comes back
        wait_for(lambda: rig.driver.link.reconnects == 1, what="the reconnect")
        wait_for(lambda: rig.servo("cycles") > 20, what="the controller's cycles")
        written = rig.holding()
        assert (written.control, written.setpoint) == (mm.CONTROL_ENABLE | mm.CONTROL_HOLD, mm.HOLD_POSE)
        assert rig.servo("mode") != FOLLOW and rig.servo("position")[0] == 0.0


def test_close_holds_the_robot_and_says_where(rig):
    """Closed while the robot moves toward a command 10 mm away, a robot driver's last answer or write
    to the controller is a hold, the robot stops short of the command, and close says in one line that
    the robot holds and where (its last command, its last actual pose).

    Nearest equivalent for an F/T driver, which commands nothing: close ends the device's stream (the
    Net F/T box is sent a stop request; the CAN bus is shut) and says in one warning line what it
    counted (here one malformed datagram or frame)."""
    if not rig.robot:
        rig.until(lambda o: rig.published in o)
        rig.send_malformed()
        rig.until(lambda o: rig.rejected()["malformed"] == 1)
        stops = rig.box.counts["stops"] if rig.name == "ft_netft" else None
        said = len(rig.logs)
        rig.driver.close()
        warnings = [line for line in rig.logs[said:] if line.startswith("warning: ")]
        counted = "1 bad datagrams" if rig.name == "ft_netft" else "1 bad frames"
        assert len(warnings) == 1 and warnings[0].startswith(f"warning: {rig.driver.device}: "), rig.logs
        assert counted in warnings[0].split(": ", 2)[2].split(", "), warnings
        if rig.name == "ft_netft":
            wait_for(lambda: rig.box.counts["stops"] == stops + 1, what="the stop request")
        else:
            assert rig.driver.bus is None
        return
    start_moving(rig)
    rig.driver.close()
    if rig.name == "robot_modbus":
        assert rig.holding().control == mm.CONTROL_ENABLE | mm.CONTROL_HOLD
        wait_for(lambda: rig.servo("mode") == HOLD, what="the hold")
        stopped = rig.servo("position")[0]
        time.sleep(0.05)
        assert rig.servo("position")[0] == stopped < 0.005
    else:
        answers, applied = rig.controller.answers, rig.controller.applied
        time.sleep(0.05)  # the answers under way at close arrive
        n = len(answers)
        time.sleep(0.05)
        assert len(answers) == n >= 2  # nothing answered after close
        # The hold: the last answer keeps the correction of the one before, or, if that one came too
        # late to be taken, the correction the controller kept.
        last, before = answers[-1], answers[-2]
        assert last == before or (before not in applied and last == applied[-1]), (answers[-5:], applied[-5:])
        assert 0.0 < last[0] < 5.0
    lines = [line for line in rig.logs if "the robot holds" in line or "hold was not confirmed" in line]
    number = r"-?\d+\.\d{4}"
    where = rf"x {number} y {number} z {number} m"
    assert len(lines) == 1 and re.fullmatch(
        re.escape(rig.driver.device) + rf": the robot holds; last command x 0\.0100 y 0\.0000 z 0\.0000 m, "
        rf"actual {where}",
        lines[0],
    ), rig.logs
    actual_x = float(lines[0].split("actual x ")[1].split()[0])
    assert 0.0 <= actual_x < 0.005 and not math.isnan(actual_x)


def test_a_second_graph_claiming_the_device_is_refused_naming_the_owner(rig):
    """A driver of another graph naming the same device is refused in one line naming the device and
    its owner, before it sends anything; the owner goes on undisturbed."""
    rig.until(lambda o: rig.published in o)
    with in_graph(OTHER_GRAPH):
        other = rig.build([])
        with pytest.raises(DeviceError) as err:
            rig.setup(other)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"{rig.claimed()} is in use by graph {GRAPH} (pid {os.getpid()} on "), text
    assert text.endswith("; stop it first, or give this graph another device"), text
    out = rig.until(lambda o: rig.published in o)
    assert measured(rig, out) == pytest.approx(0.0, abs=1e-6)


def test_a_second_graph_emulating_the_device_is_refused_naming_the_owner(rig):
    """An emulator node of another graph on the same device (the port the driver reads, the CAN bus
    it listens on, the controller's port) is refused in one line naming the device and its owner; the
    owner goes on undisturbed."""
    rig.until(lambda o: rig.published in o)
    with in_graph(OTHER_GRAPH):
        other, device = rig.second_emulator()
        try:
            with pytest.raises(DeviceError) as err:
                other.setup()
        finally:
            other.close()
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"{device} is in use by graph {GRAPH} (pid {os.getpid()} on "), text
    out = rig.until(lambda o: rig.published in o)
    assert measured(rig, out) == pytest.approx(0.0, abs=1e-6)
