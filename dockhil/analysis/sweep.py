"""Campaigns: one scene run many times over its launch arguments, one Parquet row per run.

A campaign file names a scene, fixed arguments, a grid (the product of its
axes) and random draws (per run, seeded by the campaign seed and the run
index, so any executor gives the same rows). Each run is a composed sim-time
run of the scene in the worker's own process; its summary becomes one row.

Runs go to workers in batches (a local process pool, or a Dask cluster). A
finished batch's rows are appended to a journal next to the results at once
(`RESULTS.parquet.partial`, JSON lines), and the Parquet file is written from
all rows every minute, at the end and on interruption. A rerun reads both and skips every
run whose index and argument hash are already there.

A campaign is checked whole before any run is expanded or started: the file through the
launch reader's bounds, its counts, seed and run length against stated ranges, its size
from the axes' lengths, and each argument's values through the scene's own checks. A
result that cannot be written stops it (WriteError); a local worker dies with the sweep.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
import time
from collections import Counter
from pathlib import Path
from typing import Any, Iterator

import msgspec

from dockhil.scene import boundedyaml
from dockhil.errors import DockhilError
from dockhil.scene.launchfile import SHIPPED_SCENES
from dockhil.scene.schema import MAX_DURATION

STATUSES = ("ok", "invalid", "failed")
RETRIES = 2  # a batch whose worker was lost is sent again this many times
METADATA_KEY = b"dockhil.campaign"
PARQUET_EVERY_S = 60.0  # the Parquet file is rewritten this often during a campaign (the journal at once)
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


# ---------------------------------------------------------------- the campaign file

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


def _field_list(struct) -> str:
    return ", ".join(struct.__struct_fields__)


def _convert(data: Any, typ, where: str):
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
    a, b = axis.range
    if axis.num is None or not 1 <= axis.num <= MAX_RUNS:
        raise CampaignError(f"{where}: `range` needs `num:` from 1 to {MAX_RUNS:,} points, got {axis.num!r}")
    if not (math.isfinite(a) and math.isfinite(b)):
        raise CampaignError(f"{where}: range ends must be finite numbers, got [{a}, {b}]")
    if axis.log and not (a > 0 and b > 0):
        raise CampaignError(f"{where}: a `log: true` range needs positive ends, got [{a}, {b}]")
    return axis


def _axis_len(axis: Axis) -> int:
    return len(axis.values) if axis.values is not None else axis.num


def _axis_points(axis: Axis) -> list[Any]:
    if axis.values is not None:
        return list(axis.values)
    import numpy as np

    a, b = axis.range
    points = np.geomspace(a, b, axis.num) if axis.log else np.linspace(a, b, axis.num)
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
            raise CampaignError(f"{at('duration')}: `duration` must be simulated seconds per run, > 0 and at most "
                                f"{MAX_DURATION:g}, got {_shown(d)}")
    raw = _convert(data, CampaignFile, str(path))
    scene_path = resolve_scene(raw.scene, path.parent)
    scene = launchfile.load(scene_path)
    specs = scene.args

    def check_name(name: Any, where: str) -> str:
        if name not in specs:
            raise CampaignError(f"{where}: {raw.scene} has no arg {name!r}; its args: {', '.join(sorted(specs)) or 'none'}")
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
            raise CampaignError(f"{path}: random.{name}: {name!r} is a {specs[name].type.__name__}; only float args are drawn")
        random[name] = _distribution(dist, f"{path}: random.{name}")
        seen[name] = "random"
    if "grid" in data and not axes:
        raise CampaignError(f"{path}: empty grid: give at least one axis under `grid:`, or drop the key")
    if not axes and not random:
        raise CampaignError(f"{path}: nothing to sweep: give `grid:` and/or `random:`")
    sizes = [_axis_len(axis) for axis in axes.values()]
    total = math.prod(sizes) * raw.samples  # from the axes' lengths: nothing is expanded yet
    if total > MAX_RUNS:
        raise CampaignError(f"{path}: {' x '.join(map(str, sizes)) or 1} grid points x {raw.samples} samples = "
                            f"{total:,} runs; a campaign has at most {MAX_RUNS:,}: coarsen the grid, or split it "
                            f"into several campaigns")
    grid = {name: [specs[name].check(v, f"{path}: grid.{name}") for v in _axis_points(axis)]
            for name, axis in axes.items()}
    duration = raw.duration if raw.duration is not None else scene.duration
    if duration is None:
        raise CampaignError(f"{path}: give a positive `duration:` in seconds (simulated, per run)")
    c = Campaign(str(path), str(scene_path), hashlib.sha256(scene_path.read_bytes()).hexdigest(), scene.rate,
                 float(duration), fixed, grid, random, raw.samples, raw.seed, raw.outputs, raw.bags,
                 [*fixed, *grid, *random])
    c.rate = _check_in_scene(c)
    return c


def _run_args(c: Campaign) -> Iterator[tuple[int, int, dict[str, Any]]]:
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
    for index, _sample, args in _run_args(c):
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


def draw(kind: str, a: float, b: float, rng) -> float:
    if kind == "uniform":
        return float(rng.uniform(a, b))
    if kind == "normal":
        return float(rng.normal(a, b))
    return float(math.exp(rng.uniform(math.log(a), math.log(b))))


def runs(c: Campaign, results: str | Path | None = None) -> list[dict]:
    """Every run of the campaign, in run-index order (see _run_args)."""
    bag_dir = None if not (c.bags and results) else Path(os.path.abspath(str(results) + ".bags"))  # workers' cwd may differ
    out = []
    for index, sample, args in _run_args(c):
        key = json.dumps({"scene": c.scene_sha, "duration": c.duration, "args": args}, sort_keys=True)
        out.append({"run": index, "sample": sample, "args": args, "args_hash": hashlib.sha256(key.encode()).hexdigest()[:16],
                    "scene": c.scene, "duration": c.duration, "outputs": c.outputs,
                    "bag": None if bag_dir is None else str(bag_dir / f"run-{index:06d}.mcap")})
    return out


# ---------------------------------------------------------------- one run (in a worker)

def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def flatten(summary: dict) -> dict:
    """Summary fields as columns: nested dicts become `outer.inner`; the growth rate
    of a sustained contact becomes `growth_rate_per_s` and `stable` (it decays)."""
    out = {}
    for key, value in summary.items():
        if isinstance(value, dict):
            out.update({f"{key}.{k}": v for k, v in value.items()})
        elif key != "run_time_s":  # the row's own run time counts the whole run
            out[key] = value
    if "predicted_growth_rate_1_s" in out:
        out["predicted_growth_rate_per_s"] = out.pop("predicted_growth_rate_1_s")
    for name in ("growth_rate_per_s", "growth_rate_1_s"):
        if name in out:
            rate = out.pop(name)
            out["growth_rate_per_s"] = rate
            out["stable"] = summary.get("stable", None if rate is None else bool(rate < 0.0))
            break
    return out


class RunFailed(Exception):
    """A run stopped with one line: a node's own, or the divergence it was the sign of."""


