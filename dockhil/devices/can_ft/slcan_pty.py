"""Serial-line CAN (slcan, the Lawicel ASCII protocol) adapters on pseudo-terminals.

Cross-process CAN without a kernel CAN module: an `SlcanPort` owns the
master end of a pseudo-terminal and behaves like a USB slcan adapter
(CANable, Lawicel CANUSB) plugged in at the slave end. A host opens the
slave path, or a stable symlink to it, with python-can's `slcan` interface
exactly as it would open /dev/ttyACM0:

    can.Bus(interface="slcan", channel="/run/user/1000/ft.slcan", bitrate=1_000_000)

What sits behind the adapter decides what the host talks to:

- `PtyCanBus` joins several ports into one CAN bus: a frame the host of
  one port sends reaches the hosts of all other open ports. Run it as a
  process, `python -m dockhil.devices.can_ft.slcan_pty LINK [LINK ...]`, and two
  programs that each open one link with python-can talk CAN to each other.
- A device emulator (dockhil/devices/can_ft/emulator.py) owns one port and is the only
  other node on that bus.

Protocol subset (each command ends with CR; the adapter answers CR for OK,
BEL for an error): Sn (bitrate 0-8), sxxyy (BTR), O (open), L (open listen
only), C (close), V (version), N (serial number), F (status flags),
Zn (timestamps, accepted, not sent), tiiil..., Tiiiiiiiil..., riiil,
Riiiiiiiil (transmit; answered z/Z + CR). Received frames reach the host
as tiiildd..CR / Tiiiiiiiildd..CR while the channel is open. Only
classic CAN; the bitrate is recorded, not enforced.
"""

from __future__ import annotations

import argparse
import os
import selectors
import signal
import sys
import threading
import tty
from collections.abc import Callable
from dataclasses import dataclass

OK = b"\r"
ERROR = b"\a"
VERSION_REPLY = b"V1013\r"
SERIAL_REPLY = b"NDH01\r"
# Bytes waiting for a host that does not read; past this, new frames are
# dropped whole (as an adapter overruns) rather than blocking the sender.
OUT_LIMIT = 64 * 1024


@dataclass(frozen=True)
class CanFrame:
    arbitration_id: int
    data: bytes = b""
    is_extended_id: bool = False
    is_remote_frame: bool = False
    dlc: int | None = None  # remote frames carry a DLC but no data

    def to_slcan(self) -> bytes:
        dlc = len(self.data) if self.dlc is None else self.dlc
        if self.is_extended_id:
            head = f"{'R' if self.is_remote_frame else 'T'}{self.arbitration_id:08X}{dlc:d}"
        else:
            head = f"{'r' if self.is_remote_frame else 't'}{self.arbitration_id:03X}{dlc:d}"
        body = "" if self.is_remote_frame else self.data.hex().upper()
        return (head + body).encode("ascii") + OK


def parse_transmit(line: bytes) -> CanFrame | None:
    """The frame in a t/T/r/R command, None if the command is malformed."""
    try:
        text = line.decode("ascii")
        kind = text[0]
        id_len = 3 if kind in "tr" else 8
        arbitration_id = int(text[1 : 1 + id_len], 16)
        dlc = int(text[1 + id_len])
        payload = text[2 + id_len :]
    except (UnicodeDecodeError, IndexError, ValueError):
        return None
    if dlc > 8 or arbitration_id > (0x7FF if id_len == 3 else 0x1FFFFFFF):
        return None
    if kind in "rR":
        return CanFrame(arbitration_id, b"", kind == "R", True, dlc) if payload == "" else None
    if len(payload) != 2 * dlc:
        return None
    try:
        data = bytes.fromhex(payload)
    except ValueError:
        return None
    return CanFrame(arbitration_id, data, kind == "T")


