"""Lean scenes: a node loads python-can, pymodbus, scipy or matplotlib only if it uses them,
and the science and the CLI stay light. Each node type is measured in a fresh interpreter."""

import pytest

from dockhil import node_types
from dockhil.analysis import leanness

# One worker runs this file under pytest-xdist: every node type is measured once.
pytestmark = pytest.mark.xdist_group("lean")

SIMULATED = ("satellite_dynamics", "virtual_impedance", "ft_sim", "robot_sim", "delay_injector")


@pytest.fixture(scope="module")
def rows():
    measured = leanness.measure_all(repeats=1)
    return {row["node"]: row for row in measured}


# Memory budget of one node process: its peak resident memory (VmHWM) above a bare interpreter's.
# Memory and module sets do not depend on the machine's load; start-up times do, and are only
# reported (bench/lean.py). Measured here: 25-27 MB for the whole simulated HIL scene composed in one
# process; scipy.linalg alone adds 42 MB,
# matplotlib.pyplot 51 MB, so a node that loads either breaks the budget.
# The largest node is robot_modbus (pymodbus loads asyncio and ssl): 27.5 MB on Python 3.11, 28.1 on
# 3.12, 28.8 on 3.13 here, and 33.4 MB in a fresh 3.13 venv elsewhere, each newer interpreter's modules
# a little larger. 36 MB holds it on each, and stays under numpy, msgspec and scipy.linalg together
# (40.5 MB on 3.13, 43.3 on 3.11), which test_the_budget_would_catch_scipy_or_matplotlib_in_a_node checks.
NODE_BUDGET_MB = 36.0
SCENE_BUDGET_MB = 36.0
CLI_BUDGET_MB = 5.0  # `import dockhil.cli` loads no numpy (about 14 MB) until a command needs it


def over_bare_interpreter(rows, name) -> float:
    return rows[name]["rss_mb"] - rows["python, nothing of dockhil"]["rss_mb"]


def test_every_registered_node_type_is_measured_and_within_its_memory_budget(rows):
    for type_name in node_types.REGISTRY:
        assert type_name in rows, type_name
        row = rows[type_name]
        assert row["startup_s"] is not None and "rss_mb" in row, row
        assert over_bare_interpreter(rows, type_name) <= NODE_BUDGET_MB, row


def test_the_simulated_scenes_and_the_cli_stay_within_their_memory_budget(rows):
    for scene in ("scene launch/ideal.yaml", "scene launch/hil.yaml"):
        assert over_bare_interpreter(rows, scene) <= SCENE_BUDGET_MB, rows[scene]
    assert over_bare_interpreter(rows, "import dockhil.cli") <= CLI_BUDGET_MB, rows["import dockhil.cli"]


@pytest.mark.parametrize("type_name", ["robot_sim", "ft_sim", "delay_injector"])
def test_the_servo_sensor_and_delay_nodes_do_without_numpy(rows, type_name):
    # They step on Python floats; numpy (0.13 s of CPU a process) comes only with sensor noise or
    # delay jitter and loss, which draw from its generator. Their defaults draw nothing.
    assert "numpy" not in rows[type_name]["after_setup"], rows[type_name]


def test_the_budget_would_catch_scipy_or_matplotlib_in_a_node(rows):
    # The budget holds its meaning: a node process that also loaded scipy would exceed it.
    heavy = leanness.measure("module:numpy,msgspec,scipy.linalg")
    assert heavy["rss_mb"] - rows["python, nothing of dockhil"]["rss_mb"] > NODE_BUDGET_MB, heavy


@pytest.mark.parametrize("type_name", sorted(node_types.REGISTRY))
def test_no_node_imports_a_ruled_package_at_import(rows, type_name):
    early = set(rows[type_name]["after_import"]) & set(leanness.RULED)
    assert not early, f"{type_name} imports {early} when its module is imported"


@pytest.mark.parametrize("type_name", SIMULATED)
def test_simulated_nodes_set_up_and_step_without_any_of_them(rows, type_name):
    row = rows[type_name]
    assert row["setup"] == "ok", row["setup"]
    assert not set(row["after_setup"]) & set(leanness.RULED), row["after_setup"]


@pytest.mark.parametrize("type_name, package", [("ft_can", "can"), ("robot_modbus", "pymodbus")])
def test_drivers_load_their_protocol_at_setup_and_nothing_else(rows, type_name, package):
    row = rows[type_name]
    assert package not in row["after_import"]
    # Setup ran far enough to open the (absent) device: the protocol package is loaded, no other.
    assert set(row["after_setup"]) & set(leanness.RULED) == {package}, row
    assert row["setup"].startswith("DeviceError:"), row["setup"]


def test_no_scene_or_node_breaks_the_rules(rows):
    assert leanness.violations(list(rows.values())) == []


@pytest.mark.parametrize("what", ["import dockhil.contact", "import dockhil.cli"])
def test_science_and_cli_load_no_scipy_zmq_or_matplotlib(rows, what):
    loaded = set(rows[what]["after_import"])
    assert not loaded & {"scipy", "zmq", "matplotlib", "can", "pymodbus"}, loaded


def test_simulated_hil_scene_composed_loads_none_of_them(rows):
    row = rows["scene launch/hil.yaml"]
    assert row["setup"].startswith("ok"), row["setup"]
    assert not set(row["after_setup"]) & set(leanness.RULED), row["after_setup"]


def test_violations_names_the_node_and_the_package():
    fake = [
        {"node": "ft_sim", "kind": "node", "after_import": ["scipy"], "after_setup": ["scipy", "can"]},
        {"node": "ft_can", "kind": "node", "after_import": [], "after_setup": ["can"]},
    ]
    found = leanness.violations(fake)
    assert any("ft_sim" in v and "scipy" in v and "import" in v for v in found)
    assert any("ft_sim" in v and "can" in v and "setup" in v for v in found)
    assert not any(v.startswith("ft_can") for v in found)


def test_a_node_processs_authentication_and_loop_report_load_neither_asyncio_nor_numpy(tmp_path):
    # What every node process runs besides its node: a publisher's CURVE check (a ZAP handler
    # thread; pyzmq's ThreadAuthenticator would load asyncio), a subscriber's handshake events
    # (zmq.utils.monitor would too) and its loop report at exit (numpy would cost a node that
    # does not compute with it 0.1 s of CPU).
    import subprocess
    import sys

    code = (
        "import sys, zmq\n"
        "from dockhil.runtime.looptime import LoopTiming\n"
        "from dockhil.runtime.transport import GraphKeys, Publisher, Subscriber\n"
        "keys = GraphKeys.make()\n"
        "ctx = zmq.Context.instance()\n"
        "pub = Publisher(ctx, '/x', 'ipc://' + sys.argv[1] + '/x', keys=keys)\n"
        "sub = Subscriber(ctx)\n"
        "sub.connect(pub.endpoint, keys=keys)\n"
        "pub.wait_subscribers(1, 20.0)\n"  # a handshake the ZAP handler admitted
        "sub.check_peers()\n"  # the subscriber reads its handshake events off the socket monitor
        "timing = LoopTiming(['u'], period=1e-3)\n"
        "for late in (1e-4, 3e-4, 2e-4):\n"
        "    timing.started(late)\n"
        "timing.report('n')\n"
        "sub.close(); pub.close(); ctx.term()\n"
        "print(sorted(m for m in ('asyncio', 'numpy') if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=60, cwd=str(leanness.ROOT)
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout
