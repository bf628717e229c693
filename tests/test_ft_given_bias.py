"""A given F/T bias (the loop file's tare): it reaches the driver from loop:=, the driver subtracts
exactly it instead of taring at start, its start samples only check it (tare.mismatch), a restarted
driver still keeps the graph's first, and a bad one is refused at launch in one line."""

from __future__ import annotations

import math

import pytest

from dockhil.cli import main
from dockhil.devices import tare
from dockhil.devices.ati_netft.driver import FtNetFtDriver
from dockhil.devices.can_ft.driver import FtCanDriver
from dockhil.errors import DeviceError, LaunchError, ParamError
from dockhil.node import NodeContext, Tick
from dockhil.runtime import ownership
from dockhil.scene import launchfile
from tests.conftest import VirtualFtSensor
from tests.test_hardware_netft import LBF, FakeBox, arrive, record

OFFSET = (1.5, -0.25, 0.5)  # the unloaded sensor's offset [N]
MILLION = 1_000_000  # counts per lbf of the fake box's page


def loop_file(tmp_path, tare_text='{"force_N": [0.31, -0.12, 1.05], "torque_Nm": [0.011, -0.004, 0.002]}'):
    path = tmp_path / "loop.yaml"
    path.write_text(f"args:\n  delay: 0.036\n  lag: 0.01\n  k: 1000.0\n  ft_noise: 0.2\ntare: {tare_text}\n")
    return path


def ft_params(scene) -> dict:
    return next(n for n in scene.nodes if n.name == "ft").params


# -- the scene: loop:= reaches the driver's bias -------------------------------------------------------------


@pytest.mark.parametrize(
    "scene, args",
    [
        ("hil.yaml", ["ft:=can", "robot:=modbus"]),
        ("hil.yaml", ["ft:=netft", "robot:=modbus"]),
        ("hil.yaml", ["ft:=netft", "robot:=modbus", "emulators:=true"]),
        ("hil6.yaml", ["ft:=netft", "robot:=rsi"]),
        ("hil6.yaml", ["ft:=netft", "robot:=rsi", "emulators:=true"]),
    ],
)
def test_a_loop_files_tare_reaches_the_f_t_drivers_bias(tmp_path, scene, args):
    loop = loop_file(tmp_path)
    s = launchfile.load(scene, launchfile.parse_overrides([f"loop:={loop}", *args]))
    assert ft_params(s)["bias"] == [0.31, -0.12, 1.05, 0.011, -0.004, 0.002]
    assert ft_params(s)["bias_from"] == str(loop)
    assert ft_params(launchfile.load(scene, launchfile.parse_overrides(args)))["bias"] == []  # none: tare at start


def test_the_command_line_wins_over_the_loop_files_tare(tmp_path):
    loop = loop_file(tmp_path)
    given = launchfile.parse_overrides([f"loop:={loop}", "ft:=can", "robot:=modbus", "ft_bias:=1,2,3,0.1,0.2,0.3"])
    assert ft_params(launchfile.load("hil.yaml", given))["bias"] == [1.0, 2.0, 3.0, 0.1, 0.2, 0.3]
    given = launchfile.parse_overrides([f"loop:={loop}", "ft:=can", "robot:=modbus", "ft_bias:=[]"])
    scene = launchfile.load("hil.yaml", given)
    assert ft_params(scene)["bias"] == [] and scene.values["delay"] == 0.036  # the rest of the file still holds
    # and a bad tare in the file is not read when the command line drops it
    bad = loop_file(tmp_path, '{"force_N": [1, 2]}')
    given = launchfile.parse_overrides([f"loop:={bad}", "ft:=can", "robot:=modbus", "ft_bias:=[]"])
    assert ft_params(launchfile.load("hil.yaml", given))["bias"] == []


