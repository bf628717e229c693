"""A campaign's results: a finished batch's rows are appended to a journal next to the results at
once (`RESULTS.parquet.partial`, JSON lines), and the Parquet file is written from all rows every
minute, at the end and on interruption. A rerun reads both and skips every run whose index and
argument hash are already there (`sweep`); `format_report` says what the campaign did."""

from __future__ import annotations

import json
import os
import time
from collections import Counter
from pathlib import Path
from typing import TextIO, cast

from dockhil.analysis.sweep.campaign import Campaign, CampaignError, WriteError, cannot_write, runs
from dockhil.analysis.sweep.executors import Batcher, DaskExecutor, LocalPool
from dockhil.analysis.sweep.run import exception_line

STATUSES = ("ok", "invalid", "failed")
METADATA_KEY = b"dockhil.campaign"
PARQUET_EVERY_S = 60.0  # the Parquet file is rewritten this often during a campaign (the journal at once)


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
            raise CampaignError(
                f"{results}: exists but is not a readable results file ({exception_line(exc)}); "
                f"give another --out or remove it"
            ) from None
    jp = journal_path(results)
    if jp.exists():
        try:
            text = jp.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            from dockhil.files import os_reason

            reason = os_reason(exc) if isinstance(exc, OSError) else exc
            raise CampaignError(
                f"{jp}: cannot read: {reason}; give another --out, or remove it to start over"
            ) from None
        for line in text.splitlines():
            try:
                row = json.loads(line)
            except ValueError:
                continue
            done[row["run"]] = row
    return done


def column_order(rows: list[dict], arg_names: list[str]) -> list[str]:
    head = ["run", "sample", *arg_names, "status", "error", "run_time_s"]
    rest: list[str] = []
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
    meta = {
        "path": c.path,
        "scene": c.scene,
        "rate": c.rate,
        "duration": c.duration,
        "fixed": c.fixed,
        "grid": list(c.grid),
        "random": list(c.random),
        "total": c.total,
    }
    table = pa.table(columns).replace_schema_metadata({METADATA_KEY: json.dumps(meta).encode()})
    with complete_or_nothing(str(results), WriteError) as part:  # a full disk leaves the last file whole
        pq.write_table(table, part)


class SweepProgress:
    """Runs done, failed, runs per second and time left, on one status line."""

    def __init__(self, total: int, already: int, stream: TextIO | None = None):
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
        self.line.show(
            f"[{bar(done / max(1, self.total), 24)}] {done}/{self.total} runs, {failed} failed, "
            f"{rate:.2f} runs/s, {left}"
        )

    def done(self) -> None:
        self.line.end()


def _open_journal(results: str | Path, c: Campaign) -> TextIO:
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


def sweep(
    campaign: Campaign,
    results: str | Path,
    executor: LocalPool | DaskExecutor,
    *,
    progress: bool = True,
    stream: TextIO | None = None,
) -> dict:
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
            raise CampaignError(
                f"{results}: holds run {index} of another campaign (other args, scene or duration); "
                f"give another --out, or remove the file to start over"
            )
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
            log = cast(TextIO, journal)  # open: there are runs to do
            try:
                log.write("".join(json.dumps(row) + "\n" for row in rows))
                log.flush()
            except OSError as exc:
                raise cannot_write(log.name, exc) from None
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
    return {
        "total": len(specs),
        "executed": executed,
        "skipped": skipped,
        "elapsed_s": elapsed,
        "runs_per_s": executed / elapsed if elapsed > 0 else None,
        **{s: counts[s] for s in STATUSES},
        "stable": stable.get(True, 0),
        "unstable": stable.get(False, 0),
        "classified": (True in stable or False in stable),
        "errors": errors.most_common(3),
    }


def format_report(out: dict, results: str, executor_name: str) -> str:
    rate = f", {out['runs_per_s']:.2f} runs/s" if out["runs_per_s"] else ""
    lines = [
        f"{out['total']} runs: {out['ok']} ok, {out['invalid']} invalid, {out['failed']} failed"
        + (f" ({out['skipped']} already in {results})" if out["skipped"] else "")
        + f"; {out['executed']} run in {out['elapsed_s']:.1f} s on {executor_name}{rate}"
    ]
    if out["classified"]:
        lines.append(f"stability: {out['stable']} stable, {out['unstable']} unstable (growth rate of the contact)")
    for error, n in out["errors"]:
        lines.append(f"  {n} x {error}")
    lines.append(f"results: {results}")
    return "\n".join(lines)
