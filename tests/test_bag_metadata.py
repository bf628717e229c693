"""A bag knows its run: the scene's launch files, the resolved arguments, the version, the clock, the rate
and the start time first, the run's verdict last (dockhil.bags.runinfo), in every way a bag is recorded;
a recorder killed mid-run leaves a bag that says the run did not finish; `bag info` shows it all, and
bags without it (older ones) still read."""

from __future__ import annotations

import datetime
import json
import os
import signal
import subprocess
import time

import pytest

from dockhil.bags import runinfo
from dockhil.bags.reader import BagReader
from dockhil.bags.writer import BagWriter
from dockhil.scene.launchfile import SHIPPED_SCENES, load
from tests.conftest import dockhil_cmd, registered
from tests.support.inprocess import launch_here_or_process, run_main


def records(path) -> dict[str, dict]:
    with BagReader(path) as reader:
        found = reader.metadata()
    assert [name for name, _ in found] == [runinfo.RUN, runinfo.SCENE, runinfo.VERDICT]
    return dict(found)


def messages(path):
    with BagReader(path) as bag:
        return sorted((m.topic, m.log_time_ns, m.data) for m in bag)


@pytest.mark.parametrize("mode", [["--composed"], []], ids=["composed", "processes"])
def test_a_launch_bag_records_its_scene_arguments_start_and_verdict(tmp_path, mode):
    bag = tmp_path / "run.mcap"
    before = time.time_ns()
    r = launch_here_or_process("hil.yaml", "delay:=0.016", "--duration", "0.3", "--bag", bag, "--quiet", *mode)
    assert r.returncode == 0, r.stderr
    found = records(bag)
    run = found[runinfo.RUN]
    assert run["scene"] == str(SHIPPED_SCENES / "hil.yaml")
    assert run["recorded_by"] == ("launch --composed" if mode else "launch")
    assert (run["clock"], float(run["rate_hz"]), float(run["duration_s"])) == ("sim", 1000.0, 0.3)
    assert run["dockhil_version"] == __import__("dockhil").__version__
    scene = load("hil.yaml", {"delay": "0.016"})
    assert json.loads(run["args"]) == {name: scene.values[name] for name in scene.args}
    assert json.loads(run["args_set"]) == {"delay": 0.016}
    start_ns = int(run["start_ns"])
    assert before <= start_ns <= time.time_ns()
    stamp = datetime.datetime.strptime(run["start"][:26], "%Y-%m-%dT%H:%M:%S.%f").replace(tzinfo=datetime.UTC)
    epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.UTC)
    # Integer microseconds: a float of about 1.8e9 s holds them only to a quarter of one.
    assert (stamp - epoch) // datetime.timedelta(microseconds=1) == start_ns // 1000 and run["start"].endswith("Z")
    # The launch files read, as they were read (hil.yaml's include of emulators.yaml is off by its condition).
    assert found[runinfo.SCENE] == {str(SHIPPED_SCENES / "hil.yaml"): (SHIPPED_SCENES / "hil.yaml").read_text()}
    verdict = found[runinfo.VERDICT]
    assert (verdict["verdict"], verdict["valid"], verdict["exit_code"], verdict["recorder_lost"]) == (
        "valid",
        "true",
        "0",
        "0",
    )

    code, out, _ = run_main("bag", "info", bag)
    assert code == 0
    assert "run:       hil.yaml (sim time, 1000 Hz, 0.3 s), dockhil" in out
    assert "args:      delay:=0.016" in out and "validity:  valid (exit 0)" in out
    assert f"started:   {run['start']}" in out
    code, out, _ = run_main("bag", "info", bag, "--json")
    info = json.loads(out)["run"]
    assert (info["verdict"], info["valid"], info["exit_code"], info["args_set"]) == ("valid", True, 0, {"delay": 0.016})


def test_the_same_run_recorded_twice_differs_only_in_its_start_time(tmp_path):
    """Sim time: the messages are the same, and so is every metadata field but the start (whose bytes
    keep their width: the records keep their length and place)."""
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    for bag in (a, b):
        r = launch_here_or_process("hil.yaml", "--duration", "0.3", "--bag", bag, "--quiet", "--composed")
        assert r.returncode == 0, r.stderr
    assert messages(a) == messages(b)
    ra, rb = records(a), records(b)
    assert ra[runinfo.RUN]["start_ns"] != rb[runinfo.RUN]["start_ns"]
    for name in ra:
        differ = {k for k in ra[name] if ra[name][k] != rb[name][k]}
        assert differ == ({"start", "start_ns"} if name == runinfo.RUN else set())
        assert all(len(ra[name][k]) == len(rb[name][k]) for k in ra[name])


def test_an_invalid_run_records_its_reasons(tmp_path):
    bag, summary = tmp_path / "run.mcap", tmp_path / "s.json"
    r = launch_here_or_process(
        "hil.yaml",
        "compensation:=passivity",
        "max_damping:=1",
        "--bag",
        bag,
        "--summary",
        summary,
        "--quiet",
        "--composed",
    )
    assert r.returncode == 3, r.stderr
    verdict = records(bag)[runinfo.VERDICT]
    reasons = json.loads(summary.read_text())["invalid_reasons"]
    assert reasons and "saturated" in reasons[0]
    assert (verdict["verdict"], verdict["valid"], verdict["exit_code"]) == ("INVALID", "false", "3")
    assert json.loads(verdict["invalid_reasons"]) == reasons
    code, out, _ = run_main("bag", "info", bag)
    assert code == 0 and f"validity:  INVALID: {reasons[0]}" in out