def failure_label(line: str, state) -> str:
    """What a run that stopped with a node's `line` failed of. A node's output that left the finite
    numbers is the physics diverging when the bodies' last state (`state`, a SatelliteState) had
    already left the range of docking hardware, where the loop's products leave floating point
    (dockhil/physical.py): 'diverged (...): line'. Otherwise the NaN or Inf is the node's own
    failure (a 0/0, a bug), and so is any other line: the line as the node said it."""
    if "NaN or Inf" not in line or state is None:
        return line
    from dockhil import physical

    for body in state.bodies:
        for what, vec, limit, unit in (("at", body.pose.position, physical.DISTANCE[1], "m"),
                                       ("moving at", body.twist.linear, physical.SPEED[1], "m/s")):
            size = max(abs(vec.x), abs(vec.y), abs(vec.z))
            if size > limit:
                return (f"diverged (at tick {state.header.tick} {body.name or 'a body'} was {what} {size:.3g} {unit}, "
                        f"beyond the {limit:g} {unit} of docking hardware): {line}")
    return line


def run_one(spec: dict) -> dict:
    """One composed sim-time run; returns its row. Never raises for what the run does."""
    import warnings

    import numpy as np

    from dockhil.scene import launchfile
    from dockhil.analysis import summary as summ
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene.graph import build
    from dockhil.analysis.scenecheck import scene_check

    started = time.perf_counter()
    row = {"run": spec["run"], "sample": spec["sample"], **spec["args"], "args_hash": spec["args_hash"],
           "status": "ok", "error": None}
    try:
        graph = build(launchfile.load(spec["scene"], dict(spec["args"])))
        if "/satellite/state" not in graph.publishers:
            raise DockhilError(f"{spec['scene']}: the scene publishes no /satellite/state, so a run has no summary")
        check = scene_check(graph)  # a step that does not resolve the contact is refused, as in launch
    except DockhilError as exc:
        row.update(status="invalid", error=str(exc), run_time_s=time.perf_counter() - started)
        return row
    try:
        dt = graph.scene.dt
        collector = summ.SummaryCollector(graph)
        said: list[str] = []  # the nodes' warnings and errors (a row has no log): its warnings column carries them

        def node_log(name: str, line: str) -> None:
            if line.startswith("warning:"):
                said.append(f"{name}: {line[len('warning:'):].strip()}")
            elif line.startswith("error:"):
                said.append(f"{name}: {line}")

        last: dict[str, Any] = {}  # each topic's latest message that passed its checks (a failure's label)
        g = ComposedGraph(graph, sim_time=True, log=node_log, taps=[collector, last.__setitem__])
        recorder = None
        if spec.get("bag"):
            from dockhil.bags.format import BagError
            from dockhil.bags.live import TapRecorder

            try:
                os.makedirs(os.path.dirname(spec["bag"]), exist_ok=True)
                Path(spec["bag"]).unlink(missing_ok=True)  # left by an interrupted run of this index
                recorder = TapRecorder(spec["bag"], graph, sim=True, log=lambda line: None)
            except OSError as exc:
                raise cannot_write(exc.filename or spec["bag"], exc) from None
            except BagError as exc:
                raise WriteError(str(exc)) from None
            g.taps.append(recorder)
            row["bag"] = spec["bag"]
        sim_started = time.perf_counter()
        try:
            g.setup()
            g.run(int(round(spec["duration"] / dt)) + 1)
        except DockhilError as exc:  # a node's line, or the divergence it shows
            raise RunFailed(failure_label(str(exc), last.get("/satellite/state"))) from None
        finally:
            try:
                g.close()
            finally:
                if recorder is not None:
                    recorder.close()
                    if recorder.error:  # a full disk is no result of the run: the campaign stops
                        raise WriteError(recorder.error)
        with warnings.catch_warnings():  # a diverging loop's prediction warns; its row says what happened
            warnings.simplefilter("ignore", RuntimeWarning)
            out = collector.summary(time.perf_counter() - sim_started)
            lines = [*(out.get("warnings") or check["warnings"]), *said]
            out["warnings"] = "; ".join(dict.fromkeys(lines)) or None  # one Parquet column, each line once
            fields = flatten(out)
    except RunFailed as exc:
        row.update(status="failed", error=str(exc), run_time_s=time.perf_counter() - started)
        return row
    except WriteError:
        raise
    except Exception as exc:  # a diverging or failing run is a row, never the end of the campaign
        row.update(status="failed", error=_one_line(exc), run_time_s=time.perf_counter() - started)
        return row
    bad = [k for k, v in fields.items() if isinstance(v, float) and not math.isfinite(v)]
    if bad:
        row.update(status="failed", error=f"diverged: {bad[0]} is {fields[bad[0]]}")
    elif (fields.get("note") or "").startswith("the contact lasted less than one sample"):  # not resolved
        row.update(status="invalid", error=fields["note"])
    if spec.get("outputs") is not None:
        fields = {k: fields.get(k) for k in spec["outputs"]}
    row.update(fields)
    row["run_time_s"] = time.perf_counter() - started
    return row


