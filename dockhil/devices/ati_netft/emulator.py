"""Net F/T box emulator: RDT over UDP and netftapi2.xml over HTTP, byte for byte as
dockhil/devices/ati_netft/protocol.py describes the protocol, with faults to inject.

The box answers start, stop and bias requests from any client and streams
records to the address and port of the latest start request, on its own clock
(records are due every 1/rate s; the sender wakes about every millisecond and
sends what is due). The wrench is the passive compliance against the probe's
position (dockhil.contact.hybrid.passive_force, the sensor model of every F/T
node) plus a dashpot while in contact, a bias and seeded noise: hidden truths
that the driver's tare and a calibration must find.

Faults, each drawn from one seeded generator: loss (records never sent),
duplicates (sent twice), reordering (sent after the next one), late records
(held back `late_delay` s, so newer ones overtake them; counted when they did), jitter (each send up to
`jitter` s after its due time) and a status word set from `fault_after` s into
the stream on. What the box did is counted in `stats()`, with the largest
force and torque it reported, and written as JSON to `maxima` at stop.

Run alone: python -m dockhil.devices.ati_netft.emulator --port 49152 --http-port 8080
(a probe position [m] per line on stdin moves the contact). It prints
"listening udp HOST:PORT http HOST:PORT" once both servers answer.
"""

from __future__ import annotations

import argparse
import heapq
import json
import math
import random
import signal
import socket
import sys
import threading
import time
from collections.abc import Sequence

from dockhil.devices.ati_netft import protocol as rdt

HTTP_DEFAULT = 8080  # the real box serves port 80, which only root may open here


