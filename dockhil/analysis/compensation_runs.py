"""The compensation benchmark's grid points (dockhil.contact.compensation_grid) run here, or in
batches on the campaign engine's executors (dockhil.analysis.sweep: a LocalPool whose workers die
with this process, a Dask cluster): the rows come back in the grid's order whatever order they
finish in, and a point that raises is a failed row naming it, not the end of the benchmark."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from dockhil.analysis.sweep.run import exception_line

if TYPE_CHECKING:
    from dockhil.analysis.sweep import DaskExecutor, LocalPool


def run_points(batch: list[dict]) -> list[dict]:
    """A batch's rows (in a worker, or here): each point ({"point": index, "task": run_point's
    arguments}) gives its row with its index; one that raises gives its failed row and the rest run."""
    from dockhil.contact import compensation_grid as grid

    rows = []
    for spec in batch:
        try:
            row = grid.run_point(*spec["task"])
        except Exception as exc:  # a bug or a refusal the grid did not foresee: this point's row says it
            row = failed_point(spec, exception_line(exc))
        row["point"] = spec["point"]
        rows.append(row)
    return rows


def failed_point(spec: dict, error: str) -> dict:
    """The row of a point that gave none: its place in the grid, and the line naming it and what happened."""
    from dockhil.contact import compensation_grid as grid

    scene, _ref, method, omega_h, hw_name, _hw = spec["task"]
    return {
        "scene": scene.name,
        "target": scene.target_name,
        "hardware": hw_name,
        "method": method,
        "omega_h_grid": omega_h,
        "error": f"{grid.label(spec['task'])}: {error}",
        "failed": True,
        "point": spec["point"],
    }


def make_executor(workers: int | None, dask: str | None) -> LocalPool | DaskExecutor | None:
    """Where the points run: on the Dask cluster at `dask` (or a LocalCluster of `workers`, else the
    usable CPUs, for "local"), on a LocalPool of `workers` > 1, or here (None). Close it when done."""
    from dockhil.analysis.sweep import DaskExecutor, LocalPool

    if dask is not None:
        return DaskExecutor(dask, workers, run=run_points, failed=failed_point)
    if workers is not None and workers > 1:
        return LocalPool(workers, run=run_points, failed=failed_point)
    return None


def run_grid(
    todo: list[tuple],
    executor: LocalPool | DaskExecutor | None = None,  # made by make_executor
    progress: Callable[[str], None] | None = None,
) -> list[dict]:
    """Every point's row, in the order of `todo` (run_point's arguments): in this process, one point after
    another (`progress(label)` before each), or on `executor` in batches (`progress(label)` as each ends)."""
    from dockhil.contact import compensation_grid as grid

    points = [{"point": i, "task": task} for i, task in enumerate(todo)]
    rows: list[dict | None] = [None] * len(points)
    if executor is None:
        for spec in points:
            if progress is not None:
                progress(grid.label(spec["task"]))
            (rows[spec["point"]],) = run_points([spec])
    else:
        from dockhil.analysis.sweep import Batcher

        batches = executor.map(Batcher(points, executor.workers, time_key="cpu_s"))
        try:
            for batch in batches:
                for row in batch:
                    rows[row["point"]] = row
                    if progress is not None:
                        progress(grid.label(todo[row["point"]]))
        finally:
            batches.close()  # interrupted: the workers end now, not after their batches
    out = []
    for i, row in enumerate(rows):
        if row is None:  # an executor that lost a point without a row for it
            row = failed_point(points[i], "no row came back for this point")
        del row["point"]
        out.append(row)
    return out
