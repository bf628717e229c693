"""Lean scenes: a node loads python-can, pymodbus, scipy or matplotlib only if it uses them,
and the science and the CLI stay light. Each node type is measured in a fresh interpreter."""

import pytest

import nodes
from dockhil import leanness

SIMULATED = ("satellite_dynamics", "virtual_impedance", "ft_sim", "robot_sim", "delay_injector")


@pytest.fixture(scope="module")
def rows():
    measured = leanness.measure_all(repeats=1)
    return {row["node"]: row for row in measured}


def test_every_registered_node_type_is_measured(rows):
    for type_name in nodes.REGISTRY:
        assert type_name in rows, type_name
        assert rows[type_name]["startup_s"] > 0 and rows[type_name]["rss_mb"] > 0, rows[type_name]


@pytest.mark.parametrize("type_name", sorted(nodes.REGISTRY))
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
    fake = [{"node": "ft_sim", "kind": "node", "after_import": ["scipy"], "after_setup": ["scipy", "can"]},
            {"node": "ft_can", "kind": "node", "after_import": [], "after_setup": ["can"]}]
    found = leanness.violations(fake)
    assert any("ft_sim" in v and "scipy" in v and "import" in v for v in found)
    assert any("ft_sim" in v and "can" in v and "setup" in v for v in found)
    assert not any(v.startswith("ft_can") for v in found)
