"""Diagnostics through the standard `logging` module: one line per record, `[source] level: message`.

A record's source is who speaks: a node (`[impedance]`), the launcher (`[launch]`), a command
(`dockhil bag export:`). Warnings and errors carry their level word (`warning:`, `error:`,
`debug:`); info records carry none, so `[impedance] impedance (closed form) ...` reads as before.
Records go to stderr, and with --log-file also to a file; what a command prints as its result
(a table, JSON, `topic echo` messages) is plain stdout, never a record.

A node says its level with the first word of its line (`self.log("warning: ...")`); node_line()
reads it. A node process started by the launcher sends each record to the launcher as a FORWARD
line on its output, and the launcher logs it with the node's name, so a node's records reach
the launcher's stderr and log file, at the launcher's level.

On a terminal a log record never runs into the progress line: dockhil.progress erases the line
before the record and draws it again after.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from typing import TYPE_CHECKING, TextIO

from dockhil.errors import DockhilError, one_line

if TYPE_CHECKING:
    import argparse

LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING, "error": logging.ERROR}
WORDS = {logging.DEBUG: "debug", logging.WARNING: "warning", logging.ERROR: "error", logging.CRITICAL: "error"}
# The launcher hands its level to the processes it starts; FORWARD_ENV asks them to forward records.
LEVEL_ENV = "DOCKHIL_LOG_LEVEL"
FORWARD_ENV = "DOCKHIL_LOG_FORWARD"
FORWARD = "\x1edockhil-log "  # a forwarded record: FORWARD + JSON [levelno, source, message, created]

_logger = logging.getLogger("dockhil")
_logger.propagate = False  # dockhil's own handlers only: a record is printed once


def format_line(record: logging.LogRecord, word_always: bool = False) -> str:
    """`[source] level: message`, one line. A `tag` stands in for the level word; tag "" leaves it
    out, for a line whose words already say it (`[launch] node 'x' exited ...; stopping the graph`,
    `[launch] INVALID: ...`), except where word_always (a file) asks for it."""
    tag = getattr(record, "tag", None)
    word = WORDS.get(record.levelno) if tag is None or (tag == "" and word_always) else tag
    text = one_line(record.getMessage())
    if word:
        text = f"{word}: {text}"
    source = getattr(record, "source", "")
    return f"{source} {text}" if source else text


class LineFormatter(logging.Formatter):
    def format(self, record):
        return format_line(record)


class FileFormatter(logging.Formatter):
    """The line, after the time it was made (UTC, milliseconds): a file is read later."""

    def format(self, record):
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        return f"{stamp}.{int(record.msecs):03d}Z {format_line(record, word_always=True)}"


class StderrHandler(logging.Handler):
    """Writes to the current sys.stderr (or `stream`); on a terminal the progress line is erased
    first and drawn again after, so the two never share a line."""

    def __init__(self, stream=None, level=logging.NOTSET):
        super().__init__(level)
        self._stream = stream
        self.setFormatter(LineFormatter())

    @property
    def stream(self):
        return sys.stderr if self._stream is None else self._stream

    def emit(self, record):
        from dockhil import progress

        try:
            line = self.format(record) + "\n"
            progress.write_between(self.stream, line)
        except Exception:  # noqa: BLE001 - a closed or broken stderr: nothing left to tell
            pass


class FileHandler(logging.FileHandler):
    """A log file. A write that fails later (disk full) is said once on stderr, not as a traceback."""

    def __init__(self, path: str):
        super().__init__(path, mode="a", encoding="utf-8")
        self.setFormatter(FileFormatter())
        self.failed = False

    def close(self):
        try:
            super().close()
        except OSError:  # what was still buffered cannot be written either: said already
            self.handleError(None)

    def handleError(self, record):
        if not self.failed:
            self.failed = True
            exc = sys.exc_info()[1]
            why = getattr(exc, "strerror", None) or exc
            from dockhil import progress

            progress.write_between(
                sys.stderr,
                f"dockhil: warning: --log-file {self.baseFilename}: writing failed "
                f"({why}); the log goes on to stderr only\n",
            )


class ForwardHandler(logging.Handler):
    """In a node process started by the launcher: each record as a FORWARD line on stdout."""

    def emit(self, record):
        try:
            payload = [record.levelno, getattr(record, "source", ""), record.getMessage(), record.created]
            tag = getattr(record, "tag", None)
            if tag is not None:
                payload.append(tag)
            sys.stdout.write(FORWARD + json.dumps(payload) + "\n")
            sys.stdout.flush()
        except Exception:  # noqa: BLE001 - the launcher is gone: nobody to tell
            pass


def level_name(text: str) -> int:
    """The level for a name (debug, info, warning, error), or one line saying which names there are."""
    level = LEVELS.get(str(text).strip().lower())
    if level is None:
        raise DockhilError(f"--log-level {text!r}: not a level; give one of {', '.join(LEVELS)}")
    return level


def _level_arg(text: str) -> str:
    import argparse

    if text.strip().lower() not in LEVELS:
        raise argparse.ArgumentTypeError(f"not a level; give one of {', '.join(LEVELS)}")
    return text.strip().lower()


def add_arguments(p: argparse.ArgumentParser) -> None:
    """--log-level and --log-file, for the commands that run things."""
    p.add_argument(
        "--log-level",
        metavar="LEVEL",
        type=_level_arg,
        default=None,
        help="diagnostics shown: debug, info (default), warning or error",
    )
    p.add_argument(
        "--log-file",
        metavar="PATH",
        help="also append every diagnostic, with its time, to this file (node processes' too)",
    )


def _open_file(path: str) -> FileHandler:
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise DockhilError(f"--log-file {path}: is a directory; name a file, e.g. {os.path.join(path, 'dockhil.log')}")
    if not os.path.isdir(folder):
        raise DockhilError(f"--log-file {path}: folder {folder} does not exist; create it or name another file")
    try:
        return FileHandler(path)
    except OSError as exc:
        raise DockhilError(
            f"--log-file {path}: cannot be written ({exc.strerror or exc}); name a file you can write"
        ) from None


def setup(level: str | int | None = None, file: str | None = None, stream: TextIO | None = None) -> None:
    """Where records go, and from which level: stderr (or `stream`), and `file` when given.
    An unwritable file is refused in one line (DockhilError). Replaces an earlier setup."""
    number = level if isinstance(level, int) else level_name(level or "info")
    handlers: list[logging.Handler] = [StderrHandler(stream)]
    try:
        if file:
            handlers.append(_open_file(file))
    finally:  # refused or not, the records from here on go where this setup says
        _install(number, handlers)


def setup_child() -> None:
    """A process the launcher started: its level from the launcher; records forwarded when asked,
    else on stderr (a node started by hand on another machine)."""
    number = LEVELS.get(os.environ.get(LEVEL_ENV, "info"), logging.INFO)
    forward = os.environ.get(FORWARD_ENV) == "1"
    _install(number, [ForwardHandler() if forward else StderrHandler()])


class _Source(logging.Filter):
    """Gives another library's record the prefix of the process it happens in."""

    def __init__(self, source: str):
        super().__init__()
        self.source = source

    def filter(self, record):
        if not getattr(record, "source", ""):
            record.source = self.source
        return True


