"""Diagnostics through `logging`: levels, a log file that gets the node processes' records with
their prefixes, the progress line and log records on one terminal, an unwritable log file, and
the did-you-means for node types and parameters."""

import io
import json
import os
import re
import subprocess
import sys
import threading

import pytest

from dockhil import cli, log
from dockhil.progress import Progress, StatusLine
from tests.conftest import dockhil_cmd
from tests.support.inprocess import launch_here_or_process

WORDS = ("debug", "info", "warning", "error")

# Three speakers: one node in its own process, two in one container.
CHATTY = """
rate: 100
duration: 0.05
nodes:
  - {name: alone, node: "tests.support.lognodes:Chatty"}
  - {name: left, node: "tests.support.lognodes:Chatty", container: pair, remap: {x: /l}}
  - {name: right, node: "tests.support.lognodes:Chatty", container: pair, remap: {x: /r}}
"""
SPEAKERS = ("alone", "left", "right")


@pytest.fixture(autouse=True)
def _default_logging():
    yield
    log.setup()  # what a later test in this process expects: stderr, info


def expected(words):
    """The lines the Chatty nodes say at these levels, as the format is documented."""
    return {f"[{n}] {'' if w == 'info' else w + ': '}{n} says {w}" for n in SPEAKERS for w in words}


def node_lines(text):
    return {line for line in text.splitlines() if " says " in line}


def launch(*args):
    """`dockhil launch ARGS`; a composed run needs no process of its own, so it runs through
    dockhil.cli.main in this process (no interpreter start-up)."""
    return launch_here_or_process(*args)


@pytest.mark.parametrize("level, shown", [("warning", ("warning", "error")), ("debug", WORDS)])
def test_the_level_filters_and_the_file_gets_the_node_processes_records_with_their_prefixes(
    write_launch, tmp_path, level, shown
):
    scene, file = write_launch(CHATTY), tmp_path / "run.log"
    r = launch(scene, "--log-level", level, "--log-file", file)
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""  # no result to print: every diagnostic is on stderr
    assert node_lines(r.stderr) == expected(shown)
    # The file has the same records, each after its UTC time.
    stamp = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z ")
    written = file.read_text().splitlines()
    assert all(stamp.match(line) for line in written), written
    assert {stamp.sub("", line) for line in written if " says " in line} == expected(shown)
    # The launcher's own records follow the same level.
    assert ("[launch] debug: started 'alone'" in r.stderr) == (level == "debug")
    assert ("[launch] done: " in r.stderr) == (level == "debug")


def node_process(tmp_path, env, node="Chatty"):
    """One node process (tests.support.lognodes) run as the launcher runs it, with `env` added."""
    from dockhil.runtime.transport import GraphKeys

    keys = GraphKeys.make().write(tmp_path / "graph.keys")
    spec = {
        "name": "alone",
        "type_name": f"tests.support.lognodes:{node}",
        "dt": 0.01,
        "clock": "sim",
        "n_ticks": 3,
        "params": {},
        "key_file": str(keys),
        "outputs": {"x": {"topic": "/x", "endpoint": f"ipc://{tmp_path}/x", "type": "dockhil/WrenchStamped"}},
    }
    return subprocess.run(
        [sys.executable, "-m", "dockhil.process", json.dumps(spec)],
        capture_output=True,
        text=True,
        env=dict(os.environ, **env),
        timeout=60,
    )


def test_a_node_process_sends_the_launcher_only_what_its_level_shows(tmp_path):
    r = node_process(tmp_path, {log.LEVEL_ENV: "warning", log.FORWARD_ENV: "1"})
    assert r.returncode == 0 and r.stderr == "", r.stderr
    # split at \n alone, as the launcher reads: str.splitlines() also splits at FORWARD's \x1e
    sent = [line for line in r.stdout.split("\n") if line.startswith(log.FORWARD)]
    assert [json.loads(line[len(log.FORWARD) :])[:3] for line in sent] == [
        [30, "[alone]", "alone says warning"],
        [40, "[alone]", "alone says error"],
    ]


def test_a_library_warning_in_a_node_process_is_a_warning_under_the_nodes_name(tmp_path):
    r = node_process(tmp_path, {log.LEVEL_ENV: "info", log.FORWARD_ENV: "1"}, node="Library")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    sent = [json.loads(line[len(log.FORWARD) :]) for line in r.stdout.split("\n") if line.startswith(log.FORWARD)]
    assert [s[:2] for s in sent] == [[30, "[alone]"], [30, "[alone]"]]
    assert sent[0][2] == "somelib says warning"
    assert "UserWarning: python says warning" in sent[1][2]


def test_a_node_process_started_by_hand_writes_its_lines_to_stderr(tmp_path):
    r = node_process(tmp_path, {log.LEVEL_ENV: "", log.FORWARD_ENV: ""})  # as on another host
    assert r.returncode == 0 and log.FORWARD not in r.stdout
    assert node_lines(r.stderr) == {
        f"[alone] {w}alone says {n}" for w, n in (("", "info"), ("warning: ", "warning"), ("error: ", "error"))
    }


