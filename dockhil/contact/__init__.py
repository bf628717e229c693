"""The contact-dynamics science of the paper, as plain functions and small
classes: no I/O, no processes, no transport. Importing it loads numpy only;
scipy is imported inside `simulate_reference` (solve_ivp), the one function
that needs it.

    from dockhil.contact import TABLE1, fit_impedance, ideal_contact_summary
    fit_impedance(TABLE1).impedance   # k1 = 2001.5, b1 = 40.03, k2 = 2.6687e6, b2 = 53373

Modules: scenario (parameters, TABLE1, errors), ideal (Eq. 1), hybrid
(Eqs. 2-4), impedance (Eqs. 5-6 and the closed form), stability (Eqs. 7-12
and the exact delay boundary), integrators (stepping and contact runs).
"""

from dockhil.contact.hybrid import VirtualImpedance, hybrid_contact_forces, passive_force, virtual_forces
from dockhil.contact.ideal import (
    ContactSummary,
    contact_duration,
    ideal_contact_force,
    ideal_contact_summary,
    ideal_trajectory,
    relative_motion,
)
from dockhil.contact.impedance import (
    ImpedanceFit,
    fit_impedance,
    ideal_states,
    impedance_closed_form,
    recommended_fit_times,
)
from dockhil.contact.integrators import (
    METHODS,
    Integrator,
    LinearSecondOrderSystem,
    max_stable_step,
    simulate_contact,
    simulate_reference,
    step_matrices,
)
from dockhil.contact.linalg import expm
from dockhil.contact.scenario import (
    TABLE1,
    TABLE1_PRINTED_IMPEDANCE,
    ContactModelError,
    ContactScenario,
    FitError,
    NegativeVirtualStiffnessWarning,
    StepTooLargeError,
    Trajectory,
    UnstableStepWarning,
)
from dockhil.contact.stability import (
    DAMPERS,
    StabilityBound,
    characteristic_roots,
    critical_stiffness_map,
    exact_bound,
    growth_rate,
    no_stabilizing_stiffness_reason,
    pade1_bound,
    pade_bound,
    rightmost_root,
    stability_report,
)

__all__ = [
    "TABLE1",
    "TABLE1_PRINTED_IMPEDANCE",
    "ContactModelError",
    "ContactScenario",
    "ContactSummary",
    "DAMPERS",
    "FitError",
    "ImpedanceFit",
    "Integrator",
    "LinearSecondOrderSystem",
    "METHODS",
    "NegativeVirtualStiffnessWarning",
    "StabilityBound",
    "StepTooLargeError",
    "Trajectory",
    "UnstableStepWarning",
    "VirtualImpedance",
    "characteristic_roots",
    "contact_duration",
    "critical_stiffness_map",
    "exact_bound",
    "expm",
    "fit_impedance",
    "growth_rate",
    "hybrid_contact_forces",
    "ideal_contact_force",
    "ideal_contact_summary",
    "ideal_states",
    "ideal_trajectory",
    "impedance_closed_form",
    "max_stable_step",
    "no_stabilizing_stiffness_reason",
    "pade1_bound",
    "pade_bound",
    "passive_force",
    "recommended_fit_times",
    "relative_motion",
    "rightmost_root",
    "simulate_contact",
    "simulate_reference",
    "stability_report",
    "step_matrices",
    "virtual_forces",
]
