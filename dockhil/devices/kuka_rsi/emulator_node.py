"""KUKA controller emulator node: RSI datagrams over UDP from its own clock, a servo behind them.

The controller's loop runs in a thread of its own from setup() to close();
step() has nothing to do. The loop and the servo are in
dockhil/devices/kuka_rsi/emulator.py.
"""

from __future__ import annotations

import time
from typing import Any

from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.errors import DeviceError, LaunchError
from dockhil.node import Node, Param, Tick

BIND = "127.0.0.1"  # the emulated controller's address


def _address(host: str) -> str:
    import socket

    try:
        return socket.gethostbyname(host)
    except OSError:
        return host


class RsiControllerEmulatorNode(Node):
    """Emulated KUKA controller running RSI: <Rob> every cycle, RKorr through a servo with delay and lag."""

    free_running = True  # a device: it runs from power-on, the driver's setup needs its datagrams

    params = {
        "host": Param(str, "127.0.0.1", help="the driver's address (the controller's IP_NUMBER)"),
        "port": Param(int, 49152, help="the driver's UDP port (the controller's PORT)", ge=1, le=65535),
        "cycle": Param(float, 0.004, unit="s", help="RSI cycle", choices=rsi.CYCLES),
        "delay": Param(
            float, 0.0, unit="s", help="servo delay: corrections take effect this much later", ge=0.0, le=10.0
        ),
        "tau": Param(float, 0.0, unit="s", help="servo first-order lag time constant (0: none)", ge=0.0, le=10.0),
        "timing": Param(
            str,
            "ours",
            help="ours: a correction is taken the cycle after it answers, on whole cycles, the pose read after "
            "the servo's step; immediate: taken as it arrives, followed `delay` later, the pose sampled "
            "before the step",
            choices=("ours", "immediate"),
        ),
        "max_late": Param(int, 100, help="late answers in a row that stop RSI", ge=1, le=1_000_000),
        "loss": Param(float, 0.0, unit="%", help="datagrams lost", ge=0.0, le=100.0),
        "duplicate": Param(float, 0.0, unit="%", help="datagrams sent twice", ge=0.0, le=100.0),
        "reorder": Param(float, 0.0, unit="%", help="datagrams sent after the next one", ge=0.0, le=100.0),
        "jitter": Param(
            float, 0.0, unit="s", help="send jitter, uniform up to this (below the cycle)", ge=0.0, lt=0.012
        ),
        "seed": Param(int, 0, help="seed of the faults"),
        "record": Param(str, "", help="write the maxima and counts as JSON here at close"),
        "controller": Param(
            str,
            "127.0.0.1",
            help="the controller address the driver reads (hil.yaml's "
            "rsi_host): this emulator's, 127.0.0.1; another means a real controller",
        ),
    }

    def setup(self) -> None:
        from dockhil.devices.kuka_rsi.emulator import RsiControllerEmulator

        p = self.p
        if p.jitter >= p.cycle:
            raise LaunchError(f"node {self.ctx.name!r}: jitter {p.jitter:g} s must be below the cycle {p.cycle:g} s")
        if _address(p.controller) != BIND:
            # The driver reads only that address: it would answer a real controller, and move a real robot,
            # while this graph emulates one.
            raise LaunchError(
                f"node {self.ctx.name!r}: the driver reads the controller at {p.controller}, but this "
                f"emulator sends from {BIND}: the driver would move a real robot; point rsi_host at "
                f"the emulator ({BIND}), or drop the emulator"
            )
        self._lock = rsi.claim_port(p.port)  # the port's graph: its driver may share it, no other graph
        try:
            self.emulator = RsiControllerEmulator(
                p.host,
                p.port,
                p.cycle,
                p.delay,
                p.tau,
                p.max_late,
                p.loss,
                p.duplicate,
                p.reorder,
                p.jitter,
                p.seed,
                bind=BIND,
                timing=p.timing,
            )
        except OSError as exc:
            self._lock.release()
            raise DeviceError(f"KUKA RSI emulator: cannot open a UDP socket: {exc.strerror or exc}") from None
        self.emulator.start_thread()
        self.log(f"KUKA RSI emulator sending to {p.host}:{p.port} every {p.cycle * 1000:g} ms")

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        emulator = getattr(self, "emulator", None)
        if emulator is None:
            return
        self.emulator = None
        closing = time.monotonic()
        emulator.stop_thread()
        self.log(f"KUKA RSI emulator: {emulator.account()}")
        if emulator.stopped:
            # A driver that ends before this emulator leaves it unanswered: at a graph's end that stop is the
            # end of the run (the driver says when the controller stopped RSI while it ran).
            self.log(
                f"warning: KUKA RSI emulator: RSI stopped after {emulator.max_late} late answers in a row, "
                f"{closing - emulator.stopped_at:.2f} s before the emulator closed"
            )
        if self.p.record:
            try:
                emulator.write_record(self.p.record)
            except OSError as exc:
                self.log(f"warning: KUKA RSI emulator: cannot write the record {self.p.record}: {exc.strerror or exc}")
        self._lock.release()
