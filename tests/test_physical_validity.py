"""No exploding or meaningless run is called valid.

A loop that explodes (hil.yaml with a 0.4 s delay behind a 20 kN/m compliance grows at +4.2 1/s)
runs, but is INVALID (exit 3) in every mode, and its summary's peak force is the run's largest; a
value outside the range of docking hardware (dockhil/physical.py) is refused in one line before
anything runs; an include of a file that is not a launch file never shows what the file holds; a
summary that cannot be written is refused before the run."""

from __future__ import annotations

import errno
import json
import subprocess
import sys

import pytest

from dockhil.bags.reader import BagReader
from tests.conftest import ROOT, dockhil_cmd
from tests.support.inprocess import run_main

EXPLODING = ("delay:=0.4", "k:=20000")  # the delayed loop's root: +4.176 1/s
SHORT = ("--duration", "1.5")  # 1500 ticks: the force is 700 times the ideal peak


def largest_force_in_bag(path) -> float:
    """The largest |force on the chaser| of a recorded 1-DOF run: measured plus virtual, tick by tick,
    read from the bag (not through the summary)."""
    measured, virtual = {}, {}
    with BagReader(str(path)) as bag:
        for topic, _t, msg in bag.decoded(["/ft/wrench", "/impedance/wrench"]):
            if topic == "/ft/wrench":
                measured[msg.header.tick] = msg.wrench.force.x
            else:
                virtual[msg.header.tick] = msg.wrenches[0].force.x
    return max(abs(measured.get(t, 0.0) + virtual.get(t, 0.0)) for t in set(measured) | set(virtual))


def test_an_exploding_loop_is_invalid_and_its_peak_force_is_the_runs_largest(tmp_path):
    path, bag = tmp_path / "s.json", tmp_path / "run.mcap"
    code, out, err = run_main(
        "launch", "launch/hil.yaml", *EXPLODING, "--composed", *SHORT, "--bag", bag, "--summary", path
    )
    assert code == 3, err
    s = json.loads(path.read_text())
    assert s["valid"] is False
    assert any(
        r.startswith("the force reached") and "times the ideal contact's peak" in r for r in s["invalid_reasons"]
    ), s["invalid_reasons"]
    assert any("kinetic energy" in r for r in s["invalid_reasons"])
    true_peak = largest_force_in_bag(bag)
    assert true_peak > 100 * s["ideal"]["peak_force_N"]
    assert s["peak_force_N"] == true_peak  # not the first contact's 1.2 N
    assert f"{true_peak:.4g} N" in out  # the table says it too
    assert err.strip().splitlines()[-1].startswith("[launch] INVALID: the force reached")
    # The same scene with the paper's delay and compliance is valid.
    code, _, err = run_main("launch", "launch/hil.yaml", "--composed", *SHORT, "--quiet")
    assert code == 0, err


