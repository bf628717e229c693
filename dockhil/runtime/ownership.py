"""One graph per device: a robot controller, an F/T adapter or an emulator's port is owned by one
graph at a time, and a second graph refuses in one line, naming the device and its owner, before
it sends anything.

On this host the claim is a lock file in the private runtime directory, keyed by the device and
held with flock(2) for as long as the claiming process lives (the kernel drops it when the process
dies, however it dies). The file holds the owner's description for the refusal line. Across
machines a device must enforce ownership itself: the robot controller's owner registers
(dockhil/devices/modbus_robot/registers.py).
"""

from __future__ import annotations

import fcntl
import os
import re
import secrets
import socket
import zlib

from dockhil.errors import DeviceError

_graph = ""


def set_graph(run_id: str) -> None:
    """The run id of the graph this process belongs to (set by the node process from its spec)."""
    global _graph
    _graph = run_id


def graph_dir():
    """This graph's private run directory (0700, owner checked; the launcher removes it when the graph
    ends), where a node keeps what must outlive its own restarts; None outside a graph."""
    from dockhil.runtime.rundir import private_dir, runtime_dir

    return private_dir(runtime_dir() / _graph, "run directory") if _graph else None


def owner() -> str:
    """Who claims a device from this process: the graph's run id, pid and host."""
    where = f"pid {os.getpid()} on {socket.gethostname()}"
    return f"graph {_graph} ({where})" if _graph else f"process {where} (not a graph)"


def session_id(node: str) -> int:
    """A nonzero 32-bit session id for a device that keeps its owner: the same for a node restarted
    within its graph (a respawned driver takes its own claim back at once), random outside a graph."""
    value = zlib.crc32(f"{_graph}/{node}".encode()) if _graph else secrets.randbits(32)
    return value or 1


def short_owner() -> str:
    """The owner's name for a device that keeps 32 characters: run id and host."""
    return f"{_graph or f'pid {os.getpid()}'}@{socket.gethostname()}"[:32]


class DeviceLock:
    """A held claim on one device; release() or the process's death frees it."""

    def __init__(self, fd: int, path: str):
        self.fd = fd
        self.path = path

    def release(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)  # closing drops the flock; the file stays for the next owner
            self.fd = -1


def lock_path(key: str) -> str:
    from dockhil.runtime.rundir import private_dir, runtime_dir

    name = re.sub(r"[^A-Za-z0-9_.-]", "_", key).strip("._")[:200] or "device"
    return str(private_dir(runtime_dir() / "devices", "device lock directory") / f"{name}.lock")


def claim(key: str, device: str) -> DeviceLock:
    """Claim `device` (described for people), keyed by `key`; DeviceError if another graph owns it."""
    path = lock_path(key)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        held_by = os.pread(fd, 512, 0).decode(errors="replace").strip() or "another process"
        os.close(fd)
        raise DeviceError(
            f"{device} is in use by {held_by}; stop it first, or give this graph another device"
        ) from None
    except OSError as exc:
        os.close(fd)
        raise DeviceError(f"{device}: cannot lock {path}: {exc.strerror}") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, owner().encode(), 0)
    return DeviceLock(fd, path)


def claim_for_graph(key: str, device: str, timeout: float = 1.0) -> DeviceLock:
    """Claim `device` for this process's graph: any of the graph's processes may hold it beside each
    other (a driver and its graph's emulator on one CAN bus), no process of another graph (or of none).

    A shared flock keeps the claim alive while any holder lives; the file names the graph. Who finds
    the file held by nobody takes it exclusively, writes its graph and turns the lock shared; who
    finds it held reads the graph in it. Of two graphs racing, the one whose name is not in the file
    when its shared lock is taken refuses; both are never admitted."""
    import time

    path = lock_path(key)
    mine = _graph or f"pid {os.getpid()}"
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    deadline = time.monotonic() + timeout
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{mine}\n{owner()}".encode(), 0)
        except BlockingIOError:
            pass  # held: read whose it is below
        while True:  # an exclusive holder is another claimant between its write and its downgrade
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise DeviceError(
                        f"{device}: its claim did not settle within {timeout:g} s; "
                        f"another graph is claiming it, try again"
                    ) from None
                time.sleep(0.01)
        graph, _, held_by = os.pread(fd, 512, 0).decode(errors="replace").partition("\n")
    except OSError as exc:
        os.close(fd)
        raise DeviceError(f"{device}: cannot lock {path}: {exc.strerror}") from None
    if graph != mine:
        os.close(fd)
        raise DeviceError(
            f"{device} is in use by {held_by.strip() or 'another graph'}; stop it first, "
            f"or give this graph another device"
        )
    return DeviceLock(fd, path)
