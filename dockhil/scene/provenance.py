"""What a run records of its scene, so that its bag alone rebuilds it.

`run_fields` describes the run (the launch file, its resolved arguments, the rate, the clock, the
run length, the dockhil version and the graph's start time on the wall clock) and `scene_texts`
gives the text of every launch file read (the scene and its includes), both as the str -> str maps
an MCAP metadata record holds. `rebuild` makes the scene again from them: each text is written
where it stood relative to the others, in a temporary folder, and read with the recorded arguments; an
include of any file but those is refused without being opened (the bag's scene comes from the bag).
The start time is written at a fixed width, so that two sim-time recordings of one run differ in
those bytes alone.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from dockhil.scene.launchfile import Scene

MAX_FILES = 64  # launch files one recorded scene may hold (a scene reads at most MAX_INCLUDES)


def iso_utc(ns: int) -> str:
    """Unix ns -> '2026-12-04T17:06:35.123456789Z' (always 30 characters)."""
    seconds, rest = divmod(int(ns), 1_000_000_000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(seconds)) + f".{rest:09d}Z"


def run_fields(
    scene: Scene, *, clock: str, duration: float | None, started_ns: int, recorded_by: str
) -> dict[str, str]:
    """The run's description, for a bag's metadata and the registry of running graphs."""
    from dockhil import __version__

    args = {name: scene.values[name] for name in scene.args}
    changed = {name: value for name, value in args.items() if value != scene.args[name].default}
    return {
        "dockhil_version": __version__,
        "scene": os.path.abspath(scene.path),
        "description": scene.description or "",
        "args": json.dumps(args, sort_keys=True),
        "args_set": json.dumps(changed, sort_keys=True),  # those not at the file's default
        "clock": clock,
        "rate_hz": repr(float(scene.rate)),
        "duration_s": "" if duration is None else repr(float(duration)),
        "start": iso_utc(started_ns),
        "start_ns": f"{int(started_ns):019d}",
        "recorded_by": recorded_by,
    }


def scene_texts(scene: Scene) -> dict[str, str]:
    """absolute path -> text of every launch file the scene read."""
    return dict(scene.texts)


def rebuild(
    run: dict[str, str], texts: dict[str, str], overrides: dict | None = None, *, origin: str = "the bag"
) -> Scene:
    """The scene of a recorded run: its launch files' texts read again with its arguments (and
    `overrides` on top). LaunchError (one line, naming the recorded files) if they do not read."""
    from dockhil.errors import LaunchError
    from dockhil.scene import launchfile

    where = f"{origin}: recorded scene"
    files = {os.path.normpath(os.path.abspath(p)): t for p, t in texts.items() if isinstance(t, str)}
    root = os.path.normpath(os.path.abspath(run.get("scene", "")))
    if root not in files or len(files) > MAX_FILES:
        raise LaunchError(f"{where}: the launch file {root} is not among the {len(files)} texts recorded")
    try:
        args = json.loads(run.get("args") or "{}")
    except ValueError:
        raise LaunchError(f"{where}: its launch arguments are not readable JSON") from None
    if not isinstance(args, dict):
        raise LaunchError(f"{where}: its launch arguments are not a mapping")
    if args.get("loop"):
        # The values the loop file set are among the recorded arguments; the file itself is not recorded.
        args["loop"] = ""
    args.update(overrides or {})
    common = os.path.commonpath([os.path.dirname(p) for p in files])
    with tempfile.TemporaryDirectory(prefix="dockhil-scene-") as tmp:
        for path, text in files.items():
            dst = os.path.join(tmp, os.path.relpath(path, common))
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            with open(dst, "w", encoding="utf-8") as f:
                f.write(text)
        written = frozenset(os.path.normpath(os.path.join(tmp, os.path.relpath(p, common))) for p in files)
        try:
            scene = launchfile.load(os.path.join(tmp, os.path.relpath(root, common)), args, only=written)
        except LaunchError as exc:  # named by the recorded paths, not the temporary ones
            raise LaunchError(f"{where}: " + str(exc).replace(tmp, common)) from None
        for node in scene.nodes:
            node.source = node.source.replace(tmp, common)
    scene.path = root
    scene.texts = {p.replace(tmp, common): t for p, t in scene.texts.items()}
    return scene
