"""The run summary of a 6-DOF docking scene (launch/hil6.yaml): peak contact force and torque,
contact duration, entry and exit relative linear and angular velocities, against the ideal
6-DOF contact (contact6.simulate_contact6) run on the scene's parameters, with the errors.

One pass over the ticks with O(1) memory, as the 1-DOF summary (dof1.py), whose
machinery it shares (common.py): `ContactMeter6` wraps the 1-DOF `ContactMeter` on the normal axis (contact
start and end interpolated between ticks, when the contact is over, the peak) and adds the
vector quantities; messages are matched to the state of their tick as the 1-DOF summary does.

What is measured, tick by tick, from the published messages, with the scene's own library calls:
- the contact wrench on the chaser as the dynamics apply it (hybrid6.held_wrench: the F/T
  reading moved from the sensor to the chaser's CoM, plus the virtual wrench); the peak force
  is max |F|, the peak torque max |T| with T about the chaser's interface origin A (as Run6);
- the penetration d_x and the velocities of A relative to B in B's axes: d' [m/s] and
  R_B^T (omega_1 - omega_2) [rad/s] (hybrid6.relative_interface), at the first tick in contact
  (entry) and once no force acts any more (exit). The 1-DOF keys (entry/exit_velocity_mps,
  restitution) are their normal components.

The ideal contact runs only until it has ended (`until_exit`): its memory is the contact's length.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any, cast

from dockhil import msgs
from dockhil.analysis.scenecheck import scene_check, sixdof_nodes
from dockhil.analysis.summary.common import ContactMeter, RangeMeter, TickMatcher, force_band, range_summary
from dockhil.contact.rotations import cross3, rotate, sub3

if TYPE_CHECKING:
    from dockhil.analysis.summary.common import ForceBand
    from dockhil.contact.contact6 import Contact6
    from dockhil.nodes.satellite_dynamics6 import SatelliteDynamics6
    from dockhil.scene.graph import Graph

VECTORS = ("relative_velocity_mps", "relative_angular_velocity_radps")


def _norm(v: Sequence[float]) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


class ContactMeter6:
    """6-DOF contact metrics of the first contact, fed one tick at a time; O(1) memory."""

    def __init__(self):
        self.normal = ContactMeter()
        self.peak_torque = 0.0
        self.entry: tuple | None = None  # (d', relative angular velocity) at the first tick in contact
        self.exit: tuple | None = None  # the same once the force of the previous tick has acted

    @property
    def n(self) -> int:
        return self.normal.n

    def add(
        self,
        t: float,
        p: float,
        pd: float,
        force: Sequence[float],
        torque: Sequence[float],
        velocity: Sequence[float],
        angular_velocity: Sequence[float],
        acting: bool,
    ) -> None:
        m = self.normal
        if m.prev is not None and m.prev[3] and m.state in ("in", "after"):  # ContactMeter's exit rule
            self.exit = (tuple(velocity), tuple(angular_velocity))
        before = m.state
        m.add(t, p, pd, _norm(force), acting)
        if before == "before" and m.state == "in":
            self.entry = (tuple(velocity), tuple(angular_velocity))
        torque_norm = _norm(torque)
        if not torque_norm <= self.peak_torque:  # the run's largest, as the peak force (an Inf or NaN too)
            self.peak_torque = torque_norm

    def result(self) -> dict:
        """ContactMeter's keys (peak_force_N is max |F|, velocities their normal components) and
        peak_torque_Nm, entry_/exit_relative_velocity_mps and ..._angular_velocity_radps [x, y, z]."""
        out = self.normal.result()
        out["peak_torque_Nm"] = None if out["peak_force_N"] is None else float(self.peak_torque)
        for when, got, known in (
            ("entry", self.entry, out["entry_velocity_mps"]),
            ("exit", self.exit, out["exit_velocity_mps"]),
        ):
            for key, value in zip(VECTORS, got or (None, None)):
                out[f"{when}_{key}"] = None if known is None or value is None else [float(c) for c in value]
        return out


class TickMatcher6(TickMatcher):
    """Per-tick 6-DOF samples from published messages, with the 1-DOF matcher's bounded buffers and
    its rule (the newest state, F/T reading and virtual wrench at or before each tick's stamp).

    A tick is the dynamics' /robot/command: the pose and twist of A in B that the dynamics computed
    from the state they published with it (hybrid6.relative_interface), so d_x, d' and the relative
    angular velocity are read, not recomputed. The wrench is rebuilt only while a force acts."""

    def __init__(
        self,
        sink: Callable[..., None],
        dyn: SatelliteDynamics6,
        dt: float | None,
        expect: Iterable[str] = frozenset(),
        band: ForceBand | None = None,
    ):
        super().__init__(sink, None, dt, expect, band)
        from dockhil.contact import hybrid6

        self.lib, self.dyn = hybrid6, dyn
        self.states: list = []
        self.seq = itertools.count()  # (stamp, seq, payload): equal stamps never compare the payloads

    def __call__(self, topic: str, msg: object) -> None:
        # Messages are kept as they came (bounded: `_newest` drops the old ones) and read at their tick.
        if topic == "/robot/command":
            if isinstance(msg, msgs.RobotCommand):
                bisect.insort(self.pending, (msg.header.stamp, msg.header.tick, next(self.seq), msg))
        elif topic == "/ft/wrench":
            if isinstance(msg, msgs.WrenchStamped):
                bisect.insort(self.ft, (msg.header.stamp, next(self.seq), msg))
        elif topic == "/impedance/wrench":
            if isinstance(msg, msgs.BodyWrenches) and len(msg.wrenches) >= 2:
                bisect.insort(self.virtual, (msg.header.stamp, next(self.seq), msg))
        elif isinstance(msg, msgs.SatelliteState) and len(msg.bodies) >= 2:
            bisect.insort(self.states, (msg.header.stamp, next(self.seq), msg))
        self._release()

    def _inputs(self) -> dict[str, list]:
        return {"/ft/wrench": self.ft, "/impedance/wrench": self.virtual, "/satellite/state": self.states}

    def _emit(self, command: tuple) -> None:
        stamp, tick, _, cmd = command
        if self.first is None:
            self.first = (stamp, tick)
        t = (tick - self.first[1]) * self.dt if self.dt is not None else stamp - self.first[0]
        state = self._newest(self.states, stamp)
        ft, imp = self._newest(self.ft, stamp), self._newest(self.virtual, stamp)
        zero = (0.0, 0.0, 0.0)
        force_s, torque_s = (zero, zero) if ft is None else (_triple(ft[2].wrench.force), _triple(ft[2].wrench.torque))
        virtual = (
            (zero,) * 4 if imp is None else tuple(_triple(v) for w in imp[2].wrenches[:2] for v in (w.force, w.torque))
        )
        acting = self._measured_acts(_norm(force_s), cmd.pose.position.x, cmd.twist.linear.x) or any(
            c != 0.0 for v in virtual for c in v
        )
        force = torque = zero
        if acting and state is not None:
            lib, dyn = self.lib, self.dyn
            pub1, pub2 = (_published(b) for b in state[2].bodies[:2])
            s1, s2 = lib.motion_from_published(dyn.b1, *pub1), lib.motion_from_published(dyn.b2, *pub2)
            w = lib.held_wrench(s1, s2, dyn.mount, force_s, torque_s, virtual)
            force = w.f1
            torque = sub3(w.t1, cross3(rotate(s1.q, dyn.b1._r_p), w.f1))  # about A (CoM -> A), as Run6
        velocity = _triple(cmd.twist.linear)
        self.sink(t, cmd.pose.position.x, velocity[0], force, torque, velocity, _triple(cmd.twist.angular), acting)


def _triple(v: msgs.Vector3) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


def _published(body: msgs.BodyState) -> tuple:
    """(position, orientation, velocity, world angular velocity) of a msgs.BodyState."""
    o = body.pose.orientation
    return _triple(body.pose.position), (o.x, o.y, o.z, o.w), _triple(body.twist.linear), _triple(body.twist.angular)


def ideal_metrics6(dyn: SatelliteDynamics6, ideal: Contact6, dt: float, t_end: float) -> dict:
    """`ContactMeter6.result()` of the ideal 6-DOF contact from the dynamics' start, run until the
    contact has ended (at most t_end), sampled every dt."""
    from dockhil.contact.contact6 import simulate_contact6
    from dockhil.contact.rotations import quat_multiply, rotate_back

    run = simulate_contact6(dyn.b1, dyn.b2, dyn.m1.state(), dyn.m2.state(), ideal, dt=dt, t_end=t_end, until_exit=True)
    meter = ContactMeter6()
    q_i2 = dyn.b2.interface_orientation
    for i in range(run.t.size):
        q_b = quat_multiply(tuple(run.orientations[i, 1].tolist()), q_i2)  # B -> world
        spin = rotate_back(q_b, (run.omegas[i, 0] - run.omegas[i, 1]).tolist())
        meter.add(
            float(run.t[i]),
            float(run.e[i, 0]),
            float(run.rate[i, 0]),
            run.force[i].tolist(),
            run.torque[i].tolist(),
            run.rate[i, :3].tolist(),
            spin,
            bool(run.in_contact[i]),
        )
    return meter.result()


COMPARED = (
    "peak_force_N",
    "peak_torque_Nm",
    "contact_duration_s",
    "entry_velocity_mps",
    "exit_velocity_mps",
    "restitution",
    "entry_relative_velocity_mps",
    "entry_relative_angular_velocity_radps",
    "exit_relative_velocity_mps",
    "exit_relative_angular_velocity_radps",
)


def _difference(a, b):
    if a is None or b is None:
        return None
    if isinstance(a, list):
        return [x - y for x, y in zip(a, b)]
    return a - b


class SummaryCollector6:
    """The run summary of a 6-DOF scene, gathered from published messages in one pass, O(1) memory."""

    def __init__(self, graph: Graph):
        self.graph = graph
        self.dyn, self.imp = sixdof_nodes(graph)
        self.meter = ContactMeter6()
        self.match = TickMatcher6(
            self.meter.add, self.dyn, graph.scene.dt, expect=graph.publishers, band=force_band(graph)
        )
        self.ranges = RangeMeter(inertia=(self.dyn.b1.inertia, self.dyn.b2.inertia))

    def __call__(self, topic: str, msg: object) -> None:
        if isinstance(msg, msgs.SatelliteState):
            self.ranges(msg)
        self.match(topic, msg)

    def summary(self, run_time_s: float | None = None) -> dict:
        self.match.flush()
        m = self.meter.normal
        # Both times are set once a tick came.
        sim_time = float(cast(float, m.t_last) - cast(float, m.t_first)) if m.n > 1 else 0.0
        out: dict[str, Any] = {
            "dof": 6,
            "run_time_s": run_time_s,
            "sim_time_s": sim_time,
            "real_time_factor": (sim_time / run_time_s) if run_time_s else None,
        }
        metrics = self.meter.result()
        out.update({k: metrics[k] for k in COMPARED})
        if "note" in metrics:
            out["note"] = metrics["note"]
        if self.imp is not None and m.n:
            # The ideal contact the hybrid loop reproduces, on the scene's bodies, start and dt; run at
            # most as long as this run (a contact the run did not finish is not finished there either).
            ideal = ideal_metrics6(
                self.dyn, self.imp.wall.ideal, self.graph.scene.dt, max(sim_time, self.graph.scene.dt)
            )
            out["ideal"] = {k: ideal[k] for k in COMPARED}
            out["error"] = {k: _difference(out[k], ideal[k]) for k in COMPARED}
        check = scene_check(self.graph, refuse=False)
        out["loop"] = check["loop"]
        out["warnings"] = check["warnings"]
        range_summary(out, self.graph, self.ranges, m.largest if m.n else None)
        return out


def format_summary6(out: dict) -> str:
    """A few readable lines of a 6-DOF summary."""

    def f(v, unit=""):
        if v is None:
            return "-"
        if isinstance(v, list):
            return "[" + ", ".join(f"{c:.4g}" for c in v) + "]" + (f" {unit}" if unit else "")
        return f"{v:.4g}" + (f" {unit}" if unit else "")

    rtf = out.get("real_time_factor")
    lines = [
        f"simulated {f(out['sim_time_s'], 's')}"
        + ("" if out["run_time_s"] is None else f" in {out['run_time_s']:.2f} s")  # a bag analyzed: not known
        + (f" ({rtf:.1f}x real time)" if rtf else "")
    ]
    scalars = [
        ("peak force |F|", "peak_force_N", "N"),
        ("peak torque |T|", "peak_torque_Nm", "N m"),
        ("contact duration", "contact_duration_s", "s"),
    ]
    vectors = [
        ("entry velocity", "entry_relative_velocity_mps", "m/s"),
        ("entry ang. vel.", "entry_relative_angular_velocity_radps", "rad/s"),
        ("exit velocity", "exit_relative_velocity_mps", "m/s"),
        ("exit ang. vel.", "exit_relative_angular_velocity_radps", "rad/s"),
    ]
    w = 16
    compared = "ideal" in out
    if compared:
        lines.append(f"{'':18}{'run':>{w}}{'ideal':>{w}}{'error':>{w}}")
    for label, key, unit in scalars:
        row = f"{label:18}{f(out.get(key), unit):>{w}}"
        if compared:
            row += f"{f(out['ideal'][key], unit):>{w}}{f(out['error'][key], unit):>{w}}"
        lines.append(row)
    for label, key, unit in vectors:
        lines.append(f"{label:18}{'run':6}{f(out.get(key), unit)}")
        if compared:
            lines.append(f"{'':18}{'ideal':6}{f(out['ideal'][key], unit)}")
            lines.append(f"{'':18}{'error':6}{f(out['error'][key], unit)}")
    lines.append("(velocities: of the chaser's interface A relative to the target's B, in B's axes; torque about A)")
    loop = out.get("loop") or {}
    if "spectral_radius" in loop:
        lines.append(
            f"{'sampled loop':18}{loop['rate_Hz']:g} Hz, omega*dt {loop['omega_dt']:.3g}"
            f", spectral radius {loop['spectral_radius']:.9g}"
        )
    if "note" in out:
        lines.append(f"note: {out['note']}")
    return "\n".join(lines)
