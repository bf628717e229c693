"""What the 1-DOF and 6-DOF run summaries share: the per-tick series (`Samples`), the first contact's
metrics fed one tick at a time (`ContactMeter`), how far the bodies went from the scene's own scale
(`RangeMeter`, `range_summary`), the matching of published messages to their tick (`TickMatcher`),
and a recorded bag's messages. All of it O(1) memory in the run's length.

When is a contact over? The exit velocity is the relative velocity once no force acts any
more, neither virtual nor measured: through the robot's delay the passive compliance keeps
pushing for up to h after the simulated bodies separated, so the first sample after the
separation is too early. The contact duration is the time the bodies overlap (penetration
> 0, zero crossings interpolated between ticks), comparable with the ideal model's.

A measured force acts when it stands out of the sensor's noise band (`ForceBand`): a real sensor
never reads exactly zero (noise, a bias the tare left, a tare's rounding residue), and a force that
is only noise would leave every hardware run without an exit velocity.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar, cast

import numpy as np

from dockhil import msgs, physical
from dockhil.analysis.scenecheck import first_node
from dockhil.contact.envelope import EnvelopeFit

if TYPE_CHECKING:
    from dockhil.scene.graph import Graph

_Collector = TypeVar("_Collector", bound=Callable[[str, Any], None])


@dataclass
class Samples:
    """Per-tick series: time [s], penetration p = x1 - x2 [m], its rate [m/s],
    compressive contact force on the chaser [N]; `acting` (optional): whether any
    contact force (virtual or measured, on either body) acts at that tick; by default
    where the force is not zero."""

    t: np.ndarray
    p: np.ndarray
    pd: np.ndarray
    force: np.ndarray
    acting: np.ndarray | None = None


_CHUNK = 4096  # ticks whose ideal force is evaluated at once (bounded memory)
BAND_SIGMAS = 5.0  # a reading within this many noise deviations of the sensor's rest reading is no force
FORCE_FLOOR_N = 1e-6  # N: the narrowest band: a tare's rounding residue (1e-15 N) is no force, 1 uN below any sensor
REST_READINGS = 20  # readings before the first contact that measure the band (fewer: the scene's numbers alone)
FT_NODES = ("ft_sim", "ft_emulator", "netft_emulator")  # nodes whose `noise` and `bias` are the sensor's


class ForceBand:
    """Whether a measured force acts: outside the sensor's noise band about its rest reading. The band's
    half width is the widest of FORCE_FLOOR_N, the scene's `force_deadband` and BAND_SIGMAS times the
    noise it gives its sensor (`half_width`), and BAND_SIGMAS times the spread of the readings before
    the first contact; its centre is their mean (an untared bias), else the bias the scene gives."""

    def __init__(self, half_width: float = FORCE_FLOOR_N, centre: float = 0.0):
        self.half_width = max(half_width, FORCE_FLOOR_N)
        self.centre = centre
        self.n = 0
        self._mean = 0.0
        self._m2 = 0.0
        self.closed = False  # the first contact began: the rest readings are in

    def rest(self, force: float) -> None:
        """A reading before the first contact (Welford's running mean and variance)."""
        if self.closed or not math.isfinite(force):
            return
        self.n += 1
        d = force - self._mean
        self._mean += d / self.n
        self._m2 += d * (force - self._mean)

    def close(self) -> None:
        """The first contact began: from here on the band is fixed."""
        if self.closed:
            return
        self.closed = True
        if self.n >= REST_READINGS:
            self.centre = self._mean
            self.half_width = max(self.half_width, BAND_SIGMAS * math.sqrt(self._m2 / (self.n - 1)))

    def acting(self, force: float) -> bool:
        return not abs(force - self.centre) <= self.half_width  # a NaN acts: it is not nothing


def force_band(graph: Graph) -> ForceBand:
    """The band of the scene's sensor: its force_deadband (virtual impedance) and the noise and bias its
    sensor node is given (a sim sensor, an emulator; with loop:= the loop file's noise)."""
    width, centre = 0.0, 0.0
    for gn in graph.nodes.values():
        p = gn.params
        if gn.type_name == "virtual_impedance":
            width = max(width, float(p.get("force_deadband") or 0.0))
        elif gn.type_name in FT_NODES:
            width = max(width, BAND_SIGMAS * float(p.get("noise") or 0.0), float(p.get("quantization") or 0.0))
            if gn.type_name == "ft_sim":
                centre = float(p.get("bias") or 0.0)  # the sim sensor publishes its bias untared
    return ForceBand(width, centre)


class ContactMeter:
    """Contact metrics of the first contact, fed one tick at a time; O(1) memory.

    ideal: the ideal contact's parameters (m1, m2, kcs, bcs, v1, v2, x1, x2) to compare the
    force with tick by tick; growth_about: the equilibrium penetration [m] about which the
    envelope of an oscillation is fitted (its growth rate)."""

    def __init__(self, ideal: dict | None = None, growth_about: float | None = None):
        self.n = 0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.state = "before"  # before -> in -> after -> done (a second contact is not summarized)
        self.prev: tuple[float, float, float, bool] | None = None  # (t, p, pd, acting) of the previous tick
        self.t_start: float | None = None
        self.t_end: float | None = None
        self.entry: float | None = None
        self.samples_in = 0
        self.peak = -math.inf  # the first contact's largest compressive force
        self.largest = 0.0  # the run's largest |force|, whatever happened to the contact
        self.exit: float | None = None  # relative velocity after the last acting tick seen so far
        self.ideal = ideal
        self.max_err = 0.0
        self.chunk_t: list[float] = []
        self.chunk_f: list[float] = []
        self.growth = None if growth_about is None else EnvelopeFit(growth_about)

    def add(self, t: float, p: float, pd: float, force: float, acting: bool) -> None:
        if self.n == 0:
            self.t_first = t
        self.n += 1
        self.t_last = t
        touching = p > 0.0 or (p == 0.0 and pd > 0.0)
        prev = self.prev
        if prev is not None and prev[3] and self.state in ("in", "after"):
            self.exit = pd  # the state after the force of the previous tick has acted
        if self.state == "before" and touching:
            self.state = "in"
            first = prev is None or p == 0.0
            self.t_start = t if prev is None or first else _crossing(prev[0], prev[1], t, p)
            self.entry = pd
        elif self.state == "in" and not touching:
            self.state = "after"
            last = cast("tuple[float, float, float, bool]", prev)  # a tick in contact came before
            self.t_end = _crossing(last[0], last[1], t, p)
        elif self.state == "after" and touching:
            self.state = "done"
        if not abs(force) <= self.largest:  # an Inf or NaN too: it is what the run reached
            self.largest = abs(force)
        if self.state == "in":
            self.samples_in += 1
            self.peak = max(self.peak, force)
        if self.ideal is not None:
            self.chunk_t.append(t)
            self.chunk_f.append(force)
            if len(self.chunk_t) >= _CHUNK:
                self._compare()
        if self.growth is not None:
            self.growth.add(t, p)
        self.prev = (t, p, pd, acting)

    def _compare(self) -> None:
        if not self.chunk_t:
            return
        ref = ideal_force_at(cast(dict, self.ideal), np.array(self.chunk_t))  # chunks fill only with an ideal
        self.max_err = max(self.max_err, float(np.max(np.abs(ref - np.array(self.chunk_f)))))
        self.chunk_t.clear()
        self.chunk_f.clear()

    def result(self) -> dict:
        """peak_force_N (the largest |force| of the run, whatever happened to the contact),
        contact_duration_s, entry_velocity_mps, exit_velocity_mps, restitution, contact_start_s
        (None where absent), and a `note` when something is not resolved or not over."""
        out: dict[str, Any] = {
            "peak_force_N": float(self.largest) if self.n else None,
            "contact_duration_s": None,
            "entry_velocity_mps": None,
            "exit_velocity_mps": None,
            "restitution": None,
            "contact_start_s": None,
        }
        if self.state == "before":
            return out
        # Set at the contact's first tick, as the previous tick is and, once it ended, its end.
        t_start, entry = cast(float, self.t_start), cast(float, self.entry)
        out["contact_start_s"] = float(t_start)
        out["entry_velocity_mps"] = float(entry)
        if self.state != "in" and self.samples_in <= 1:
            out["note"] = (
                "the contact lasted less than one sample: its duration is not resolved at this rate, "
                "nor its peak force compared"
            )
        if self.state == "in":
            out["note"] = (
                "the contact had not ended when the run stopped: its peak force so far is not compared "
                "with the ideal's; run longer for its peak, duration and exit"
            )
            return out
        if "note" not in out:
            out["contact_duration_s"] = float(cast(float, self.t_end) - t_start)
        if cast("tuple[float, float, float, bool]", self.prev)[3] and self.state == "after":
            out["note"] = (
                "a force still acted when the run stopped (the passive compliance behind the robot's "
                "delay): run longer for the exit velocity"
            )
            return out
        if self.exit is not None:
            out["exit_velocity_mps"] = float(self.exit)
            if self.entry:
                out["restitution"] = float(-self.exit / self.entry)
        return out

    def max_force_error(self) -> float:
        self._compare()
        return self.max_err


class RangeMeter:
    """How far a run's bodies went from the scene's own scale, fed the published states one at a
    time; O(1) memory. Kinetic energy [J] is taken in the frame of the start: the fixed target's
    (a body of mass 0), else the bodies' centre of mass; `inertia` (the two bodies' 3x3 inertias
    in body axes, 6-DOF) adds the rotation's. What the loop may give the bodies is judged by
    `reasons` (docs/summary.md, "A run that leaves the physical range")."""

    def __init__(self, inertia: tuple | None = None):
        self.inertia = None if inertia is None else tuple(np.asarray(i, float).tolist() for i in inertia)
        if inertia is not None:
            from dockhil.contact.rotations import rotate_back

            self.rotate_back = rotate_back
        self.start: list[list[float]] | None = None  # positions at the first state
        self.frame: list[float] | None = None  # velocity of the frame of the start
        self.m_red = 0.0  # reduced mass of the relative motion [kg] (the chaser's alone, for a fixed target)
        self.p0 = 0.0  # penetration x1 - x2 along x at the start (1-DOF) [m]
        self.ke0 = self.ke_max = 0.0
        self.far = self.fast = 0.0  # [m], [m/s]: the largest distance from the start and speed in the frame
        self.tick: int | None = None  # tick of the largest kinetic energy

    def __call__(self, msg: msgs.SatelliteState) -> None:
        bodies = msg.bodies[:2]
        if len(bodies) < 2:
            return
        velocities = [_xyz(b.twist.linear) for b in bodies]
        if self.start is None:
            self.start = [_xyz(b.pose.position) for b in bodies]
            masses = [b.mass for b in bodies]
            fixed = next((v for m, v in zip(masses, velocities) if m == 0.0), None)
            total = sum(masses)
            self.frame = (
                fixed
                if fixed is not None
                else [sum(m * v[i] for m, v in zip(masses, velocities)) / total for i in range(3)]
            )
            m1, m2 = masses
            self.m_red = m1 if m2 == 0.0 else m2 if m1 == 0.0 else m1 * m2 / (m1 + m2)
            self.p0 = self.start[0][0] - self.start[1][0]
            self.ke0 = self._kinetic(bodies, velocities)
        ke = self._kinetic(bodies, velocities)
        if not ke <= self.ke_max:  # an Inf or NaN too
            self.ke_max, self.tick = ke, msg.header.tick
        (x1, x2), (v1, v2) = self.start, velocities
        p1, p2 = bodies[0].pose.position, bodies[1].pose.position
        far = max(
            math.hypot(p1.x - x1[0], p1.y - x1[1], p1.z - x1[2]), math.hypot(p2.x - x2[0], p2.y - x2[1], p2.z - x2[2])
        )
        frame = cast("list[float]", self.frame)  # set with the start
        fast = max(_distance(v1, frame), _distance(v2, frame))
        if not far <= self.far:
            self.far = far
        if not fast <= self.fast:
            self.fast = fast

    def _kinetic(self, bodies: Sequence[msgs.BodyState], velocities: list[list[float]]) -> float:
        ke = 0.0
        f = cast("list[float]", self.frame)  # set with the start
        for i, (b, v) in enumerate(zip(bodies, velocities)):
            dx, dy, dz = v[0] - f[0], v[1] - f[1], v[2] - f[2]
            ke += 0.5 * b.mass * (dx * dx + dy * dy + dz * dz)  # not ** 2: an exploded speed overflows to Inf
            if self.inertia is not None:
                o, w = b.pose.orientation, b.twist.angular
                x, y, z = self.rotate_back((o.x, o.y, o.z, o.w), (w.x, w.y, w.z))  # body axes
                (a, b_, c), (d, e, g), (h, k, m) = self.inertia[i]
                ke += 0.5 * (x * (a * x + b_ * y + c * z) + y * (d * x + e * y + g * z) + z * (h * x + k * y + m * z))
        return ke

    def reasons(
        self,
        largest_force: float | None,
        force_scale: list[tuple[float, str]],
        energy_extra: float,
        stiffness: float = 0.0,
    ) -> list[str]:
        """Why the run left the physical range (dockhil.physical), or nothing. force_scale: the scene's
        forces to judge the largest by, as (newtons, what); energy_extra [J]: what else than the bodies'
        start gives them energy (a thrust); stiffness [N/m]: the stiffest spring a starting penetration
        compresses."""
        out = []
        scale = max(force_scale, default=(0.0, ""))
        if largest_force is not None:
            if scale[0] > 0.0 and not largest_force <= physical.RUN_FORCE_FACTOR * scale[0]:
                out.append(
                    f"the force reached {largest_force:.3g} N, {largest_force / scale[0]:.3g} times "
                    f"{scale[1]} ({scale[0]:.4g} N; more than {physical.RUN_FORCE_FACTOR:g} times is "
                    f"beyond the physical range): the loop exploded or its input is not physical"
                )
            elif scale[0] == 0.0 and not largest_force <= physical.RUN_FORCE:
                out.append(
                    f"the force reached {largest_force:.3g} N, beyond the {physical.RUN_FORCE:g} N any "
                    f"docking hardware bears: the loop exploded or its input is not physical"
                )
        if self.start is None:
            return out
        floor = 0.5 * self.m_red * physical.RUN_SPEED_FLOOR**2
        given = self.ke0 + energy_extra + (0.5 * stiffness * self.p0**2 if self.p0 > 0.0 else 0.0)
        budget = max(given, floor)
        if not self.ke_max <= physical.RUN_ENERGY_FACTOR * budget:
            out.append(
                f"the bodies' kinetic energy reached {self.ke_max:.3g} J at tick {self.tick}, "
                f"{self.ke_max / budget:.3g} times the {budget:.3g} J the scene gave them (more than "
                f"{physical.RUN_ENERGY_FACTOR:g} times): the loop made the energy"
            )
        if not self.far <= physical.RUN_DISTANCE:
            out.append(f"a body went {self.far:.3g} m from where it started, beyond {physical.RUN_DISTANCE:g} m")
        if not self.fast <= physical.RUN_SPEED:
            out.append(f"a body reached {self.fast:.3g} m/s, beyond the {physical.RUN_SPEED:g} m/s of docking hardware")
        return out


def _xyz(v: msgs.Vector3) -> list[float]:
    return [v.x, v.y, v.z]


def _distance(a: Sequence[float], b: Sequence[float]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _crossing(t0: float, p0: float, t1: float, p1: float) -> float:
    """Time where p crosses zero between (t0, p0) and (t1, p1) (linear)."""
    dp = p1 - p0
    return float(t0 if dp == 0.0 else t0 - p0 * (t1 - t0) / dp)


def ideal_force_at(ideal: dict, t: np.ndarray) -> np.ndarray:
    from dockhil.contact.ideal import ideal_trajectory
    from dockhil.contact.scenario import ContactScenario

    scn = ContactScenario(ideal["m1"], ideal["m2"], ideal["kcs"], ideal["bcs"], 0.0, ideal["v1"], ideal["v2"])
    traj = ideal_trajectory(scn, t, gap=max(0.0, ideal.get("x2", 0.0) - ideal.get("x1", 0.0)))
    return np.where(traj.in_contact, scn.kcs * traj.penetration + scn.bcs * traj.penetration_rate, 0.0)


class TickMatcher:
    """Turns published messages into per-tick samples (t, p, pd, force, acting), in time order,
    with bounded buffers: a state waits in a window of WINDOW states for the forces of its tick,
    and longer (up to HOLD states) while a force topic that has come lags behind it: a bag holds
    its topics in the order the recorder got them, which can be hundreds of ticks apart.

    Time is simulated time: (tick - first tick) * dt when dt is known, else the stamps from the
    first state on. Forces are matched to each state by header stamp, taking the newest force at
    or before it: in sim time that is the force of the same tick (stamps are k dt everywhere), in
    wall time the one the dynamics would have seen."""

    WINDOW = 256
    HOLD = 20_000

    def __init__(
        self,
        sink: Callable[..., None],  # ContactMeter.add, ContactMeter6.add
        ideal_force: tuple[float, float] | None = None,
        dt: float | None = None,
        expect: Iterable[str] = frozenset(),
        band: ForceBand | None = None,
    ):
        self.sink = sink
        self.band = ForceBand() if band is None else band  # when a measured force acts
        self.ideal_force = ideal_force  # (kcs, bcs) when the dynamics run the ideal model inside
        self.dt = dt
        # The input topics the graph publishes: a tick waits for those even before their first message.
        self.expect = frozenset(expect) if ideal_force is None else frozenset()
        # Sorted by stamp: (stamp, tick, p, pd), (stamp, force), (stamp, f1, f2); TickMatcher6 keeps its messages.
        self.pending: list[tuple] = []
        self.ft: list[tuple] = []
        self.virtual: list[tuple] = []
        self.first: tuple[float, int] | None = None

    def __call__(self, topic: str, msg: object) -> None:
        if isinstance(msg, msgs.SatelliteState) and len(msg.bodies) >= 2:
            c, g = msg.bodies[0], msg.bodies[1]
            bisect.insort(
                self.pending,
                (
                    msg.header.stamp,
                    msg.header.tick,
                    c.pose.position.x - g.pose.position.x,
                    c.twist.linear.x - g.twist.linear.x,
                ),
            )
        elif topic == "/ft/wrench" and isinstance(msg, msgs.WrenchStamped):
            bisect.insort(self.ft, (msg.header.stamp, msg.wrench.force.x))
        elif topic == "/impedance/wrench" and isinstance(msg, msgs.BodyWrenches) and msg.wrenches:
            f2 = msg.wrenches[1].force.x if len(msg.wrenches) > 1 else 0.0
            bisect.insort(self.virtual, (msg.header.stamp, msg.wrenches[0].force.x, f2))
        self._release()

    def _inputs(self) -> dict[str, list]:
        """The series a tick reads besides its own, by topic, each sorted by stamp."""
        return {"/ft/wrench": self.ft, "/impedance/wrench": self.virtual}

    def _release(self) -> None:
        """Emits the oldest ticks past WINDOW whose inputs have come, and past HOLD whatever came."""
        pending = self.pending
        while len(pending) > self.WINDOW and (len(pending) > self.HOLD or self._came(pending[0][0])):
            self._emit(pending.pop(0))

    def _came(self, stamp: float) -> bool:
        """Every input of the tick at `stamp` has come: each input topic expected or seen so far has
        reached the stamp."""
        for topic, series in self._inputs().items():
            if series[-1][0] < stamp if series else topic in self.expect:
                return False
        return True

    @staticmethod
    def _newest(series: list, stamp: float) -> tuple | None:
        """The newest entry at or before stamp (None before the first); drops older ones."""
        i = bisect.bisect_right(series, (stamp, math.inf, math.inf)) - 1
        if i < 0:
            return None
        del series[:i]
        return series[0]

    def _emit(self, state: tuple) -> None:
        stamp, tick, p, pd = state
        if self.first is None:
            self.first = (stamp, tick)
        t = (tick - self.first[1]) * self.dt if self.dt is not None else stamp - self.first[0]
        if self.ideal_force is not None:
            kcs, bcs = self.ideal_force
            touching = p > 0.0 or (p == 0.0 and pd > 0.0)
            force, acting = (kcs * p + bcs * pd if touching else 0.0), touching
        else:
            ft, virtual = self._newest(self.ft, stamp), self._newest(self.virtual, stamp)
            fs = 0.0 if ft is None else ft[1]
            v1, v2 = (0.0, 0.0) if virtual is None else virtual[1:]
            # Compressive force on the chaser: minus (measured + virtual) force along +x.
            force, acting = -(fs + v1), (self._measured_acts(fs, p, pd) or v1 != 0.0 or v2 != 0.0)
        self.sink(t, p, pd, force, acting)

    def _measured_acts(self, fs: float, p: float, pd: float) -> bool:
        """Whether the measured force acts: the band learns the sensor at rest until the first contact."""
        band = self.band
        if not band.closed:
            if p > 0.0 or (p == 0.0 and pd > 0.0):
                band.close()
            else:
                band.rest(fs)
        return band.acting(fs)

    def flush(self) -> None:
        while self.pending:
            self._emit(self.pending.pop(0))


def range_summary(out: dict, graph: Graph, ranges: RangeMeter, largest_force: float | None) -> None:
    """Mark a summary invalid, with its reasons, where the run left the physical range: its forces,
    its bodies' energy, distance or speed (RangeMeter.reasons), judged by the scene's own scale."""
    scale = []
    ideal_peak = (out.get("ideal") or {}).get("peak_force_N")
    if ideal_peak:
        scale.append((ideal_peak, "the ideal contact's peak"))
    dyn, ft, imp = (
        first_node(graph, "satellite_dynamics"),
        first_node(graph, "ft_sim"),
        first_node(graph, "virtual_impedance"),
    )
    thrust = abs(dyn.params["thrust"]) if dyn is not None else 0.0
    if thrust:
        scale.append((thrust, "the thrust"))
    for gn in graph.nodes.values():
        if gn.type_name == "robot_modbus" and gn.params.get("max_force"):
            scale.append((gn.params["max_force"], f"node {gn.name!r}'s max_force"))
    k = ft.params["k"] if ft is not None else 0.0
    # What a thrust gives the bodies: pressed on a spring k from rest, at most thrust^2 / 2k of motion;
    # with nothing to press on, its work over the farthest a body may go.
    extra = 0.0 if not thrust else thrust * thrust / (2.0 * k) if k > 0.0 else thrust * physical.RUN_DISTANCE
    springs = [
        k,
        imp.params["kcs"] if imp is not None else 0.0,
        dyn.params["kcs"] if dyn is not None and dyn.params["model"] == "ideal" else 0.0,
    ]
    reasons = ranges.reasons(largest_force, scale, extra, max(springs))
    if reasons:
        out["invalid_reasons"] = [*(out.get("invalid_reasons") or []), *reasons]
        out["valid"] = False


# What a run's summary reads; /robot/command: the 6-DOF summary's ticks (summary/dof6.py), the 1-DOF one
# ignores it. A recorder kept only for the summary records just these.
SUMMARY_TOPICS = ("/satellite/state", "/ft/wrench", "/impedance/wrench", "/energy", "/robot/command")


def bag_messages(path: str) -> Iterator[tuple[str, int, Any]]:
    from dockhil.bags.reader import BagReader

    with BagReader(path) as bag:
        yield from bag.decoded(list(SUMMARY_TOPICS))


def feed_from_bag(path: str, collector: _Collector) -> _Collector:
    """Feed a recorded run into a summary collector, one message at a time."""
    for topic, _t, msg in bag_messages(path):
        collector(topic, msg)
    return collector