class ContactModel:
    """The passive compliance k (and dashpot b while touching) against the probe's position along
    the docking axis, with a constant bias and seeded white noise: the wrench on the probe [N, N m]."""

    def __init__(
        self, k: float, b: float = 0.0, bias: float = 0.0, noise: float = 0.0, torque_noise: float = 0.0, seed: int = 0
    ):
        from dockhil.contact.hybrid import passive_force

        self._passive = passive_force
        self.k, self.b, self.bias, self.noise, self.torque_noise = k, b, bias, noise, torque_noise
        self.rng = random.Random(seed)
        self.x: float | None = None  # probe position [m] (x > 0: penetration); None: no pose yet
        self.v = 0.0

    def set_pose(self, x: float | None, v: float = 0.0) -> None:
        self.x, self.v = x, v

    def wrench(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        x, v = self.x, self.v
        compression = 0.0
        if x is not None and x > 0.0:
            # the sheet pushes, never pulls: the dashpot may slow a release, not reverse the force
            compression = max(0.0, self._passive(x, self.k) + self.b * v)
        gauss, sd, td = self.rng.gauss, self.noise, self.torque_noise
        force = (
            -compression + self.bias + (gauss(0.0, sd) if sd else 0.0),
            gauss(0.0, sd) if sd else 0.0,
            gauss(0.0, sd) if sd else 0.0,
        )
        torque = (gauss(0.0, td) if td else 0.0, gauss(0.0, td) if td else 0.0, gauss(0.0, td) if td else 0.0)
        return force, torque


class NetFtBox:
    """The emulated box: UDP RDT server on (host, port), HTTP server on (host, http_port)."""

    def __init__(
        self,
        model: ContactModel,
        host: str = "127.0.0.1",
        port: int = rdt.RDT_PORT,
        http_port: int = HTTP_DEFAULT,
        rate: float = 1000.0,
        counts_per_force: float = 1_000_000.0,
        counts_per_torque: float = 1_000_000.0,
        force_unit: str = "N",
        torque_unit: str = "Nm",
        seed: int = 0,
        loss: float = 0.0,
        duplicate: float = 0.0,
        reorder: float = 0.0,
        late: float = 0.0,
        late_delay: float = 0.05,
        jitter: float = 0.0,
        fault_after: float = -1.0,
        fault_status: int = 0x80020000,
        maxima: str = "",
    ):
        if not 0.0 < rate <= rdt.MAX_RDT_RATE:
            raise ValueError(f"rate {rate!r} Hz: the box streams at most {rdt.MAX_RDT_RATE:g} Hz")
        for name, value in (("loss", loss), ("duplicate", duplicate), ("reorder", reorder), ("late", late)):
            if not 0.0 <= value <= 100.0:
                raise ValueError(f"{name} {value!r}: a percentage, 0 to 100")
        if not (late_delay >= 0.0 and jitter >= 0.0):
            raise ValueError(f"late_delay {late_delay!r} s and jitter {jitter!r} s must be >= 0")
        self.calibration = rdt.Calibration(counts_per_force, counts_per_torque, force_unit, torque_unit)
        self.model = model
        self.host, self.port, self.http_port, self.rate = host, port, http_port, rate
        self.loss, self.duplicate, self.reorder, self.late = loss / 100, duplicate / 100, reorder / 100, late / 100
        self.late_delay, self.jitter = late_delay, jitter
        self.fault_after, self.fault_status, self.maxima_path = fault_after, fault_status, maxima
        self.rng = random.Random(seed + 1)  # apart from the noise's generator: faults do not change the noise
        self._lock = threading.Lock()
        self._client: tuple[str, int] | None = None  # (address, port) of the latest start request
        self._remaining = 0  # records left of a counted request (0: until stopped)
        self._stream_t0 = 0.0
        self._seq = 0
        self._next_due = 0.0
        self._bias_counts = (0,) * 6
        self._held: tuple[bytes, tuple[str, int] | None] | None = (
            None  # a record held back to be sent after the next (reordering)
        )
        self._later: list = []  # heap of (send time, rdt_sequence, late?, datagram, address)
        self._sent_seq = 0  # the newest rdt_sequence sent in this stream
        self._lost_tail = 0  # records lost since the last one that went out
        self._jitter_t = 0.0
        self._boot = time.monotonic()
        self._running = False
        self.counts = {
            "requests": 0,
            "bad_requests": 0,
            "starts": 0,
            "stops": 0,
            "biases": 0,
            "records": 0,
            "sent": 0,
            "lost": 0,
            "duplicated": 0,
            "reordered": 0,
            "late": 0,
            "faulty": 0,
            "saturated": 0,
        }
        self.max_force = [0.0, 0.0, 0.0]  # largest |F| per axis the box reported [N]
        self.max_torque = [0.0, 0.0, 0.0]

    # -- life cycle -------------------------------------------------------------------
    def start_thread(self) -> NetFtBox:
        from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.udp.bind((self.host, self.port))
            self.port = self.udp.getsockname()[1]
            self.udp.settimeout(0.001)
            box = self

            class Handler(BaseHTTPRequestHandler):
                def do_GET(self):
                    if self.path.split("?", 1)[0] != "/netftapi2.xml":
                        self.send_error(404)
                        return
                    body = box.xml().encode()
                    self.send_response(200)
                    self.send_header("Content-Type", "text/xml")
                    self.send_header("Content-Length", str(len(body)))
                    self.end_headers()
                    self.wfile.write(body)

                def log_message(self, *args):  # a web server's access log is not the box's business
                    pass

            self.http = ThreadingHTTPServer((self.host, self.http_port), Handler)
        except OSError:
            self.udp.close()
            raise
        self.http.daemon_threads = True
        self.http_port = self.http.server_address[1]
        self._running = True
        self._threads = [
            threading.Thread(target=self._serve_rdt, name="netft-rdt", daemon=True),
            threading.Thread(
                target=self.http.serve_forever, kwargs={"poll_interval": 0.05}, name="netft-http", daemon=True
            ),
        ]
        for thread in self._threads:
            thread.start()
        return self

    def stop_thread(self) -> None:
        if not self._running:
            return
        self._running = False
        self.http.shutdown()
        self.http.server_close()
        for thread in self._threads:
            thread.join(timeout=5.0)
        self.udp.close()
        if self.maxima_path:
            with open(self.maxima_path, "w") as f:
                json.dump(self.stats(), f, indent=1)

    def stats(self) -> dict:
        with self._lock:
            # lost_unseen: the lost records after the last one sent, which no sequence can show
            return {
                **self.counts,
                "lost_unseen": self._lost_tail,
                "max_abs_force_N": list(self.max_force),
                "max_abs_torque_Nm": list(self.max_torque),
                "rate_Hz": self.rate,
                "calibration": self.calibration.describe(),
            }

    def xml(self) -> str:
        """netftapi2.xml as the box serves it (the elements a client reads, in the box's spelling)."""
        c = self.calibration
        fu = next((code for code, name in rdt.FORCE_CODES.items() if name == c.force_unit), 0)
        tu = next((code for code, name in rdt.TORQUE_CODES.items() if name == c.torque_unit), 0)
        return (
            '<?xml version="1.0" encoding="utf-8"?>\r\n<netft>\r\n'
            f"<runstat>0x{self.status_now():08X}</runstat><runrate>{rdt.INTERNAL_RATE:.0f}</runrate>\r\n"
            "<cfgnam>dockhil emulator</cfgnam><cfgcalsel>0</cfgcalsel><cfgcalsn>FT-EMULATED</cfgcalsn>\r\n"
            f"<cfgfu>{fu}</cfgfu><cfgtu>{tu}</cfgtu>\r\n"
            f"<scfgfu>{c.force_unit}</scfgfu><scfgtu>{c.torque_unit}</scfgtu>\r\n"
            f"<cfgcpf>{c.counts_per_force:g}</cfgcpf><cfgcpt>{c.counts_per_torque:g}</cfgcpt>\r\n"
            "<setuserfilter>0</setuserfilter>\r\n"
            f"<comrdte>Enabled</comrdte><comrdtrate>{self.rate:g}</comrdtrate><comrdtbsiz>1</comrdtbsiz>\r\n"
            "</netft>\r\n"
        )

    def status_now(self) -> int:
        if (
            self.fault_after >= 0
            and self._client is not None
            and time.monotonic() - self._stream_t0 >= self.fault_after
        ):
            return self.fault_status
        return 0

    # -- the box's loop -----------------------------------------------------------------
    def _serve_rdt(self) -> None:
        from dockhil.log import Log
        from dockhil.runtime import realtime

        realtime.raise_device_thread(
            Log("netft emulator:").warning, "the Net F/T emulator's stream"
        )  # it stands for the box
        while self._running:
            try:
                data, address = self.udp.recvfrom(2048)
            except TimeoutError:
                data = None
            except OSError:
                if not self._running:
                    return
                data = None
            if data is not None:
                self._request(data, address)
            self._send_due(time.monotonic())

    def _request(self, data: bytes, address: tuple[str, int]) -> None:
        try:
            command, count = rdt.decode_request(data)
        except rdt.RdtError:
            self.counts["bad_requests"] += 1
            return
        with self._lock:
            self.counts["requests"] += 1
            if command == rdt.CMD_START:
                self.counts["starts"] += 1
                self._client, self._remaining = address, count
                self._seq = self._sent_seq = 0  # rdt_sequence starts again with every stream
                self._stream_t0 = self._next_due = time.monotonic()
                self._held = None
            elif command == rdt.CMD_STOP:
                self.counts["stops"] += 1
                if self._held is not None:  # the record held back goes now, the last: in order after all
                    heapq.heappush(self._later, (time.monotonic(), self._seq, False, *self._held))
                    self._held = None
                    self.counts["reordered"] -= 1
                self._client = None
            elif command == rdt.CMD_BIAS:
                self.counts["biases"] += 1
                self._bias_counts = self._raw_counts(*self.model.wrench())[0]
            else:
                self.counts["bad_requests"] += 1

    def _raw_counts(self, force: Sequence[float], torque: Sequence[float]) -> tuple[tuple, bool]:
        c = self.calibration
        scaled = [f / c.newtons_per_count for f in force] + [t / c.newton_metres_per_count for t in torque]
        counts, saturated = [], False
        for value in scaled:
            n = round(value) if math.isfinite(value) else 0
            if not rdt.INT32[0] <= n <= rdt.INT32[1]:
                n, saturated = max(rdt.INT32[0], min(rdt.INT32[1], n)), True
            counts.append(n)
        return tuple(counts), saturated

    def _send_due(self, now: float) -> None:
        sends = []
        with self._lock:
            while self._later and self._later[0][0] <= now:
                _, seq, late, datagram, address = heapq.heappop(self._later)
                if late and seq < self._sent_seq:
                    self.counts["late"] += 1  # it did arrive after newer ones
                self._sent_seq = max(self._sent_seq, seq)
                sends.append((datagram, address))
            while self._client is not None and self._next_due <= now:
                out = self._record(now, self._next_due)
                if out:  # the newest record went out (a held one may go with it)
                    self._sent_seq = max(self._sent_seq, self._seq)
                sends.extend(out)
                self._next_due += 1.0 / self.rate
                if self._remaining:
                    self._remaining -= 1
                    if self._remaining == 0:
                        self._client = None
        sent = 0
        for datagram, address in sends:
            try:
                self.udp.sendto(datagram, address)
                sent += 1
            except OSError:  # nobody listening there (yet): a box keeps streaming
                pass
        if sent:
            with self._lock:
                self.counts["sent"] += sent

    def _record(self, now: float, due: float) -> list:
        """The next record of the stream; the datagrams to send now (faults applied)."""
        self._seq += 1
        self.counts["records"] += 1
        force, torque = self.model.wrench()
        counts, saturated = self._raw_counts(force, torque)
        counts = tuple(max(rdt.INT32[0], min(rdt.INT32[1], a - b)) for a, b in zip(counts, self._bias_counts))
        status = self.status_now() | (rdt.STATUS_SATURATED if saturated else 0)
        self.counts["faulty"] += bool(status)
        self.counts["saturated"] += saturated
        c = self.calibration
        for i in range(3):
            self.max_force[i] = max(self.max_force[i], abs(counts[i] * c.newtons_per_count))
            self.max_torque[i] = max(self.max_torque[i], abs(counts[3 + i] * c.newton_metres_per_count))
        ft_seq = round((due - self._boot) * rdt.INTERNAL_RATE)  # the internal sample it was due at
        datagram = (rdt.encode_record(self._seq, ft_seq, status, counts), self._client)
        draw = self.rng.random
        if self.loss and draw() < self.loss:
            self.counts["lost"] += 1
            self._lost_tail += 1
            return []
        self._lost_tail = 0
        if self.late and draw() < self.late:
            heapq.heappush(self._later, (now + self.late_delay, self._seq, True, *datagram))
            return []
        out = [datagram]
        if self.duplicate and draw() < self.duplicate:
            self.counts["duplicated"] += 1
            out.append(datagram)
        if self._held is not None:
            out.append(self._held)  # the held record goes after this newer one
            self._held = None
        elif self.reorder and draw() < self.reorder:
            self.counts["reordered"] += 1
            self._held = datagram
            out = out[1:]  # a duplicate of it still goes now
        if self.jitter and out:
            # sent up to `jitter` late, in order: a late send delays those after it, never swaps them
            self._jitter_t = max(self._jitter_t, now + draw() * self.jitter)
            for item in out:
                heapq.heappush(self._later, (self._jitter_t, self._seq, False, *item))
            return []
        return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dockhil.devices.ati_netft.emulator",
        description="ATI Net F/T box emulator: RDT over UDP, netftapi2.xml over HTTP.",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on")
    parser.add_argument("--port", type=int, default=rdt.RDT_PORT, help="UDP port of RDT (0: any free port)")
    parser.add_argument(
        "--http-port",
        type=int,
        default=HTTP_DEFAULT,
        help="TCP port of netftapi2.xml (the real box: 80; 0: any free port)",
    )
    parser.add_argument("--rate", type=float, default=1000.0, help="RDT records a second (at most 7000)")
    parser.add_argument("--counts-per-force", type=float, default=1_000_000.0)
    parser.add_argument("--counts-per-torque", type=float, default=1_000_000.0)
    parser.add_argument("--force-unit", default="N", help="N, lbf, klbf, kN, kgf, gf")
    parser.add_argument("--torque-unit", default="Nm", help="Nm, Nmm, lbf-in, lbf-ft, kgf-cm, kNm")
    parser.add_argument("--k", type=float, default=1000.0, help="passive stiffness [N/m]")
    parser.add_argument("--b", type=float, default=0.0, help="passive damping [N s/m]")
    parser.add_argument("--bias", type=float, default=0.0, help="offset on Fx [N]")
    parser.add_argument("--noise", type=float, default=0.0, help="force noise standard deviation [N]")
    parser.add_argument("--position", type=float, default=0.0, help="probe position [m] (x > 0: penetration)")
    parser.add_argument("--seed", type=int, default=0)
    for name, what in (
        ("loss", "records never sent"),
        ("duplicate", "records sent twice"),
        ("reorder", "records sent after the next"),
        ("late", "records held back --late-delay"),
    ):
        parser.add_argument(f"--{name}", type=float, default=0.0, help=f"percent of {what}")
    parser.add_argument("--late-delay", type=float, default=0.05, help="[s]")
    parser.add_argument("--jitter", type=float, default=0.0, help="sends up to this late [s]")
    parser.add_argument("--fault-after", type=float, default=-1.0, help="status fault from this time into a stream [s]")
    parser.add_argument("--maxima", default="", help="JSON file for the box's counts and maxima, written at exit")
    args = parser.parse_args(argv)
    from dockhil.log import Log

    say = Log("netft emulator:")
    model = ContactModel(args.k, args.b, args.bias, args.noise, seed=args.seed)
    model.set_pose(args.position)
    try:
        box = NetFtBox(
            model,
            args.host,
            args.port,
            args.http_port,
            args.rate,
            args.counts_per_force,
            args.counts_per_torque,
            args.force_unit,
            args.torque_unit,
            args.seed,
            args.loss,
            args.duplicate,
            args.reorder,
            args.late,
            args.late_delay,
            args.jitter,
            args.fault_after,
            maxima=args.maxima,
        )
    except ValueError as exc:  # an argument out of its range (rdt.RdtError too: units, counts per unit)
        say.error(str(exc))
        return 2
    try:
        box.start_thread()
    except OSError as exc:
        say.error(f"cannot listen on {args.host} (udp {args.port}, http {args.http_port}): {exc.strerror or exc}")
        return 2
    print(f"listening udp {box.host}:{box.port} http {box.host}:{box.http_port}", flush=True)
    signal.signal(signal.SIGTERM, _interrupt)  # a terminated box still writes its maxima
    try:
        for line in sys.stdin:
            try:
                model.set_pose(float(line))
            except ValueError:
                say.warning(f"not a position: {line.strip()!r}")
        while True:  # stdin closed: serve until interrupted
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        box.stop_thread()
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt


if __name__ == "__main__":
    sys.exit(main())
