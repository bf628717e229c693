"""The optional compiled twins that `pip install` builds where a C compiler is (setup.py): each
does what a Python function does, with the same bits, faster."""

from __future__ import annotations

import importlib
import os
from types import ModuleType

PURE_PYTHON_ENV = "DOCKHIL_PURE_PYTHON"

# Every compiled twin and what it computes: setup.py builds these, twin() loads only these, and
# `dockhil --version` names them.
TWINS = {
    "dockhil.contact._rigid": "rigid-body arithmetic",  # the 6-DOF loop's (contact/rotations, rigid, interface6)
    "dockhil.runtime._screen": "message screen",  # each message of a composed run (runtime/executor.py)
}


def twin(module: str) -> ModuleType | None:
    """The compiled module `module`, or None where it was not built (no C compiler at install) or
    DOCKHIL_PURE_PYTHON is set: the Python twins then run."""
    if module not in TWINS:
        raise ValueError(f"{module} is not a compiled twin; name it in dockhil.compiled.TWINS")
    if os.environ.get(PURE_PYTHON_ENV):
        return None
    try:
        return importlib.import_module(module)
    except ImportError:
        return None


def which_arithmetic() -> str:
    """What runs, in a few words (`dockhil --version`): the compiled twins, or pure Python and why."""
    if os.environ.get(PURE_PYTHON_ENV):
        return f"pure Python: {PURE_PYTHON_ENV} is set"
    built = {what: twin(module) is not None for module, what in TWINS.items()}
    compiled = [what for what, ok in built.items() if ok]
    if not compiled:
        return "pure Python: the C twins were not built; install a C compiler and reinstall for speed"
    missing = [what for what, ok in built.items() if not ok]
    return f"compiled: {', '.join(compiled)}" + (f"; pure Python: {', '.join(missing)} (not built)" if missing else "")
