"""A sweep's workers end with it, however it ends: Ctrl-C and SIGTERM (the workers ended now, not
after their runs, the finished rows written, and the rerun does only the rest), SIGKILL (no
clean-up runs: the kernel ends them); on a local pool and on a Dask LocalCluster."""

from __future__ import annotations

import signal
import subprocess
import textwrap
import time
from pathlib import Path

import psutil
import pytest

from dockhil.analysis import sweep
from tests.conftest import dockhil_cmd, sigint_as_a_terminal_sends_it
from tests.test_sweep import Counting

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "launch" / "stability.yaml"
GONE_WITHIN_S = 5.0  # "a couple of seconds", with room for a machine whose both cores are busy


def gated_campaign(tmp_path: Path) -> tuple[Path, Path]:
    """A campaign whose runs 0 and 1 finish and whose runs 2 and 3 wait at a gate (a file that never
    appears here), so that the workers are mid-run when the sweep is killed."""
    gate = tmp_path / "gate"
    (tmp_path / "gated.yaml").write_text(
        textwrap.dedent(f"""
        args:
          k: {{default: 6000.0}}
          hold: {{default: false}}
          gate: {{default: ""}}
        include:
          - file: {SCENE}
            args: {{m: 20.0, delay: 0.016, b: 150.0, k: $(arg k)}}
        nodes:
          - {{name: gate, node: "tests.support.faultnodes:Gate", params: {{hold: $(arg hold), path: $(arg gate)}}}}
        """)
    )
    campaign = tmp_path / "campaign.yaml"
    campaign.write_text(
        textwrap.dedent(f"""
        scene: gated.yaml
        args: {{gate: "{gate}"}}
        duration: 0.2
        grid:
          hold: [false, true]
          k: [6000, 7000]
        """)
    )
    return campaign, gate


def signal_mid_run(command: tuple, stderr: Path, ready, sig: int, settle_s: float = 0.0):
    """Start `dockhil COMMAND` (stderr to a file: a worker left behind would hold a pipe open), wait until
    `ready()` (then `settle_s` more), send `sig` to it alone (not its process group) as a terminal sends
    SIGINT, and return (the workers it had then, the process, its stderr)."""
    with open(stderr, "w") as err:
        proc = subprocess.Popen(
            dockhil_cmd(*command),
            stdout=subprocess.DEVNULL,
            stderr=err,
            cwd=ROOT,
            preexec_fn=sigint_as_a_terminal_sends_it,
        )
    workers = []
    try:
        deadline = time.monotonic() + 120
        while not ready():
            assert proc.poll() is None and time.monotonic() < deadline, stderr.read_text()
            time.sleep(0.05)
        time.sleep(settle_s)
        workers = psutil.Process(proc.pid).children(recursive=True)
        assert workers
        proc.send_signal(sig)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return workers, proc, stderr.read_text()


def start_and_kill(tmp_path: Path, sig: int, *extra: str):
    """Start the gated sweep, wait until runs 0 and 1 are journaled and the workers hold runs, send `sig`
    to the sweep alone, and return (its workers, the process, stderr)."""
    campaign, _gate = gated_campaign(tmp_path)
    out = tmp_path / "r.parquet"
    journal = sweep.journal_path(out)
    return signal_mid_run(
        ("sweep", campaign, "--out", out, "--quiet", *extra),
        tmp_path / "stderr.txt",
        lambda: journal.exists() and journal.read_text().count("\n") >= 2,
        sig,
        settle_s=0.5,  # the workers take the held runs
    )


def assert_gone(workers) -> None:
    started = time.monotonic()
    _gone, alive = psutil.wait_procs(workers, timeout=GONE_WITHIN_S)
    for p in alive:  # leave nothing behind, whatever the verdict
        p.kill()
    assert not alive, f"{len(alive)} of {len(workers)} workers still there {time.monotonic() - started:.1f} s later"


@pytest.mark.wall_time
@pytest.mark.parametrize("sig, said", [(signal.SIGINT, "interrupted"), (signal.SIGTERM, "stopped by SIGTERM")])
def test_ctrl_c_or_sigterm_ends_the_workers_keeps_the_rows_and_the_rerun_does_only_the_rest(tmp_path, sig, said):
    import pyarrow.parquet as pq

    workers, proc, err = start_and_kill(tmp_path, sig, "--workers", "1")
    assert proc.returncode == 128 + sig, err
    assert f"{said}; the finished runs are in" in err and "rerun the same command to resume" in err, err
    assert "Traceback" not in err
    assert_gone(workers)  # the worker waiting at the gate was ended, not left to finish its batch
    out = tmp_path / "r.parquet"
    rows = pq.read_table(out).to_pylist()
    assert sorted(r["run"] for r in rows) == [0, 1] and all(r["status"] == "ok" for r in rows), rows
    (tmp_path / "gate").touch()
    rerun = Counting(sweep.LocalPool(1))
    result = sweep.sweep(sweep.load_campaign(tmp_path / "campaign.yaml"), out, rerun, progress=False)
    assert sorted(rerun.executed) == [2, 3] and result["skipped"] == 2
    assert sorted(r["run"] for r in pq.read_table(out).to_pylist()) == [0, 1, 2, 3]
    assert all(r["status"] == "ok" for r in pq.read_table(out).to_pylist())


@pytest.mark.wall_time
def test_a_sweep_killed_outright_leaves_no_worker(tmp_path):
    workers, proc, err = start_and_kill(tmp_path, signal.SIGKILL, "--workers", "2")
    assert proc.returncode == -signal.SIGKILL, err
    assert_gone(workers)  # no clean-up ran: the kernel ended them


@pytest.mark.wall_time
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_sweep_on_a_dask_local_cluster_leaves_no_worker(tmp_path, sig):
    import dask.distributed  # noqa: F401  (a dev dependency: fails, never skips)

    workers, proc, err = start_and_kill(tmp_path, sig, "--dask", "local", "--workers", "2")
    assert proc.returncode == -sig if sig == signal.SIGKILL else 128 + sig, err
    assert_gone(workers)
