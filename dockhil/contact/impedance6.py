"""The 6x6 virtual impedance of the hybrid 6-DOF model (dockhil.contact.hybrid6, whose module text
derives it): each body's mobility at the contact point, the wall split, the closed form and the
two-time fit (Eqs. 5-6) per axis."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from dockhil.contact.contact6 import Contact6, Run6
from dockhil.contact.interface6 import AXES, InterfaceGeometry, skew
from dockhil.contact.rigid import Motion
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.rotations import Quat, Vec3, quat_to_matrix
from dockhil.contact.scenario import ContactModelError, FitError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


def wrench_map(g: InterfaceGeometry) -> np.ndarray:
    """S (6x6): [F; M about o_A] on body 1 = -S q for a generalized force q."""
    s = np.zeros((6, 6))
    s[:3, :3] = g.rot_b
    s[3:, 3:] = g.rot_b @ g.jinv.T
    return s


def body_mobility(m: Motion, point: Vec3, g: InterfaceGeometry) -> np.ndarray:
    """G_i (6x6, symmetric positive definite) of one body at `point`, generalized coordinates."""
    return mobility(m.body, m.x, m.q, point, g)


def mobility(body: RigidBody, x: Vec3, q: Quat, point: Vec3, g: InterfaceGeometry) -> np.ndarray:
    """`body_mobility` of a body at CoM x with principal-frame attitude q."""
    rot = quat_to_matrix(q)
    inv_inertia = (rot / body.principal_moments) @ rot.T
    rho = skew(np.asarray(point) - x)
    spatial = np.block(
        [
            [np.eye(3) / body.mass - rho @ inv_inertia @ rho, -rho @ inv_inertia],
            [inv_inertia @ rho, inv_inertia],
        ]
    )
    pt = np.zeros((6, 6))
    pt[:3, :3] = g.rot_b.T
    pt[3:, 3:] = g.jinv @ g.rot_b.T
    return pt @ spatial @ pt.T


def interface_mobilities(
    body1: RigidBody, body2: RigidBody, state1: BodyState, state2: BodyState
) -> tuple[np.ndarray, np.ndarray]:
    """(G1, G2) at the chaser's interface origin for the given states."""
    m1, m2 = Motion.from_state(body1, state1), Motion.from_state(body2, state2)
    g = InterfaceGeometry(m1, m2)
    return body_mobility(m1, g.point, g), body_mobility(m2, g.point, g)


@dataclass(frozen=True)
class Impedance6:
    """Virtual stiffness and damping of chaser (1) and target (2) on the wall
    (6x6, need not be symmetric), and the wall split D_1, D_2 they act through."""

    k1: np.ndarray
    c1: np.ndarray
    k2: np.ndarray
    c2: np.ndarray
    d1: np.ndarray
    d2: np.ndarray

    def per_axis(self) -> dict[str, dict[str, float]]:
        """Diagonal entries by axis (the whole story only when the axes decouple)."""
        return {
            a: {
                "k1": float(self.k1[i, i]),
                "c1": float(self.c1[i, i]),
                "k2": float(self.k2[i, i]),
                "c2": float(self.c2[i, i]),
            }
            for i, a in enumerate(AXES)
        }


def wall_split(g1: np.ndarray, g2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """D_i = G_i (G1 + G2)^-1: each body's share of the relative displacement."""
    total = np.linalg.inv(g1 + g2)
    return g1 @ total, g2 @ total


def check_frictionless(ideal: Contact6) -> None:
    if ideal.mu > 0.0:
        raise ContactModelError(
            f"the hybrid 6-DOF model reproduces a frictionless ideal contact (mu = {ideal.mu!r});"
            " set mu = 0 in the ideal contact: friction comes from the hardware"
        )


def impedance_closed_form6(ideal: Contact6, passive: Contact6, g1: np.ndarray, g2: np.ndarray) -> Impedance6:
    """K_i, C_i with K_i D_i = K - K_p and C_i D_i = C - C_p (exact: see the module text)."""
    check_frictionless(ideal)
    d1, d2 = wall_split(g1, g2)
    dk, dc = ideal.stiffness - passive.stiffness, ideal.damping - passive.damping
    inv1, inv2 = np.linalg.inv(d1), np.linalg.inv(d2)
    return Impedance6(dk @ inv1, dc @ inv1, dk @ inv2, dc @ inv2, d1, d2)


def fit_impedance6(
    run: Run6,
    times: Iterable[float],
    passive: Contact6,
    g1: ArrayLike,
    g2: ArrayLike,
    axes: Iterable[str] = AXES,
    max_condition: float = 1e8,
) -> dict[str, tuple[float, float, float, float]]:
    """The two-time fit (Eqs. 5-6) per axis: (k1, c1, k2, c2) for each axis in `axes`.

    At two times inside the contact of the ideal `run`, the virtual part must
    supply what the ideal contact exerts beyond the passive one:
        y(t) = q_ideal(t) - K_p (e - e_0) - C_p e'
    and body i sees the wall displacement D_i (e - e_0) and rate D_i e'. Axis j
    then gives the 2x2 system y_j = k_ij (D_i (e - e_0))_j + c_ij (D_i e')_j.
    It is exact where D_i is diagonal (interface on principal axes through the
    CoM, or pure translation); with a lever arm the axes couple and the
    diagonal fit is an approximation of `impedance_closed_form6`.
    """
    t_list = [float(t) for t in times]
    if len(t_list) != 2:
        raise FitError(f"the fit takes two times inside the contact, got {len(t_list)}")
    d1, d2 = wall_split(np.asarray(g1, float), np.asarray(g2, float))
    idx = []
    for t in t_list:
        i = int(round(t / (run.t[1] - run.t[0])))
        if not (0 <= i < run.t.size and abs(run.t[i] - t) < 1e-9 * max(1.0, t) and run.in_contact[i]):
            raise FitError(
                f"t = {t:.10g} s is not a sample of the run inside the contact"
                f" (onset {run.onset}, exit {run.exit}); choose two samples about 1/3 and 2/3 into it"
            )
        idx.append(i)
    if idx[0] == idx[1]:
        raise FitError(f"t1 = t2 = {t_list[0]:.10g} s gives two identical rows (singular); choose two different times")
    out = {}
    for axis in axes:
        if axis not in AXES:
            raise FitError(f"unknown axis {axis!r}; axes are {', '.join(AXES)}")
        j = AXES.index(axis)
        rows: dict[int, list[list[float]]] = {1: [], 2: []}
        rhs = []
        for i in idx:
            de = run.e[i] - run.anchor
            y = cast(np.ndarray, run.generalized)[i] - passive.stiffness @ de - passive.damping @ run.rate[i]
            rhs.append(y[j])
            rows[1].append([(d1 @ de)[j], (d1 @ run.rate[i])[j]])
            rows[2].append([(d2 @ de)[j], (d2 @ run.rate[i])[j]])
        result = []
        for body in (1, 2):
            a = np.array(rows[body])
            scale = np.max(np.abs(a), axis=0)
            if np.any(scale == 0.0) or not np.all(np.isfinite(a)):
                raise FitError(
                    f"axis {axis}: the contact does not move this axis at the chosen times, so its"
                    " impedance cannot be fitted; fit only the axes the run excites or use the closed form"
                )
            cond = float(np.linalg.cond(a / scale))
            if cond > max_condition:
                raise FitError(
                    f"axis {axis}: times {t_list[0]:.6g} s and {t_list[1]:.6g} s give an ill-conditioned fit"
                    f" (condition {cond:.3g} > {max_condition:.3g}); choose two times about 1/3 and 2/3"
                    " into the contact"
                )
            result.extend(np.linalg.solve(a, np.array(rhs)).tolist())
        out[axis] = (result[0], result[1], result[2], result[3])
    return out
