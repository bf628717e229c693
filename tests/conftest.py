import glob
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

# As the `dockhil` command does (dockhil/cli.py), for the tests that call the library in this process
# and the processes they start: BLAS worker threads only spin on small matrices and a busy machine.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

# No per-example time limit: a busy machine makes an example slow, not wrong.
settings.register_profile("dockhil", deadline=None)
settings.load_profile("dockhil")


def pytest_configure(config):
    # The suite starts a few hundred Python processes (launches, nodes, CLI calls). Where the
    # environment sets PYTHONDONTWRITEBYTECODE, as many CI images do (and an editable install writes
    # no bytecode either), each would compile the package from source again: about 0.1 CPU-s a
    # process. Compile it once, in the controller rather than in each xdist worker.
    if not hasattr(config, "workerinput"):
        import compileall

        for folder in ("dockhil", "tests"):
            compileall.compile_dir(str(ROOT / folder), quiet=1)


def pytest_ignore_collect(collection_path, config):
    # The suite's second phase, `-m wall_time`, needs only the files that have such tests: importing
    # the other modules (hypothesis, numpy, the models) cost that phase about 7 CPU-s of collection.
    if (
        config.option.markexpr == "wall_time"
        and collection_path.suffix == ".py"
        and collection_path.name.startswith("test_")
        and "wall_time" not in collection_path.read_text()
    ):
        return True
    return None


@pytest.fixture(autouse=True)
def _runtime_dir(monkeypatch):
    # Each test gets its own registry and ipc directory: no test sees a user's graphs or another
    # test's. Short, under /tmp, because ipc socket paths are limited to about 100 characters.
    d = tempfile.mkdtemp(prefix="dh-", dir="/tmp")
    monkeypatch.setenv("DOCKHIL_RUNTIME_DIR", d)
    monkeypatch.chdir(ROOT)
    yield
    shutil.rmtree(d, ignore_errors=True)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (for a server a test starts)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago (for a device a test starts)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(done, timeout: float = 10.0, what: str = "condition") -> None:
    """Wait until done() (a device's thread did something); fail naming `what` after `timeout` s."""
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not reached within {timeout} s")
        time.sleep(0.002)


def dockhil_cmd(*args):
    return [sys.executable, "-m", "dockhil.cli", *map(str, args)]


def sigint_as_a_terminal_sends_it() -> None:
    """For Popen(preexec_fn=...): SIGINT's default disposition in the child. A script's background job
    (this suite started by `cmd &`) runs with SIGINT ignored, which a Python child would inherit and
    never raise KeyboardInterrupt; a user's Ctrl-C reaches a command that does not ignore it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture
def write_launch(tmp_path):
    def write(text: str, name: str = "scene.yaml") -> Path:
        p = tmp_path / name
        p.write_text(text)
        return p

    return write


@pytest.fixture
def controller():
    """A robot controller emulator (Modbus TCP on a free port) in this process."""
    from dockhil.devices.modbus_robot.emulator import RobotControllerEmulator

    em = RobotControllerEmulator(port=0, tau=0.005)
    em.start_thread()
    yield em
    em.stop_thread()


def node_process_error(spec: dict, env=None) -> str:
    """Run one node process that must fail fast (a missing device): return its single error line."""
    t = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "dockhil.process", json.dumps(spec)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert time.monotonic() - t < 15.0  # fails at once, not after a hang (interpreter start-up on a busy machine)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


def registered(pid: int, timeout=20.0, proc: subprocess.Popen | None = None) -> dict:
    """The registry entry of the graph run by process `pid` (`proc`: its Popen, whose output an
    early end shows)."""
    graphs = os.path.join(os.environ["DOCKHIL_RUNTIME_DIR"], "graphs")
    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc is not None and proc.poll() is not None:
            out = proc.communicate(timeout=5)[0] if proc.stdout else ""
            raise AssertionError(f"process {pid} ended (exit {proc.returncode}) with no graph registered:\n{out}")
        for name in glob.glob(os.path.join(graphs, "*.json")):
            try:
                entry = json.load(open(name))
            except (OSError, ValueError):
                continue
            if entry.get("pid") == pid:
                return entry
        time.sleep(0.02)
    raise AssertionError(f"process {pid} registered no graph")


class Lines:
    """Reads a process's text output (stdout, or the `stream` given) in a thread, so a test can wait for a
    line with a deadline."""

    def __init__(self, proc: subprocess.Popen, stream=None):
        self.proc = proc
        self.stream = proc.stdout if stream is None else stream
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self.stream:
            with self._cond:
                self.lines.append(line)
                self._cond.notify_all()
        with self._cond:
            self._eof = True
            self._cond.notify_all()

    def wait_for(self, text: str, count: int = 1, timeout: float = 60.0) -> str:
        """Block until `text` has appeared in `count` lines; all output so far."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while sum(text in line for line in self.lines) < count:
                left = deadline - time.monotonic()
                if left <= 0 or getattr(self, "_eof", False):
                    raise AssertionError(f"no {count} lines with {text!r} within {timeout} s:\n" + "".join(self.lines))
                self._cond.wait(min(left, 0.5))
            return "".join(self.lines)

    def rest(self, timeout: float = 60.0) -> str:
        """Wait for the process to end; all its output."""
        self.proc.wait(timeout=timeout)
        self._thread.join(timeout)
        return "".join(self.lines)


def kill_child_and_expect_the_graph_to_stop(
    launch: subprocess.Popen, name: str, dependent: str = "", lines: Lines | None = None
) -> str:
    """SIGKILL the launched process `name`; the launcher must stop the graph, non-zero, in plain lines.
    `dependent`: a node that may notice first (a driver whose device died) and fail with its own line.
    `lines`: the launcher's output, if a test already reads it."""
    pid = registered(launch.pid, proc=launch)["nodes"][name]["pid"]
    try:
        os.kill(pid, signal.SIGKILL)
        out = lines.rest(timeout=60) if lines else launch.communicate(timeout=60)[0]
    finally:
        if launch.poll() is None:
            launch.kill()
    assert launch.returncode != 0
    killed = f"[launch] node '{name}' was killed by SIGKILL while running; stopping the graph" in out
    noticed = (
        bool(dependent)
        and f"[launch] node '{dependent}' exited with code 2 while running" in out
        and f"[{dependent}] error: " in out
    )
    assert killed or noticed, out
    assert "Traceback" not in out
    return out


class VirtualFtSensor:
    """Sends F/T frames on a python-can virtual bus, as the sensor would."""

    def __init__(self, channel: str):
        import can

        self._can = can
        self.channel = channel
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.seq = 0
        self.force = (0.0, 0.0, 0.0)
        self.torque = (0.0, 0.0, 0.0)
        self._run = False
        self._thread = None

    def send(self, force=None, torque=None, seq=None, status=0, advance=True):
        from dockhil.devices.can_ft import frames as ff

        seq = self.seq if seq is None else seq
        for fid, data in ff.encode_sample(force or self.force, torque or self.torque, seq, status=status):
            self.bus.send(self._can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        if advance:
            self.seq = (seq + 1) & 0xFF

    def stream(self):
        """Send at about 1 kHz in a thread (for the tare in setup)."""
        self._run = True

        def loop():
            while self._run:
                self.send()
                time.sleep(0.001)

        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()
        return self

    def quiet(self):
        self._run = False
        if self._thread:
            self._thread.join()

    def close(self):
        self.quiet()
        self.bus.shutdown()
