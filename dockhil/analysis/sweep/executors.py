"""Where a campaign's runs go: batches sized to the runs' time (`Batcher`), to a local process pool
whose workers die with the sweep (`LocalPool`) or a Dask cluster (`DaskExecutor`).

What a batch is run with is the executor's `run` (a batch of specs -> their rows) and `failed`
(a spec and a line -> its failed row): module-level functions, since a worker receives them by
name. A sweep's run_batch and failed_row by default; the compensation benchmark gives its own."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Generator

from dockhil.analysis.sweep.campaign import CampaignError, WriteError
from dockhil.analysis.sweep.run import exception_line, failed_row, run_batch
from dockhil.runtime.parent import die_with_parent

RETRIES = 2  # a batch whose worker was lost is sent again this many times

BatchRunner = Callable[[list[dict]], list[dict]]
FailedRow = Callable[[dict, str], dict]


def _worker_start(parent: int) -> None:
    """A local worker's start. Ctrl-C is the parent's to handle (it ends the workers itself), and
    a worker ends with its parent however the parent ends, a SIGKILL included: the kernel kills
    it then, else a thread that watches the parent does (die_with_parent). A sim-time run has
    nothing to save: the parent keeps the rows."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the parent's handler, inherited by fork
    die_with_parent(signal.SIGKILL, parent)


class Batcher:
    """Cuts the runs into batches sized so that one batch takes about `target_s`, from
    the mean run time seen so far (the first batches hold one run each): per-task
    overhead stays small for short runs, and progress and the journal stay current for
    long ones. Near the end batches shrink so that every worker gets a share. A batch
    whose worker was lost comes back first, RETRIES times. A row's run time is its
    `time_key` column (rows without it do not count)."""

    def __init__(
        self,
        specs: list[dict],
        workers: int,
        target_s: float = 2.0,
        max_size: int = 50,
        time_key: str = "run_time_s",
    ):
        from collections import deque

        self.queue = deque(specs)
        self.retry: deque = deque()  # (batch, tries so far)
        self.workers = max(1, workers)
        self.target_s, self.max_size = target_s, max_size
        self.time_key = time_key
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
            if row.get(self.time_key) is not None:
                self.seen += 1
                self.total_s += row[self.time_key]

    def lost(self, batch: list[dict], tries: int) -> bool:
        """Send the batch again (True), or not after RETRIES (False: its runs become failed rows)."""
        if tries < RETRIES:
            self.retry.append((batch, tries + 1))
            return True
        return False


class LocalPool:
    """A process pool of `workers`, two batches in flight per worker. A pool broken by a
    lost worker is replaced and its unfinished batches are sent again."""

    name = "local"

    def __init__(self, workers: int, run: BatchRunner | None = None, failed: FailedRow | None = None):
        self.workers = workers
        # The defaults are looked up now, not where the signature is read: a test can stand in for them.
        self.run = run or run_batch
        self.failed = failed or failed_row

    def _lost(self, batcher: Batcher, batch: list[dict], tries: int) -> list[dict] | None:
        if batcher.lost(batch, tries):
            return None
        return [self.failed(spec, f"worker lost {tries + 1} times running this batch") for spec in batch]

    def map(self, batcher: Batcher) -> Generator[list[dict], None, None]:
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
        from concurrent.futures.process import BrokenProcessPool

        while batcher:
            pool = ProcessPoolExecutor(self.workers, initializer=_worker_start, initargs=(os.getpid(),))
            in_flight: dict = {}
            finished = False
            try:
                while batcher or in_flight:
                    while len(in_flight) < 2 * self.workers and (item := batcher.next()) is not None:
                        in_flight[pool.submit(self.run, item[0])] = item
                    done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                    broken = False
                    for fut in done:
                        batch, tries = in_flight.pop(fut)
                        try:
                            rows = fut.result()
                        except BrokenProcessPool:
                            broken = True
                            rows = self._lost(batcher, batch, tries)
                        except WriteError:
                            raise
                        except Exception as exc:
                            rows = [self.failed(spec, f"batch failed: {exception_line(exc)}") for spec in batch]
                        if rows is not None:
                            batcher.finished(rows)
                            yield rows
                    if broken:  # every batch still in flight is lost with the pool: send them again
                        for _fut, (batch, tries) in list(in_flight.items()):
                            rows = self._lost(batcher, batch, tries)
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

    def __init__(
        self, address: str, workers: int | None, run: BatchRunner | None = None, failed: FailedRow | None = None
    ):
        import logging

        self.run = run or run_batch
        self.failed = failed or failed_row
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise CampaignError(
                "--dask needs dask.distributed: pip install 'dask[distributed]' (or dockhil[sweep])"
            ) from None
        self.cluster = None
        try:
            if address == "local":
                self.cluster = LocalCluster(
                    n_workers=workers or usable_cpus(),
                    processes=True,
                    threads_per_worker=1,
                    dashboard_address=None,
                    # A worker whose scheduler closed first logs its failed heartbeat at ERROR, with a
                    # traceback, when a run ends early (Ctrl-C, SIGTERM); a task's own error reaches the
                    # client as its row's failure, so the workers' logs are not needed.
                    silence_logs=logging.CRITICAL,
                )
                self.client = Client(self.cluster)
            else:
                self.client = Client(address, timeout="10s")
        except (OSError, TimeoutError) as exc:
            self.close()
            raise CampaignError(f"--dask {address}: cannot reach the scheduler: {exception_line(exc)}") from None
        except ValueError as exc:  # no scheme or port: Dask's own parse of the address
            self.close()
            raise CampaignError(
                f"--dask {address!r}: not a scheduler's address ({exc}); give tcp://HOST:PORT, or local"
            ) from None
        self.workers = max(1, len(self.client.scheduler_info().get("workers", {})))
        self.name = f"dask {address}"

    def map(self, batcher: Batcher) -> Generator[list[dict], None, None]:
        from dask.distributed import as_completed

        in_flight: dict = {}
        pending = as_completed()

        def feed() -> None:
            while len(in_flight) < 2 * self.workers and (item := batcher.next()) is not None:
                fut = self.client.submit(self.run, item[0], retries=RETRIES, pure=False)
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
                    rows = [self.failed(spec, f"task failed: {exception_line(exc)}") for spec in batch]
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
