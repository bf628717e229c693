"""A result a sweep cannot write (a full disk, an unwritable folder) is one line naming the file and
what to do: refused with exit 2 when nothing ran, else the campaign stops with exit 1, keeps the
rows already written and ends its workers; the rerun resumes."""

from __future__ import annotations

import errno
import gc
import os
import subprocess
import textwrap
import time
from pathlib import Path

import psutil
import pyarrow.parquet as pq
import pytest

from dockhil import cli
from dockhil.analysis import sweep
from dockhil.analysis.sweep import results as sweep_results
from tests.test_sweep import Counting

CAMPAIGN = """
scene: stability.yaml
args: {m: 20.0, delay: 0.016, b: 150}
duration: 0.05
grid:
  k: {range: [6000, 9000], num: N}
"""


def campaign(tmp_path: Path, runs: int = 4) -> Path:
    path = tmp_path / "campaign.yaml"
    path.write_text(textwrap.dedent(CAMPAIGN).replace("num: N", f"num: {runs}"))
    return path


def sweep_cli(path: Path, out: Path, capsys) -> tuple[int, list[str]]:
    code = cli.main(["sweep", str(path), "--out", str(out), "--workers", "1", "--quiet"])
    return code, capsys.readouterr().err.strip().splitlines()


def enospc() -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def children() -> set:
    return set(psutil.Process().children(recursive=True))


def assert_no_worker_left(before: set) -> None:
    """No child of this process that was not there `before` (a resource tracker an earlier test
    started lives as long as this process) is left after a few seconds."""
    _gone, alive = psutil.wait_procs(children() - before, timeout=5)
    assert not alive


class FullAfter:
    """The journal, on a disk that fills after `n` writes."""

    def __init__(self, f, n: int):
        self.f, self.n, self.name = f, n, f.name

    def write(self, text: str) -> None:
        if self.n == 0:
            raise enospc()
        self.n -= 1
        self.f.write(text)

    def flush(self) -> None:
        self.f.flush()

    def close(self) -> None:
        self.f.close()


def test_a_full_disk_under_the_journal_stops_the_campaign_keeps_its_rows_and_the_rerun_resumes(
    tmp_path, capsys, monkeypatch
):
    path, out = campaign(tmp_path), tmp_path / "r.parquet"
    real = sweep_results._open_journal
    monkeypatch.setattr(sweep_results, "_open_journal", lambda results, c: FullAfter(real(results, c), 1))
    before = children()
    code, err = sweep_cli(path, out, capsys)
    assert code == 1 and len(err) == 1, err
    assert err[0] == (
        f"dockhil sweep: error: cannot write {out}.partial: No space left on device (ENOSPC); the rows "
        f"written before stay: make room on that disk (or make it writable) and rerun the same command "
        f"to resume"
    )
    assert_no_worker_left(before)
    assert len(sweep.journal_path(out).read_text().splitlines()) == 1
    kept = sorted(r["run"] for r in pq.read_table(out).to_pylist())
    assert kept == [0, 1]  # the second row reached the Parquet file, not the full journal
    monkeypatch.undo()
    rerun = Counting(sweep.LocalPool(1))
    result = sweep.sweep(sweep.load_campaign(path), out, rerun, progress=False)
    assert sorted(rerun.executed) == [2, 3] and result["ok"] == 4
    assert sorted(r["run"] for r in pq.read_table(out).to_pylist()) == [0, 1, 2, 3]
    assert not sweep.journal_path(out).exists()


def test_a_full_disk_under_the_parquet_file_keeps_the_journal_and_no_partial_file(tmp_path, capsys, monkeypatch):
    path, out = campaign(tmp_path), tmp_path / "r.parquet"

    def full(table, where, **kw):
        Path(where).write_bytes(b"PAR1 half a file")
        raise OSError(errno.ENOSPC, "Error writing bytes to file. Detail: [errno 28] No space left on device")

    monkeypatch.setattr(pq, "write_table", full)
    code, err = sweep_cli(path, out, capsys)
    assert code == 1 and len(err) == 1, err
    assert f"cannot write {out}: " in err[0] and "(ENOSPC)" in err[0] and "rerun the same command" in err[0]
    assert not out.exists() and not Path(f"{out}.part").exists()
    assert len(sweep.journal_path(out).read_text().splitlines()) == 4
    monkeypatch.undo()
    code, err = sweep_cli(path, out, capsys)
    assert code == 0 and len(pq.read_table(out)) == 4 and not sweep.journal_path(out).exists()


def test_a_journal_that_cannot_be_read_or_opened_is_refused_before_anything_runs(tmp_path, capsys):
    path, out = campaign(tmp_path), tmp_path / "r.parquet"
    sweep.journal_path(out).mkdir()
    code, err = sweep_cli(path, out, capsys)
    assert code == 2 and len(err) == 1, err
    assert f"{out}.partial: cannot read: Is a directory (EISDIR); give another --out" in err[0]
    sweep.journal_path(out).rmdir()
    sweep.journal_path(out).symlink_to(tmp_path / "no-such-folder" / "journal")
    code, err = sweep_cli(path, out, capsys)
    assert code == 2 and len(err) == 1, err
    assert f"cannot write {out}.partial: No such file or directory (ENOENT); give --out in a folder" in err[0]
    assert not out.exists()


