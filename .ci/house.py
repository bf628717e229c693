#!/usr/bin/env python3
"""The house in numbers, as one JSON object: the modules directly in dockhil/ and in dockhil/analysis/,
the largest module, the modules over 600 lines, the import cycles between dockhil's modules and the
imports that go up the layer order (both from the source's ast, imports at any depth: a
function-level import still ties two modules together), the pairs of packages that import each
other, the names imported across modules that their module keeps private (_name), the test helpers
outside tests/support/, the share of the library's lines mypy checks, and whether ruff and mypy are
clean.

    python3 .ci/house.py            everything (runs ruff and mypy: a few seconds)
    python3 .ci/house.py --fast     without ruff and mypy
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "dockhil"
MAX_LINES = 600
MAX_ANALYSIS_MODULES = 12  # modules directly in dockhil/analysis/: more, and a subject wants a package

# The layers, lowest first: a module imports its own layer and those below it, never one above.
# A name is a package of dockhil or a module directly in it ("dockhil" is dockhil/__init__.py).
LAYERS: list[list[str]] = [
    ["dockhil", "errors", "files", "physical", "compiled", "progress"],  # no dockhil import but these
    ["log"],
    ["msgs"],  # the message types
    ["contact"],  # the science: no I/O, no transport
    ["node"],  # the node API
    ["node_types"],  # node types by name (imported by their "module:Class" string, never statically)
    ["scene"],  # launch files and the graph a scene builds
    ["argtypes"],
    ["runtime", "process"],  # the running graph
    ["bags"],
    ["nodes"],  # simulation and graph node types
    ["devices"],  # the lab's devices: driver bases, one folder per device
    ["analysis"],
    ["testing", "session"],
    ["commands"],  # one module per subcommand
    ["cli"],  # names the commands by their "module" string
]


def modules() -> dict[str, Path]:
    """Every module of the package by its dotted name (a package by its __init__)."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _imports(tree: ast.AST, name: str, is_package: bool, known: dict[str, Path]):
    """(module imported, names taken from it, line) for every dockhil import in a module's tree."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "dockhil":
                    yield alias.name, [], node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against this module's package
                here = name.split(".") if is_package else name.split(".")[:-1]
                here = here[: len(here) - node.level + 1]
                base = ".".join(here + ([base] if base else []))
            if base.split(".")[0] != "dockhil":
                continue
            names = []
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                if sub in known:  # `from dockhil.scene import graph`: the submodule itself
                    yield sub, [], node.lineno
                else:
                    names.append(alias.name)
            if names:
                yield base, names, node.lineno


def graph_and_private(mods: dict[str, Path]):
    edges: dict[str, set[str]] = {m: set() for m in mods}
    private = []
    for name, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        bound: dict[str, str] = {}  # local name -> dockhil module, for `module._name`
        for target, names, line in _imports(tree, name, path.name == "__init__.py", mods):
            target = (
                target
                if target in mods
                else next(
                    (t for t in (target.rsplit(".", k)[0] for k in range(1, target.count(".") + 1)) if t in mods), None
                )
            )
            if target is None or target == name:
                continue
            edges[name].add(target)
            for n in names:
                if n.startswith("_") and not n.startswith("__"):
                    private.append(f"{path.relative_to(ROOT)}:{line}: {n} from {target}")
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("dockhil"):
                for alias in node.names:
                    if f"{node.module}.{alias.name}" in mods:
                        bound[alias.asname or alias.name] = f"{node.module}.{alias.name}"
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.asname and alias.name in mods:
                        bound[alias.asname] = alias.name
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in bound
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and bound[node.value.id] != name
            ):
                private.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.attr} from {bound[node.value.id]}")
    return edges, sorted(set(private))


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found = []
    sys.setrecursionlimit(10000)

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return sorted(found)


def layer_of(module: str) -> str:
    """The layer name of a dockhil module: its package, or itself when directly in dockhil/."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "dockhil"


def upward_imports(edges: dict[str, set[str]], layers: list[list[str]] = LAYERS) -> list[str]:
    """`a -> b` for every import of a module b in a layer above a's (or in no layer: every package
    must have its place)."""
    rank = {name: i for i, group in enumerate(layers) for name in group}
    found = []
    for a, targets in sorted(edges.items()):
        for b in sorted(targets):
            la, lb = layer_of(a), layer_of(b)
            if la == lb:
                continue
            if la not in rank or lb not in rank:
                found.append(f"{a} -> {b} ({la if la not in rank else lb} has no layer in .ci/house.py)")
            elif rank[lb] > rank[la]:
                found.append(f"{a} -> {b} ({la} is below {lb})")
    return found


def package_pairs(edges: dict[str, set[str]]) -> list[str]:
    """The pairs of layers (packages) that import each other, at any depth."""
    between = {(layer_of(a), layer_of(b)) for a, targets in edges.items() for b in targets}
    return sorted(f"{a} <-> {b}" for a, b in between if a < b and (b, a) in between)


def test_helpers_outside_support() -> list[str]:
    """Modules in tests/ that are not tests (test_*.py, conftest.py) nor in tests/support/."""
    tests = ROOT / "tests"
    return sorted(
        p.name
        for p in tests.glob("*.py")
        if not (p.name.startswith("test_") or p.name in ("conftest.py", "__init__.py"))
    )


def typed_share(mods: dict[str, Path], lines: dict[str, int]) -> dict:
    """The library's lines in the files mypy checks ([tool.mypy] files in pyproject.toml)."""
    import tomllib

    listed = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"].get("files", [])
    roots = [ROOT / f for f in listed]
    checked = sum(k for n, k in lines.items() if any(mods[n] == r or r in mods[n].parents for r in roots))
    total = sum(lines.values())
    return {"checked_lines": checked, "library_lines": total, "share": round(checked / total, 3)}


def _clean(argv: list[str]) -> bool | None:
    try:
        return subprocess.run(argv, cwd=ROOT, capture_output=True, timeout=600).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return None  # not installed (pip install -e '.[dev]')


def house(fast: bool = False) -> dict:
    mods = modules()
    lines = {n: len(p.read_text().splitlines()) for n, p in mods.items()}
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    largest = max(lines, key=lines.get)
    edges, private = graph_and_private(mods)
    found = cycles(edges)
    analysis = sorted(p.name for p in (PACKAGE / "analysis").glob("*.py") if p.name != "__init__.py")
    upward = upward_imports(edges)
    pairs = package_pairs(edges)
    helpers = test_helpers_outside_support()
    out = {
        "top_level_modules": {"count": len(top), "names": top},
        "analysis_modules": {"count": len(analysis), "max": MAX_ANALYSIS_MODULES, "names": analysis},
        "largest_module": {"name": largest, "lines": lines[largest]},
        "over_600_lines": {n: k for n, k in sorted(lines.items()) if k > MAX_LINES},
        "import_cycles": {"count": len(found), "cycles": found},
        "private_imports": {"count": len(private), "where": private},
        "layers": {"order": LAYERS, "upward_imports": {"count": len(upward), "where": upward}},
        "package_pairs": {"count": len(pairs), "pairs": pairs},
        "test_helpers_outside_support": {"count": len(helpers), "names": helpers},
        "mypy": typed_share(mods, lines),
    }
    if not fast:
        out["ruff_clean"] = _clean([sys.executable, "-m", "ruff", "check", "--quiet", "."])
        out["mypy_clean"] = _clean([sys.executable, "-m", "mypy"])
    return out


if __name__ == "__main__":
    print(json.dumps(house(fast="--fast" in sys.argv[1:]), indent=1))
