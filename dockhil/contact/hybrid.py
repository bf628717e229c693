"""The hybrid contact model of Eqs. 2-4: the real passive compliance k on the
robot plus virtual (software) springs and dampers k1, b1, k2, b2 that tie each
body to a virtual wall.

Equations, with the sign slips of the paper's Eq. 3 corrected:
    m1 x1'' = -k1 (x1 - w) - b1 (x1' - w') - k (x1 - x2)
    m2 x2'' = -k2 (x2 - w) - b2 (x2' - w') + k (x1 - x2)

The wall w is the centre of mass of the two bodies, w = (m1 x1 + m2 x2) / M.
At contact onset the CoM sits at the contact point, and without external
force it moves at V_CoM (Eq. 4), so w = V_CoM t in the paper's frame
(positions measured from the contact point). Taking w from the current state
keeps that meaning under thrust too, and it makes the virtual forces functions
of the penetration p = x1 - x2 alone, since x1 - w = (m2 / M) p and
x2 - w = -(m1 / M) p. Like the passive force, they act only while p > 0.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from dockhil.contact.scenario import check_finite


@dataclass(frozen=True)
class VirtualImpedance:
    """Virtual stiffness [N/m] and damping [N s/m] of chaser (1) and target (2)."""

    k1: float
    b1: float
    k2: float
    b2: float

    def __post_init__(self) -> None:
        for name, unit in (("k1", "N/m"), ("b1", "N s/m"), ("k2", "N/m"), ("b2", "N s/m")):
            object.__setattr__(self, name, check_finite(name, getattr(self, name), unit))

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def passive_force(penetration: float, k: float) -> float:
    """Compressive force [N] of the passive compliance: k p while p > 0, else 0."""
    return k * penetration if penetration > 0.0 else 0.0


def virtual_forces(
    x1: float, x2: float, v1: float, v2: float, m1: float, m2: float, impedance: VirtualImpedance
) -> tuple[float, float]:
    """Forces [N] of the virtual impedance on the chaser and on the target
    (positive along +x), zero out of contact. Cheap: call it every step."""
    p = x1 - x2
    pd = v1 - v2
    # Touching as in the ideal model: penetrating, or at the surface and closing in
    # (so the dashpot acts from the first sample of a contact that starts at p = 0).
    if p < 0.0 or (p == 0.0 and pd <= 0.0):
        return 0.0, 0.0
    total = m1 + m2
    imp = impedance
    return -(m2 / total) * (imp.k1 * p + imp.b1 * pd), (m1 / total) * (imp.k2 * p + imp.b2 * pd)


def hybrid_contact_forces(
    x1: float, x2: float, v1: float, v2: float, m1: float, m2: float, k: float, impedance: VirtualImpedance
) -> tuple[float, float]:
    """Total contact forces [N] on chaser and target (passive + virtual, +x positive)."""
    f1, f2 = virtual_forces(x1, x2, v1, v2, m1, m2, impedance)
    fp = passive_force(x1 - x2, k)
    return f1 - fp, f2 + fp