@pytest.mark.parametrize(
    "tare_text, why",
    [
        ('{"force_N": [1, 2]}', "tare.force_N is [1, 2], not three finite numbers"),
        ('{"force_N": [1, 2, 3]}', "tare.torque_Nm is None, not three finite numbers"),
        ('{"force_N": [1, 2, .nan], "torque_Nm": [0, 0, 0]}', "tare.force_N is [1, 2, nan], not three finite"),
        ('{"force_N": [1, 2, "x"], "torque_Nm": [0, 0, 0]}', "not three finite numbers"),
        ("[1, 2, 3, 4, 5, 6]", "tare.force_N is None"),
    ],
)
def test_a_bad_tare_in_the_loop_file_is_one_line(tmp_path, tare_text, why):
    loop = loop_file(tmp_path, tare_text)
    with pytest.raises(LaunchError) as err:
        launchfile.load("hil.yaml", {"loop": str(loop)})
    text = str(err.value)
    assert "\n" not in text and text.startswith(f"loop file {loop}: ") and why in text, text
    assert "ft_bias:=[]" in text


@pytest.mark.parametrize(
    "value, words",
    [
        ("[1,2,3,0.1,0.2,nan]", "arg 'ft_bias'[5] is nan; give a finite number"),
        ("[1,2,3,0.1,0.2,inf]", "arg 'ft_bias'[5] is inf; give a finite number"),
        ("[1,2,x]", "arg 'ft_bias' expects a list of numbers, got '[1,2,x]'"),
        ("1,2,3", "parameter 'bias': 3 numbers; give [fx, fy, fz, tx, ty, tz]"),
        ("[1,2,3,4,5,6,7]", "parameter 'bias': 7 numbers"),
        ("[60,0,0,0,0,0]", "parameter 'bias': |F| = 60.0 N > max_bias 50 N"),
    ],
)
@pytest.mark.parametrize("ft", ["can", "netft"])
def test_a_bad_bias_is_refused_at_launch_in_one_line_exit_2(capsys, ft, value, words):
    assert main(["graph", "hil.yaml", f"ft:={ft}", "robot:=modbus", f"ft_bias:={value}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err


@pytest.mark.parametrize(
    "bias, words",
    [
        ([1, 2, 3], "parameter 'bias': 3 numbers"),
        ([1, 2, 3, 0, 0, math.nan], "parameter 'bias'[5]: nan is not a finite number"),
        ([1, 2, 3, 0, 0, True], "parameter 'bias'[5]: True is not a finite number"),
        ([1, 2, 3, 0, 0, "0"], "parameter 'bias'[5]: '0' is not a finite number"),
        ("1,2,3,0,0,0", "parameter 'bias': expected list, got str"),
        ([0, 0, 0, 3, 0, 4.01], "|T| = 5.01 N m > max_bias_torque 5 N m"),
    ],
)
@pytest.mark.parametrize("cls", [FtCanDriver, FtNetFtDriver])
def test_a_bad_bias_parameter_is_refused_in_one_line(cls, bias, words):
    with pytest.raises(ParamError) as err:
        cls.resolve_params("ft", {"bias": bias})
    assert "\n" not in str(err.value) and words in str(err.value), str(err.value)


# -- the rule: the start samples against the given bias ------------------------------------------------------


def start_of(force, torque=(0.0, 0.0, 0.0), force_spread=0.0, torque_spread=0.0) -> tare.Bias:
    return tare.Bias(force, torque, force_spread, torque_spread, 100)


def given(force, torque=(0.0, 0.0, 0.0)) -> tare.Bias:
    return tare.given_bias([*force, *torque])


def test_the_start_may_differ_from_the_given_bias_by_5_noise_sd_and_a_floor():
    limits = tare.TareLimits()
    # noise sd 0.1 N: the band is 5 * 0.1 + 0.5 = 1.0 N on each axis
    assert tare.mismatch(start_of((1.0, 0.0, 0.0), force_spread=0.1), given((0.01, 0.0, 0.0)), limits) is None
    why = tare.mismatch(start_of((1.0, 0.0, 0.0), force_spread=0.1), given((-0.01, 0.0, 0.0)), limits)
    assert why and "Fx - bias = +1.010 N, beyond the noise band 1.000 N (5 sd 0.100 N + 0.5 N)" in why
    # no noise: the floor alone
    assert tare.mismatch(start_of((0.0, 0.49, 0.0)), given((0.0, 0.0, 0.0)), limits) is None
    assert "Fy - bias = -0.510 N" in tare.mismatch(start_of((0.0, -0.51, 0.0)), given((0.0, 0.0, 0.0)), limits)
    # torque: 5 * 0.002 + 0.05 N m
    ok, off = start_of((0, 0, 0), (0.0, 0.0, 0.059), torque_spread=0.002), given((0, 0, 0))
    assert tare.mismatch(ok, off, limits) is None
    bad = start_of((0, 0, 0), (0.0, 0.0, 0.061), torque_spread=0.002)
    assert "Tz - bias = +0.0610 N m, beyond the noise band 0.0600 N m" in tare.mismatch(bad, off, limits)


def test_a_start_further_than_max_bias_from_the_given_bias_or_spread_is_refused():
    limits = tare.TareLimits(max_bias=20.0)
    why = tare.mismatch(start_of((30.0, 0.0, 0.0), force_spread=5.0), given((5.0, 0.0, 0.0)), limits)
    assert why and "|F - bias| = 25.0 N > max_bias 20 N" in why
    # within the band that a large spread makes, but the probe moved while starting
    why = tare.mismatch(start_of((5.0, 0.0, 0.0), force_spread=3.0), given((0.0, 0.0, 0.0)), limits)
    assert why and "force spread 3.00 N over 100 samples > max_tare_spread 2 N" in why


# -- the CAN driver on a virtual bus ---------------------------------------------------------------------------


@pytest.fixture
def can_sensor(request):
    s = VirtualFtSensor(f"ft-{request.node.name}")
    nodes: list = []
    yield s, nodes
    for node in nodes:
        node.close()
    s.close()


def can_start(can_sensor, logs, force, tare_samples=20, **params):
    """A CAN driver started while the sensor reads `force`; its first tick (t = 0) taken."""
    sensor, nodes = can_sensor
    sensor.force = force
    sensor.stream()
    node = FtCanDriver(
        NodeContext("ft", 0.001, sim_time=False, log=logs.append),
        interface="virtual",
        channel=sensor.channel,
        tare_samples=tare_samples,
        **params,
    )
    nodes.append(node)
    try:
        node.setup()
    finally:
        sensor.quiet()
    node.step(Tick(0, 0.0, 0.001), {})
    return node


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_the_can_driver_subtracts_exactly_the_given_bias_not_the_start_mean(can_sensor, sign):
    logs: list[str] = []
    # The bias as the driver publishes the unloaded probe untared (sign applied), 0.25 N off the
    # start on x: within the band, and not what a tare would take.
    bias = [sign * OFFSET[0] + 0.25, sign * OFFSET[1], sign * OFFSET[2], 0.0, 0.0, 0.03]
    node = can_start(can_sensor, logs, OFFSET, sign=sign, bias=bias, bias_from="loop.yaml")
    sensor, _ = can_sensor
    sensor.send(force=(11.5, -0.25, 0.5), torque=(0.0, 0.0, 0.0))
    w = node.step(Tick(1, 0.001, 0.001), {})["wrench"].wrench
    assert (w.force.x, w.force.y, w.force.z) == pytest.approx((sign * 11.5 - bias[0], 0.0, 0.0), abs=1e-12)
    assert w.torque.z == pytest.approx(-0.03, abs=1e-12)
    line = next(m for m in logs if "within the noise band" in m)
    assert "of the bias given by loop.yaml" in line and "tared over" not in " ".join(logs)


def test_the_can_driver_refuses_a_given_bias_the_start_does_not_fit_naming_the_file(can_sensor):
    logs: list[str] = []
    bias = [OFFSET[0], OFFSET[1] + 3.0, OFFSET[2], 0.0, 0.0, 0.0]  # re-mounted: 3 N off on y
    with pytest.raises(DeviceError) as err:
        can_start(can_sensor, logs, OFFSET, bias=bias, bias_from="lab/loop.yaml")
    text = str(err.value)
    assert "\n" not in text and text.startswith("F/T sensor (virtual "), text
    assert "the given bias (lab/loop.yaml) does not fit" in text and "Fy - bias = -3.000 N" in text
    assert "dockhil calibrate --out" in text and "ft_bias:=[]" in text


def test_a_restarted_driver_keeps_the_graphs_first_bias_given_and_is_not_refused_in_contact(can_sensor):
    ownership.set_graph("graph-given-bias")
    try:
        logs: list[str] = []
        bias = [*OFFSET, 0.0, 0.0, 0.0]
        can_start(can_sensor, logs, OFFSET, bias=bias).close()
        loaded = (OFFSET[0] + 10.5, OFFSET[1], OFFSET[2])  # it comes back in contact: 10.5 N
        again = can_start(can_sensor, logs, loaded, bias=bias)
        assert again.bias_force == pytest.approx(OFFSET)
        assert any("restarted: kept the graph's first tare" in m for m in logs)
    finally:
        ownership.set_graph("")


def test_tare_samples_0_reads_raw_even_with_a_given_bias(can_sensor):
    """What dockhil calibrate asks for to measure the bias, whatever loop file the scene was given."""
    logs: list[str] = []
    node = can_start(can_sensor, logs, OFFSET, tare_samples=0, bias=[*OFFSET, 0.0, 0.0, 0.0])
    sensor, _ = can_sensor
    sensor.send(force=OFFSET)
    w = node.step(Tick(1, 0.001, 0.001), {})["wrench"].wrench
    assert (w.force.x, w.force.y, w.force.z) == pytest.approx(OFFSET)
    assert any("tare_samples 0: raw readings, the bias given is not subtracted" in m for m in logs)


# -- the Net F/T driver against a fake box ----------------------------------------------------------------------


def test_the_netft_driver_subtracts_exactly_the_given_bias():
    logs: list[str] = []
    box = FakeBox()
    counts = (MILLION, 0, 0, 0, 0, 0)  # 1 lbf of offset on x
    box.on_start = [record(i + 1, 10 * (i + 1), 0, counts) for i in range(20)]
    bias = [LBF + 0.3, 0.0, 0.0, 0.0, 0.0, 0.01]
    driver = FtNetFtDriver(
        NodeContext("ft", 0.001, sim_time=False, log=logs.append),
        host="127.0.0.1",
        port=box.port,
        http_port=box.http_port,
        tare_samples=20,
        bias=bias,
        bias_from="loop.yaml",
    )
    try:
        driver.setup()
        box.send(record(21, 210, 0, (11 * MILLION, 0, 0, 0, 0, 0)))
        arrive(driver, 21)
        w = driver.step(Tick(0, 0.0, 0.001), {})["wrench"].wrench
        assert w.force.x == pytest.approx(11 * LBF - bias[0], abs=1e-9) and w.force.y == 0.0
        assert w.torque.z == pytest.approx(-0.01, abs=1e-12)
        assert any("within the noise band of the bias given by loop.yaml" in m for m in logs)
    finally:
        driver.close()
        box.close()


def test_the_netft_driver_refuses_a_given_bias_the_start_does_not_fit():
    box = FakeBox()
    box.on_start = [record(i + 1, 10 * (i + 1), 0, (MILLION, 0, 0, 0, 0, 0)) for i in range(20)]
    driver = FtNetFtDriver(
        NodeContext("ft", 0.001, sim_time=False, log=lambda m: None),
        host="127.0.0.1",
        port=box.port,
        http_port=box.http_port,
        tare_samples=20,
        bias=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        bias_from="loop.yaml",
    )
    try:
        with pytest.raises(DeviceError) as err:
            driver.setup()
        text = str(err.value)
        assert "\n" not in text and "the given bias (loop.yaml) does not fit" in text, text
        assert f"Fx - bias = +{LBF:.3f} N, beyond the noise band 0.500 N" in text
    finally:
        driver.close()
        box.close()
