"""KUKA controller emulator running RSI: sends <Rob> each cycle from its own clock, applies RKorr.

As a controller with an RSI context of ETHERNET (the datagram of
dockhil/devices/kuka_rsi/protocol.py: RIst, RSol, Delay, IPOC) and an absolute Cartesian
correction in BASE (docs/hardware.md):

- every `cycle` it sends one datagram to the sensor's address and port, IPOC
  its millisecond timestamp; the answer carrying that IPOC must arrive within
  the cycle (judged on the kernel's receive timestamp, so an emulator that
  wakes late does not blame the sensor);
- an answer in time sets the correction (absolute, from the start pose) from the
  next cycle on, the one that takes it; a late
  or missing one keeps the last correction (HOLDON) and counts in Delay D, also
  in a cycle this emulator itself sent too late to judge (`unjudged`, not the
  sensor's late answer): D tells the sensor every correction not taken;
  `max_late` late answers in a row stop RSI: it sends nothing more, as a
  controller does. The count starts at the first answer (the operator starts
  the RSI program once the sensor listens);
- the commanded pose start + correction reaches the robot through a servo with
  a pure delay and a first-order lag (hidden truths: `delay`, `tau`), position
  and orientation (a slerp toward the target, as robot_emulator's servo). When,
  inside the controller, the cycles are spent is `timing` (a driver cannot know
  it; both are plausible, and calibrate must hold on either):
  `ours`: the correction is taken by the cycle after the one it answers, its
  delay counts from there on whole cycles, and a datagram carries the pose after
  the servo's step over the cycle before (the loop is up to two cycles longer);
  `immediate`: the correction is taken as it arrives, the servo follows it
  `delay` later in continuous time (a drive behind the cycle: any delay, not
  whole cycles), and a datagram carries the pose sampled at its cycle, before
  the servo's step over it;
- faults: datagram loss, duplicates and reordering (percent, seeded), send
  jitter (uniform, up to `jitter` seconds).

It records its maxima (largest TCP speed and angular speed, largest
correction step in a cycle) and the answers' latencies (late ones too, if
they come at all), and writes them as JSON at exit (`record`), for tests and
the bench.

Run alone: python -m dockhil.devices.kuka_rsi.emulator --port 49152 [--delay S --tau S --duration S]
"""

from __future__ import annotations

import argparse
import json
import math
import random
import signal
import socket
import struct
import sys
import threading
import time
from collections import deque

from dockhil.contact.rotations import quat_conjugate, quat_from_rotvec, quat_multiply, rotvec3
from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.servo_line import follow_due
from dockhil.runtime.histogram import Histogram

START_POSE = (500.0, 0.0, 900.0, 180.0, 0.0, 180.0)  # mm, degrees: a TCP in front of the robot, pointing down
# The kernel's receive time of each answer (Python's socket module names the option from 3.13 on; 35 is
# Linux's number on x86 and ARM): an answer is judged by when it came, not by when this thread woke.
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35 if sys.platform == "linux" else None)
DEFAULT_MAX_LATE = 100  # late answers in a row before RSI stops (the ETHERNET object's Timeout)


