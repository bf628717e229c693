"""The tare of an F/T sensor: the bias its unloaded probe reads, found once per graph.

A tare takes whatever loads the probe for the sensor's offset, and every force limit downstream
then misses that load. So a tare is refused when its bias is too large (the probe is pressed) or
its samples spread beyond the sensor's noise band (the probe moved or was touched while taring),
and a driver that restarts within its graph keeps the graph's first tare instead of taring again
(it may restart in contact): the first tare is kept in the graph's private run directory
(owner-checked, mode 0600) for the graph's lifetime. No I/O but the store; any F/T driver uses it.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

from dockhil.errors import DeviceError

Vec = tuple[float, float, float]


@dataclass(frozen=True)
class Bias:
    """A tare: mean force [N] and torque [N m] over `samples` samples, and their spread (the largest
    standard deviation of one axis)."""

    force: Vec
    torque: Vec
    force_spread: float
    torque_spread: float
    samples: int


@dataclass(frozen=True)
class TareLimits:
    """What a tare may find (0: that check is off)."""

    max_bias: float = 50.0  # N: more means something presses the probe
    max_bias_torque: float = 5.0  # N m
    max_spread: float = 2.0  # N: more means the probe moved or was touched while taring
    max_spread_torque: float = 0.2  # N m


def norm(v: Sequence[float]) -> float:
    return math.sqrt(sum(x * x for x in v))


def measure(samples: Sequence[tuple[Sequence[float], Sequence[float]]]) -> Bias:
    """The bias of (force, torque) samples: their mean and spread."""
    n = len(samples)
    if not n:
        raise ValueError("a tare needs at least one sample")

    def mean_and_spread(which: int) -> tuple[Vec, float]:
        axes = [[s[which][i] for s in samples] for i in range(3)]
        mean = tuple(sum(a) / n for a in axes)
        spread = max(math.sqrt(sum((x - m) ** 2 for x in a) / n) for a, m in zip(axes, mean))
        return mean, spread

    force, force_spread = mean_and_spread(0)
    torque, torque_spread = mean_and_spread(1)
    return Bias(force, torque, force_spread, torque_spread, n)


def refusal(bias: Bias, limits: TareLimits) -> str | None:
    """Why this tare must not be taken (one clause, with what to do), or None."""
    f, t = norm(bias.force), norm(bias.torque)
    if limits.max_bias and f > limits.max_bias:
        what = f"bias force |F| = {f:.1f} N > max_bias {limits.max_bias:g} N"
    elif limits.max_bias_torque and t > limits.max_bias_torque:
        what = f"bias torque |T| = {t:.2f} N m > max_bias_torque {limits.max_bias_torque:g} N m"
    elif limits.max_spread and bias.force_spread > limits.max_spread:
        what = (
            f"force spread {bias.force_spread:.2f} N over {bias.samples} samples > max_tare_spread "
            f"{limits.max_spread:g} N"
        )
    elif limits.max_spread_torque and bias.torque_spread > limits.max_spread_torque:
        what = (
            f"torque spread {bias.torque_spread:.3f} N m over {bias.samples} samples > "
            f"max_tare_spread_torque {limits.max_spread_torque:g} N m"
        )
    else:
        return None
    return (
        f"{what}: something loads the probe (taring it away would hide that force from every limit); "
        f"free the probe and start again, or raise the bound for a heavy tool or a noisy sensor"
    )


class TareStore:
    """The graph's first tare of one sensor, kept in a private directory across the driver's restarts."""

    def __init__(self, directory: Path, name: str):
        safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name).strip("._")[:100] or "ft"
        self.path = Path(directory) / f"tare-{safe}.json"

    def load(self) -> Bias | None:
        """The kept tare, or None if there is none yet; DeviceError if the file cannot be trusted."""
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise DeviceError(
                f"tare file {self.path}: {exc.strerror}; the graph's first tare cannot be "
                f"read: stop the graph and start it again with the probe free"
            ) from None
        try:
            st = os.fstat(fd)
            mode = stat.S_IMODE(st.st_mode)
            if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid() or mode & 0o077:
                raise DeviceError(
                    f"tare file {self.path} is not a file of yours of mode 0600 (uid {st.st_uid}, "
                    f"mode {mode:04o}): it cannot be trusted; stop the graph and start it again "
                    f"with the probe free"
                )
            text = os.read(fd, 4096)
        finally:
            os.close(fd)
        try:
            d = json.loads(text)
            bias = Bias(
                _vec(d["force"]),
                _vec(d["torque"]),
                float(d["force_spread"]),
                float(d["torque_spread"]),
                int(d["samples"]),
            )
        except (ValueError, KeyError, TypeError):
            raise DeviceError(
                f"tare file {self.path} is damaged; stop the graph and start it again with the probe free"
            ) from None
        return bias

    def save(self, bias: Bias) -> None:
        """Keep `bias` (atomically, mode 0600): a driver killed while saving leaves no half file."""
        tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
        try:
            os.write(fd, json.dumps(asdict(bias)).encode())
        finally:
            os.close(fd)
        os.replace(tmp, self.path)


def _vec(v) -> Vec:
    x = tuple(float(a) for a in v)
    if len(x) != 3 or not all(math.isfinite(a) for a in x):
        raise ValueError(v)
    return x  # type: ignore[return-value]


def graph_store(node: str) -> TareStore | None:
    """The tare store of `node` in this graph's private run directory; None outside a graph (no
    restart within a graph to outlive: every start tares)."""
    from dockhil.runtime import ownership

    directory = ownership.graph_dir()
    return TareStore(directory, node) if directory is not None else None


Samples = Sequence[tuple[Sequence[float], Sequence[float]]]


def graph_tare(
    node: str,
    device: str,
    tare_samples: int,
    limits: TareLimits,
    read: Callable[[int], Samples],
    log: Callable[[str], None],
    unit: str = "samples",
) -> Bias | None:
    """The tare of `node` for this graph: at its first start, over `read(tare_samples)` (refused in
    one line where `refusal` says so) and kept; at a restart, the kept one (read(1): the sensor
    streams). None when tare_samples is 0 (no tare)."""
    store = graph_store(node) if tare_samples else None
    try:
        first = store.load() if store else None
    except DeviceError as exc:
        raise DeviceError(f"{device}: {exc}") from None
    got = read(tare_samples if tare_samples and first is None else 1)
    if first is not None:
        off = norm([a - b for a, b in zip(measure(got).force, first.force)])
        log(
            f"{device}: restarted: kept the graph's first tare, bias force {fmt(first.force)} N, "
            f"torque {fmt(first.torque)} N m (the probe reads {off:.2f} N from it now)"
        )
        return first
    if not tare_samples:
        return None
    bias = measure(got)
    why = refusal(bias, limits)
    if why:
        raise DeviceError(f"{device}: tare: {why}")
    if store is not None:
        try:
            store.save(bias)
        except OSError as exc:
            raise DeviceError(f"{device}: cannot keep the tare in {store.path}: {exc.strerror}") from None
    log(f"{device}: tared over {bias.samples} {unit}: bias force {fmt(bias.force)} N, torque {fmt(bias.torque)} N m")
    return bias


def fmt(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"