def test_a_composed_run_says_the_same_lines(write_launch):
    r = launch(write_launch(CHATTY), "--composed", "--log-level", "info")
    assert r.returncode == 0, r.stderr
    assert node_lines(r.stderr) == expected(("info", "warning", "error"))


def test_a_file_that_appends_keeps_the_earlier_runs(write_launch, tmp_path):
    scene, file = write_launch(CHATTY), tmp_path / "run.log"
    # Composed: the launcher's file is the same whoever speaks (the node processes' records reach
    # it, the test above holds), and a composed run costs no processes.
    for _ in range(2):
        assert launch(scene, "--composed", "--log-level", "error", "--log-file", file).returncode == 0
    said = [line.split("Z ", 1)[1] for line in file.read_text().splitlines()]
    assert sorted(said) == sorted(2 * [f"[{n}] error: {n} says error" for n in SPEAKERS])


# --------------------------------------------------------------------------- the records' form


@pytest.mark.parametrize(
    "line, level, text",
    [
        ("warning: low", 30, "low"),
        ("error: bad", 40, "bad"),
        ("debug: detail", 10, "detail"),
        ("note: kept", 20, "note: kept"),
        ("plain words", 20, "plain words"),
        ("warning:no space", 20, "warning:no space"),
    ],
)
def test_a_nodes_line_says_its_level_with_its_first_word(line, level, text):
    assert log.level_of(line) == (level, text)


def test_records_are_one_line_each_with_their_prefix():
    out = io.StringIO()
    log.setup("debug", stream=out)
    log.node_line("ft", "warning: a\nb")  # a line break in a message stays in its one line
    log.node_line("hw", "[robot] error: held")  # a container member: its own name
    log.Log("[launch]").error("node 'x' exited with code 3 while running; stopping the graph", tag="")
    log.replay(log.FORWARD + '[30, "[dynamics]", "late", 0.0]', "[proc]")  # a node process's record
    log.replay("Traceback (most recent call last):", "[proc]")  # anything else a process prints
    assert out.getvalue().splitlines() == [
        "[ft] warning: a\\nb",
        "[robot] error: held",
        "[launch] node 'x' exited with code 3 while running; stopping the graph",
        "[dynamics] warning: late",
        "[proc] Traceback (most recent call last):",
    ]


def test_the_file_gives_every_warning_and_error_its_level_word(tmp_path):
    out, file = io.StringIO(), tmp_path / "x.log"
    log.setup("info", file=str(file), stream=out)
    log.Log("[launch]").error("node 'x' exited with code 3 while running; stopping the graph", tag="")
    log.Log("[launch]").error("INVALID: late (exit 3)", tag="")
    log.Log("[launch]").info("done")
    log.setup()  # closes the file
    assert out.getvalue().splitlines() == [
        "[launch] node 'x' exited with code 3 while running; stopping the graph",
        "[launch] INVALID: late (exit 3)",
        "[launch] done",
    ]
    assert [line.split("Z ", 1)[1] for line in file.read_text().splitlines()] == [
        "[launch] error: node 'x' exited with code 3 while running; stopping the graph",
        "[launch] error: INVALID: late (exit 3)",
        "[launch] done",
    ]


# --------------------------------------------------------------------------- progress and records


class Tty(io.StringIO):
    def isatty(self):
        return True


def screen(written: str) -> list[str]:
    """What a terminal shows for `written`: \\r returns to column 0, \\x1b[K erases to the end of
    the line, \\n starts the next line, other characters overwrite."""
    lines, col = [[]], 0
    for token in re.findall(r"\x1b\[K|\r|\n|[^\r\n\x1b]+", written):
        row = lines[-1]
        if token == "\r":
            col = 0
        elif token == "\n":
            lines.append([])
            col = 0
        elif token == "\x1b[K":
            del row[col:]
        else:
            row[col : col + len(token)] = list(token)
            col += len(token)
    return ["".join(row) for row in lines]


def test_a_record_never_runs_into_the_progress_line_on_a_terminal():
    tty = Tty()
    log.setup(stream=tty)
    bar = Progress(total_ticks=1001, dt=1e-3, stream=tty)
    bar.update(400, force=True)
    log.Log("[bag-recorder]").info("recorded 17942 messages")
    shown = screen(tty.getvalue())
    assert shown[0] == "[bag-recorder] recorded 17942 messages"
    assert shown[1].startswith("[") and "0.40 of 1.00 s simulated" in shown[1]  # drawn again below it
    assert len(shown) == 2
    bar.update(1001, force=True)
    bar.done()
    assert screen(tty.getvalue()) == ["[bag-recorder] recorded 17942 messages", ""]  # erased at the end
    log.Log("[launch]").warning("after the run")
    assert screen(tty.getvalue()) == ["[bag-recorder] recorded 17942 messages", "[launch] warning: after the run", ""]


