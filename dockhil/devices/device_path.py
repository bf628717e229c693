"""Whether a device path (a serial port, an emulated adapter's link) can be trusted: whoever can
plant or replace it feeds the driver whatever readings they like.

The rule: every component of the path, each symlink on the way and what it points to, belongs to
us or to root; and every directory on the way that others may write to (world-writable, or
group-writable by a group other than our own) has the sticky bit, so that others cannot replace
what we own in it. /dev/ttyACM0, /dev/serial/by-id/... (root's, in root's /dev) and a link of our
own in /tmp (root's, sticky) pass; a link another user planted in /tmp, or any path in a 0777
directory without the sticky bit, does not. A path that does not exist yet passes if its
directories do (the driver checks again once it has opened it).
"""

from __future__ import annotations

import os
import stat

MAX_LINKS = 40  # as the kernel's ELOOP


def untrusted(path: str) -> str | None:
    """Why `path` cannot be trusted as a device (one clause), or None."""
    trusted = {0, os.getuid()}
    todo = [p for p in reversed(os.path.abspath(path).split("/")) if p]
    current = "/"
    links = 0
    while todo:
        part = todo.pop()
        if part == ".":
            continue
        if part == "..":
            current = os.path.dirname(current)
            continue
        try:
            directory = os.stat(current)  # resolved: each entry on the way was checked as below
        except OSError:
            return None  # the open reports it
        mode = directory.st_mode
        others_write = mode & stat.S_IWOTH or (mode & stat.S_IWGRP and directory.st_gid != os.getgid())
        if others_write and not mode & stat.S_ISVTX:
            return (
                f"directory {current} (mode {stat.S_IMODE(mode):04o}) is writable by others without the "
                f"sticky bit: anyone may replace what is in it"
            )
        entry = os.path.join(current, part)
        try:
            st = os.lstat(entry)
        except OSError:
            return None  # missing: its directories are safe; the open reports it
        if st.st_uid not in trusted:
            return f"{entry} belongs to uid {st.st_uid}, not to you or root"
        if stat.S_ISLNK(st.st_mode):
            links += 1
            if links > MAX_LINKS:
                return f"{entry}: too many levels of symbolic links"
            target = os.readlink(entry)
            todo.extend(p for p in reversed(target.split("/")) if p)
            if target.startswith("/"):
                current = "/"
            continue
        current = entry
    return None


def private_link(name: str) -> str:
    """`name` in the graph's private run directory (outside a graph: the private runtime directory),
    where nobody else can plant a device: the default path of an emulated adapter's link."""
    from dockhil.runtime import ownership
    from dockhil.runtime.transport import runtime_dir

    return str((ownership.graph_dir() or runtime_dir()) / name)
