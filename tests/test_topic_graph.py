"""topic echo / hz with two graphs running: --graph picks one, none chosen is refused in one line,
and each says in one line when its own graph ends."""

import json
import signal
import subprocess
from types import SimpleNamespace

import pytest

from dockhil import cli
from tests.conftest import Lines, dockhil_cmd, registered

pytestmark = pytest.mark.wall_time


def launch(m1: float, log):
    # Wall time at a gentle 100 Hz, longer than the test: the graph runs until the test stops it.
    return subprocess.Popen(
        dockhil_cmd("launch", "launch/ideal.yaml", "--wall-time", "--duration", "300", "rate:=100", f"m1:={m1}"),
        stdout=log,
        stderr=subprocess.STDOUT,
    )


def dockhil(capsys, *args):
    """A short `dockhil` command, run in this process (no interpreter start-up): exit code and output."""
    capsys.readouterr()
    code = cli.main(list(args))
    out = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)


def chaser_mass(line: str) -> float:
    return json.loads(line)["bodies"][0]["mass"]


def stop(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def test_graph_is_chosen_refused_when_ambiguous_and_its_end_is_said(tmp_path, capsys):
    logs = [open(tmp_path / name, "w") for name in ("a.log", "b.log")]
    a, b = launch(700.0, logs[0]), launch(750.0, logs[1])
    watchers = []
    try:
        ida, idb = registered(a.pid, timeout=30)["run_id"], registered(b.pid, timeout=30)["run_id"]

        for action in ("echo", "hz"):  # none chosen: one line naming both graphs, nothing read
            r = dockhil(capsys, "topic", action, "/satellite/state", "-n", "1")
            lines = r.stderr.strip().splitlines()
            assert r.returncode == 2 and len(lines) == 1 and r.stdout == "", r.stderr
            assert ida in lines[0] and idb in lines[0] and "--graph ID" in lines[0]

        # Each graph's messages, and only its: the chasers differ in mass.
        for run_id, mass in ((ida, 700.0), (idb, 750.0)):
            r = dockhil(capsys, "topic", "echo", "/satellite/state", "-n", "2", "--graph", run_id)
            rows = r.stdout.splitlines()
            assert r.returncode == 0 and len(rows) == 2, r.stderr
            assert [chaser_mass(x) for x in rows] == [mass, mass]

        listed = dockhil(capsys, "topic", "list", "--graph", ida).stdout.splitlines()
        assert listed and all(line.endswith(f"({ida})") for line in listed)
        nodes = dockhil(capsys, "node", "list", "--graph", idb).stdout
        assert nodes.startswith(idb) and ida not in nodes and "dynamics  satellite_dynamics" in nodes

        r = dockhil(capsys, "topic", "echo", "/satellite/state", "--graph", "no-such-run")
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
        assert "--graph no-such-run: no such running graph" in r.stderr and ida in r.stderr and idb in r.stderr
        r = dockhil(capsys, "topic", "hz", "/nope", "--graph", ida)
        assert r.returncode == 2 and f"topic /nope is not published by graph {ida}" in r.stderr

        # Echo on A and hz on B, without a count: each ends, exit 0, when its own graph ends.
        echo = subprocess.Popen(
            dockhil_cmd("topic", "echo", "/satellite/state", "--graph", ida),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        hz = subprocess.Popen(
            dockhil_cmd("topic", "hz", "/satellite/state", "--graph", idb, "--every", "0.5"),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        watchers = [echo, hz]
        echoed, rates = Lines(echo), Lines(hz)
        assert chaser_mass(echoed.wait_for("{", timeout=30).splitlines()[0]) == 700.0
        rates.wait_for("average rate: ", timeout=30)

        stop(a)
        echoed.rest(timeout=30)
        err = echo.stderr.read()
        assert echo.returncode == 0 and err.strip().splitlines()[-1] == f"[topic] graph {ida} ended", err
        # B runs on, so does its watcher: three more reports of 0.5 s after A ended, while it looks
        # at the registry every ALIVE_CHECK_S (0.5 s).
        rates.wait_for("average rate: ", count=sum("average rate: " in line for line in rates.lines) + 3, timeout=30)
        assert hz.poll() is None

        stop(b)
        rates.rest(timeout=30)
        err = hz.stderr.read()
        assert hz.returncode == 0 and err.strip().splitlines()[-1] == f"[topic] graph {idb} ended", err
    finally:
        for p in watchers + [a, b]:
            stop(p)
        for f in logs:
            f.close()
