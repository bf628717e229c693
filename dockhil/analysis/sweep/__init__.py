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

Modules: `campaign` (the file, its bounds and its runs), `run` (one run, in a worker),
`executors` (batches, the local pool, Dask), `results` (the journal, the Parquet file, the report).
"""

from __future__ import annotations

from dockhil.analysis.sweep.campaign import (
    MAX_RUNS,
    MAX_SEED,
    Campaign,
    CampaignError,
    WriteError,
    draw,
    load_campaign,
    runs,
)
from dockhil.analysis.sweep.executors import Batcher, DaskExecutor, LocalPool, usable_cpus
from dockhil.analysis.sweep.results import METADATA_KEY, format_report, journal_path, read_done, sweep
from dockhil.analysis.sweep.run import check_outputs, flatten, run_batch, run_one

__all__ = [
    "MAX_RUNS",
    "MAX_SEED",
    "METADATA_KEY",
    "Batcher",
    "Campaign",
    "CampaignError",
    "DaskExecutor",
    "LocalPool",
    "WriteError",
    "check_outputs",
    "draw",
    "flatten",
    "format_report",
    "journal_path",
    "load_campaign",
    "read_done",
    "run_batch",
    "run_one",
    "runs",
    "sweep",
    "usable_cpus",
]
