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
