"""Bags with a running graph: launch --bag, bag record, bag play, bag_source."""

from __future__ import annotations

import csv
import json
import os
import resource
import subprocess
import time
from pathlib import Path

import pytest

from dockhil import cli
from dockhil.bags.reader import BagReader
from dockhil.bags.tools import info
from dockhil.bags.writer import BagWriter
from dockhil.errors import DockhilError
from dockhil.msgs import Header, Vector3, Wrench, WrenchStamped, type_name
from dockhil.msgs.codec import encode
from tests.conftest import Lines, dockhil_cmd, kill_child_and_expect_the_graph_to_stop, registered
from tests.support.bagfiles import assert_messages_meet_their_channel_schemas
from tests.support.inprocess import completed, run_main

# A driven loop: /drive (a seeded noisy source, silent at every 5th tick) feeds
# the plant at the same tick; plant and gain close a loop through /x and /u.
# With drive:=bag, /drive comes from a bag instead of from its source node.
SCENE = """
rate: 1000
duration: 0.3
args:
  drive: {default: sim, choices: [sim, bag]}
  bag: {default: "", help: "bag to take /drive from with drive:=bag"}
  seed: {default: 7, help: "noise seed of the simulated drive"}
nodes:
  - {name: drive, node: "tests.support.bagnodes:Drive", params: {seed: $(arg seed), quiet_every: 5}, if: $(arg drive) == sim}
  - {name: drive, node: bag_source, params: {path: $(arg bag), topics: [/drive]}, if: $(arg drive) == bag}
  - {name: plant, node: "tests.support.bagnodes:Plant"}
  - {name: gain, node: "tests.support.graphnodes:Gain"}
"""
TICKS = 301  # 0..300 at 1 kHz for 0.3 s
NO_AGE_LIMIT = ("--max-age", "plant.u=inf", "--max-age", "plant.d=inf", "--max-age", "gain.x=inf")


def launch(scene, *args, timeout=60, **kw):
    return subprocess.run(dockhil_cmd("launch", scene, *args), capture_output=True, text=True, timeout=timeout, **kw)


def launch_here(scene, *args):
    """A composed launch through dockhil.cli.main in this process (no interpreter start-up),
    returned as subprocess.run's result is."""
    return completed("launch", scene, *args)


