"""A bag knows its run: three MCAP metadata records (name, str -> str) that every recorder writes.

- `dockhil.run`, first: the launch file, its resolved arguments (JSON; `args_set`: those not at
  their default), the dockhil version, the clock (sim/wall), the rate, the run length, the graph's
  start time on the wall clock (`start`, ISO 8601 UTC, and `start_ns`) and who recorded it
  (`launch`, `launch --composed`, `bag record`). Fields dockhil.scene.provenance.run_fields makes.
- `dockhil.scene`, next: absolute path -> text of every launch file the scene read (its includes too),
  from which `dockhil analyze` rebuilds the graph.
- `dockhil.verdict`, last, written as the recorder closes the bag: `verdict` (valid, INVALID, failed,
  not known), `valid` (true/false, empty when not known), `exit_code` (the launch's), `invalid_reasons`
  (JSON list), `why` (one line) and `recorder_lost` (messages the recorder lost). The launch tells
  the recorder the verdict before it closes (dockhil.session); a recorder that was not told (one
  started from outside with `bag record`) says so. A bag with a run record and no verdict is one
  whose recorder stopped before the run ended (killed): the run did not finish.

Bags of older versions hold none of these: `read` says so, and everything still reads.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dockhil.bags.reader import BagReader
    from dockhil.bags.writer import BagWriter

RUN, SCENE, VERDICT = "dockhil.run", "dockhil.scene", "dockhil.verdict"
NOT_FINISHED = "did not finish"


def verdict_fields(code: int, reasons: list[str]) -> dict[str, str]:
    """The verdict record of a run that ended with exit `code` and these invalid reasons."""
    from dockhil.runtime.validity import INVALID_EXIT

    if code == 0:
        verdict, valid, why = "valid", "true", "the run completed and its result is valid"
    elif code == INVALID_EXIT:
        verdict, valid, why = "INVALID", "false", "; ".join(reasons)
    elif code >= 128:
        verdict, valid, why = "failed", "false", f"the run was stopped by signal {code - 128} (exit {code})"
    else:
        verdict, valid, why = (
            "failed",
            "false",
            f"a node stopped the graph, or the run could not complete (exit {code})",
        )
    return {
        "verdict": verdict,
        "valid": valid,
        "exit_code": str(code),
        "invalid_reasons": json.dumps(list(reasons)),
        "why": why,
    }


def not_told(why: str) -> dict[str, str]:
    """The verdict record of a recorder that was not told the run's verdict, and why."""
    return {"verdict": "not known", "valid": "", "exit_code": "", "invalid_reasons": "[]", "why": why}


def with_loss(verdict: dict[str, str], lost: int) -> dict[str, str]:
    """The verdict as the recorder writes it: a recorder that lost messages fails the run (the launch
    exits 1 then) and says so, whatever it was told."""
    out = dict(verdict, recorder_lost=str(lost))
    if lost:
        out.update(
            verdict="failed",
            valid="false",
            exit_code="1",
            why=f"the recorder lost {lost} message(s): the bag is not the whole run",
        )
    return out


