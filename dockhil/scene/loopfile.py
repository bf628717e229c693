"""A loop file (`dockhil calibrate --out`): the loop calibration identified, as the arguments it sets in a
scene that takes it as loop:=FILE (launchfile), and nothing else."""

from __future__ import annotations

import math
import reprlib
from collections.abc import Collection
from typing import Any

from dockhil.errors import DockhilError, LaunchError
from dockhil.log import Log
from dockhil.scene import boundedyaml

# What a loop file may hold: what calibration identified (the loop's delay and lag, the passive stiffness and
# damping, the F/T noise and delay in `args`; the sensor's bias as `tare`), and its record. Nothing else: a
# loop file is no way to set a scene's limits or masses.
LOOP_ARGS = ("delay", "lag", "k", "b_passive", "ft_noise", "ft_delay")
LOOP_KEYS = ("args", "tare", "calibration", "verdict")


NO_FT_BIAS = (
    "loop file {path}: its tare (the F/T bias calibration measured) is not applied: the scene {scene} declares "
    "no ft_bias argument, so its F/T driver tares at start; declare ft_bias and pass it to the driver's bias "
    "to use the file's"
)


def loop_args(path: str, specs: dict, given: Collection[str] = (), scene: str = "") -> dict[str, Any]:
    """The arguments a loop file (written by `dockhil calibrate --out`: delay, lag, k, ...) sets that the
    scene declares (specs) and the command line does not give (given); a scene takes it as loop:=FILE. A
    key calibration does not identify is refused. The file's tare becomes ft_bias where the scene declares
    it; where it does not, one line says the tare is not applied."""
    try:
        with open(path, "rb") as f:
            raw = f.read(boundedyaml.MAX_BYTES + 1)
        data, _root = boundedyaml.load(raw.decode("utf-8"), path)
    except OSError as exc:
        raise LaunchError(f"loop file {path}: cannot read: {exc.strerror}") from None
    except (UnicodeDecodeError, DockhilError) as exc:
        raise LaunchError(f"loop file {path}: {exc}") from None
    args = data.get("args") if isinstance(data, dict) else None
    if len(raw) > boundedyaml.MAX_BYTES or not isinstance(args, dict):
        raise LaunchError(
            f"loop file {path}: not a loop file (a mapping with `args:`); write one with dockhil calibrate --out"
        )
    for key in data:
        if key not in LOOP_KEYS:
            raise LaunchError(
                f"loop file {path}: {key!r} is not what calibration identifies (a loop file holds "
                f"{', '.join(LOOP_KEYS)}); remove it, or give a scene's argument as {key}:=VALUE"
            )
    for name, value in args.items():
        if name not in LOOP_ARGS:
            raise LaunchError(
                f"loop file {path}: args.{name} is not what calibration identifies (only "
                f"{', '.join(LOOP_ARGS)}); remove it, or give it on the command line as {name}:=VALUE"
            )
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise LaunchError(f"loop file {path}: args.{name} is {value!r}, not a number")
    out = {name: value for name, value in args.items() if name in specs and name not in given}
    if data.get("tare") is not None and "ft_bias" not in given:  # ft_bias:= on the command line: unread
        if "ft_bias" in specs:
            out["ft_bias"] = _loop_tare(path, data["tare"])
        else:
            Log("[launch]").warning(NO_FT_BIAS.format(path=path, scene=scene or "(this scene)"))
    return out


def _loop_tare(path: str, tare: Any) -> list[float]:
    """The loop file's `tare: {force_N: [x, y, z], torque_Nm: [x, y, z]}` as the F/T driver's
    bias [fx, fy, fz, tx, ty, tz]."""
    bias: list[float] = []
    for key in ("force_N", "torque_Nm"):
        axes = tare.get(key) if isinstance(tare, dict) else None
        if (
            not isinstance(axes, list)
            or len(axes) != 3
            or not all(isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) for a in axes)
        ):
            raise LaunchError(
                f"loop file {path}: tare.{key} is {reprlib.repr(axes)}, not three finite numbers; write the "
                f"file again with dockhil calibrate --out, or drop its tare with ft_bias:=[] (tare at start)"
            )
        bias += [float(a) for a in axes]
    return bias