def test_a_journal_line_cut_short_is_ended_before_the_next_row(tmp_path):
    c, out = sweep.load_campaign(campaign(tmp_path, runs=2)), tmp_path / "r.parquet"
    sweep.journal_path(out).write_text('{"run": 0, "sta')  # a crash or a full disk, mid-line
    first = Counting(sweep.LocalPool(1), stop_after=1)
    with pytest.raises(KeyboardInterrupt):
        sweep.sweep(c, out, first, progress=False)
    out.unlink()  # as after a crash: only the journal
    assert sorted(sweep.read_done(out)) == sorted(first.executed) != []


def test_a_bag_that_cannot_be_written_stops_the_campaign(tmp_path, monkeypatch):
    from dockhil.bags.tap import TapRecorder

    c = sweep.load_campaign(campaign(tmp_path))
    spec = {**sweep.runs(c, tmp_path / "r.parquet")[0], "bag": str(tmp_path / "a-file" / "run-000000.mcap")}
    (tmp_path / "a-file").write_text("")
    with pytest.raises(sweep.WriteError, match=r"cannot write .*a-file: File exists \(EEXIST\)"):
        sweep.run_one(spec)

    def full(self, topic, msg):  # what the recorder does when its disk fills
        self.error = f"bag {self.path}: write failed: No space left on device (ENOSPC); recording stopped"

    monkeypatch.setattr(TapRecorder, "__call__", full)
    spec["bag"] = str(tmp_path / "bags" / "run-000000.mcap")
    with pytest.raises(sweep.WriteError, match=r"run-000000.mcap: write failed: No space left on device"):
        sweep.run_one(spec)


def test_a_rerun_records_again_the_bag_an_interrupted_run_left(tmp_path):
    c = sweep.load_campaign(campaign(tmp_path, runs=1))
    spec = {**sweep.runs(c, tmp_path / "r.parquet")[0]}
    spec["bag"] = str(tmp_path / "run-000000.mcap")
    Path(spec["bag"]).write_bytes(b"\x89MCAP0\r\n cut short")
    row = sweep.run_one({**spec, "bags": True})
    assert row["status"] == "ok" and row["bag"] == spec["bag"] and os.path.getsize(spec["bag"]) > 1000


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs with one 4 KiB page free (root only; skipped where mounting is not allowed)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if (
        os.geteuid() != 0
        or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)], capture_output=True
        ).returncode
        != 0
    ):
        pytest.skip("needs root and mount to make a small disk")
    try:
        filler = disk / "filler"
        with open(filler, "wb") as f:
            try:
                f.write(b"x" * (1 << 20))
                f.flush()
            except OSError:
                pass
        os.truncate(filler, max(0, filler.stat().st_size - 4096))
        yield disk
    finally:
        unmount(disk)


def holders(disk: Path) -> list[str]:
    """The processes with a file or their working directory on `disk`."""
    found = []
    for proc in psutil.process_iter(["pid", "name"]):
        try:
            paths = [f.path for f in proc.open_files()] + [proc.cwd()]
        except (psutil.Error, OSError):
            continue
        if any(p == str(disk) or p.startswith(f"{disk}/") for p in paths):
            found.append(f"{proc.info['name']} ({proc.info['pid']})")
    return found


def unmount(disk: Path) -> None:
    """Unmount once nothing holds the disk: a worker that has just exited, or a file object of this process
    not yet collected, can keep it busy for a moment (3.13 once failed to unmount it at once)."""
    gc.collect()
    deadline = time.monotonic() + 10.0
    while (r := subprocess.run(["umount", str(disk)], capture_output=True, text=True)).returncode:
        if time.monotonic() > deadline:
            raise AssertionError(f"{disk} still busy after 10 s, held by {holders(disk)}: {r.stderr.strip()}")
        time.sleep(0.1)


def test_a_real_full_disk_is_one_line_and_the_rerun_resumes(tmp_path, capsys, small_disk):
    path, out = campaign(tmp_path, runs=12), small_disk / "r.parquet"
    before = children()
    code, err = sweep_cli(path, out, capsys)
    assert code == 1 and len(err) == 1, err
    assert f"cannot write {out}" in err[0] and "No space left on device (ENOSPC)" in err[0], err
    kept = sweep.read_done(out)
    assert 0 < len(kept) < 12
    assert_no_worker_left(before)
    (small_disk / "filler").unlink()
    code, err = sweep_cli(path, out, capsys)
    assert code == 0, err
    assert sorted(r["run"] for r in pq.read_table(out).to_pylist()) == list(range(12))