def _normalised(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


MAX_LOST_KEPT = 100_000  # lost IPOCs the record lists: a driver's count is checked against them


TIMINGS = ("ours", "immediate")  # where inside the controller its cycles are spent (module docstring)


class RsiServo:
    """The robot behind the controller: start pose + correction, through a delay and a first-order lag. No I/O.

    `timing` ours: a correction in force from `now` becomes the target at the first advance at or after
    now + delay, and the pose moves toward it over the cycle after. immediate: the target switches at
    now + delay exactly and the pose follows it in continuous time (exact for a first-order lag), so
    advance(t) leaves the pose of time t."""

    def __init__(self, start=START_POSE, delay: float = 0.0, tau: float = 0.0, timing: str = "ours"):
        if timing not in TIMINGS:
            raise ValueError(f"timing {timing!r}: one of {', '.join(TIMINGS)}")
        self.timing = timing
        self.start_p = tuple(start[:3])
        self.start_q = rsi.abc_to_quat(*start[3:])
        self.delay = delay
        self.tau = tau
        self.position = list(self.start_p)
        self.orientation = self.start_q
        self.setpoint = (self.start_p, self.start_q)  # what the correction commands now
        self._target = self.setpoint  # what the servo follows now (the setpoint, `delay` later)
        self._line: deque = deque()
        self._last_t: float | None = None

    def correct(self, korr, now: float) -> None:
        """The correction X Y Z (mm) A B C (degrees) in force from `now`."""
        p = self.start_p
        q = _normalised(quat_multiply(rsi.abc_to_quat(*korr[3:]), self.start_q))
        self.setpoint = ((p[0] + korr[0], p[1] + korr[1], p[2] + korr[2]), q)
        self._line.append((now, self.setpoint))

    def advance(self, now: float) -> None:
        """ours: move over the cycle that ends now toward the target held during it (a zero-order hold), then
        take the targets due. immediate: follow each target from the moment it is due, up to now."""
        if self.timing == "immediate":
            t = now if self._last_t is None else self._last_t
            follow_due(self._line, self.delay, t, now, self._follow, self._set_target)
            self._last_t = now
            return
        dt = 0.0 if self._last_t is None else now - self._last_t
        self._last_t = now
        self._follow(dt)
        while self._line and self._line[0][0] <= now - self.delay + 1e-12:
            self._target = self._line.popleft()[1]

    def _set_target(self, target: tuple) -> None:
        self._target = target

    def _follow(self, dt: float) -> None:
        """The first-order lag toward the target over dt (exact for a target held over it)."""
        a = 1.0 if self.tau == 0 else (1.0 - math.exp(-dt / self.tau) if dt > 0 else 0.0)
        tp, tq = self._target
        self.position = [x + a * (t - x) for x, t in zip(self.position, tp)]
        error = rotvec3(quat_multiply(tq, quat_conjugate(self.orientation)))
        self.orientation = _normalised(quat_multiply(quat_from_rotvec([a * e for e in error]), self.orientation))

    def rist(self) -> tuple:
        return (*self.position, *rsi.quat_to_abc(self.orientation))

    def rsol(self) -> tuple:
        p, q = self.setpoint
        return (*p, *rsi.quat_to_abc(q))


class RsiControllerEmulator:
    """The controller's RSI loop over UDP, in a thread (start_thread/stop_thread) or in the caller (run)."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 49152,
        cycle: float = 0.004,
        delay: float = 0.0,
        tau: float = 0.0,
        max_late: int = DEFAULT_MAX_LATE,
        loss: float = 0.0,
        duplicate: float = 0.0,
        reorder: float = 0.0,
        jitter: float = 0.0,
        seed: int = 0,
        start=START_POSE,
        bind: str = "127.0.0.1",
        ipoc0: int = 1_000_000,
        timing: str = "ours",
    ):
        self.host, self.port, self.cycle = host, port, cycle
        self.max_late = max_late
        self.loss, self.duplicate, self.reorder, self.jitter = loss / 100.0, duplicate / 100.0, reorder / 100.0, jitter
        self.rng = random.Random(seed)
        self.servo = RsiServo(start, delay, tau, timing)
        self.cycle_ms = round(cycle * 1000)
        self.ipoc = ipoc0
        self.korr = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self.stopped = False  # RSI stopped: too many late answers
        self.stopped_at = 0.0  # when (monotonic)
        self.armed = False  # the first answer came: late answers count from now on
        self.lost_ipocs: list[int] = []  # which cycles' datagrams were lost (the first MAX_LOST_KEPT)
        # when the late cycles' datagrams went (CLOCK_MONOTONIC, s; the first MAX_LOST_KEPT): to line them
        # up with a scheduler trace or the graph's logs
        self.late_sent_at: list[float] = []
        self.stats = {
            "cycles": 0,
            "sent": 0,
            "lost": 0,
            "duplicated": 0,
            "reordered": 0,
            "answered": 0,
            "late": 0,
            "late_in_a_row_max": 0,
            "unjudged": 0,  # cycles this emulator itself sent too late to judge the answer
            "bad_answers": 0,
            "stray_answers": 0,
            "max_speed": 0.0,
            "max_angular_speed": 0.0,
            "max_step_mm": 0.0,
            "max_step_deg": 0.0,
        }
        self.latencies = Histogram()  # send to answer arrival [s], on time or late
        self._sent_at: dict[int, float] = {}  # IPOC -> when its datagram was sent (Unix time), recent ones
        self._answered_late: dict[int, bool] = {}
        self._late_in_a_row = 0
        self._held_back: bytes | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((bind, 0))
        self._stamped = SO_TIMESTAMPNS is not None
        if self._stamped:
            self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)

    # -- one cycle ----------------------------------------------------------------------
    def _send(self, data: bytes) -> None:
        rng = self.rng
        if self.loss and rng.random() < self.loss:
            self.stats["lost"] += 1
            if len(self.lost_ipocs) < MAX_LOST_KEPT:
                self.lost_ipocs.append(self.ipoc)
            return
        if self.reorder and self._held_back is None and rng.random() < self.reorder:
            self._held_back = data  # goes out after the next one
            self.stats["reordered"] += 1
            return
        out = [data]
        if self.duplicate and rng.random() < self.duplicate:
            out.append(data)
            self.stats["duplicated"] += 1
        if self._held_back is not None:
            out.append(self._held_back)
            self._held_back = None
        for d in out:
            try:
                self.sock.sendto(d, (self.host, self.port))
            except OSError:
                pass  # nobody listening yet: a controller keeps its cycle
        self.stats["sent"] += 1

    def _receive(self, deadline: float):
        """One datagram before `deadline` (monotonic): (data, sender host, arrival in Unix time) or None."""
        # Past the deadline, what is already queued is still read: the kernel's arrival time judges it, not
        # when this thread woke (a busy machine may wake it late with the answer waiting since on time).
        self.sock.settimeout(max(0.0, deadline - time.monotonic()))
        try:
            if self._stamped:
                data, anc, _flags, addr = self.sock.recvmsg(rsi.MAX_DATAGRAM + 1, 64)
                arrival = time.time()
                for level, kind, payload in anc:
                    if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= 16:
                        sec, nsec = struct.unpack("qq", payload[:16])
                        arrival = sec + nsec * 1e-9
                return data, addr[0], arrival
            data, addr = self.sock.recvfrom(rsi.MAX_DATAGRAM + 1)
            return data, addr[0], time.time()
        except (TimeoutError, BlockingIOError):
            return None
        except OSError:
            return None

    def _apply(self, korr, now: float) -> None:
        step_mm = math.dist(korr[:3], self.korr[:3])
        q_old, q_new = rsi.abc_to_quat(*self.korr[3:]), rsi.abc_to_quat(*korr[3:])
        x, y, z, w = quat_multiply(q_new, quat_conjugate(q_old))
        step_deg = math.degrees(2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w)))
        s = self.stats
        s["max_step_mm"] = max(s["max_step_mm"], step_mm)
        s["max_step_deg"] = max(s["max_step_deg"], step_deg)
        self.korr = korr
        self.servo.correct(korr, now)

    def cycle_once(self, slot_start: float) -> None:
        """Cycle: move the robot, send its datagram, wait until the cycle ends for the answer."""
        s = self.stats
        before = (list(self.servo.position), self.servo.orientation, self.servo._last_t)
        self.servo.advance(slot_start)
        if before[2] is not None and slot_start > before[2]:
            dt = slot_start - before[2]
            turn = rotvec3(quat_multiply(self.servo.orientation, quat_conjugate(before[1])))
            s["max_speed"] = max(s["max_speed"], math.dist(self.servo.position, before[0]) / 1000.0 / dt)
            s["max_angular_speed"] = max(s["max_angular_speed"], math.sqrt(sum(c * c for c in turn)) / dt)
        s["cycles"] += 1
        if self.jitter:
            time.sleep(self.rng.uniform(0.0, self.jitter))
        ipoc = self.ipoc
        data = rsi.build_rob(ipoc, self.servo.rist(), self.servo.rsol(), s["late"] + s["unjudged"])
        sent_at, sent_mono = time.time(), time.monotonic()
        self._send(data)
        answered_late = self._answered_late
        self._sent_at[ipoc] = sent_at
        if len(self._sent_at) > 64:  # an answer later than that is not waited for
            oldest = min(self._sent_at)
            del self._sent_at[oldest]
            answered_late.pop(oldest, None)
        deadline = slot_start + self.cycle
        answered = False
        while True:
            got = self._receive(deadline)
            if got is None:
                break
            payload, sender, arrival = got
            if sender != self.host:
                continue  # a controller reads only its sensor's address
            try:
                answer_ipoc, korr = rsi.parse_sen(payload)
            except rsi.RsiError:
                s["bad_answers"] += 1
                continue
            self.armed = True  # the sensor answers: late answers count from now on
            if answer_ipoc != ipoc or answered or arrival - sent_at > self.cycle:
                s["stray_answers"] += 1
                if answer_ipoc in self._sent_at and not answered_late.get(answer_ipoc):
                    answered_late[answer_ipoc] = True
                    self.latencies.add(arrival - self._sent_at[answer_ipoc])  # late, but it came
                continue
            answered = True
            s["answered"] += 1
            self.latencies.add(arrival - sent_at)
            if self.servo.timing == "immediate":  # taken as it arrives (on the monotonic clock)
                self._apply(korr, sent_mono + (arrival - sent_at))
            else:
                # the next cycle takes it (this one's interpolation has run): the servo's delay counts from
                # there, as the Modbus controller's counts from the cycle that takes a setpoint
                self._apply(korr, slot_start + self.cycle)
        if self.armed and not answered and deadline - sent_mono < 0.5 * self.cycle:
            # this emulator sent so late (its thread woken late on a busy machine) that the sensor had less
            # than half a cycle: the cycle is not the sensor's to answer for, and the next one keeps the slot
            s["unjudged"] += 1
        elif self.armed and not answered:
            s["late"] += 1
            if len(self.late_sent_at) < MAX_LOST_KEPT:
                self.late_sent_at.append(sent_mono)
            self._late_in_a_row += 1
            s["late_in_a_row_max"] = max(s["late_in_a_row_max"], self._late_in_a_row)
            if self._late_in_a_row >= self.max_late:
                self.stopped = True
                self.stopped_at = time.monotonic()
        elif answered:
            self._late_in_a_row = 0
        self.ipoc += self.cycle_ms

    def run(self, duration: float | None = None) -> None:
        """Cycles on the monotonic clock until stopped, RSI stops, or `duration` seconds have passed."""
        from dockhil.log import Log
        from dockhil.runtime import realtime

        # It stands for the controller: its cycle is the device's clock, above the node loops.
        realtime.raise_device_thread(Log("rsi emulator:").warning, "the RSI controller emulator's cycle")
        t0 = next_t = time.monotonic()
        while not self._stop.is_set() and not self.stopped:
            if duration is not None and next_t - t0 >= duration:
                break
            self.cycle_once(next_t)
            next_t += self.cycle
            behind = time.monotonic() - next_t
            if behind > self.cycle:  # the emulator itself fell behind: skip the slots, as the IPOC does
                skipped = int(behind // self.cycle)
                next_t += skipped * self.cycle
                self.ipoc += skipped * self.cycle_ms

    # -- in a thread ----------------------------------------------------------------------
    def start_thread(self, duration: float | None = None) -> None:
        self._thread = threading.Thread(target=self.run, args=(duration,), name="rsi-emulator", daemon=True)
        self._thread.start()

    def stop_thread(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.sock.close()

    def account(self) -> str:
        """The cycles in one line: answered in time, late while the sensor answered, late at the end once
        its answers stopped (a driver that closed first), and this emulator's own stalls."""
        s = self.stats
        trailing = self._late_in_a_row  # after the last answer in time: at a graph's end, the driver had closed
        return (
            f"{s['cycles']} cycles: {s['answered']} answered in time, {s['late'] - trailing} late, then "
            f"{trailing} unanswered at the end; {s['unjudged']} sent too late by this emulator to judge"
        )

    def record(self) -> dict:
        lat = self.latencies
        ms = lambda v: None if v is None else round(v * 1000.0, 4)  # noqa: E731
        return {
            **self.stats,
            "delay": self.stats["late"] + self.stats["unjudged"],  # D: every answer not taken
            "stopped": self.stopped,
            "cycle": self.cycle,
            "lost_ipocs": self.lost_ipocs,
            "late_sent_at": self.late_sent_at,
            "latency_ms": {
                "p50": ms(lat.percentile(50)),
                "p99": ms(lat.percentile(99)),
                "max": ms(lat.max if lat.count else None),
            },
        }

    def write_record(self, path: str) -> None:
        with open(path, "w") as f:
            json.dump(self.record(), f)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dockhil.devices.kuka_rsi.emulator",
        description="KUKA controller emulator running RSI (XML over UDP).",
    )
    parser.add_argument("--host", default="127.0.0.1", help="the sensor's (driver's) address")
    parser.add_argument("--port", type=int, default=49152, help="the sensor's UDP port")
    parser.add_argument("--bind", default="127.0.0.1", help="this controller's address")
    parser.add_argument("--cycle", type=float, default=0.004, choices=rsi.CYCLES, help="RSI cycle [s]")
    parser.add_argument("--delay", type=float, default=0.0, help="servo delay [s]")
    parser.add_argument("--tau", type=float, default=0.0, help="servo lag time constant [s]")
    parser.add_argument(
        "--timing", choices=TIMINGS, default="ours", help="when a correction is taken and the pose sampled"
    )
    parser.add_argument("--max-late", type=int, default=DEFAULT_MAX_LATE, help="late answers in a row that stop RSI")
    parser.add_argument("--loss", type=float, default=0.0, help="datagrams lost [percent]")
    parser.add_argument("--duplicate", type=float, default=0.0, help="datagrams sent twice [percent]")
    parser.add_argument("--reorder", type=float, default=0.0, help="datagrams sent after the next [percent]")
    parser.add_argument("--jitter", type=float, default=0.0, help="send jitter, uniform up to [s]")
    parser.add_argument("--seed", type=int, default=0, help="seed of the faults")
    parser.add_argument(
        "--start",
        type=float,
        nargs=6,
        default=START_POSE,
        metavar=("X", "Y", "Z", "A", "B", "C"),
        help="start pose of the TCP [mm, degrees]",
    )
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--record", default="", help="write the maxima and counts as JSON here at exit")
    parser.add_argument("--realtime", action="store_true", help="ask for SCHED_FIFO scheduling")
    args = parser.parse_args(argv)
    from dockhil.log import Log

    say = Log("rsi emulator:")
    problems = [
        f"--{name} {getattr(args, name.replace('-', '_'))} must be within 0 to 100"
        for name in ("loss", "duplicate", "reorder")
        if not 0 <= getattr(args, name) <= 100
    ]
    problems += [f"--{name} must be >= 0" for name in ("delay", "tau", "jitter") if getattr(args, name) < 0]
    problems += [f"--{name} must be at most 10 s" for name in ("delay", "tau") if getattr(args, name) > 10]
    if args.jitter >= args.cycle:
        problems.append(f"--jitter {args.jitter:g} must be below the cycle {args.cycle:g} s")
    if args.max_late < 1:
        problems.append("--max-late must be >= 1")
    if problems:
        say.error(problems[0])
        return 2
    if args.realtime:
        from dockhil.runtime import realtime

        realtime.ask(realtime.DEVICE_PRIORITY, "the RSI controller emulator", say.warning)
    try:
        emulator = RsiControllerEmulator(
            args.host,
            args.port,
            args.cycle,
            args.delay,
            args.tau,
            args.max_late,
            args.loss,
            args.duplicate,
            args.reorder,
            args.jitter,
            args.seed,
            tuple(args.start),
            args.bind,
            timing=args.timing,
        )
    except OSError as exc:
        say.error(f"cannot open a UDP socket on {args.bind}: {exc.strerror or exc}")
        return 2
    signal.signal(signal.SIGTERM, lambda *_: emulator._stop.set())
    print(f"sending to {args.host}:{args.port} every {args.cycle * 1000:g} ms", flush=True)
    try:
        emulator.run(args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        emulator.sock.close()
    if args.record:
        try:
            emulator.write_record(args.record)
        except OSError as exc:
            say.error(f"cannot write the record {args.record}: {exc.strerror or exc}")
            return 1
    if emulator.stopped:
        say.error(f"RSI stopped: {emulator.max_late} late answers in a row")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
