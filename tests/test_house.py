"""The house's shape, from the source's ast (.ci/house.py): no import cycle between dockhil's
modules, no private name taken across modules, and no module over 600 lines."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("house", ROOT / ".ci" / "house.py")
house = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(house)


def test_no_import_cycle_between_modules():
    edges, _ = house.graph_and_private(house.modules())
    assert house.cycles(edges) == []


def test_no_private_name_is_imported_across_modules():
    _, private = house.graph_and_private(house.modules())
    assert private == []


def test_the_checks_find_a_cycle_and_a_private_import(tmp_path):
    assert house.cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert house.cycles({"a": {"b"}, "b": set()}) == []
    pkg = tmp_path / "dockhil"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "one.py").write_text("def _hidden():\n    pass\n")
    (pkg / "two.py").write_text("from dockhil.one import _hidden\nfrom dockhil import one\none._hidden()\n")
    mods = {"dockhil": pkg / "__init__.py", "dockhil.one": pkg / "one.py", "dockhil.two": pkg / "two.py"}
    old_root = house.ROOT
    house.ROOT = tmp_path
    try:
        edges, private = house.graph_and_private(mods)
    finally:
        house.ROOT = old_root
    assert edges["dockhil.two"] == {"dockhil.one"}
    assert private == ["dockhil/two.py:1: _hidden from dockhil.one", "dockhil/two.py:3: _hidden from dockhil.one"]


def test_no_module_is_over_600_lines():
    over = {n: len(p.read_text().splitlines()) for n, p in house.modules().items()}
    assert {n: k for n, k in over.items() if k > house.MAX_LINES} == {}


def test_no_import_goes_up_the_layer_order_and_no_two_packages_import_each_other():
    edges, _ = house.graph_and_private(house.modules())
    assert house.upward_imports(edges) == []
    assert house.package_pairs(edges) == []


def test_the_layer_check_finds_an_import_that_goes_up_and_a_package_without_a_layer():
    edges = {
        "dockhil.contact.x": {"dockhil.runtime.y", "dockhil.errors"},
        "dockhil.runtime.y": {"dockhil.contact.x"},
        "dockhil.newpkg.z": {"dockhil.errors"},
    }
    assert house.upward_imports(edges) == [
        "dockhil.contact.x -> dockhil.runtime.y (contact is below runtime)",
        "dockhil.newpkg.z -> dockhil.errors (newpkg has no layer in .ci/house.py)",
    ]
    assert house.package_pairs(edges) == ["contact <-> runtime"]


def test_every_package_and_top_level_module_has_a_layer():
    named = {name for group in house.LAYERS for name in group}
    assert {house.layer_of(m) for m in house.modules()} <= named


def test_analysis_keeps_its_subjects_in_packages_and_test_helpers_live_in_tests_support():
    analysis = [p for p in (house.PACKAGE / "analysis").glob("*.py") if p.name != "__init__.py"]
    assert len(analysis) <= house.MAX_ANALYSIS_MODULES
    assert house.test_helpers_outside_support() == []
