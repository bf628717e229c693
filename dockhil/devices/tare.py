"""The tare of an F/T sensor: the bias its unloaded probe reads, found once per graph.

A tare takes whatever loads the probe for the sensor's offset, and every force limit downstream
then misses that load. So a tare is refused when its bias is too large (the probe is pressed) or
its samples spread beyond the sensor's noise band (the probe moved or was touched while taring),
and a driver that restarts within its graph keeps the graph's first tare instead of taring again
(it may restart in contact): the first tare is kept in the graph's private run directory
(owner-checked, mode 0600) for the graph's lifetime. A bias given instead (a loop file's tare) is
not tared: the start's samples only check it (`mismatch`), and it is kept as the first tare. No I/O
but the store; any F/T driver uses it.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from dockhil.errors import DeviceError, ParamError

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
        mean: Vec = (sum(axes[0]) / n, sum(axes[1]) / n, sum(axes[2]) / n)
        spread = max(math.sqrt(sum((x - m) ** 2 for x in a) / n) for a, m in zip(axes, mean))
        return mean, spread

    force, force_spread = mean_and_spread(0)
    torque, torque_spread = mean_and_spread(1)
    return Bias(force, torque, force_spread, torque_spread, n)


def refusal(bias: Bias, limits: TareLimits) -> str | None:
    """Why this tare must not be taken (one clause, with what to do), or None."""
    f, t = norm(bias.force), norm(bias.torque)
    what: str | None
    if limits.max_bias and f > limits.max_bias:
        what = f"bias force |F| = {f:.1f} N > max_bias {limits.max_bias:g} N"
    elif limits.max_bias_torque and t > limits.max_bias_torque:
        what = f"bias torque |T| = {t:.2f} N m > max_bias_torque {limits.max_bias_torque:g} N m"
    else:
        what = spread(bias, limits)
    if what is None:
        return None
    return (
        f"{what}: something loads the probe (taring it away would hide that force from every limit); "
        f"free the probe and start again, or raise the bound for a heavy tool or a noisy sensor"
    )


# A given bias (the loop file's tare) is checked against the start samples: an axis whose start mean
# lies further from it than BAND_SD standard deviations of the start samples' noisiest axis plus the
# floor means the sensor drifted, was re-mounted or is loaded since the bias was measured.
BAND_SD = 5.0
BAND_FLOOR = 0.5  # N
BAND_FLOOR_TORQUE = 0.05  # N m


def given_bias(values: Sequence[float], sign: float = 1.0) -> Bias | None:
    """A bias given as [fx, fy, fz, tx, ty, tz] in the published frame (as the driver publishes the
    unloaded probe without a tare: the loop file's), in the sensor's own frame; None for []."""
    if not values:
        return None
    raw = [sign * float(v) for v in values]
    return Bias(tuple(raw[:3]), tuple(raw[3:]), 0.0, 0.0, 0)  # type: ignore[arg-type]


def check_bias_param(node: str, values: dict) -> None:
    """Refuse (ParamError, one line) a driver's `bias` that is not six finite numbers or [], or
    one beyond max_bias / max_bias_torque (what a tare would refuse)."""
    bias, where = values["bias"], f"node {node!r} parameter 'bias'"
    if len(bias) not in (0, 6):
        raise ParamError(
            f"{where}: {len(bias)} numbers; give [fx, fy, fz, tx, ty, tz] [N, N m], or [] to tare at start"
        )
    for i, v in enumerate(bias):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ParamError(
                f"{where}[{i}]: {v!r} is not a finite number; give six numbers [N, N m], or [] to tare at start"
            )
    given = given_bias(bias)
    if given is not None:
        f, t = norm(given.force), norm(given.torque)
        if values["max_bias"] and f > values["max_bias"]:
            raise ParamError(
                f"{where}: |F| = {f:.1f} N > max_bias {values['max_bias']:g} N (raise it for a heavy tool)"
            )
        if values["max_bias_torque"] and t > values["max_bias_torque"]:
            raise ParamError(
                f"{where}: |T| = {t:.2f} N m > max_bias_torque {values['max_bias_torque']:g} N m (raise it for a heavy tool)"
            )


def mismatch(start: Bias, given: Bias, limits: TareLimits) -> str | None:
    """Why the start samples `start` do not fit the given bias (one clause, with what to do), or None."""
    band = BAND_SD * start.force_spread + BAND_FLOOR
    band_t = BAND_SD * start.torque_spread + BAND_FLOOR_TORQUE
    df = [a - b for a, b in zip(start.force, given.force)]
    dt = [a - b for a, b in zip(start.torque, given.torque)]
    worst_f = max(range(3), key=lambda i: abs(df[i]))
    worst_t = max(range(3), key=lambda i: abs(dt[i]))
    what: str | None
    if limits.max_bias and norm(df) > limits.max_bias:
        what = f"|F - bias| = {norm(df):.1f} N > max_bias {limits.max_bias:g} N"
    elif limits.max_bias_torque and norm(dt) > limits.max_bias_torque:
        what = f"|T - bias| = {norm(dt):.2f} N m > max_bias_torque {limits.max_bias_torque:g} N m"
    elif abs(df[worst_f]) > band:
        what = (
            f"F{'xyz'[worst_f]} - bias = {df[worst_f]:+.3f} N, beyond the noise band {band:.3f} N "
            f"({BAND_SD:g} sd {start.force_spread:.3f} N + {BAND_FLOOR:g} N)"
        )
    elif abs(dt[worst_t]) > band_t:
        what = (
            f"T{'xyz'[worst_t]} - bias = {dt[worst_t]:+.4f} N m, beyond the noise band {band_t:.4f} N m "
            f"({BAND_SD:g} sd {start.torque_spread:.4f} N m + {BAND_FLOOR_TORQUE:g} N m)"
        )
    else:
        what = spread(start, limits)
    if what is None:
        return None
    return (
        f"the probe reads force {fmt(start.force)} N, torque {fmt(start.torque)} N m over {start.samples} "
        f"samples at start: {what}"
    )


def spread(bias: Bias, limits: TareLimits) -> str | None:
    """What spreads beyond the noise band over the samples of `bias` (the probe moved or was touched), or None."""
    if limits.max_spread and bias.force_spread > limits.max_spread:
        return (
            f"force spread {bias.force_spread:.2f} N over {bias.samples} samples > max_tare_spread "
            f"{limits.max_spread:g} N"
        )
    if limits.max_spread_torque and bias.torque_spread > limits.max_spread_torque:
        return (
            f"torque spread {bias.torque_spread:.3f} N m over {bias.samples} samples > "
            f"max_tare_spread_torque {limits.max_spread_torque:g} N m"
        )
    return None


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


def _vec(v: Sequence[float]) -> Vec:
    x = tuple(float(a) for a in v)
    if len(x) != 3 or not all(math.isfinite(a) for a in x):
        raise ValueError(v)
    return x[0], x[1], x[2]


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
    given: Bias | None = None,
    given_from: str = "",
) -> Bias | None:
    """The tare of `node` for this graph: at its first start, over `read(tare_samples)` (refused in
    one line where `refusal` says so) and kept; at a restart, the kept one (read(1): the sensor
    streams). None when tare_samples is 0 (no tare). With a `given` bias (from `given_from`, the
    loop file) the first start does not tare: its samples only check the given bias (`mismatch`),
    which is kept as the graph's first tare."""
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
        if given is not None:
            log(f"{device}: tare_samples 0: raw readings, the bias given is not subtracted")
        return None
    start = measure(got)
    if given is None:
        why = refusal(start, limits)
        if why:
            raise DeviceError(f"{device}: tare: {why}")
        bias, said = start, f"tared over {start.samples} {unit}: bias"
    else:
        why = mismatch(start, given, limits)
        if why:
            source = f" ({given_from})" if given_from else ""
            raise DeviceError(
                f"{device}: the given bias{source} does not fit: {why}; the probe is loaded, or the sensor "
                f"drifted or was re-mounted since the bias was measured: free the probe and start again, "
                f"or calibrate again (dockhil calibrate --out), or drop the bias (ft_bias:=[]: tare at start)"
            )
        bias = Bias(given.force, given.torque, start.force_spread, start.torque_spread, start.samples)
        said = (
            f"the probe reads {fmt(start.force)} N, {fmt(start.torque)} N m over {start.samples} {unit}, "
            f"within the noise band of the bias given{f' by {given_from}' if given_from else ''}:"
        )
    if store is not None:
        try:
            store.save(bias)
        except OSError as exc:
            raise DeviceError(f"{device}: cannot keep the tare in {store.path}: {exc.strerror}") from None
    log(f"{device}: {said} force {fmt(bias.force)} N, torque {fmt(bias.torque)} N m")
    return bias


def fmt(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"
