"""A child ends with its parent (dockhil.runtime.parent.die_with_parent): the kernel's signal when
the parent ends later, and an exit at once when the parent it names had already ended."""

from __future__ import annotations

import subprocess
import sys
import time

import psutil
import pytest

# The middle process starts a grandchild, which sleeps (calling die_with_parent first or not), prints
# the grandchild's pid and ends: the grandchild's parent is gone.
MIDDLE = """
import subprocess, sys
child = ("import signal, time\\n"
         + ("from dockhil.runtime.parent import die_with_parent\\ndie_with_parent(signal.%s)\\n" if %r else "")
         + "print('ready', flush=True)\\ntime.sleep(60)\\n")
p = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
p.stdout.readline()
print(p.pid, flush=True)
"""


def _orphan(sig: str, call: bool) -> int:
    out = subprocess.run([sys.executable, "-c", MIDDLE % (sig, call)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return int(out.stdout.split()[-1])


def _gone(pid: int, within: float) -> bool:
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        try:
            if psutil.Process(pid).status() == psutil.STATUS_ZOMBIE:
                return True
        except psutil.NoSuchProcess:
            return True
        time.sleep(0.05)
    return False


@pytest.mark.wall_time
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGKILL"])
def test_a_child_ends_when_its_parent_ends(sig):
    assert _gone(_orphan(sig, True), within=20.0)


@pytest.mark.wall_time
def test_without_it_the_child_outlives_its_parent():
    pid = _orphan("SIGTERM", False)
    try:
        assert not _gone(pid, within=1.0)
    finally:
        psutil.Process(pid).kill()


def test_a_parent_already_gone_ends_the_child_at_once():
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    code = (
        "import signal\nfrom dockhil.runtime.parent import die_with_parent\n"
        f"die_with_parent(signal.SIGKILL, {gone.pid})\nprint('still here')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert (out.returncode, out.stdout) == (1, "")
    here = subprocess.run(
        [sys.executable, "-c", code.replace(str(gone.pid), "__import__('os').getppid()")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (here.returncode, here.stdout) == (0, "still here\n")
