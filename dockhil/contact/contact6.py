"""The ideal 6-DOF contact: a spring-dashpot between the two docking-interface
frames, unilateral on the normal axis, with optional regularised Coulomb
friction; and the contact run. The interface coordinates e = [d, theta], their
rate e' and the sensor's wrench are dockhil.contact.interface6's.

The potential V = 1/2 e^T K e and the dissipation 1/2 e'^T C e' give, by
virtual work, the wrench on body 1 at the point o_A (body 2 gets its negative
at the same point, so momenta are conserved whatever K, C and friction are):

    g   = K_t e + C_t e'        (first three rows of K e + C e')
    tau = K_r e + C_r e'        (last three rows)
    F   = -R_B g,   M = -R_B J_l(theta)^{-T} tau

with e' the rate of e (interface6). Along one axis this is the 1-DOF Eq. 1:
compressive force kcs p + bcs p'.

Unilateral: the whole spring-dashpot acts while the bodies touch (p > 0, or
p = 0 and closing) and vanishes when p returns to 0. The springs of the five
non-normal axes rest at the relative pose of first touch (e_0, with d_x = 0):
V = 1/2 (e - e_0)^T K (e - e_0), so a contact starts without a jump in force
or energy however far off-axis it is. The pull of the dashpot
just before separation is kept, as in the 1-DOF library. The potential stored
in the non-normal springs at separation is released with the contact (the
interface lets go), so energy is conserved through a whole contact when only
the normal axis is stiff; with full K it is conserved while touching.

Friction (optional): on the tangential sliding velocity u = (e'_y, e'_z),
    f_t = -mu max(g_x, 0) u / sqrt(|u|^2 + v_s^2)      (in B, on body 1, at o_A)
a Coulomb law regularised below the sliding speed v_s [m/s].

Hunt-Crossley normal (optional, `normal`): the normal row of K e + C e' is replaced by
dockhil.contact.hunt_crossley's kcs d^n (1 + alpha d') (0 where it would pull), the other five axes
keep their linear law; the normal row and column of K and C must then be uncoupled, and their normal
entries hold the target's linear equivalent (`hunt_crossley_normal`), which the linear analyses of
the contact (the scene check, the stability of the delayed loop) read.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, cast

import numpy as np

from dockhil.contact import rigid, rigidbody
from dockhil.contact.hunt_crossley import TargetContact, linear_equivalent
from dockhil.contact.interface6 import InterfaceGeometry, add6, interface_state, mat3t_vec, sub6
from dockhil.contact.rigid import Motion, Wrench, WrenchOf
from dockhil.contact.rigidbody import BodyState, RigidBody, check_symmetric
from dockhil.contact.rotations import Vec3, rotate
from dockhil.contact.scenario import ContactModelError, check_nonnegative, check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


class MatVec6:
    """v -> A v for a fixed 6x6 matrix A on plain floats (the per-tick products of the
    contact matrices). A diagonal A costs six products; a zero one, none."""

    __slots__ = ("rows", "diagonal", "zero")

    def __init__(self, a):
        a = np.asarray(a, float)
        self.rows = tuple(tuple(float(c) for c in row) for row in a)
        off = a - np.diag(np.diag(a))
        self.diagonal = tuple(float(c) for c in np.diag(a)) if not off.any() else None
        self.zero = not a.any()

    def __call__(self, v: Sequence[float]) -> tuple:
        if self.zero:
            return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        v0, v1, v2, v3, v4, v5 = v
        if self.diagonal is not None:
            d = self.diagonal
            return (d[0] * v0, d[1] * v1, d[2] * v2, d[3] * v3, d[4] * v4, d[5] * v5)
        r0, r1, r2, r3, r4, r5 = self.rows
        return (
            r0[0] * v0 + r0[1] * v1 + r0[2] * v2 + r0[3] * v3 + r0[4] * v4 + r0[5] * v5,
            r1[0] * v0 + r1[1] * v1 + r1[2] * v2 + r1[3] * v3 + r1[4] * v4 + r1[5] * v5,
            r2[0] * v0 + r2[1] * v1 + r2[2] * v2 + r2[3] * v3 + r2[4] * v4 + r2[5] * v5,
            r3[0] * v0 + r3[1] * v1 + r3[2] * v2 + r3[3] * v3 + r3[4] * v4 + r3[5] * v5,
            r4[0] * v0 + r4[1] * v1 + r4[2] * v2 + r4[3] * v3 + r4[4] * v4 + r4[5] * v5,
            r5[0] * v0 + r5[1] * v1 + r5[2] * v2 + r5[3] * v3 + r5[4] * v4 + r5[5] * v5,
        )


def check_matrix6(name: str, value: object, unit: str) -> np.ndarray:
    """A 6x6 symmetric PSD matrix; a 6-vector means its diagonal."""
    arr = np.asarray(value, dtype=float) if rigidbody.is_numeric(value) else None
    if arr is not None and arr.shape == (6,):
        if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
            raise ContactModelError(f"{name} diagonal must be 6 finite numbers >= 0 [{unit}], got {arr.tolist()}")
        return np.diag(arr)
    return check_symmetric(name, value, 6, definite=False, unit=unit)


@dataclass(frozen=True)
class Contact6:
    """Spring-dashpot between the interfaces: stiffness [N/m, N/rad, coupled]
    and damping (6x6 symmetric PSD, or a 6-vector for the diagonal, axes
    x y z rx ry rz of the target's interface frame); friction coefficient mu
    and its regularising sliding speed [m/s]; `normal`: a Hunt-Crossley law
    for the normal axis in place of its row of K e + C e' (module text)."""

    stiffness: np.ndarray
    damping: np.ndarray = field(default_factory=lambda: np.zeros(6))
    mu: float = 0.0
    slip_velocity: float = 1e-3
    normal: TargetContact | None = None
    if TYPE_CHECKING:  # also set in __post_init__, as attributes only: the per-tick products K v and C v
        stiffness_of: MatVec6 = field(init=False)
        damping_of: MatVec6 = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "stiffness", check_matrix6("stiffness", self.stiffness, "N/m, N m/rad"))
        object.__setattr__(self, "damping", check_matrix6("damping", self.damping, "N s/m, N m s/rad"))
        object.__setattr__(self, "mu", check_nonnegative("mu", self.mu))
        object.__setattr__(self, "slip_velocity", check_positive("slip_velocity", self.slip_velocity, "m/s"))
        if self.normal is not None:
            if self.normal.kind != "hunt_crossley":
                raise ContactModelError(f"the normal law must be a hunt_crossley contact, got {self.normal.kind!r}")
            for name, matrix in (("stiffness", self.stiffness), ("damping", self.damping)):
                if np.any(matrix[0, 1:] != 0.0):
                    raise ContactModelError(
                        f"contact hunt_crossley: the {name}'s normal row couples x to the other axes"
                        f" ({matrix[0, 1:].tolist()}); give a diagonal normal entry"
                    )
        # The per-tick products K v and C v on plain floats.
        object.__setattr__(self, "stiffness_of", MatVec6(self.stiffness))
        object.__setattr__(self, "damping_of", MatVec6(self.damping))

    @property
    def dissipative(self) -> bool:
        return bool(np.any(self.damping != 0.0) or self.mu > 0.0 or (self.normal is not None and self.normal.alpha))

    def normal_force(self, penetration: float, rate: float) -> float:
        """[N] the compressive Hunt-Crossley normal force at penetration d and its rate d' (`normal` set)."""
        return cast(TargetContact, self.normal).force(penetration, rate)


