"""The node API: a node is a step function with declared, typed ports.

A node class declares `inputs`, `outputs` and `params` and implements
`step(tick, inputs) -> outputs`. It never opens sockets, reads clocks or
sleeps: the runtime owns transport and time, so the same class runs as its
own process, composed with others in one process, in sim time or wall time.

    class Gain(Node):
        '''Multiplies a wrench by a gain.'''
        inputs = {"wrench": Input(WrenchStamped, "/ft/wrench")}
        outputs = {"scaled": Output(WrenchStamped, "/ft/scaled")}
        params = {"gain": Param(float, 1.0, unit="1", help="scale factor")}

        def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
            w = inputs["wrench"]
            ...
            return {"scaled": WrenchStamped(header=tick.header(), ...)}

Feedthrough and delay: an input with `feedthrough=True` (the default) is
read at the same tick k (the output at tick k depends on it);
`feedthrough=False` means the output at tick k depends on this input only up
to tick k-1, and in sim time the runtime hands the node the message of tick
k-1 (None at tick 0). `delay` [s] says more: the output depends on the input
only up to `delay` earlier, and the node gets the message of tick
k - round(delay/dt) (None before). A node that declares its delay lets the
graph pipeline: the ticks behind the delay need not wait for each other. A
cycle made only of inputs read at the same tick is an algebraic loop and is
refused.

Maximum age (wall time): an input's latest message may be used for at most
`max_age` seconds after it arrived; past it the runtime stops the node with
one line naming node, input and age (a driver holds the robot in close()).
None means the default, `default_max_age(dt)`; math.inf means no limit (an
event topic such as an e-stop that is silent while nothing happens).

Clock: drivers and watchdogs read time only through `ctx.clock` (monotonic
seconds), which the runtime owns; a test hands a node a `ManualClock` and
advances it, so "the watchdog holds after 0.2 s" is decided the same way on
any machine.
"""

from __future__ import annotations

import math
import reprlib
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any, ClassVar

from dockhil.errors import ParamError, suggest
from dockhil.msgs import Header
from dockhil.physical import Range


@dataclass(frozen=True)
class Input:
    type: type
    topic: str
    feedthrough: bool = True
    required: bool = True
    help: str = ""
    delay: float = 0.0  # [s]
    max_age: float | None = None  # [s], wall time; None: default_max_age(dt); math.inf: no limit

    def age_limit(self, dt: float) -> float:
        return default_max_age(dt) if self.max_age is None else self.max_age

    def lag_ticks(self, dt: float) -> int:
        """Ticks between the message a node reads and the tick it computes."""
        return max(0 if self.feedthrough else 1, int(round(self.delay / dt)))


MAX_AGE_PERIODS = 20  # default maximum age of a wall-time input, in periods of the scene rate ...
MAX_AGE_FLOOR_S = 0.1  # ... but never below this: a busy general-purpose OS stalls a process that long


def default_max_age(dt: float) -> float:
    """Default maximum age [s] of a wall-time input at step dt."""
    return max(MAX_AGE_PERIODS * dt, MAX_AGE_FLOOR_S)


class ManualClock:
    """A monotonic clock that moves only when told: `clock.advance(0.001)`. For tests."""

    def __init__(self, start: float = 0.0):
        self.now = float(start)

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> float:
        if not seconds >= 0:
            raise ValueError(f"a monotonic clock cannot go back ({seconds!r} s)")
        self.now += seconds
        return self.now

    def sleep_until(self, deadline: float) -> None:
        """What a wall-time loop's wait does on this clock: time jumps to the deadline."""
        self.now = max(self.now, deadline)


@dataclass(frozen=True)
class Output:
    type: type
    topic: str
    help: str = ""


@dataclass(frozen=True)
class Param:
    """A typed parameter: type is float, int, bool or str."""

    type: type
    default: Any
    unit: str = ""
    help: str = ""
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple | None = None
    # (low, high): the magnitude of a nonzero value (of each number of a list) lies within this range,
    # that of docking hardware (dockhil.physical), so no product or quotient the loop and its scene
    # check form leaves floating point (1e-300 kg otherwise asks the scene check for a rate of 1e150 Hz).
    scale: tuple[float, float] | Range | None = None  # a Range also says what a value beyond it is a slip for

    def check(self, node: str, name: str, value: Any) -> Any:
        """Return `value` converted to this type, or raise one clear ParamError."""
        where = f"node {node!r} parameter {name!r}"
        want = self.type
        if want is float and isinstance(value, int) and not isinstance(value, bool):
            try:
                value = float(value)
            except OverflowError:
                raise ParamError(
                    f"{where}: an integer of {len(str(abs(value)))} digits is too large for a float "
                    f"({self._describe()})"
                ) from None
        if (
            want is bool
            and not isinstance(value, bool)
            or (want is not bool and (isinstance(value, bool) or not isinstance(value, want)))
        ):
            raise ParamError(
                f"{where}: expected {want.__name__}, got {type(value).__name__} {reprlib.repr(value)}"
                f" ({self._describe()})"
            )
        if want is float and not math.isfinite(value):
            raise ParamError(f"{where}: {value!r} is not a finite number ({self._describe()})")
        if want is float and value != 0.0 and abs(value) < sys.float_info.min:
            # Subnormal: no physical quantity is that small, and 1/value overflows.
            raise ParamError(
                f"{where}: {value!r} is too small to compute with; give 0 or a normal number ({self._describe()})"
            )
        if want is int and not -(2**63) <= value < 2**63:  # nodes get their parameters as msgpack int64
            raise ParamError(
                f"{where}: an integer of {len(str(abs(value)))} digits does not fit in 64 bits ({self._describe()})"
            )
        for bound, ok, sym in (
            (self.ge, lambda b: value >= b, ">="),
            (self.gt, lambda b: value > b, ">"),
            (self.le, lambda b: value <= b, "<="),
            (self.lt, lambda b: value < b, "<"),
        ):
            if bound is not None and not ok(bound):
                raise ParamError(f"{where}: {value!r} is out of range, must be {sym} {bound}")
        if self.scale is not None:
            for at, number in _numbers(value):  # a list parameter: each of its numbers
                if isinstance(number, float) and not math.isfinite(number):
                    raise ParamError(f"{where}{at}: {number!r} is not a finite number ({self._describe()})")
                if number != 0 and not self.scale[0] <= abs(number) <= self.scale[1]:
                    what = getattr(self.scale, "what", "")
                    if what and self.unit == "s" and abs(number) > self.scale[1]:
                        raise _time_slip(f"{where}{at}", number, what, self.scale[1])
                    unit = f" {self.unit}" if self.unit else ""
                    raise ParamError(
                        f"{where}{at}: {number!r}{unit} is outside {self.scale[0]:g} to "
                        f"{self.scale[1]:g}{unit} in magnitude, the range of docking hardware; "
                        f"give a physical value"
                    )
        if self.choices is not None and value not in self.choices:
            raise ParamError(f"{where}: {value!r} is not one of {', '.join(map(str, self.choices))}")
        return value

    def _describe(self) -> str:
        unit = f" [{self.unit}]" if self.unit else ""
        return f"{self.type.__name__}{unit}, default {self.default!r}: {self.help}".rstrip(": ")


def _time_slip(where: str, seconds: float, what: str, high: float) -> ParamError:
    """A time too long for what it is: in one line, with the unit, and the value in seconds if it was
    given in milliseconds."""
    meant = seconds / 1000.0
    hint = f"did you mean {meant:g}?" if meant <= high else f"give it in seconds, at most {high:g} s"
    err = ParamError(f"{where}: {seconds:g} s is longer than {high:g} s: {what}; {hint}")
    if meant <= high:
        err.slip = (seconds, what, meant)
    return err


def _numbers(value: Any, at: str = "") -> Iterator[tuple[str, int | float]]:
    """(where, number) of a number or of each number in nested lists (`[1]`, `[0][2]`); what is not
    a number is left to the node's own check of the list's shape."""
    if isinstance(value, list):
        for i, item in enumerate(value):
            yield from _numbers(item, f"{at}[{i}]")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield at, value


@dataclass
class Tick:
    """What the runtime tells a node about the current step."""

    index: int  # tick number k, from 0
    t: float  # time [s]: k * dt in sim time, seconds since the node started in wall time
    dt: float  # nominal step [s]
    frame: str = ""
    stamp: float | None = None  # header stamp [s]: t in sim time, Unix time in wall time

    def header(self, frame: str | None = None) -> Header:
        # Wall-time stamps are absolute, so stamps of different processes compare (latencies, alignment).
        # Positional (stamp, tick, seq, frame): keywords cost more than the rest of the call.
        return Header(
            self.t if self.stamp is None else self.stamp, self.index, self.index, self.frame if frame is None else frame
        )


@dataclass
class NodeContext:
    """Given to a node at construction: its name, the step, a logger and the runtime's clock
    (monotonic seconds; drivers time their watchdogs and limits with it, never with time.*)."""

    name: str
    dt: float
    sim_time: bool = True
    log: Any = field(default=None)
    clock: Callable[[], float] = time.monotonic

    def __post_init__(self):
        if self.log is None:  # a line to the log under this node's name; `warning: ...` is a warning
            from dockhil.log import node_line

            self.log = lambda msg: node_line(self.name, msg)


class Node:
    """Base class of every node. Subclasses declare ports and params."""

    inputs: ClassVar[dict[str, Input]] = {}
    outputs: ClassVar[dict[str, Output]] = {}
    params: ClassVar[dict[str, Param]] = {}
    # Wall time: a node stands for a device that runs from power-on (an emulator), so it does not
    # wait for the graph's common start; drivers may need it running to finish their own setup.
    free_running: ClassVar[bool] = False
    # The node moves real hardware (a robot driver): it may act only on this graph's live run, so no
    # input of it may come, directly or through other nodes, from a node that replays a recording.
    moves_hardware: ClassVar[bool] = False
    replays_recording: ClassVar[bool] = False

    def __init__(self, ctx: NodeContext, **params: Any):
        self.ctx = ctx
        self.p = SimpleNamespace(**self.resolve_params(ctx.name, params))

    @classmethod
    def resolve_params(cls, node_name: str, given: dict[str, Any]) -> dict[str, Any]:
        """Defaults overlaid with `given`, each checked; unknown names refused."""
        unknown = sorted(set(given) - set(cls.params))
        if unknown:
            raise ParamError(
                f"node {node_name!r} ({cls.__name__}): unknown parameter {unknown[0]!r}; "
                f"{suggest(unknown[0], cls.params, 'known')}"
            )
        values = {}
        for name, spec in cls.params.items():
            value = given.get(name, spec.default)
            values[name] = spec.check(node_name, name, value)
        return values

    @classmethod
    def ports(cls, params: dict[str, Any]) -> tuple[dict[str, Input], dict[str, Output]]:
        """Inputs and outputs for these parameters; override for nodes whose
        ports depend on parameters (a bag source, a recorder)."""
        return cls.inputs, cls.outputs

    def setup(self) -> None:
        """Open devices, determine constants. Raise DeviceError if hardware is missing."""

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        raise NotImplementedError

    def close(self) -> None:
        """Release devices; hardware drivers hold or stop the robot here."""

    def log(self, msg: str) -> None:
        self.ctx.log(msg)

    @classmethod
    def describe(cls) -> str:
        doc = (cls.__doc__ or "").strip().splitlines()
        return doc[0] if doc else cls.__name__
