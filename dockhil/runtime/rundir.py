"""A run's private directories: the runtime directory (ipc sockets, key files, device locks, the
registry of running graphs) and each run's own, refused in one line where another user could plant
or swap what is in them."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from dockhil.errors import DockhilError


def _check_private_dir(path: Path, what: str) -> None:
    """Refuse, in one line, a directory another user could plant sockets or files in; tighten our own."""
    try:
        st = path.lstat()
    except OSError as exc:
        raise DockhilError(
            f"{what} {path}: {exc.strerror}; set DOCKHIL_RUNTIME_DIR to a directory of your own"
        ) from None
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise DockhilError(
            f"{what} {path} is not a plain directory (a symlink or a file); "
            f"remove it, or set DOCKHIL_RUNTIME_DIR to a directory of your own"
        )
    if st.st_uid != os.getuid():
        raise DockhilError(
            f"{what} {path} belongs to uid {st.st_uid}, not to you (uid {os.getuid()}): "
            f"its owner could read or replace your graph's sockets; remove it, "
            f"or set DOCKHIL_RUNTIME_DIR to a directory of your own"
        )
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o022:
        raise DockhilError(
            f"{what} {path} has mode {mode:04o}: other users may write to it and replace your "
            f"graph's sockets; remove it (with what is in it), or chmod 700 {path}"
        )
    if mode != 0o700:
        os.chmod(path, 0o700)  # ours and not writable by others: readable by others need not be


def private_dir(path: Path, what: str = "runtime directory") -> Path:
    """`path` as a directory of mode 0700 owned by this user, made if missing, refused otherwise."""
    try:
        path.mkdir(mode=0o700)
    except FileExistsError:
        pass
    except OSError as exc:
        raise DockhilError(
            f"cannot create {what} {path}: {exc.strerror}; set DOCKHIL_RUNTIME_DIR to a directory of your own"
        ) from None
    _check_private_dir(path, what)
    return path


def _check_ancestors(path: Path, what: str) -> None:
    """Refuse, in one line, a directory whose parent (or one of its parents) another user could
    rename or replace mid-run (with a directory of theirs): each must belong to this user or to
    root, and be writable by no one else unless sticky (as /tmp, where only an entry's owner may
    remove or rename it)."""
    uid = os.getuid()
    for parent in (*path.parent.resolve().parents[::-1], path.parent.resolve()):
        st = parent.stat()
        mode = stat.S_IMODE(st.st_mode)
        if st.st_uid not in (uid, 0):
            why = f"belongs to uid {st.st_uid}, not to you (uid {uid}) or root"
        elif mode & 0o022 and not mode & stat.S_ISVTX:
            why = f"has mode {mode:04o}: other users may write to it"
        else:
            continue
        raise DockhilError(
            f"{what} {path}: its parent {parent} {why}, and could swap your graph's sockets "
            f"mid-run; set DOCKHIL_RUNTIME_DIR to a directory under one that only you or root own"
        )


def runtime_dir() -> Path:
    """Where ipc sockets, key files, device locks and the registry of running graphs live: private,
    in a parent no other user can change."""
    base = Path(os.environ.get("DOCKHIL_RUNTIME_DIR") or f"/tmp/dockhil-{os.getuid()}")
    if not base.parent.exists():
        base.parent.mkdir(parents=True, mode=0o700)
    _check_ancestors(base, "runtime directory")
    return private_dir(base)


def new_run_dir(run_id: str) -> Path:
    """A fresh private directory for one run's sockets and keys."""
    path = runtime_dir() / run_id
    try:
        path.mkdir(mode=0o700)
    except OSError as exc:
        raise DockhilError(f"cannot create run directory {path}: {exc.strerror}") from None
    _check_private_dir(path, "run directory")
    return path
