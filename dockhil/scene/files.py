"""Where a scene file is: the shipped scenes (`hil.yaml` runs from any directory), and why no file can be
at a path, said in dockhil's words rather than the interpreter's."""

from __future__ import annotations

import difflib
import errno
import os
from pathlib import Path

from dockhil.errors import LaunchError


def _shipped_dir() -> Path:
    here = Path(__file__).resolve().parent.parent  # the dockhil package
    packaged = here / "launch"  # an installed wheel: the package data dockhil.launch
    return packaged if packaged.is_dir() else here.parent / "launch"  # a source checkout


SHIPPED_SCENES = _shipped_dir()


def find_shipped(path: str | Path, kind: str = "launch file", folder: str = "") -> Path:
    """`path` itself if it exists, else the shipped file of that name (`hil.yaml`,
    `launch/hil.yaml`; with folder="campaigns" also `fig7.yaml`), so that a shipped
    scene runs from any directory. A file in the current directory always wins."""
    path = Path(path)
    if path.exists() or path.is_absolute():
        return path
    parts = path.parts[1:] if path.parts[:1] == ("launch",) else path.parts
    if parts and ".." not in parts:
        for candidate in (SHIPPED_SCENES / folder).joinpath(*parts), SHIPPED_SCENES.joinpath(*parts):
            if candidate.is_file():
                return candidate
    names = sorted(p.name for p in (SHIPPED_SCENES / folder).glob("*.yaml"))
    near = difflib.get_close_matches(path.stem, [Path(n).stem for n in names], n=1)  # the name, not .yaml
    hint = f"; did you mean {str(path.with_name(near[0] + '.yaml'))}?" if near else ""
    raise LaunchError(
        f"{kind} {str(path)!r} not found: no such file here and no shipped one of that name{hint} "
        f"(shipped: {', '.join(names) or 'none'})"
    )


def unopenable(path: Path) -> str | None:
    """Why no file can be at this path, in our words: Python's own differ between versions (3.13 resolves
    a symlink loop without an error and words a NUL in a path differently)."""
    if "\x00" in str(path):
        return "its name holds a NUL character; name the file without it"
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "it is a symbolic link that leads back to itself (a loop); point it at a launch file"
    return None