def check_outputs(c: Campaign) -> None:
    """Refuse `outputs:` naming no summary field: a probe of the first run for a few ticks
    shows the scene's fields (skipped when the scene refuses that run's args)."""
    if not c.outputs:
        return
    _index, _sample, args = next(_run_args(c))
    probe = run_one({"run": 0, "sample": 0, "args": args, "args_hash": "", "scene": c.scene,
                     "duration": 3.0 / c.rate, "outputs": None, "bag": None})
    if probe["status"] != "ok":
        return
    fields = [k for k in probe if k not in ("run", "sample", "args_hash", "status", "error", "run_time_s", *c.arg_names)]
    unknown = [name for name in c.outputs if name not in fields]
    if unknown:
        raise CampaignError(f"{c.path}: outputs: {unknown[0]!r} is not a summary field of {Path(c.scene).name}; "
                            f"its fields: {', '.join(fields)}")


def run_batch(batch: list[dict]) -> list[dict]:
    return [run_one(spec) for spec in batch]


def failed_row(spec: dict, error: str) -> dict:
    return {"run": spec["run"], "sample": spec["sample"], **spec["args"], "args_hash": spec["args_hash"],
            "status": "failed", "error": error, "run_time_s": None}


# ---------------------------------------------------------------- executors

def _worker_start(parent: int) -> None:
    """A local worker's start. Ctrl-C is the parent's to handle (it ends the workers itself), and
    a worker ends with its parent however the parent ends, a SIGKILL included: the kernel kills
    it then (PR_SET_PDEATHSIG, Linux), else a thread that watches the parent does. A sim-time run
    has nothing to save: the parent keeps the rows."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the parent's handler, inherited by fork
    try:
        import ctypes

        if ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0) != 0:  # PR_SET_PDEATHSIG
            raise OSError
    except (OSError, AttributeError):  # not Linux
        import threading

        threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    if not _alive(parent):  # it died before the prctl
        os._exit(1)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except OSError:  # gone, or its number now another user's
        return False
    return True


def _watch_parent(parent: int) -> None:
    while _alive(parent):
        time.sleep(0.5)
    os._exit(1)


class Batcher:
    """Cuts the runs into batches sized so that one batch takes about `target_s`, from
    the mean run time seen so far (the first batches hold one run each): per-task
    overhead stays small for short runs, and progress and the journal stay current for
    long ones. Near the end batches shrink so that every worker gets a share. A batch
    whose worker was lost comes back first, RETRIES times."""

    def __init__(self, specs: list[dict], workers: int, target_s: float = 2.0, max_size: int = 50):
        from collections import deque

        self.queue = deque(specs)
        self.retry: deque = deque()  # (batch, tries so far)
        self.workers = max(1, workers)
        self.target_s, self.max_size = target_s, max_size
        self.seen = 0
        self.total_s = 0.0

    def __bool__(self) -> bool:
        return bool(self.queue or self.retry)

    def next(self) -> tuple[list[dict], int] | None:
        if self.retry:
            return self.retry.popleft()
        if not self.queue:
            return None
        size = 1 if not self.seen else int(self.target_s / max(self.total_s / self.seen, 1e-6))
        size = max(1, min(size, self.max_size, math.ceil(len(self.queue) / self.workers)))
        return [self.queue.popleft() for _ in range(size)], 0

    def finished(self, rows: list[dict]) -> None:
        for row in rows:
            if row.get("run_time_s") is not None:
                self.seen += 1
                self.total_s += row["run_time_s"]

    def lost(self, batch: list[dict], tries: int) -> list[dict] | None:
        """Send the batch again, or (after RETRIES) its runs as failed rows."""
        if tries < RETRIES:
            self.retry.append((batch, tries + 1))
            return None
        return [failed_row(spec, f"worker lost {tries + 1} times running this batch") for spec in batch]


class LocalPool:
    """A process pool of `workers`, two batches in flight per worker. A pool broken by a
    lost worker is replaced and its unfinished batches are sent again."""

    name = "local"

    def __init__(self, workers: int):
        self.workers = workers

    def map(self, batcher: Batcher) -> Iterator[list[dict]]:
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
        from concurrent.futures.process import BrokenProcessPool

        while batcher:
            pool = ProcessPoolExecutor(self.workers, initializer=_worker_start, initargs=(os.getpid(),))
            in_flight: dict = {}
            finished = False
            try:
                while batcher or in_flight:
                    while len(in_flight) < 2 * self.workers and (item := batcher.next()) is not None:
                        in_flight[pool.submit(run_batch, item[0])] = item
                    done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                    broken = False
                    for fut in done:
                        batch, tries = in_flight.pop(fut)
                        try:
                            rows = fut.result()
                        except BrokenProcessPool:
                            broken = True
                            rows = batcher.lost(batch, tries)
                        except WriteError:
                            raise
                        except Exception as exc:
                            rows = [failed_row(spec, f"batch failed: {_one_line(exc)}") for spec in batch]
                        if rows is not None:
                            batcher.finished(rows)
                            yield rows
                    if broken:  # every batch still in flight is lost with the pool: send them again
                        for fut, (batch, tries) in list(in_flight.items()):
                            rows = batcher.lost(batch, tries)
                            if rows is not None:
                                yield rows
                        in_flight.clear()
                        break
                else:
                    finished = True
            finally:
                if not finished:  # interrupted or broken: end the workers now, not after their batches
                    for proc in list(getattr(pool, "_processes", {}).values()):
                        proc.terminate()
                pool.shutdown(wait=finished, cancel_futures=True)

    def close(self) -> None:
        pass


class DaskExecutor:
    """Batches as Dask tasks on a cluster at `address`, or on a LocalCluster of worker
    processes (address "local"), two in flight per worker. Dask resubmits a lost
    worker's tasks itself (retries=)."""

    name = "dask"

    def __init__(self, address: str, workers: int | None):
        import logging

        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise CampaignError("--dask needs dask.distributed: pip install 'dask[distributed]' "
                                "(or dockhil[sweep])") from None
        self.cluster = None
        try:
            if address == "local":
                self.cluster = LocalCluster(n_workers=workers or usable_cpus(), processes=True, threads_per_worker=1,
                                            dashboard_address=None, silence_logs=logging.ERROR)
                self.client = Client(self.cluster)
            else:
                self.client = Client(address, timeout="10s")
        except (OSError, TimeoutError) as exc:
            self.close()
            raise CampaignError(f"--dask {address}: cannot reach the scheduler: {_one_line(exc)}") from None
        self.workers = max(1, len(self.client.scheduler_info().get("workers", {})))
        self.name = f"dask {address}"

    def map(self, batcher: Batcher) -> Iterator[list[dict]]:
        from dask.distributed import as_completed

        in_flight: dict = {}
        pending = as_completed()

        def feed() -> None:
            while len(in_flight) < 2 * self.workers and (item := batcher.next()) is not None:
                fut = self.client.submit(run_batch, item[0], retries=RETRIES, pure=False)
                in_flight[fut] = item[0]
                pending.add(fut)

        feed()
        try:
            for fut in pending:
                batch = in_flight.pop(fut)
                try:
                    rows = fut.result()
                except WriteError:
                    raise
                except Exception as exc:  # e.g. KilledWorker after the retries
                    rows = [failed_row(spec, f"task failed: {_one_line(exc)}") for spec in batch]
                batcher.finished(rows)
                yield rows
                feed()
        finally:
            if in_flight:
                self.client.cancel(list(in_flight))

    def close(self) -> None:
        for thing in (getattr(self, "client", None), self.cluster):
            if thing is not None:
                try:
                    thing.close()
                except Exception:  # shutting down: nothing left to save
                    pass


def usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


# ---------------------------------------------------------------- results: journal and Parquet

def journal_path(results: str | Path) -> Path:
    return Path(str(results) + ".partial")


def read_done(results: str | Path) -> dict[int, dict]:
    """Rows already finished: from the Parquet file, then the journal (a line cut short
    by a crash is ignored)."""
    done: dict[int, dict] = {}
    results = Path(results)
    if results.exists():
        import pyarrow.parquet as pq

        try:
            for row in pq.read_table(results).to_pylist():
                done[row["run"]] = row
        except Exception as exc:
            raise CampaignError(f"{results}: exists but is not a readable results file ({_one_line(exc)}); "
                                f"give another --out or remove it") from None
    jp = journal_path(results)
    if jp.exists():
        try:
            text = jp.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            from dockhil.files import os_reason

            reason = os_reason(exc) if isinstance(exc, OSError) else exc
            raise CampaignError(f"{jp}: cannot read: {reason}; give another --out, or remove it to start over") from None
        for line in text.splitlines():
            try:
                row = json.loads(line)
            except ValueError:
                continue
            done[row["run"]] = row
    return done


def column_order(rows: list[dict], arg_names: list[str]) -> list[str]:
    head = ["run", "sample", *arg_names, "status", "error", "run_time_s"]
    rest = []
    for row in rows:
        rest.extend(k for k in row if k not in head and k not in rest)
    return head + [k for k in rest if k != "args_hash"] + ["args_hash"]