def hunt_crossley_normal(model: Contact6, target: TargetContact, mass: float, v_close: float) -> Contact6:
    """`model` with the Hunt-Crossley `target` on its normal axis: the normal entries of K and C become the
    target's linear equivalent for the reduced mass `mass` [kg] at the closing velocity `v_close` [m/s]
    (its secant stiffness at the deepest undamped penetration and the damping of its restitution)."""
    if not target.kcs > 0.0:
        raise ContactModelError(f"contact hunt_crossley: kcs (the normal stiffness) must be > 0, got {target.kcs!r}")
    stiffness, damping = model.stiffness.copy(), model.damping.copy()
    stiffness[0, 0], damping[0, 0] = linear_equivalent(target, mass, check_positive("v_close", v_close, "m/s"))
    return Contact6(stiffness, damping, model.mu, model.slip_velocity, target)


def contact_wrench(
    model: Contact6, g: InterfaceGeometry, rate: Sequence[float], anchor: Sequence[float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F, M, generalized force) on body 1 at o_A while touching; the springs
    pull toward `anchor` (the onset pose, normal axis 0)."""
    force, moment, q = contact_wrench3(model, g, rate, anchor)
    return np.array(force), np.array(moment), np.array(q)


def contact_wrench3(
    model: Contact6, g: InterfaceGeometry, rate: Sequence[float], anchor: Sequence[float]
) -> tuple[tuple, tuple, tuple]:
    """`contact_wrench` on plain floats (the integrator's kicks): F = -R_B q_t, M = -R_B J^-T q_r."""
    q = add6(model.stiffness_of(sub6(g.e, anchor)), model.damping_of(rate))
    if model.normal is not None:  # the normal row is uncoupled: its law alone
        q = (model.normal_force(g.e[0] - anchor[0], rate[0]),) + q[1:]
    fx, fy, fz = rotate(g.q_b, q[:3])
    if model.mu > 0.0:  # regularised Coulomb friction on A's sliding (u = e'_y, e'_z), in B's axes
        u1, u2 = rate[1], rate[2]
        scale = model.mu * max(q[0], 0.0) / math.sqrt(u1 * u1 + u2 * u2 + model.slip_velocity**2)
        tx, ty, tz = rotate(g.q_b, (0.0, scale * u1, scale * u2))
        fx, fy, fz = fx + tx, fy + ty, fz + tz
    mx, my, mz = rotate(g.q_b, mat3t_vec(g.jinv3, q[3:]))
    return (-fx, -fy, -fz), (-mx, -my, -mz), q


class IdealContactWrench(Wrench):
    """The ideal contact as the integrator's wrench, active while `touching`."""

    def __init__(self, model: Contact6):
        self.model = model
        self.velocity_dependent = model.dissipative
        self.touching = False
        self.anchor = (0.0,) * 6

    def start(self, m1: Motion, m2: Motion) -> None:
        """Contact onset: the tangential and rotational springs rest at the pose of first touch."""
        self.touching = True
        self.anchor = (0.0,) + InterfaceGeometry(m1, m2).e[1:]

    def prepare(self, m1: Motion, m2: Motion) -> tuple[Vec3, WrenchOf]:
        g = InterfaceGeometry(m1, m2)
        if not self.touching:
            zero = (0.0, 0.0, 0.0)
            return g.point, lambda v1, w1, v2, w2: (zero, zero)
        model, anchor = self.model, self.anchor

        def wrench_of(v1, w1, v2, w2):
            force, moment, _ = contact_wrench3(model, g, g.rate(v1, w1, v2, w2), anchor)
            return force, moment

        return g.point, wrench_of


def touching_at(m1: Motion, m2: Motion) -> bool:
    """Penetrating, or at the surface and closing in (as the 1-DOF library)."""
    g, rate = interface_state(m1, m2)
    return g.e[0] > 0.0 or (g.e[0] == 0.0 and rate[0] > 0.0)


# --- the contact run ------------------------------------------------------------------------


@dataclass
class Run6:
    """Samples of a two-body 6-DOF run at t = n dt.

    positions, velocities [m, m/s] (n, 2, 3) of the CoMs in world;
    orientations (n, 2, 4) of the body frames; omegas (n, 2, 3) in world [rad/s];
    force (n, 3) [N] on the chaser in world and torque (n, 3) [N m] on the chaser
    about its interface origin; e, rate (n, 6) interface coordinates;
    momentum (n, 3), angular_momentum (n, 3) about the world origin; energy (n,)
    kinetic + contact potential [J]; in_contact (n,); onset, exit [s] or None;
    generalized (n, 6): the contact's generalized force K (e - anchor) + C e'
    (its first entry is the compressive normal force); anchor: the spring
    rest pose of the (last) contact.
    """

    t: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    orientations: np.ndarray
    omegas: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    e: np.ndarray
    rate: np.ndarray
    momentum: np.ndarray
    angular_momentum: np.ndarray
    energy: np.ndarray
    in_contact: np.ndarray
    onset: float | None
    exit: float | None
    final: tuple
    generalized: np.ndarray | None = None
    anchor: np.ndarray | None = None
    impedance: object = None  # the hybrid loop's Impedance6

    @property
    def normal_force(self) -> np.ndarray:
        """Compressive force [N] along the target interface's normal (the 1-DOF 'force')."""
        return cast(np.ndarray, self.generalized)[:, 0]  # a run's own: recorded

    def peak(self, what: str) -> float:
        return float(np.max(np.linalg.norm(getattr(self, what), axis=1)))


class Recorder:
    """Collects the samples of a run."""

    def __init__(self, steps: int):
        n = steps + 1
        self.t = np.empty(n)
        self.pos = np.empty((n, 2, 3))
        self.vel = np.empty((n, 2, 3))
        self.quat = np.empty((n, 2, 4))
        self.omega = np.empty((n, 2, 3))
        self.force = np.zeros((n, 3))
        self.torque = np.zeros((n, 3))
        self.e = np.empty((n, 6))
        self.rate = np.empty((n, 6))
        self.p = np.empty((n, 3))
        self.l = np.empty((n, 3))
        self.energy = np.empty(n)
        self.flag = np.zeros(n, dtype=bool)
        self.q = np.zeros((n, 6))

    def record(
        self,
        i: int,
        t: float,
        m1: Motion,
        m2: Motion,
        force: ArrayLike,
        torque: ArrayLike,
        q: ArrayLike,
        potential: float,
        touching: bool,
    ) -> None:
        g, rate = interface_state(m1, m2)
        self.t[i] = t
        for j, m in enumerate((m1, m2)):
            st = m.state()
            self.pos[i, j] = st.position
            self.vel[i, j] = st.velocity
            self.quat[i, j] = st.orientation
            self.omega[i, j] = m.omega_world()
        self.force[i], self.torque[i], self.q[i] = force, torque, q
        self.e[i], self.rate[i] = g.e, rate
        self.p[i] = rigid.total_momentum(m1, m2)
        self.l[i] = rigid.total_angular_momentum(m1, m2)
        self.energy[i] = m1.kinetic_energy() + m2.kinetic_energy() + potential
        self.flag[i] = touching

    def run(
        self,
        onset: float | None,
        exit_time: float | None,
        final: tuple,
        anchor: np.ndarray | None,
        n: int | None = None,
    ) -> Run6:
        """The run of the first n samples (all by default)."""
        k = slice(None, n)
        return Run6(
            self.t[k],
            self.pos[k],
            self.vel[k],
            self.quat[k],
            self.omega[k],
            self.force[k],
            self.torque[k],
            self.e[k],
            self.rate[k],
            self.p[k],
            self.l[k],
            self.energy[k],
            self.flag[k],
            onset,
            exit_time,
            final,
            self.q[k],
            anchor,
        )


def _step_with_events(m1: Motion, m2: Motion, wrench: IdealContactWrench, h: float, order: int) -> list:
    """One step of h with contact onset/separation located inside it (bisection on the
    step map, as the 1-DOF library): returns [(time into the step, touching after)].
    A contact that starts and ends within one step is not seen."""
    events: list[tuple[float, bool]] = []
    done = 0.0
    remaining = h
    for _ in range(16):
        start = (m1.copy(), m2.copy())
        rigid.step(m1, m2, wrench, remaining, order)
        if touching_at(m1, m2) == wrench.touching:
            return events
        lo, hi = 0.0, remaining
        while hi - lo > 4.0 * np.finfo(float).eps * max(1.0, hi):
            mid = 0.5 * (lo + hi)
            a, b = start[0].copy(), start[1].copy()
            rigid.step(a, b, wrench, mid, order)
            if touching_at(a, b) == wrench.touching:
                lo = mid
            else:
                hi = mid
        a, b = start
        rigid.step(a, b, wrench, hi, order)
        _assign(m1, a)
        _assign(m2, b)
        done += hi
        remaining -= hi
        if wrench.touching:
            wrench.touching = False
        else:
            wrench.start(m1, m2)
        events.append((done, wrench.touching))
        if remaining <= 0.0:
            return events
    raise ContactModelError(f"more than 16 contact events within one step of {h:.6g} s (chatter); use a smaller dt")


def _assign(dst: Motion, src: Motion) -> None:
    dst.x, dst.v, dst.q, dst.L = src.x, src.v, src.q, src.L


def potential_energy(model: Contact6, g: InterfaceGeometry, anchor: Sequence[float], touching: bool) -> float:
    """1/2 (e - anchor)^T K (e - anchor) [J] while touching (a Hunt-Crossley normal: its own potential
    on the normal axis)."""
    if not touching:
        return 0.0
    de = np.array(g.e) - anchor
    energy = 0.5 * float(de @ model.stiffness @ de)
    if model.normal is not None:
        energy += model.normal.potential(float(de[0])) - 0.5 * float(model.stiffness[0, 0]) * float(de[0]) ** 2
    return energy


def simulate_contact6(
    body1: RigidBody,
    body2: RigidBody,
    state1: BodyState,
    state2: BodyState,
    model: Contact6,
    *,
    dt: float = 1e-3,
    t_end: float = 2.0,
    order: int = 4,
    substeps: int = 1,
    until_exit: bool = False,
) -> Run6:
    """Fixed-step run of the ideal 6-DOF contact from the given states, samples
    every dt [s]; each sample interval is `substeps` integrator steps. With
    `until_exit` the run ends at the first sample after the contact ended (what
    follows is free flight), so its length is the contact's, not t_end's."""
    dt = check_positive("dt", dt, "s")
    t_end = check_positive("t_end", t_end, "s")
    if int(substeps) != substeps or substeps < 1:
        raise ContactModelError(f"substeps must be a whole number >= 1, got {substeps!r}")
    m1, m2 = Motion.from_state(body1, state1), Motion.from_state(body2, state2)
    wrench = IdealContactWrench(model)
    if touching_at(m1, m2):
        wrench.start(m1, m2)
    steps = int(math.ceil(t_end / dt - 1e-9))
    rec = Recorder(steps)
    onset = 0.0 if wrench.touching else None
    exit_time = None
    h = dt / substeps

    def sample(i):
        g, rate = interface_state(m1, m2)
        if wrench.touching:
            force, moment, q = contact_wrench(model, g, rate, wrench.anchor)
        else:
            force, moment, q = np.zeros(3), np.zeros(3), np.zeros(6)
        rec.record(
            i,
            i * dt,
            m1,
            m2,
            force,
            moment,
            q,
            potential_energy(model, g, wrench.anchor, wrench.touching),
            wrench.touching,
        )

    sample(0)
    for i in range(steps):
        for j in range(substeps):
            for offset, now in _step_with_events(m1, m2, wrench, h, order):
                t_event = i * dt + j * h + offset
                if now and onset is None:
                    onset = t_event
                elif not now and exit_time is None and onset is not None:
                    exit_time = t_event
        sample(i + 1)
        if until_exit and exit_time is not None:
            return rec.run(onset, exit_time, (m1.state(), m2.state()), np.array(wrench.anchor), n=i + 2)
    return rec.run(onset, exit_time, (m1.state(), m2.state()), np.array(wrench.anchor))
