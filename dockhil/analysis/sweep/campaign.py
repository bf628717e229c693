"""A campaign file: one scene, fixed arguments, a grid (the product of its axes) and random draws
(per run, seeded by the campaign seed and the run index, so any executor gives the same rows),
checked whole before any run is expanded or started: the file through the launch reader's bounds,
its counts, seed and run length against stated ranges, its size from the axes' lengths, and each
argument's values through the scene's own checks. Its runs (`runs`), and the errors of a campaign.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar, cast

import msgspec

from dockhil.errors import DockhilError
from dockhil.scene import boundedyaml
from dockhil.scene.launchfile import SHIPPED_SCENES
from dockhil.scene.schema import MAX_DURATION

if TYPE_CHECKING:
    import numpy as np

T = TypeVar("T", bound=msgspec.Struct)

# Runs in one campaign (grid points x samples): some CPU-days of one-second runs, and the runs'
# list stays near 100 MB and 2 s to expand. A larger study is several campaigns.
MAX_RUNS = 100_000
MAX_SEED = 2**32 - 1  # numpy seeds from 32-bit words; a larger one is no more random


class CampaignError(DockhilError):
    """The campaign file or the results file is refused."""


class WriteError(DockhilError):
    """A result (the journal, the Parquet file, a bag) cannot be written while the campaign runs:
    a full disk, a folder made read-only. The campaign stops; the rows written stay."""


def cannot_write(path: str | Path, exc: OSError) -> WriteError:
    from dockhil.files import os_reason

    return WriteError(f"cannot write {path}: {os_reason(exc)}")


class Axis(msgspec.Struct, forbid_unknown_fields=True):
    """One grid axis: `values: [...]`, or `range: [a, b]` with `num` points (evenly, or `log: true`)."""

    values: list[Any] | None = None
    range: tuple[float, float] | None = None
    num: int | None = None
    log: bool = False


class Distribution(msgspec.Struct, forbid_unknown_fields=True):
    """One random argument: exactly one of uniform [a, b], normal [mean, std], loguniform [a, b]."""

    uniform: tuple[float, float] | None = None
    normal: tuple[float, float] | None = None
    loguniform: tuple[float, float] | None = None


class CampaignFile(msgspec.Struct, forbid_unknown_fields=True):
    scene: str
    description: str = ""
    args: dict[str, Any] = {}
    duration: float | None = None
    grid: dict[str, Any] = {}
    random: dict[str, Any] = {}
    samples: int = 1
    seed: int = 0
    outputs: list[str] | None = None  # summary columns to keep; all when absent
    bags: bool = False  # record one MCAP bag per run, in RESULTS.bags/


class Campaign(msgspec.Struct):
    """A validated campaign: everything a run needs, resolved."""

    path: str
    scene: str  # absolute path of the scene file
    scene_sha: str
    rate: float
    duration: float
    fixed: dict[str, Any]
    grid: dict[str, list[Any]]
    random: dict[str, tuple[str, float, float]]
    samples: int
    seed: int
    outputs: list[str] | None
    bags: bool
    arg_names: list[str]  # column order: fixed, grid, random

    @property
    def points(self) -> int:
        return math.prod(len(v) for v in self.grid.values()) if self.grid else 1

    @property
    def total(self) -> int:
        return self.points * self.samples


def _field_list(struct: type[msgspec.Struct]) -> str:
    return ", ".join(struct.__struct_fields__)


def _convert(data: Any, typ: type[T], where: str) -> T:
    """msgspec validation with the error in one line naming the place in the file."""
    try:
        return msgspec.convert(data, typ)
    except msgspec.ValidationError as exc:
        text = str(exc)
        unknown = re.match(r"Object contains unknown field `(.+?)`", text)
        missing = re.match(r"Object missing required field `(.+?)`", text)
        at = re.search(r" - at `\$(.*)`", text)
        place = f"{where}: {at.group(1).lstrip('.')}" if at and at.group(1) else where
        if unknown:
            raise CampaignError(f"{place}: unknown key {unknown.group(1)!r}; allowed: {_field_list(typ)}") from None
        if missing:
            raise CampaignError(f"{place}: `{missing.group(1)}:` is required") from None
        raise CampaignError(f"{place}: {text.split(' - at ')[0]}") from None


def _axis(raw: Any, where: str) -> Axis:
    """A grid axis checked, not yet expanded: `values`, or a `range` whose `num` is bounded."""
    if isinstance(raw, list):
        axis = Axis(values=raw)
    elif isinstance(raw, dict):
        axis = _convert(raw, Axis, where)
    else:
        raise CampaignError(f"{where}: give a list of values, or {{range: [a, b], num: n}}; got {raw!r}")
    if (axis.values is None) == (axis.range is None):
        raise CampaignError(f"{where}: give either `values: [...]` or `range: [a, b]` with `num: n`")
    if axis.values is not None:
        if axis.num is not None or axis.log:
            raise CampaignError(f"{where}: `num` and `log` go with `range`, not with `values`")
        if not axis.values:
            raise CampaignError(f"{where}: empty grid axis: give at least one value")
        return axis
    a, b = cast(tuple[float, float], axis.range)  # values is None: range is given
    if axis.num is None or not 1 <= axis.num <= MAX_RUNS:
        raise CampaignError(f"{where}: `range` needs `num:` from 1 to {MAX_RUNS:,} points, got {axis.num!r}")
    if not (math.isfinite(a) and math.isfinite(b)):
        raise CampaignError(f"{where}: range ends must be finite numbers, got [{a}, {b}]")
    if axis.log and not (a > 0 and b > 0):
        raise CampaignError(f"{where}: a `log: true` range needs positive ends, got [{a}, {b}]")
    return axis


def _axis_len(axis: Axis) -> int:
    return len(axis.values) if axis.values is not None else cast(int, axis.num)  # a range: _axis checked num


def _axis_points(axis: Axis) -> list[Any]:
    if axis.values is not None:
        return list(axis.values)
    import numpy as np

    a, b = cast(tuple[float, float], axis.range)  # no values: a range with its num (_axis)
    num = cast(int, axis.num)
    points = np.geomspace(a, b, num) if axis.log else np.linspace(a, b, num)
    return [float(v) for v in points]


def _distribution(raw: Any, where: str) -> tuple[str, float, float]:
    hint = "give one of {uniform: [a, b]}, {normal: [mean, std]}, {loguniform: [a, b]}"
    if not isinstance(raw, dict):
        raise CampaignError(f"{where}: bad distribution {raw!r}; {hint}")
    try:
        dist = _convert(raw, Distribution, where)
    except CampaignError as exc:
        raise CampaignError(f"{exc}; {hint}") from None
    given = [(kind, getattr(dist, kind)) for kind in Distribution.__struct_fields__ if getattr(dist, kind) is not None]
    if len(given) != 1:
        raise CampaignError(f"{where}: bad distribution: {hint}")
    kind, (a, b) = given[0]
    if not (math.isfinite(a) and math.isfinite(b)):
        raise CampaignError(f"{where}: {kind} parameters must be finite, got [{a}, {b}]")
    if kind == "uniform" and not (a <= b and math.isfinite(b - a)):
        raise CampaignError(f"{where}: uniform [a, b] needs a <= b, b - a finite, got [{a}, {b}]")
    if kind == "normal" and not b >= 0:
        raise CampaignError(f"{where}: normal [mean, std] needs std >= 0, got {b}")
    if kind == "loguniform" and not 0 < a <= b:
        raise CampaignError(f"{where}: loguniform [a, b] needs 0 < a <= b, got [{a}, {b}]")
    return kind, float(a), float(b)


def resolve_scene(name: str, campaign_dir: Path) -> Path:
    """A path as given, else relative to the campaign file, else a shipped scene by name."""
    for candidate in (Path(name), campaign_dir / name, SHIPPED_SCENES / name):
        if candidate.is_file():
            return candidate.resolve()
    shipped = ", ".join(sorted(p.name for p in SHIPPED_SCENES.glob("*.yaml")))
    raise CampaignError(f"scene {name!r} not found (as a path, next to the campaign file, or shipped: {shipped})")


def _read(path: Path) -> tuple[Any, Any]:
    """(data, root node) of the campaign file, read with the launch reader's bounds: size,
    nesting depth, aliases."""
    try:
        with open(path, "rb") as f:
            raw = f.read(boundedyaml.MAX_BYTES + 1)
    except OSError as exc:
        raise CampaignError(f"{path}: cannot read: {exc}") from None
    if len(raw) > boundedyaml.MAX_BYTES:
        raise CampaignError(f"{path}: larger than {boundedyaml.MAX_BYTES} bytes; a campaign file is a page or two")
    try:
        return boundedyaml.load(raw.decode("utf-8"), str(path))
    except UnicodeDecodeError as exc:
        raise CampaignError(f"{path}: cannot read: {exc}") from None
    except DockhilError as exc:
        raise CampaignError(str(exc)) from None


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _whole(data: dict, key: str, low: int, high: int, at: str) -> None:
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise CampaignError(f"{at}: `{key}` must be a whole number from {low:,} to {high:,}, got {_shown(value)}")


def load_campaign(path: str | Path) -> Campaign:
    """Read and check a campaign file; every refusal is one CampaignError line, before any run
    is expanded or started."""
    from dockhil.scene import launchfile

    try:
        path = launchfile.find_shipped(path, "campaign file", folder="campaigns")
    except DockhilError as exc:
        raise CampaignError(str(exc)) from None
    if not path.is_file():
        raise CampaignError(f"campaign file {str(path)!r} not found (or not a file)")
    data, root = _read(path)
    if not isinstance(data, dict):
        raise CampaignError(f"{path}: a campaign file is a YAML mapping with `scene:`; got {type(data).__name__}")

    def at(key: str) -> str:
        line = boundedyaml.line_of(root, [key])
        return f"{path}:{line}" if line else str(path)

    if "samples" in data:
        _whole(data, "samples", 1, MAX_RUNS, at("samples"))
    if "seed" in data:
        _whole(data, "seed", 0, MAX_SEED, at("seed"))
    if data.get("duration") is not None:
        d = data["duration"]
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not 0 < d <= MAX_DURATION:  # NaN fails too
            raise CampaignError(
                f"{at('duration')}: `duration` must be simulated seconds per run, > 0 and at most "
                f"{MAX_DURATION:g}, got {_shown(d)}"
            )
    raw = _convert(data, CampaignFile, str(path))
    scene_path = resolve_scene(raw.scene, path.parent)
    scene = launchfile.load(scene_path)
    specs = scene.args

    def check_name(name: Any, where: str) -> str:
        if name not in specs:
            raise CampaignError(
                f"{where}: {raw.scene} has no arg {name!r}; its args: {', '.join(sorted(specs)) or 'none'}"
            )
        return name

    seen: dict[str, str] = {}
    fixed = {}
    for name, value in raw.args.items():
        check_name(name, f"{path}: args")
        fixed[name] = specs[name].check(value, f"{path}: args.{name}")
        seen[name] = "args"
    axes = {}
    for name, axis in raw.grid.items():
        check_name(name, f"{path}: grid")
        if name in seen:
            raise CampaignError(f"{path}: grid.{name}: {name!r} is already in `{seen[name]}:`; give it once")
        axes[name] = _axis(axis, f"{path}: grid.{name}")
        seen[name] = "grid"
    random = {}
    for name, dist in raw.random.items():
        check_name(name, f"{path}: random")
        if name in seen:
            raise CampaignError(f"{path}: random.{name}: {name!r} is already in `{seen[name]}:`; give it once")
        if specs[name].type is not float:
            raise CampaignError(
                f"{path}: random.{name}: {name!r} is a {specs[name].type.__name__}; only float args are drawn"
            )
        random[name] = _distribution(dist, f"{path}: random.{name}")
        seen[name] = "random"
    if "grid" in data and not axes:
        raise CampaignError(f"{path}: empty grid: give at least one axis under `grid:`, or drop the key")
    if not axes and not random:
        raise CampaignError(f"{path}: nothing to sweep: give `grid:` and/or `random:`")
    sizes = [_axis_len(axis) for axis in axes.values()]
    total = math.prod(sizes) * raw.samples  # from the axes' lengths: nothing is expanded yet
    if total > MAX_RUNS:
        raise CampaignError(
            f"{path}: {' x '.join(map(str, sizes)) or 1} grid points x {raw.samples} samples = "
            f"{total:,} runs; a campaign has at most {MAX_RUNS:,}: coarsen the grid, or split it "
            f"into several campaigns"
        )
    grid = {
        name: [specs[name].check(v, f"{path}: grid.{name}") for v in _axis_points(axis)] for name, axis in axes.items()
    }
    duration = raw.duration if raw.duration is not None else scene.duration
    if duration is None:
        raise CampaignError(f"{path}: give a positive `duration:` in seconds (simulated, per run)")
    c = Campaign(
        str(path),
        str(scene_path),
        hashlib.sha256(scene_path.read_bytes()).hexdigest(),
        scene.rate,
        float(duration),
        fixed,
        grid,
        random,
        raw.samples,
        raw.seed,
        raw.outputs,
        raw.bags,
        [*fixed, *grid, *random],
    )
    c.rate = _check_in_scene(c)
    return c


def run_args(c: Campaign) -> Iterator[tuple[int, int, dict[str, Any]]]:
    """(run index, sample, args) of every run, in run-index order: grid point-major, then sample.
    The random draws of run i come from the generator seeded by (seed, i) alone."""
    import numpy as np

    names = list(c.grid)
    for point_index, point in enumerate(itertools.product(*c.grid.values())):
        for sample in range(c.samples):
            index = point_index * c.samples + sample
            args = {**c.fixed, **dict(zip(names, point))}
            if c.random:
                rng = np.random.default_rng([c.seed, index])
                for name, (kind, a, b) in c.random.items():
                    args[name] = draw(kind, a, b, rng)
            yield index, sample, {name: args[name] for name in c.arg_names}


def _check_in_scene(c: Campaign) -> float:
    """Refuse, before anything runs, a campaign with a run the scene refuses, by the path
    `dockhil launch` takes (launch arguments, then every node's parameters): the first run, the
    first run with each grid argument at each end of its axis (each value of a non-numeric one),
    and the runs holding each random argument's least and greatest draw. A parameter's physical
    range is an interval, so the ends stand for the values between; what only a combination of
    arguments refuses is that run's `invalid` row. Returns the first run's rate [Hz]."""
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    first: dict[str, Any] = {}
    ends: dict[str, list] = {}  # random arg -> [(least, run, args), (greatest, run, args)]
    for index, _sample, args in run_args(c):
        if index == 0:
            first = args
        if not c.random:
            break
        for name in c.random:
            value = args[name]
            if not math.isfinite(value):
                raise CampaignError(f"{c.path}: random.{name}: run {index} draws {value}; give a narrower distribution")
            low, high = ends.setdefault(name, [(value, index, args), (value, index, args)])
            if value < low[0]:
                ends[name][0] = (value, index, args)
            if value > high[0]:
                ends[name][1] = (value, index, args)
    probes = {"run 0": first}
    for name, values in c.grid.items():
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
        for v in (min(values), max(values)) if numeric else dict.fromkeys(values):
            probes.setdefault(f"grid.{name} = {v!r}", {**first, name: v})
    for name, pair in ends.items():
        for value, index, args in pair:
            probes.setdefault(f"random.{name} = {value:g} (run {index})", args)
    rate = c.rate
    tried = set()
    for label, args in probes.items():
        key = json.dumps(args, sort_keys=True)
        if key in tried:
            continue
        tried.add(key)
        try:
            scene = launchfile.load(c.scene, dict(args))
            build(scene)
        except DockhilError as exc:
            raise CampaignError(f"{c.path}: {label}: refused by the scene: {exc}") from None
        if label == "run 0":
            rate = scene.rate
    return rate


def draw(kind: str, a: float, b: float, rng: np.random.Generator) -> float:
    if kind == "uniform":
        return float(rng.uniform(a, b))
    if kind == "normal":
        return float(rng.normal(a, b))
    return float(math.exp(rng.uniform(math.log(a), math.log(b))))


def runs(c: Campaign, results: str | Path | None = None) -> list[dict]:
    """Every run of the campaign, in run-index order (see run_args)."""
    bag_dir = (
        None if not (c.bags and results) else Path(os.path.abspath(str(results) + ".bags"))
    )  # workers' cwd may differ
    out = []
    for index, sample, args in run_args(c):
        key = json.dumps({"scene": c.scene_sha, "duration": c.duration, "args": args}, sort_keys=True)
        out.append(
            {
                "run": index,
                "sample": sample,
                "args": args,
                "args_hash": hashlib.sha256(key.encode()).hexdigest()[:16],
                "scene": c.scene,
                "duration": c.duration,
                "outputs": c.outputs,
                "bag": None if bag_dir is None else str(bag_dir / f"run-{index:06d}.mcap"),
            }
        )
    return out