def _check_replaceable(link: str) -> None:
    """The link may replace only a link an earlier emulated adapter left (to a pseudo-terminal):
    a file or a real adapter's name given by mistake is refused, not destroyed. Nor is it made
    where another user could replace it (the driver would refuse it: dockhil/devices/device_path.py)."""
    from dockhil.devices.device_path import untrusted
    from dockhil.errors import DeviceError

    why = untrusted(link)
    if why:
        raise DeviceError(
            f"slcan adapter {link}: refused: {why}; give the adapter a path in a directory only you can write"
        )
    if not os.path.lexists(link):
        return
    if os.path.islink(link):
        target = os.readlink(link)
        if target.startswith("/dev/pts/"):
            return
        what = f"a link to {target}"
    elif os.path.isdir(link):
        what = "a directory"
    elif os.path.isfile(link):
        what = "a regular file"
    else:
        what = "a device or other special file"
    raise DeviceError(
        f"slcan adapter {link}: the path exists and is {what}, not the link of an emulated "
        f"adapter; it was left as it is: give the emulator a path of its own"
    )


class SlcanPort:
    """One emulated slcan adapter: the master end of a pseudo-terminal.

    `path` is the slave device (/dev/pts/N); `link`, if given, is a symlink
    to it with a stable name. The port keeps its own copy of the slave open,
    so a host that closes and reopens the device does not hang up the
    master end. A link is claimed for this process first (one graph per
    adapter path): a second adapter at the same path is refused in one
    line naming the owner, instead of taking the link over.
    """

    def __init__(self, link: str | None = None):
        self._claim = None  # this process's claim on the link path
        if link:
            from dockhil.runtime import ownership

            self._claim = ownership.claim(f"slcan-adapter-{os.path.abspath(link)}", f"slcan adapter {link}")
            try:
                _check_replaceable(link)
            except BaseException:
                self._release()
                raise
        try:
            self._master, self._slave = os.openpty()
        except OSError:
            self._release()
            raise
        # Raw mode before any host opens it: no echo of what we write, no line editing.
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self.link = None
        if link:
            tmp = f"{link}.{os.getpid()}.tmp"
            os.symlink(self.path, tmp)
            os.replace(tmp, link)  # atomically replace a stale link from an earlier run
            self.link = link
        self.is_open = False
        self.listen_only = False
        self.bitrate_code: str | None = None
        self.dropped = 0  # frames dropped because the host did not read
        self._in = bytearray()
        self._out = bytearray()
        self._lock = threading.Lock()

    @property
    def name(self) -> str:
        return self.link or self.path

    def fileno(self) -> int:
        return self._master

    def wants_write(self) -> bool:
        return bool(self._out)

    # -- host -> adapter ------------------------------------------------------
    def read_host(self) -> list[CanFrame]:
        """Read what the host wrote, answer its commands; return the frames it sent."""
        try:
            chunk = os.read(self._master, 4096)
        except BlockingIOError:
            return []
        except OSError:  # EIO: nothing to read
            return []
        self._in += chunk
        frames = []
        replies = bytearray()
        while True:
            # Commands end with CR; a BEL-free host never sends LF, but tolerate it.
            cut = self._in.find(b"\r")
            if cut < 0:
                if len(self._in) > 1024:  # garbage without terminators
                    self._in.clear()
                break
            line = bytes(self._in[:cut]).strip(b"\n")
            del self._in[: cut + 1]
            reply, frame = self._command(line)
            replies += reply
            if frame is not None:
                frames.append(frame)
        if replies:
            self._send(bytes(replies), force=True)
        return frames

    def _command(self, line: bytes) -> tuple[bytes, CanFrame | None]:
        if not line:
            return OK, None
        op = line[:1]
        if op in (b"t", b"T", b"r", b"R"):
            frame = parse_transmit(line)
            if frame is None or not self.is_open or self.listen_only:
                return ERROR, None
            return (b"z\r" if op in (b"t", b"r") else b"Z\r"), frame
        if op == b"S":
            if self.is_open or line[1:] not in [str(i).encode() for i in range(9)]:
                return ERROR, None
            self.bitrate_code = line.decode()
            return OK, None
        if op == b"s":
            if self.is_open:
                return ERROR, None
            self.bitrate_code = line.decode()
            return OK, None
        if op in (b"O", b"L"):
            if self.is_open:
                return ERROR, None
            self.is_open, self.listen_only = True, op == b"L"
            return OK, None
        if op == b"C":
            self.is_open = False
            return OK, None
        if op == b"V":
            return VERSION_REPLY, None
        if op == b"N":
            return SERIAL_REPLY, None
        if op == b"F":
            return b"F00\r", None
        if op in (b"Z", b"Y", b"M", b"m", b"X", b"W", b"U", b"Q"):
            return OK, None
        return ERROR, None

    # -- adapter -> host ------------------------------------------------------
    def deliver(self, frame: CanFrame) -> bool:
        """Pass a bus frame to the host; False if the channel is closed or the host lags."""
        if not self.is_open:
            return False
        return self._send(frame.to_slcan())

    def _send(self, data: bytes, force: bool = False) -> bool:
        with self._lock:
            # What the host has read since makes room first: a host that lagged and caught up
            # gets frames again (the sender calls nothing else that would flush the queue).
            self._flush_locked()
            if not force and len(self._out) + len(data) > OUT_LIMIT:
                self.dropped += 1
                return False
            self._out += data
            self._flush_locked()
        return True

    def flush(self) -> None:
        with self._lock:
            self._flush_locked()

    def _flush_locked(self) -> None:
        # Whole frames are queued; a partial write leaves the rest queued, so
        # the host never sees a frame cut in two.
        while self._out:
            try:
                n = os.write(self._master, self._out)
            except BlockingIOError:
                return
            except OSError:
                self._out.clear()
                return
            del self._out[:n]

    def close(self) -> None:
        if self.link:
            try:
                if os.path.islink(self.link) and os.readlink(self.link) == self.path:
                    os.unlink(self.link)
            except OSError:
                pass
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self._release()

    def _release(self) -> None:
        if self._claim is not None:
            self._claim.release()
            self._claim = None