def capture_others(source: str) -> None:
    """In a node process: other libraries' records and Python's warnings, from warning up, go
    where dockhil's go, under `source` (the node's name) and with their level."""
    number = max(logging.WARNING, _logger.getEffectiveLevel())
    handler = ForwardHandler() if os.environ.get(FORWARD_ENV) == "1" else StderrHandler()
    handler.addFilter(_Source(source))
    handler.setLevel(number)
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(min(root.level or logging.WARNING, number))
    logging.captureWarnings(True)


def _install(number: int, handlers: list[logging.Handler]) -> None:
    for old in list(_logger.handlers):
        _logger.removeHandler(old)
        old.close()
    for h in handlers:
        _logger.addHandler(h)
    _logger.setLevel(number)


def _ensure_setup() -> None:
    # Used as a library (tests, notebooks), dockhil still says what it says, on stderr at info.
    if not _logger.handlers:
        _install(logging.INFO, [StderrHandler()])


def current_level() -> str:
    """The name of the level in force, to hand to processes started from here."""
    _ensure_setup()
    number = _logger.getEffectiveLevel()
    return next((name for name, n in LEVELS.items() if n >= number), "error")


def child_env(env: dict) -> dict:
    """`env` for a process the launcher starts: this level, records forwarded to the launcher."""
    return dict(env, **{LEVEL_ENV: current_level(), FORWARD_ENV: "1"})


def emit(level: int, source: str, message: str, tag: str | None = None, created: float | None = None) -> None:
    _ensure_setup()
    if not _logger.isEnabledFor(level):
        return
    record = _logger.makeRecord(
        _logger.name, level, "(dockhil)", 0, message, (), None, extra={"source": source, "tag": tag}
    )
    if created is not None:
        record.created, record.msecs = created, (created % 1) * 1000
    _logger.handle(record)


class Log:
    """The records of one source: `Log("[launch]").warning("...")`."""

    def __init__(self, source: str):
        self.source = source

    def debug(self, message: str) -> None:
        emit(logging.DEBUG, self.source, message)

    def info(self, message: str) -> None:
        emit(logging.INFO, self.source, message)

    def warning(self, message: str, tag: str | None = None) -> None:
        emit(logging.WARNING, self.source, message, tag)

    def error(self, message: str, tag: str | None = None) -> None:
        emit(logging.ERROR, self.source, message, tag)

    def line(self, text: str) -> None:
        """A line whose first word may say its level (`warning: ...`), as nodes write them."""
        level, message = level_of(text)
        emit(level, self.source, message)


def level_of(text: str) -> tuple[int, str]:
    """A node's line -> (level, message without the level word). `error:`, `warning:` and `debug:`
    lead a line of that level; any other line is info (a `note:` stays in its text)."""
    word, sep, rest = text.partition(": ")
    if sep and word in ("error", "warning", "debug"):
        return LEVELS[word], rest
    return logging.INFO, text


def node_line(name: str, text: str) -> None:
    """A node's log line, logged with the node's name as its prefix. A container's members write
    `[member] line`: logged under the member's name, at the member line's level."""
    if text.startswith("["):
        member, sep, rest = text[1:].partition("] ")
        if sep and member and " " not in member:
            name, text = member, rest
    Log(f"[{name}]").line(text)


def replay(line: str, source: str) -> None:
    """In the launcher: a line a process printed. A FORWARD line is its record, logged as it was
    made; any other line (a traceback, a print) is logged at info under `source`."""
    if line.startswith(FORWARD):
        try:
            level, src, message, created, *tag = json.loads(line[len(FORWARD) :])
            emit(int(level), str(src) or source, str(message), tag[0] if tag else None, float(created))
            return
        except (ValueError, TypeError):
            pass
    emit(logging.INFO, source, line)