def test_an_exploding_loop_is_invalid_quiet_and_as_processes():
    # --quiet prints no summary, and the node processes' run is summarised from its bag: still judged.
    r = subprocess.run(
        dockhil_cmd("launch", "launch/hil.yaml", *EXPLODING, *SHORT, "--quiet"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 3, r.stderr
    assert "INVALID: the force reached" in r.stderr.strip().splitlines()[-1]


def test_an_exploding_6dof_loop_is_invalid(tmp_path):
    path = tmp_path / "s.json"
    code, _, err = run_main(
        "launch", "launch/hil6.yaml", *EXPLODING, "--composed", *SHORT, "--quiet", "--summary", path
    )
    assert code == 3, err
    s = json.loads(path.read_text())
    assert s["dof"] == 6 and s["valid"] is False
    assert any("times the ideal contact's peak" in r for r in s["invalid_reasons"]), s["invalid_reasons"]
    assert s["peak_force_N"] > 100 * s["ideal"]["peak_force_N"]


def test_a_loop_that_made_energy_but_not_yet_force_is_invalid(tmp_path):
    # After 1 s the 6-DOF loop's force is still within 100 times the ideal peak, its energy is not.
    path = tmp_path / "s.json"
    code, _, err = run_main(
        "launch", "launch/hil6.yaml", *EXPLODING, "--composed", "--duration", "1", "--quiet", "--summary", path
    )
    assert code == 3, err
    reasons = json.loads(path.read_text())["invalid_reasons"]
    assert len(reasons) == 1 and reasons[0].startswith("the bodies' kinetic energy reached"), reasons


# -- meaningless input: one line, exit 2, before anything runs ----------------------------------------

MEANINGLESS = [
    # The virtual impedance is told lag and ft_noise too (its compensation), and is checked first.
    ("launch/hil.yaml", "lag:=1e9", "node 'impedance' parameter 'lag': 1e+09 s is longer than 1 s"),
    (
        "launch/hil.yaml",
        "ft_noise:=1e12",
        "node 'impedance' parameter 'ft_noise': 1000000000000.0 N is outside 0 to 1e+06 N",
    ),
    ("launch/hil.yaml", "ft_noise:=1e300", "node 'impedance' parameter 'ft_noise': 1e+300 N is outside"),
    ("launch/hil.yaml", "k:=1e13", "node 'impedance' parameter 'k': 10000000000000.0 N/m is outside 0 to 1e+12"),
    ("launch/hil.yaml", "kcs:=1e13", "parameter 'kcs': 10000000000000.0 N/m is outside"),
    ("launch/hil.yaml", "v1:=6", "node 'dynamics' parameter 'v1': 6.0 m/s is outside 0 to 5 m/s"),
    ("launch/hil6.yaml", "v1:=1e4", "node 'dynamics' parameter 'v1'[0]: 10000.0 m/s is outside 0 to 5 m/s"),
    ("launch/hil6.yaml", "v1:=1001", "parameter 'v1'[0]: 1001.0 m/s is outside"),
    ("launch/hil6.yaml", "v1:=2000", "parameter 'v1'[0]: 2000.0 m/s is outside"),
    ("launch/hil6.yaml", "m2:=1e15", "parameter 'm2': 1000000000000000.0 kg is outside 0.01 to 1e+08 kg"),
    ("launch/hil6.yaml", "m2:=2e12", "parameter 'm2': 2000000000000.0 kg is outside"),
    ("launch/hil6.yaml", "spin:=1e4", "parameter 'w1'[0]: 10000.0 rad/s is outside 0 to 10 rad/s"),
    ("launch/hil6.yaml", "spin:=1e6", "parameter 'w1'[0]: 1000000.0 rad/s is outside"),
    ("launch/hil6.yaml", "tilt:=1e9", "parameter 'attitude1'[2]: 1000000000.0 rad is outside 0 to 6.28319 rad"),
    ("launch/hil6.yaml", "tilt:=100", "parameter 'attitude1'[2]: 100.0 rad is outside"),
    ("launch/hil6.yaml", "k:=1e13", "parameter 'passive_stiffness'[0]: 10000000000000.0 N/m, N m/rad is outside"),
    # As hil.yaml's: the 6-DOF virtual impedance is told lag too (its compensation), and is checked first.
    ("launch/hil6.yaml", "lag:=1e9", "node 'impedance' parameter 'lag': 1e+09 s is longer than 1 s"),
]


def assert_refused(code, out, err, expected):
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and expected in err, err
    assert "Traceback" not in err and "internal error" not in err and "simulated" not in out + err


@pytest.mark.parametrize("scene, override, expected", MEANINGLESS, ids=[f"{s[7:]} {o}" for s, o, _ in MEANINGLESS])
def test_a_meaningless_argument_is_refused_in_one_line(scene, override, expected):
    code, out, err = run_main("launch", scene, override, "--composed", "--duration", "0.01", "--quiet")
    assert_refused(code, out, err, expected)


def hil6_with(param: str) -> str:
    """launch/hil6.yaml with one more parameter of its dynamics (a list no launch argument sets)."""
    text = (ROOT / "launch" / "hil6.yaml").read_text()
    anchor = "      order: $(arg order)\n"
    assert text.count(anchor) == 1
    return text.replace(anchor, anchor + f"      {param}\n")


@pytest.mark.parametrize(
    "params, expected",
    [
        ("attitude1: [1.0e6, 0.0, 0.0]", "parameter 'attitude1'[0]: 1000000.0 rad is outside 0 to 6.28319 rad"),
        ("attitude1: [1.0e300, 0.0, 0.0]", "parameter 'attitude1'[0]: 1e+300 rad is outside"),
        ("inertia1: [1.0e-30, 1.0e-30, 1.0e-30]", "parameter 'inertia1'[0]: 1e-30 kg m^2 is outside 1e-06 to 1e+13"),
        (
            "inertia1: [[1.0e20, 0.0, 0.0], [0.0, 1.0e20, 0.0], [0.0, 0.0, 1.0e20]]",
            "parameter 'inertia1'[0][0]: 1e+20 kg m^2 is outside",
        ),
        ("inertia1: [1.0, 1.0, 3.0]", "principal moments [1.0, 1.0, 3.0] break I1 + I2 >= I3"),
        ("w2: [0.0, .inf, 0.0]", "parameter 'w2'[1]: inf is not a finite number"),
        ("x2: [2.0e3, 0.0, 0.0]", "parameter 'x2'[0]: 2000.0 m is outside 0 to 1000 m"),
    ],
)
def test_a_meaningless_6dof_parameter_is_refused_in_one_line(params, expected, write_launch):
    code, out, err = run_main("launch", write_launch(hil6_with(params)), "--composed", "--duration", "0.01", "--quiet")
    assert_refused(code, out, err, expected)


def test_a_refusal_takes_little_time_and_memory():
    """CPU time and peak memory of the refusing process alone (wait4): the same on a busy machine. It
    is started by a small interpreter of its own: a child forked from this test's process would count
    the worker's resident memory at the fork in its peak (Linux keeps the larger of the two at exec)."""
    measure = (
        "import json, os, subprocess, sys\n"
        "proc = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)\n"
        "err = proc.stderr.read()\n"
        "_pid, status, usage = os.wait4(proc.pid, 0)\n"
        "print(json.dumps({'code': os.waitstatus_to_exitcode(status), 'err': err,\n"
        "                  'cpu': usage.ru_utime + usage.ru_stime, 'maxrss': usage.ru_maxrss}))\n"
    )
    argv = dockhil_cmd("launch", "launch/hil6.yaml", "tilt:=1e9", "--duration", "1")
    done = subprocess.run([sys.executable, "-c", measure, *argv], capture_output=True, text=True, timeout=120)
    r = json.loads(done.stdout)
    assert r["code"] == 2 and len(r["err"].splitlines()) == 1, r
    assert r["cpu"] < 10.0
    assert r["maxrss"] < 500 * 1024  # [KiB]


# -- an include of a file that is not a launch file ---------------------------------------------------

SECRET = "S3CRET"
NOT_LAUNCH_FILES = {
    "shadow": f"root:$6${SECRET}hash:19000:0:99999:7:::\ndaemon:*:19000:0:99999:7:::\n",
    "key: value": f"password: {SECRET}\n",
    "json": f'{{"{SECRET}": 1}}',
    "tab": f"{SECRET} word\n\t{SECRET}: x\n",
    "alias": f"a: *{SECRET}\n",
    "tag": f"a: !{SECRET} x\n",
    "list": f"- {SECRET}\n",
    "binary": f"\x00\x01{SECRET}",
}


@pytest.mark.parametrize("name", NOT_LAUNCH_FILES)
def test_an_include_of_a_file_that_is_not_a_launch_file_never_shows_it(name, write_launch, tmp_path):
    secret = tmp_path / "secret"
    secret.write_text(NOT_LAUNCH_FILES[name])
    scene = write_launch("nodes:\n  - {name: a, node: 'tests.support.graphnodes:Source'}\ninclude:\n  - file: secret\n")
    for command in ("graph", "launch"):
        code, out, err = run_main(command, scene, *(["--duration", "0.01"] if command == "launch" else []))
        assert code == 2, err
        assert len(err.strip().splitlines()) == 1, err
        assert f"{secret} (included from {scene}): not a launch file" in err, err
        assert SECRET not in out + err and "hash" not in err


def test_a_file_given_that_is_no_launch_file_is_not_shown_either(tmp_path):
    secret = tmp_path / "shadow"
    secret.write_text(NOT_LAUNCH_FILES["shadow"])
    code, _, err = run_main("graph", secret)
    assert code == 2 and f"{secret}: not a launch file" in err and SECRET not in err, err


# -- the summary file ---------------------------------------------------------------------------------


def test_a_summary_on_a_full_disk_is_refused_before_the_run(tmp_path, monkeypatch):
    import dockhil.session as session

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(session.os, "fsync", full)
    path = tmp_path / "s.json"
    code, out, err = run_main("launch", "launch/ideal.yaml", "--composed", "--summary", path)
    assert_refused(code, out, err, f"--summary {path}: cannot be written (No space left on device (ENOSPC))")
    assert not path.exists()


def test_a_summary_where_nothing_can_be_written_is_refused_before_the_run():
    code, out, err = run_main("launch", "launch/ideal.yaml", "--composed", "--summary", "/proc/self/s.json")
    assert_refused(code, out, err, "--summary /proc/self/s.json: cannot be written")


def test_a_disk_that_fills_during_the_run_fails_it_in_one_line(tmp_path, monkeypatch):
    import contextlib

    import dockhil.session as session
    from dockhil.errors import DockhilError

    @contextlib.contextmanager
    def filled(path):
        raise DockhilError(f"cannot write {path}: No space left on device (ENOSPC)")
        yield  # pragma: no cover

    monkeypatch.setattr(session, "complete_or_nothing", filled)
    path = tmp_path / "s.json"
    code, out, err = run_main(
        "launch", "launch/ideal.yaml", "--composed", "--quiet", "--duration", "0.05", "--summary", path
    )
    assert code == 1, err
    assert err.strip().splitlines() == [
        f"[launch] error: --summary: cannot write {path}: No space left on device (ENOSPC); the run's summary is lost"
    ]
    assert not path.exists()


def test_the_ranges_of_a_shipped_scene_hold_its_defaults():
    # Every shipped scene's defaults are physical: a range that refused them would refuse the paper.
    for scene in ("hil.yaml", "hil6.yaml", "ideal.yaml", "stability.yaml"):
        code, _, err = run_main("graph", f"launch/{scene}")
        assert code == 0, err