def by_topic(path) -> dict[str, list[tuple[int, bytes]]]:
    """topic -> [(log time ns, wire bytes)] in file order."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    with BagReader(path) as reader:
        for m in reader:
            out.setdefault(m.topic, []).append((m.log_time_ns, m.data))
    return out


def assert_ok(r):
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stdout + r.stderr


def one_line(text: str) -> str:
    assert text.endswith("\n") and text.count("\n") == 1, text
    assert "Traceback" not in text
    return text


def play_and_record(bag, out, *play_args, timing: dict | None = None):
    """`bag play BAG ...` with `bag record OUT` joined to it; both must end by themselves; their stderr.
    timing: gets "recording" (the recorder says it records: play may start) and "ended" (play exited)."""
    play = subprocess.Popen(
        dockhil_cmd("bag", "play", bag, *play_args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    rec = None
    try:
        registered(play.pid)
        rec = subprocess.Popen(
            dockhil_cmd("bag", "record", out), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        rec_lines = Lines(rec, rec.stderr)
        rec_lines.wait_for("recording ", timeout=30)
        recording = time.monotonic()
        _, play_err = play.communicate(timeout=30)
        ended = time.monotonic()
        rec_err = rec_lines.rest(timeout=30)
    finally:
        for proc in (play, rec):
            if proc is not None and proc.poll() is None:
                proc.kill()
    if timing is not None:
        timing.update(recording=recording, ended=ended)
    assert play.returncode == 0, play_err
    assert rec.returncode == 0 and "Traceback" not in rec_err, rec_err
    return play_err, rec_err


# --------------------------------------------------------------------------- round trip


def test_launch_bag_round_trip_record_info_export_play(write_launch, tmp_path, capsys):
    scene = write_launch(SCENE)
    multi, composed = tmp_path / "multi.mcap", tmp_path / "composed.mcap"
    r = launch(scene, "--bag", multi)
    assert_ok(r)
    assert f"[bag-recorder] recorded 843 messages on 3 topics to {multi}; 0 lost" in r.stderr
    r = launch_here(scene, "--composed", "--bag", composed)
    assert_ok(r)
    assert f"[bag-recorder] recorded 843 messages on 3 topics to {composed}; 0 lost" in r.stderr

    # One graph, two ways of running it: the same bytes at the same (sim) log times.
    a, b = by_topic(multi), by_topic(composed)
    assert a == b
    # Recorded as json that viewers read: every message meets its channel's schema.
    assert (
        assert_messages_meet_their_channel_schemas(multi) == assert_messages_meet_their_channel_schemas(composed) == 843
    )
    assert {t: len(v) for t, v in a.items()} == {"/x": TICKS, "/u": TICKS, "/drive": TICKS - TICKS // 5}
    assert [ns for ns, _ in a["/x"]] == [k * 1_000_000 for k in range(TICKS)]  # sim times, not wall times
    assert [ns for ns, _ in a["/drive"]] == [k * 1_000_000 for k in range(TICKS) if k % 5 != 4]

    code = cli.main(["bag", "info", str(multi), "--json"])
    found = json.loads(capsys.readouterr().out)
    assert code == 0 and found["recovered"] is False and found["duration_s"] == pytest.approx(0.3)
    assert {t["topic"]: (t["type"], t["count"]) for t in found["topics"]} == {
        "/x": ("dockhil/WrenchStamped", TICKS),
        "/u": ("dockhil/WrenchStamped", TICKS),
        "/drive": ("dockhil/WrenchStamped", 241),
    }

    out_csv = tmp_path / "x.csv"
    assert cli.main(["bag", "export", str(multi), "--topic", "/x", "--csv", str(out_csv)]) == 0
    with open(out_csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(row["header.tick"]) for row in rows] == list(range(TICKS))
    with BagReader(multi) as reader:
        xs = [m.decode().wrench.force.x for m in reader.messages(["/x"])]
    assert [float(row["wrench.force.x"]) for row in rows] == xs

    # Play in sim time to a recorder joined to the player: the same bag again.
    replayed = tmp_path / "replayed.mcap"
    play_err, rec_err = play_and_record(multi, replayed, "--sim-time")
    assert "played 843 messages on 3 topics in tick order" in play_err
    assert "0 lost" in rec_err
    assert by_topic(replayed) == a

    # From 0.1 s on: the played run starts again at tick 0, with the recorded values of tick 100 on.
    later = tmp_path / "later.mcap"
    play_and_record(multi, later, "--sim-time", "--start", "0.1", "--topics", "/x")
    with BagReader(later) as reader:
        got = [msg for _, _, msg in reader.decoded()]
    assert [m.header.tick for m in got] == list(range(TICKS - 100))
    assert [m.header.stamp for m in got] == pytest.approx([k * 1e-3 for k in range(TICKS - 100)])
    assert [m.wrench.force.x for m in got] == xs[100:]


# --------------------------------------------------------------------------- replay as a source


def test_replay_as_source_reproduces_the_recorded_run(write_launch, tmp_path):
    scene = write_launch(SCENE)
    recorded = tmp_path / "recorded.mcap"
    # Recorded composed: its bag has the multi-process run's bytes (the round trip above holds that).
    assert_ok(launch_here(scene, "--composed", "--bag", recorded))
    want = by_topic(recorded)

    # /drive from the bag instead of its source node: every topic, bit for bit, multi-process and composed.
    for mode in ([], ["--composed"]):
        out = tmp_path / f"replay{len(mode)}.mcap"
        r = (launch_here if mode else launch)(scene, "drive:=bag", f"bag:={recorded}", "--bag", out, *mode)
        assert_ok(r)
        assert by_topic(out) == want, mode

    # The bag is what drives the replay: another seed gives another run.
    other = tmp_path / "other.mcap"
    assert_ok(launch_here(scene, "seed:=8", "--composed", "--bag", other))
    assert by_topic(other)["/x"] != want["/x"]

    # A run longer than the bag stops at the first tick the bag does not hold, in one line.
    r = launch_here(scene, "drive:=bag", f"bag:={recorded}", "--duration", "0.5", "--composed")
    assert r.returncode != 0
    assert "has no tick 301: it ends at tick 300" in r.stderr and "Traceback" not in r.stderr
    code, out, err = run_main("launch", scene, "drive:=bag", f"bag:={tmp_path / 'missing.mcap'}")
    assert code == 2 and "missing.mcap: no such file" in one_line(err) and out == ""


def test_bag_source_steps_by_tick_or_by_time(tmp_path):
    from dockhil.node import NodeContext, Tick
    from dockhil.nodes.bag_source import BagSource

    bag = tmp_path / "100hz.mcap"
    write_wrench_bag(bag, 1.0, 100.0)  # ticks 0..100, force.x = 0.5 k, log times 10 ms apart
    _, outs = BagSource.ports({"path": str(bag), "topics": [], "start": 0.0})
    assert list(outs) == ["/ft/wrench"] and outs["/ft/wrench"].type is WrenchStamped

    def source(sim, **params):
        node = BagSource(NodeContext("ft", 0.01, sim_time=sim, log=lambda m: None), path=str(bag), **params)
        node.setup()
        return node

    def x(out):
        return out["/ft/wrench"].wrench.force.x

    # Sim time, 0.5 s in: tick k replays recorded tick k + 50, renumbered to k.
    node = source(True, start=0.5)
    for k in range(51):
        msg = node.step(Tick(k, k * 0.01, 0.01), {})["/ft/wrench"]
        assert (msg.header.tick, msg.wrench.force.x) == (k, 0.5 * (k + 50))
    with pytest.raises(DockhilError, match="has no tick 101: it ends at tick 100"):
        node.step(Tick(51, 0.51, 0.01), {})
    node.close()

    # Wall time: the newest message whose time has come; nothing new, nothing sent.
    node = source(False)
    assert x(node.step(Tick(0, 0.0, 0.01), {})) == 0.0
    assert node.step(Tick(1, 0.005, 0.01), {}) == {}
    assert x(node.step(Tick(2, 0.0149, 0.01), {})) == 0.5
    assert x(node.step(Tick(3, 0.0501, 0.01), {})) == 2.5  # 0.02..0.04 s are passed over
    assert x(node.step(Tick(4, 5.0, 0.01), {})) == 50.0  # past the end: the last message, once
    assert node.step(Tick(5, 5.01, 0.01), {}) == {}
    node.close()


# --------------------------------------------------------------------------- failures


def test_recorder_killed_mid_run_leaves_a_readable_bag(write_launch, tmp_path):
    scene = write_launch(SCENE)
    path = tmp_path / "killed.mcap"
    p = subprocess.Popen(
        # no input ages out on a busy machine: the graph runs until the recorder is killed
        dockhil_cmd("launch", scene, "--wall-time", "--duration", "20", "--bag", path, *NO_AGE_LIMIT),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.time() + 15
    registered(p.pid)
    while time.time() < deadline and (not path.exists() or path.stat().st_size < 30_000):
        time.sleep(0.05)  # a few chunks on disk
    kill_child_and_expect_the_graph_to_stop(p, "bag-recorder")

    found = info(path)
    assert found["recovered"] is True
    counts = {t["topic"]: t["count"] for t in found["topics"]}
    assert counts["/x"] > 100 and counts["/u"] > 100
    out_csv = tmp_path / "x.csv"
    assert cli.main(["bag", "export", str(path), "--topic", "/x", "--csv", str(out_csv)]) == 0
    with open(out_csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == counts["/x"]
    seqs = [int(row["header.seq"]) for row in rows]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # nothing missing before the cut


def test_unwritable_bag_fails_the_launch_in_one_line_before_any_node_runs(write_launch, tmp_path):
    scene = write_launch(SCENE)
    existing = tmp_path / "existing.mcap"
    existing.write_bytes(b"keep me")
    for bag, words in [
        (tmp_path / "no" / "run.mcap", "No such file or directory"),
        (existing, "already exists"),
        (tmp_path, "directory"),
    ]:
        for mode in ([], ["--composed"]):
            # In this process: a refusal needs no interpreter of its own (a node it started would
            # still print here, through the launcher's log).
            code, out, err = run_main("launch", scene, "--bag", bag, *mode)
            assert code == 2, (bag, mode, out + err)
            line = one_line(err)
            assert line.startswith("dockhil launch: error: ") and str(bag) in line and words in line
            assert out == ""  # no node started
    assert existing.read_bytes() == b"keep me"

    # `bag record` of a running graph: the same, one line.
    code, _, err = run_main("bag", "record", tmp_path / "x.mcap")
    assert code == 2 and "no running graph found" in one_line(err)
    graphs = Path(os.environ["DOCKHIL_RUNTIME_DIR"]) / "graphs"
    graphs.mkdir(exist_ok=True)
    (graphs / "fake.json").write_text(
        json.dumps(
            {
                "run_id": "fake",
                "pid": os.getpid(),
                "file": "test",
                "clock": "wall",
                "nodes": {},
                "topics": {"/x": {"type": "dockhil/WrenchStamped", "endpoint": "tcp://127.0.0.1:9", "publisher": "t"}},
            }
        )
    )
    try:
        code, _, err = run_main("bag", "record", tmp_path / "no" / "x.mcap")
        assert code == 2 and "No such file or directory" in one_line(err)
        code, _, err = run_main("bag", "record", tmp_path / "x.mcap", "--topics", "/nope")
        assert code == 2 and "topic /nope is not published by any running graph; topics: /x" in one_line(err)
    finally:
        (graphs / "fake.json").unlink()


def _small_file_limit():
    # The disk "fills up" at 20 kB for this process and its children (Python ignores SIGXFSZ: writes fail).
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))


@pytest.mark.parametrize("mode", ["multi", "composed"])
def test_full_disk_stops_recording_in_one_line_and_fails_the_run_with_the_count(write_launch, tmp_path, mode):
    scene = write_launch(SCENE)
    path = tmp_path / "full.mcap"
    r = launch(
        scene,
        "--duration",
        "1",
        "--bag",
        path,
        *(["--composed"] if mode == "composed" else []),
        preexec_fn=_small_file_limit,
    )
    text = r.stdout + r.stderr
    assert r.returncode != 0 and "Traceback" not in text, text  # lost messages: the run is not valid
    stopped = [line for line in text.splitlines() if "recording stopped" in line and "error" in line]
    assert len(stopped) == 1 and "File too large (EFBIG)" in stopped[0] and "the graph keeps running" in stopped[0]
    found = info(path)
    assert found["recovered"] is True and 0 < found["messages"] < 3 * 1001
    report = next(line for line in text.splitlines() if "[bag-recorder] recorded" in line)
    lost = 1001 + 1001 + 801 - found["messages"]
    assert f"recorded {found['messages']} messages" in report and f"{lost} lost" in report
    failed = [
        line for line in text.splitlines() if f"{lost} message(s) lost" in line or f"lost {lost} message(s)" in line
    ]
    assert len(failed) == 1 and "error" in failed[0], text


# --------------------------------------------------------------------------- play


def write_wrench_bag(path, seconds: float, rate_hz: float) -> list[bytes]:
    n = int(seconds * rate_hz) + 1
    data = []
    with BagWriter(path) as bag:
        bag.add_topic("/ft/wrench", type_name(WrenchStamped))
        for k in range(n):
            ns = 1_700_000_000_000_000_000 + int(k * 1e9 / rate_hz)
            msg = encode(
                WrenchStamped(header=Header(stamp=k / rate_hz, tick=k, seq=k), wrench=Wrench(force=Vector3(x=0.5 * k)))
            )
            bag.write("/ft/wrench", ns, ns, msg)
            data.append(msg)
    return data


@pytest.mark.wall_time  # playback paced on the real clock, timed on it (two interpreter start-ups included)
def test_play_rate_scales_the_recorded_timing(tmp_path):
    bag, out = tmp_path / "3s.mcap", tmp_path / "played.mcap"
    sent = write_wrench_bag(bag, 3.0, 100.0)
    timing = {}
    play_err, _ = play_and_record(bag, out, "--rate", "10", "--subscribers", "1", timing=timing)
    # Well under the bag's own 3 s: from the recorder taking messages (play waits for it) to play's exit,
    # the two interpreters' start-ups left out.
    assert timing["ended"] - timing["recording"] < 3.0
    # 0.3 s at --rate 10; the 3 s of --rate 1 stays far above the bound a busy machine may need.
    played_s = float(play_err.split(" in ")[-1].split(" s")[0])
    assert 0.29 <= played_s < 1.5, play_err
    got = by_topic(out)["/ft/wrench"]
    assert [d for _, d in got] == sent
    span = (got[-1][0] - got[0][0]) / 1e9  # receive times in the new bag
    assert 0.25 < span < 1.5


def test_play_refuses_bad_files_and_topics_in_one_line(tmp_path, capsys):
    bag = tmp_path / "ok.mcap"
    write_wrench_bag(bag, 0.1, 100.0)
    text = tmp_path / "text.mcap"
    text.write_text("time,force\n")
    for args, words in [
        ([text], "not an MCAP bag"),
        ([tmp_path / "none.mcap"], "no such file"),
        ([bag, "--topics", "/nope"], "no messages on /nope; topics in the bag: /ft/wrench"),
        ([bag, "--start", "5"], "no message after --start 5 s"),
    ]:
        code = cli.main(["bag", "play", *map(str, args)])
        err = capsys.readouterr().err
        assert code == 2 and words in one_line(err), err