def test_records_from_threads_and_the_status_line_take_turns():
    tty = Tty()
    log.setup(stream=tty)
    line = StatusLine(tty)
    line.show("status 0")
    start = threading.Barrier(4)

    def speak(name):
        start.wait()
        for i in range(50):
            log.node_line(name, f"line {i}")

    threads = [threading.Thread(target=speak, args=(f"n{k}",)) for k in range(3)]
    for t in threads:
        t.start()
    start.wait()
    for i in range(50):
        line.show(f"status {i}")
    for t in threads:
        t.join()
    shown = screen(tty.getvalue())
    assert shown[-1] == "status 49"
    assert sorted(shown[:-1]) == sorted(f"[n{k}] line {i}" for k in range(3) for i in range(50))
    line.end()


def test_off_a_terminal_the_progress_and_the_records_are_plain_lines():
    out = io.StringIO()
    log.setup(stream=out)
    line = StatusLine(out)
    line.show("status")
    log.Log("[launch]").info("said")
    line.end()
    assert out.getvalue() == "status\n[launch] said\n"


# --------------------------------------------------------------------------- a log file that cannot be written


def bad_places(tmp_path):
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    return [
        (tmp_path / "missing" / "run.log", "folder {} does not exist".format(tmp_path / "missing")),
        (tmp_path, "is a directory; name a file"),
        (a_file / "run.log", f"folder {a_file} does not exist"),
    ]


COMMANDS = [
    ("launch", "launch/ideal.yaml", "--duration", "0.01"),
    ("run", "tests.support.graphnodes:Source", "--duration", "0.01"),
    ("sweep", "launch/campaigns/fig7.yaml", "--out", "{tmp}/r.parquet"),
    ("bag", "play", "{tmp}/none.mcap"),
    ("bag", "record", "{tmp}/new.mcap"),
]


@pytest.mark.parametrize("command", COMMANDS, ids=[" ".join(c[:2]) for c in COMMANDS])
def test_an_unwritable_log_file_is_one_line_and_exit_2_before_anything_runs(command, tmp_path, capsys):
    for path, says in bad_places(tmp_path):
        argv = [a.format(tmp=tmp_path) for a in command] + ["--log-file", str(path)]
        assert cli.main(argv) == 2
        out, err = capsys.readouterr()
        assert out == "" and err.count("\n") == 1, err
        assert err.startswith(f"dockhil {command[0]}: error: --log-file {path}: {says}"), err
    assert not (tmp_path / "r.parquet").exists() and not (tmp_path / "new.mcap").exists()


def test_a_bad_level_is_one_line_and_exit_2():
    r = subprocess.run(
        dockhil_cmd("launch", "launch/ideal.yaml", "--log-level", "loud"), capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == (
        "dockhil launch: error: argument --log-level: not a level; give one of debug, info, "
        "warning, error; see 'dockhil launch --help'\n"
    )


def test_a_log_file_that_fails_later_says_so_once_and_the_log_goes_on(capsys):
    out = io.StringIO()
    log.setup("info", file="/dev/full", stream=out)  # opens, but every write fails: a full disk
    for i in range(3):
        log.Log("[x]").info(f"record {i}")
    err = capsys.readouterr().err
    assert err == (
        "dockhil: warning: --log-file /dev/full: writing failed (No space left on device); "
        "the log goes on to stderr only\n"
    )
    assert out.getvalue().splitlines() == [f"[x] record {i}" for i in range(3)]


# --------------------------------------------------------------------------- did you mean


def test_a_misspelt_node_type_gets_a_suggestion(write_launch, capsys):
    scene = write_launch("duration: 0.1\nnodes:\n  - {name: dynamics, node: satelite_dynamics}\n")
    assert cli.main(["launch", str(scene)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert (
        f"{scene}:3: node 'dynamics': unknown node type 'satelite_dynamics'; did you mean "
        f"'satellite_dynamics'? (known types: " in err
    )


@pytest.mark.parametrize(
    "given, says",
    [
        ("kcss", "unknown parameter 'kcss'; did you mean 'kcs'? (known: b1, b2, bcs, compensation, "),
        ("zzz", "unknown parameter 'zzz'; known: b1, b2, bcs, compensation, "),  # nothing close: the list alone
    ],
)
def test_a_misspelt_node_parameter_gets_a_suggestion(write_launch, capsys, given, says):
    scene = write_launch(
        f"duration: 0.1\nnodes:\n  - {{name: imp, node: virtual_impedance, params: {{{given}: 1.0}}}}\n"
    )
    assert cli.main(["graph", str(scene)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert "node 'imp' (VirtualImpedance): " + says in err, err
