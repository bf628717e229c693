"""A graph's CURVE keys and the ZAP handler that admits only its subscribers (dockhil.runtime.transport).

Every socket of a graph speaks CURVE with keys the launcher makes per graph (GraphKeys, handed
over in a key file of mode 0600, never on a command line); a publisher's context runs one ZAP
handler that admits only the client keys of the graphs whose publishers live in the process."""

from __future__ import annotations

import itertools
import json
import os
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import zmq

from dockhil.errors import DockhilError


@dataclass(frozen=True)
class GraphKeys:
    """One graph's CURVE keys (Z85 text): publishers prove the server key, subscribers the client key."""

    server_public: bytes
    server_secret: bytes
    client_public: bytes
    client_secret: bytes

    @classmethod
    def make(cls) -> GraphKeys:
        import zmq

        server_public, server_secret = zmq.curve_keypair()
        client_public, client_secret = zmq.curve_keypair()
        return cls(server_public, server_secret, client_public, client_secret)

    def write(self, path: Path) -> Path:
        """A new key file of mode 0600 (refused if something is already there)."""
        text = json.dumps({k: getattr(self, k).decode() for k in self.__dataclass_fields__})
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(text)
        return path

    @classmethod
    def read(cls, path: str | Path) -> GraphKeys:
        """Keys from a key file that only this user can read; one line otherwise."""
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
        except OSError as exc:
            raise DockhilError(
                f"key file {path}: {exc.strerror}; copy the graph's key file there (mode 0600) or start the graph again"
            ) from None
        with os.fdopen(fd) as f:
            st = os.fstat(f.fileno())
            if st.st_uid != os.getuid():
                raise DockhilError(
                    f"key file {path} belongs to uid {st.st_uid}, not to you (uid {os.getuid()}); "
                    f"use a copy of your own with mode 0600"
                )
            mode = stat.S_IMODE(st.st_mode)
            if mode & 0o077:
                raise DockhilError(
                    f"key file {path} has mode {mode:04o}: other users can read the graph's keys; chmod 600 {path}"
                )
            try:
                data = json.loads(f.read())
                keys = cls(**{k: data[k].encode() for k in cls.__dataclass_fields__})
            except (ValueError, KeyError, TypeError, AttributeError):
                raise DockhilError(f"key file {path} is not a dockhil key file") from None
        if any(len(getattr(keys, k)) != 40 for k in cls.__dataclass_fields__):
            raise DockhilError(f"key file {path} is not a dockhil key file (keys must be 40 Z85 characters)")
        return keys


ZAP_ENDPOINT = "inproc://zeromq.zap.01"  # where libzmq asks a context's ZAP handler (RFC 27)


_ZAP_WAKES = itertools.count()


class ZapHandler:
    """A context's ZAP handler: a thread that answers every CURVE handshake of the context's
    publishers, admitting a client only if its public key is one of `allowed` (Z85), the client
    keys of the graphs whose publishers live in this process. Any other mechanism or key is
    refused. (pyzmq's ThreadAuthenticator does the same through an asyncio event loop, whose
    import alone costs each node process about 50 ms of CPU.)"""

    def __init__(self, ctx: zmq.Context) -> None:
        self.allowed: set[bytes] = set()
        self._zap = ctx.socket(zmq.REP)
        self._zap.linger = 0
        # The handler a context had before (its last publisher closed) lets go of the address only
        # when libzmq's reaper gets to its socket: wait for that rather than fail a new graph's start.
        deadline = time.monotonic() + 2.0
        while True:
            try:
                self._zap.bind(ZAP_ENDPOINT)
                break
            except zmq.ZMQError as exc:
                if exc.errno != zmq.EADDRINUSE or time.monotonic() > deadline:
                    raise
                time.sleep(0.001)
        wake = f"inproc://dockhil-zap-stop-{next(_ZAP_WAKES)}"  # never an address a closed handler may still hold
        self._stop = ctx.socket(zmq.PAIR)
        self._stop.linger = 0
        self._stop.bind(wake)
        woken = ctx.socket(zmq.PAIR)
        woken.linger = 0
        woken.connect(wake)
        self._thread = threading.Thread(target=self._serve, args=(woken,), name="dockhil-zap", daemon=True)
        self._thread.start()

    def _serve(self, woken: zmq.Socket) -> None:
        name_os_thread("dockhil-zap")
        poller = zmq.Poller()
        poller.register(self._zap, zmq.POLLIN)
        poller.register(woken, zmq.POLLIN)
        try:
            while True:
                ready = dict(poller.poll())
                if woken in ready:
                    return
                if self._zap in ready:
                    self._zap.send_multipart(self.reply(self._zap.recv_multipart()))
        finally:
            woken.close()
            self._zap.close()

    def reply(self, request: list[bytes]) -> list[bytes]:
        """The answer to one ZAP request: [version, request id, domain, address, routing id,
        mechanism, credentials...]; for CURVE the credential is the client's 32-byte public key."""
        from zmq.utils import z85

        request_id = request[1] if len(request) > 1 else b""
        admitted = (
            len(request) == 7
            and request[0] == b"1.0"
            and request[5] == b"CURVE"
            and len(request[6]) == 32
            and z85.encode(request[6]) in self.allowed
        )
        if admitted:
            return [b"1.0", request_id, b"200", b"OK", b"graph", b""]
        return [b"1.0", request_id, b"400", b"not a client of this graph", b"", b""]

    def stop(self) -> None:
        self._stop.send(b"")
        self._thread.join()
        self._stop.close()


def name_os_thread(name: str) -> None:
    """The calling thread's name as the OS shows it (/proc/PID/task/TID/comm: `top -H`, bench/graph.py's
    context switches by thread); Python 3.11 names only its own thread object. At most 15 bytes."""
    try:
        with open(f"/proc/self/task/{threading.get_native_id()}/comm", "w") as f:
            f.write(name[:15])
    except OSError:  # not Linux: the name is only a help
        pass


_auth_lock = threading.Lock()
_auth: dict[int, list] = {}  # id(context) -> [its ZAP handler, publishers using it]


def allow_clients(ctx: zmq.Context, keys: GraphKeys) -> None:
    """Start this context's ZAP handler (once) and let the graph's client key in."""
    with _auth_lock:
        entry = _auth.get(id(ctx))
        if entry is None:
            entry = _auth[id(ctx)] = [ZapHandler(ctx), 0]
        entry[0].allowed.add(keys.client_public)
        entry[1] += 1


def release_clients(ctx: zmq.Context) -> None:
    with _auth_lock:
        entry = _auth.get(id(ctx))
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] <= 0:
            del _auth[id(ctx)]
            entry[0].stop()
