"""One run of a campaign, in a worker's process: a composed sim-time run of the scene whose summary
becomes one row (`run_one`), never raising for what the run does; and the probe of a campaign's
`outputs:` against the scene's summary fields (`check_outputs`)."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dockhil.analysis.sweep.campaign import Campaign, CampaignError, WriteError, cannot_write, run_args
from dockhil.errors import DockhilError

if TYPE_CHECKING:
    from dockhil.msgs import SatelliteState


def exception_line(exc: BaseException) -> str:
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


def failure_label(line: str, state: SatelliteState | None) -> str:
    """What a run that stopped with a node's `line` failed of. A node's output that left the finite
    numbers is the physics diverging when the bodies' last state (`state`, a SatelliteState) had
    already left the range of docking hardware, where the loop's products leave floating point
    (dockhil/physical.py): 'diverged (...): line'. Otherwise the NaN or Inf is the node's own
    failure (a 0/0, a bug), and so is any other line: the line as the node said it."""
    if "NaN or Inf" not in line or state is None:
        return line
    from dockhil import physical

    for body in state.bodies:
        for what, vec, limit, unit in (
            ("at", body.pose.position, physical.DISTANCE[1], "m"),
            ("moving at", body.twist.linear, physical.SPEED[1], "m/s"),
        ):
            size = max(abs(vec.x), abs(vec.y), abs(vec.z))
            if size > limit:
                return (
                    f"diverged (at tick {state.header.tick} {body.name or 'a body'} was {what} {size:.3g} {unit}, "
                    f"beyond the {limit:g} {unit} of docking hardware): {line}"
                )
    return line


def run_one(spec: dict) -> dict:
    """One composed sim-time run; returns its row. Never raises for what the run does."""
    import warnings

    from dockhil.analysis import summary as summ
    from dockhil.analysis.scenecheck import scene_check
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    started = time.perf_counter()
    row = {
        "run": spec["run"],
        "sample": spec["sample"],
        **spec["args"],
        "args_hash": spec["args_hash"],
        "status": "ok",
        "error": None,
    }
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
                said.append(f"{name}: {line[len('warning:') :].strip()}")
            elif line.startswith("error:"):
                said.append(f"{name}: {line}")

        last: dict[str, Any] = {}  # each topic's latest message that passed its checks (a failure's label)
        g = ComposedGraph(graph, sim_time=True, log=node_log, taps=[collector, last.__setitem__])
        recorder = None
        if spec.get("bag"):
            from dockhil.bags.format import BagError
            from dockhil.bags.tap import TapRecorder

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
        row.update(status="failed", error=exception_line(exc), run_time_s=time.perf_counter() - started)
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
    _index, _sample, args = next(run_args(c))
    probe = run_one(
        {
            "run": 0,
            "sample": 0,
            "args": args,
            "args_hash": "",
            "scene": c.scene,
            "duration": 3.0 / c.rate,
            "outputs": None,
            "bag": None,
        }
    )
    if probe["status"] != "ok":
        return
    fields = [
        k for k in probe if k not in ("run", "sample", "args_hash", "status", "error", "run_time_s", *c.arg_names)
    ]
    unknown = [name for name in c.outputs if name not in fields]
    if unknown:
        raise CampaignError(
            f"{c.path}: outputs: {unknown[0]!r} is not a summary field of {Path(c.scene).name}; "
            f"its fields: {', '.join(fields)}"
        )


def run_batch(batch: list[dict]) -> list[dict]:
    return [run_one(spec) for spec in batch]


def failed_row(spec: dict, error: str) -> dict:
    return {
        "run": spec["run"],
        "sample": spec["sample"],
        **spec["args"],
        "args_hash": spec["args_hash"],
        "status": "failed",
        "error": error,
        "run_time_s": None,
    }