@dataclass
class RunInfo:
    """What a bag says of its run (empty for a bag of an older dockhil)."""

    runs: list[dict[str, str]] = field(default_factory=list)
    texts: dict[str, str] = field(default_factory=dict)
    verdict: dict[str, str] | None = None

    @property
    def recorded(self) -> bool:
        return bool(self.runs)

    @property
    def run(self) -> dict[str, str]:
        return self.runs[0] if self.runs else {}

    @property
    def state(self) -> str:
        """valid, INVALID, failed, not known, did not finish; or 'not recorded' (an older bag)."""
        if not self.runs:
            return "not recorded"
        if self.verdict is None:
            return NOT_FINISHED
        return self.verdict.get("verdict", "not known")

    @property
    def valid(self) -> bool | None:
        """The recorded validity: None where it is not known."""
        if self.runs and self.verdict is None:
            return False
        value = (self.verdict or {}).get("valid", "")
        return None if value == "" else value == "true"

    @property
    def reasons(self) -> list[str]:
        """Why the recorded run is not valid (empty when it is, or when that is not known)."""
        if self.runs and self.verdict is None:
            return [f"the run {NOT_FINISHED}: {self.why}"]
        if self.state == "failed":
            return [self.why]
        try:
            found = json.loads((self.verdict or {}).get("invalid_reasons") or "[]")
        except ValueError:
            return []
        return [str(r) for r in found] if isinstance(found, list) else []

    @property
    def why(self) -> str:
        if not self.runs:
            return "the bag holds no run metadata (recorded by an older dockhil, or another writer)"
        if self.verdict is None:
            return "the recorder stopped before the run ended (killed?), so the run's verdict is not in the bag"
        return self.verdict.get("why", "")

    def exit_code(self) -> int | None:
        try:
            return int((self.verdict or {}).get("exit_code", ""))
        except ValueError:
            return None

    def args(self, key: str = "args") -> dict:
        try:
            found = json.loads(self.run.get(key) or "{}")
        except ValueError:
            return {}
        return found if isinstance(found, dict) else {}

    def as_json(self) -> dict | None:
        """The run's description as `bag info --json` gives it (None for an older bag)."""
        if not self.runs:
            return None
        run = self.run
        out: dict[str, Any] = {
            k: run.get(k)
            for k in ("scene", "description", "dockhil_version", "clock", "start", "recorded_by", "joined")
        }
        out["args"] = self.args()
        out["args_set"] = self.args("args_set")
        for key in ("rate_hz", "duration_s", "start_ns"):
            try:
                out[key] = float(run[key]) if key != "start_ns" else int(run[key])
            except (KeyError, ValueError):
                out[key] = None
        out["scene_files"] = sorted(self.texts)
        if len(self.runs) > 1:
            out["other_runs"] = [r.get("scene") for r in self.runs[1:]]
        out.update(
            verdict=self.state, valid=self.valid, invalid_reasons=self.reasons, exit_code=self.exit_code(), why=self.why
        )
        if self.verdict is not None and "recorder_lost" in self.verdict:
            out["recorder_lost"] = int(self.verdict["recorder_lost"] or 0)
        return out


OLDER_BAG = (
    "not recorded (a bag of an older dockhil, or of another writer): its scene, arguments and validity are not known"
)


def info_lines(run: dict | None) -> list[str]:
    """The lines of `bag info`'s table on the run, from RunInfo.as_json()."""
    if run is None:
        return [f"run:       {OLDER_BAG}"]
    scene = (run.get("scene") or "not known").rsplit("/", 1)[-1]
    rate = f", {run['rate_hz']:g} Hz" if run.get("rate_hz") else ""
    length = f", {run['duration_s']:g} s" if run.get("duration_s") else ""
    changed = " ".join(f"{k}:={v}" for k, v in (run.get("args_set") or {}).items())
    state = run["verdict"] + (f" (exit {run['exit_code']})" if run["verdict"] == "valid" else f": {run['why']}")
    return [
        f"run:       {scene} ({run.get('clock') or '?'} time{rate}{length}), dockhil "
        f"{run.get('dockhil_version') or '?'}, recorded by {run.get('recorded_by') or '?'}",
        f"started:   {run.get('start') or 'not known'}"
        + (f" (the recording joined at {run['joined']})" if run.get("joined") else ""),
        f"args:      {changed or ('(all at their defaults)' if run.get('scene') else 'not known')}",
        f"validity:  {state}",
    ]


def read(reader: BagReader) -> RunInfo:
    """The run records of an open BagReader."""
    info = RunInfo()
    for name, data in reader.metadata():
        if name == RUN:
            info.runs.append(data)
        elif name == SCENE and not info.texts:
            info.texts = data
        elif name == VERDICT:
            info.verdict = data
    return info


def read_path(path: str) -> RunInfo:
    from dockhil.bags.reader import BagReader

    with BagReader(path) as reader:
        return read(reader)


def write_start(bag: BagWriter, run: dict[str, str] | None, texts: dict[str, str] | None) -> None:
    """The run's description and its scene's texts, first in the bag."""
    if run is not None:
        bag.add_metadata(RUN, run)
    if texts:
        bag.add_metadata(SCENE, texts)
