"""A file that appears whole or not at all: written aside as PATH.part, moved into place when
complete, removed otherwise (a recording, a CSV, a run summary)."""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator

from dockhil.errors import DockhilError


def os_reason(exc: OSError) -> str:
    """'No space left on device (ENOSPC)': the words and the name people search for."""
    text = exc.strerror or str(exc)
    name = errno.errorcode.get(exc.errno or 0)
    return f"{text} ({name})" if name else text


@contextlib.contextmanager
def complete_or_nothing(path: str, error: type[DockhilError] = DockhilError) -> Iterator[str]:
    """Yields `path`.part to write; it becomes `path` when the block ends well and is removed when
    it does not, so `path` appears only complete. An OSError is one `error` line."""
    part = f"{path}.part"
    try:
        yield part
        os.replace(part, path)
    except OSError as exc:
        remove_quietly(part)
        raise error(f"cannot write {path}: {os_reason(exc)}") from None
    except BaseException:
        remove_quietly(part)
        raise


def remove_quietly(path: str) -> None:
    try:
        os.remove(path)
    except OSError:
        pass