def test_a_recorder_killed_mid_run_leaves_a_bag_that_says_the_run_did_not_finish(tmp_path):
    bag = tmp_path / "run.mcap"
    proc = subprocess.Popen(
        dockhil_cmd("launch", "hil.yaml", "--duration", "60", "--bag", bag, "--quiet"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        recorder = registered(proc.pid, timeout=60)["nodes"]["bag-recorder"]["pid"]
        deadline = time.monotonic() + 60
        while (not bag.exists() or bag.stat().st_size < 200_000) and time.monotonic() < deadline:  # a few chunks
            time.sleep(0.05)
        os.kill(recorder, signal.SIGKILL)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1 and "'bag-recorder' was killed by SIGKILL" in err, err
    with BagReader(bag) as reader:
        info = runinfo.read(reader)
    assert info.runs and info.texts and info.verdict is None, (bag.stat().st_size, err)
    assert info.state == "did not finish" and info.valid is False
    code, out, _ = run_main("bag", "info", bag)
    assert code == 0 and "validity:  did not finish: the recorder stopped before the run ended" in out
    code, out, _ = run_main("bag", "info", bag, "--json")
    assert json.loads(out)["run"]["verdict"] == "did not finish"


def test_a_bag_without_run_records_still_reads_and_says_so(tmp_path):
    bag = tmp_path / "old.mcap"
    with BagWriter(bag) as w:
        w.add_topic("/ft/wrench", "dockhil/WrenchStamped")
    info = runinfo.read_path(str(bag))
    assert not info.recorded and info.state == "not recorded" and info.valid is None
    code, out, _ = run_main("bag", "info", bag)
    assert code == 0 and "run:       not recorded (a bag of an older dockhil" in out
    code, out, _ = run_main("bag", "info", bag, "--json")
    assert json.loads(out)["run"] is None


def test_metadata_is_read_past_a_damaged_chunk(tmp_path):
    bag = tmp_path / "run.mcap"
    r = launch_here_or_process("hil.yaml", "--duration", "1", "--bag", bag, "--quiet", "--composed")
    assert r.returncode == 0, r.stderr
    data = bytearray(bag.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4000] = bytes(4000)
    bag.write_bytes(bytes(data))
    found = records(bag)
    assert found[runinfo.VERDICT]["verdict"] == "valid"


def test_an_outside_recorder_writes_what_the_graph_registered_and_that_its_verdict_is_not_known(tmp_path):
    from dockhil.bags.live import registered_run
    from dockhil.runtime.registry import registry_dir
    from dockhil.scene.provenance import run_fields, scene_texts

    scene = load("hil.yaml")
    run = run_fields(scene, clock="sim", duration=3.0, started_ns=1, recorded_by="launch")
    (registry_dir() / "r1.json").write_text(
        json.dumps({"run_id": "r1", "clock": "sim", "run": run, "scene_files": scene_texts(scene)})
    )
    (registry_dir() / "r2.json").write_text(json.dumps({"run_id": "r2", "clock": "wall", "file": "play x.mcap"}))
    got, texts = registered_run("r1", "bag record")
    assert got["recorded_by"] == "bag record" and got["start"] == run["start"] and got["joined"].endswith("Z")
    assert texts == scene.texts
    got, texts = registered_run("r2", "bag record")
    assert got["scene"] == "" and got["scene_known"].startswith("false") and texts == {}

    bag = tmp_path / "outside.mcap"
    with BagWriter(bag) as w:
        runinfo.write_start(w, got, texts)
        w.add_metadata(runinfo.VERDICT, runinfo.with_loss(runinfo.not_told("recorded from outside"), 0))
    info = runinfo.read_path(str(bag))
    assert info.state == "not known" and info.valid is None and info.why == "recorded from outside"
    code, out, _ = run_main("bag", "info", bag)
    assert "validity:  not known: recorded from outside" in out and "args:      not known" in out


@pytest.mark.wall_time
def test_a_wall_time_run_records_the_verdict_its_launch_exits_with(tmp_path):
    """Wall time: the launch stops the recorder at the duration, and it closes the bag once told the
    verdict, which is the launch's (valid, or INVALID on a machine too busy to keep up)."""
    bag = tmp_path / "wall.mcap"
    r = subprocess.run(
        dockhil_cmd("launch", "ideal.yaml", "--wall-time", "--duration", "1", "--bag", bag, "--quiet"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode in (0, 3), r.stderr
    found = records(bag)
    assert found[runinfo.RUN]["clock"] == "wall"
    verdict = found[runinfo.VERDICT]
    assert verdict["exit_code"] == str(r.returncode)
    assert verdict["verdict"] == ("valid" if r.returncode == 0 else "INVALID")