def write_parquet(results: str | Path, rows: list[dict], c: Campaign) -> None:
    """All rows, sorted by run index, written atomically (temporary file, then rename)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dockhil.files import complete_or_nothing

    rows = sorted(rows, key=lambda r: r["run"])
    names = column_order(rows, c.arg_names)
    columns = {}
    text = {"status", "error", "args_hash", "bag"}
    for name in names:
        values = [r.get(name) for r in rows]
        try:
            columns[name] = pa.array(values, type=pa.string() if name in text else None)
        except (pa.ArrowInvalid, pa.ArrowTypeError):  # mixed types: keep them readable as text
            columns[name] = pa.array([None if v is None else str(v) for v in values])
    meta = {"path": c.path, "scene": c.scene, "rate": c.rate, "duration": c.duration, "fixed": c.fixed,
            "grid": list(c.grid), "random": list(c.random), "total": c.total}
    table = pa.table(columns).replace_schema_metadata({METADATA_KEY: json.dumps(meta).encode()})
    with complete_or_nothing(str(results), WriteError) as part:  # a full disk leaves the last file whole
        pq.write_table(table, part)


class SweepProgress:
    """Runs done, failed, runs per second and time left, on one status line."""

    def __init__(self, total: int, already: int, stream=None):
        from dockhil.progress import StatusLine

        self.total, self.already = total, already
        self.line = StatusLine(stream)
        self.started = time.perf_counter()
        self.last = 0.0
        self.interval = 0.2 if self.line.tty else 5.0

    def update(self, done: int, failed: int, force: bool = False) -> None:
        from dockhil.progress import bar

        now = time.perf_counter()
        if not force and now - self.last < self.interval:
            return
        self.last = now
        elapsed = now - self.started
        new = done - self.already
        rate = new / elapsed if elapsed > 0 else 0.0
        left = f"{(self.total - done) / rate:.0f} s left" if rate > 0 else "time left: -"
        self.line.show(f"[{bar(done / max(1, self.total), 24)}] {done}/{self.total} runs, {failed} failed, "
                       f"{rate:.2f} runs/s, {left}")

    def done(self) -> None:
        self.line.end()


def _open_journal(results: str | Path, c: Campaign):
    """The journal, open to append, and the bags' folder made: refused before anything runs
    when they cannot be written. A line a crash or a full disk cut short is ended first."""
    jp = journal_path(results)
    try:
        if c.bags:
            os.makedirs(str(results) + ".bags", exist_ok=True)
        journal = open(jp, "a")
        if journal.tell():
            with open(jp, "rb") as f:
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":
                    journal.write("\n")
        return journal
    except OSError as exc:
        raise CampaignError(f"{cannot_write(jp, exc)}; give --out in a folder with room that you can write") from None


def sweep(campaign: Campaign, results: str | Path, executor, *, progress: bool = True, stream=None) -> dict:
    """Run every run not yet in `results`; returns counts. Rows are journaled per batch;
    the Parquet file is written at the end, and on interruption before it is re-raised.
    A result that cannot be written (a full disk) stops the campaign with a WriteError;
    the rows already journaled stay, and a rerun resumes from them."""
    import sys

    stream = sys.stderr if stream is None else stream
    specs = runs(campaign, results)
    done = read_done(results)
    by_run = {s["run"]: s for s in specs}
    for index, row in done.items():
        spec = by_run.get(index)
        if spec is None or spec["args_hash"] != row.get("args_hash"):
            raise CampaignError(f"{results}: holds run {index} of another campaign (other args, scene or duration); "
                                f"give another --out, or remove the file to start over")
    todo = [s for s in specs if s["run"] not in done]
    counts = Counter(r["status"] for r in done.values())
    skipped = len(done)
    journal = _open_journal(results, campaign) if todo else None
    bar = SweepProgress(len(specs), skipped, stream) if progress else None
    started = time.perf_counter()
    executed = 0
    written = started
    batches = executor.map(Batcher(todo, executor.workers)) if todo else None
    stopped: BaseException | None = None
    try:
        for rows in batches or ():
            for row in rows:
                done[row["run"]] = row
                counts[row["status"]] += 1
            try:
                journal.write("".join(json.dumps(row) + "\n" for row in rows))
                journal.flush()
            except OSError as exc:
                raise cannot_write(journal.name, exc) from None
            executed += len(rows)
            if time.perf_counter() - written > PARQUET_EVERY_S:  # readable while the campaign runs
                write_parquet(results, list(done.values()), campaign)
                written = time.perf_counter()
            if bar is not None:
                bar.update(len(done), counts["failed"])
    except BaseException as exc:
        stopped = exc
        raise
    finally:
        if batches is not None:
            batches.close()  # on an interruption or an error: the workers end now, not after their batches
        if journal is not None:
            try:
                journal.close()
            except OSError:  # its last rows did not reach the disk: they run again on the rerun
                pass
        if bar is not None:
            bar.done()
        if done:
            try:
                write_parquet(results, list(done.values()), campaign)
            except WriteError:
                if stopped is None or isinstance(stopped, KeyboardInterrupt):
                    raise
                # else the first failure (often the same full disk) is the one said; the journal keeps the rows
            else:
                if len(done) == len(specs):
                    journal_path(results).unlink(missing_ok=True)
    elapsed = time.perf_counter() - started
    stable = Counter(r.get("stable") for r in done.values() if r["status"] == "ok")
    errors = Counter(r["error"] for r in done.values() if r["status"] != "ok" and r.get("error"))
    return {"total": len(specs), "executed": executed, "skipped": skipped, "elapsed_s": elapsed,
            "runs_per_s": executed / elapsed if elapsed > 0 else None,
            **{s: counts[s] for s in STATUSES}, "stable": stable.get(True, 0), "unstable": stable.get(False, 0),
            "classified": (True in stable or False in stable), "errors": errors.most_common(3)}


def format_report(out: dict, results: str, executor_name: str) -> str:
    rate = f", {out['runs_per_s']:.2f} runs/s" if out["runs_per_s"] else ""
    lines = [f"{out['total']} runs: {out['ok']} ok, {out['invalid']} invalid, {out['failed']} failed"
             + (f" ({out['skipped']} already in {results})" if out["skipped"] else "")
             + f"; {out['executed']} run in {out['elapsed_s']:.1f} s on {executor_name}{rate}"]
    if out["classified"]:
        lines.append(f"stability: {out['stable']} stable, {out['unstable']} unstable (growth rate of the contact)")
    for error, n in out["errors"]:
        lines.append(f"  {n} x {error}")
    lines.append(f"results: {results}")
    return "\n".join(lines)
