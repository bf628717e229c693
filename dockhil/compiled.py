"""The optional compiled twins that `pip install` builds where a C compiler is (setup.py): each
does what a Python function does, with the same bits, faster."""

from __future__ import annotations

import importlib
import os


def twin(module: str):
    """The compiled module `module`, or None where it was not built (no C compiler at install) or
    DOCKHIL_PURE_PYTHON is set: the Python twins then run."""
    if os.environ.get("DOCKHIL_PURE_PYTHON"):
        return None
    try:
        return importlib.import_module(module)
    except ImportError:
        return None