class PtyCanBus:
    """Several SlcanPorts joined into one CAN bus, served by `serve()` or a thread."""

    def __init__(
        self, links: list[str | None], on_frame: Callable[[SlcanPort, CanFrame], object] | None = None
    ) -> None:
        self.ports: list[SlcanPort] = []
        try:
            for link in links:
                self.ports.append(SlcanPort(link))
        except BaseException:
            for port in self.ports:
                port.close()
            raise
        self.frames = 0
        self._on_frame = on_frame  # called with (port, frame) for every frame a host sends
        self._stop_r, self._stop_w = os.pipe()
        self._thread: threading.Thread | None = None

    def serve(self) -> None:
        """Forward frames until stop() is called."""
        sel = selectors.DefaultSelector()
        sel.register(self._stop_r, selectors.EVENT_READ)
        for port in self.ports:
            sel.register(port.fileno(), selectors.EVENT_READ, port)
        try:
            while True:
                for key, events in sel.select(timeout=0.05):
                    if key.data is None:
                        return
                    port = key.data
                    if events & selectors.EVENT_READ:
                        for frame in port.read_host():
                            self.frames += 1
                            if self._on_frame:
                                self._on_frame(port, frame)
                            for other in self.ports:
                                if other is not port:
                                    other.deliver(frame)
                # Hosts that lagged get the rest of their bytes as soon as they read.
                for port in self.ports:
                    if port.wants_write():
                        port.flush()
        finally:
            sel.close()

    def start(self) -> PtyCanBus:
        self._thread = threading.Thread(target=self.serve, name="pty-can-bus", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        os.write(self._stop_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for port in self.ports:
            port.close()
        for fd in (self._stop_r, self._stop_w):
            os.close(fd)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dockhil.devices.can_ft.slcan_pty",
        description="A CAN bus of emulated slcan adapters on pseudo-terminals: open each LINK "
        "with python-can's slcan interface; frames sent on one reach the others.",
    )
    parser.add_argument("links", nargs="+", metavar="LINK", help="symlink to create for each adapter")
    args = parser.parse_args(argv)
    from dockhil.errors import DockhilError
    from dockhil.log import Log

    try:
        bus = PtyCanBus(args.links)
    except OSError as exc:
        Log("slcan_pty:").error(f"cannot create adapter: {exc}")
        return 2
    except DockhilError as exc:
        Log("slcan_pty:").error(str(exc))
        return 2

    def _stop(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _stop)
    print("ready " + " ".join(f"{p.link}={p.path}" for p in bus.ports), flush=True)
    try:
        bus.serve()
    except KeyboardInterrupt:
        pass
    finally:
        bus.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
