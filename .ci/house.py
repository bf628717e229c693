#!/usr/bin/env python3
"""The house in numbers, as one JSON object: the modules directly in dockhil/, the largest module,
the modules over 600 lines, the import cycles between dockhil's modules (from the source's ast,
imports at any depth: a function-level import still ties two modules together), the names imported
across modules that their module keeps private (_name), and whether ruff and mypy are clean.

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
    out = {
        "top_level_modules": {"count": len(top), "names": top},
        "largest_module": {"name": largest, "lines": lines[largest]},
        "over_600_lines": {n: k for n, k in sorted(lines.items()) if k > MAX_LINES},
        "import_cycles": {"count": len(found), "cycles": found},
        "private_imports": {"count": len(private), "where": private},
    }
    if not fast:
        out["ruff_clean"] = _clean([sys.executable, "-m", "ruff", "check", "--quiet", "."])
        out["mypy_clean"] = _clean([sys.executable, "-m", "mypy"])
    return out


if __name__ == "__main__":
    print(json.dumps(house(fast="--fast" in sys.argv[1:]), indent=1))
