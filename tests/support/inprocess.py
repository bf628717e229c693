"""Run a `dockhil` command line in the test's own process: (exit code, stdout, stderr).

A command that refuses its input, or runs a composed scene, needs no interpreter of its own; a
subprocess costs a Python start-up and the imports again (0.3-0.5 CPU-s here). What the command
changes in the process for its run is put back after it: SIGINT/SIGTERM handlers (a composed run
installs its own), the `dockhil` logger's handlers and level (--log-level, --log-file).
"""

from __future__ import annotations

import contextlib
import io
import logging
import signal
import subprocess


def run_main(*argv) -> tuple[int, str, str]:
    from dockhil import cli

    logger = logging.getLogger("dockhil")
    handlers, level = list(logger.handlers), logger.level
    signals = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main([str(a) for a in argv])
            except SystemExit as exc:  # argparse: --help, --version, a refused command line
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        for h in list(logger.handlers):
            if h not in handlers:
                logger.removeHandler(h)
                h.close()
        for h in handlers:
            if h not in logger.handlers:
                logger.addHandler(h)
        logger.setLevel(level)
        for s, h in signals.items():
            signal.signal(s, h)
    return code, out.getvalue(), err.getvalue()


def completed(*argv) -> subprocess.CompletedProcess:
    """run_main's result as subprocess.run gives it (text output)."""
    code, out, err = run_main(*argv)
    return subprocess.CompletedProcess(["dockhil", *map(str, argv)], code, out, err)


def launch_here_or_process(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    """`dockhil launch ARGS`: a composed run needs no process of its own and runs in this process;
    any other as a process of its own."""
    if "--composed" in args:
        return completed("launch", *args)
    from tests.conftest import dockhil_cmd

    return subprocess.run(dockhil_cmd("launch", *args), capture_output=True, text=True, timeout=timeout)
