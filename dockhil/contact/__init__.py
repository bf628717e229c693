"""The contact-dynamics science of the paper, as plain functions and small
classes: no I/O, no processes, no transport. Each name below is imported
from its module on first use, so a node that steps the loop loads the
loop's modules and not, say, the stability analysis; they load numpy, and
scipy only inside `simulate_reference` (solve_ivp), the one function that
needs it.

    from dockhil.contact import TABLE1, fit_impedance, ideal_contact_summary
    fit_impedance(TABLE1).impedance   # k1 = 2001.5, b1 = 40.03, k2 = 2.6687e6, b2 = 53373

Modules: scenario (parameters, TABLE1, errors), ideal (Eq. 1), hybrid
(Eqs. 2-4), impedance (Eqs. 5-6 and the closed form), stability (Eqs. 7-12
and the exact delay boundary), integrators (stepping and contact runs).
"""

from __future__ import annotations

import importlib
from typing import Any

# module -> the names it provides here
_PROVIDES = {
    "hybrid": (
        "VirtualImpedance",
        "hybrid_contact_forces",
        "passive_force",
        "virtual_forces",
    ),
    "ideal": (
        "ContactSummary",
        "contact_duration",
        "ideal_contact_force",
        "ideal_contact_summary",
        "ideal_trajectory",
        "relative_motion",
    ),
    "impedance": (
        "ImpedanceFit",
        "fit_impedance",
        "ideal_states",
        "impedance_closed_form",
        "recommended_fit_times",
    ),
    "integrators": (
        "METHODS",
        "Integrator",
        "LinearSecondOrderSystem",
        "max_stable_step",
        "simulate_contact",
        "simulate_reference",
        "step_matrices",
    ),
    "linalg": ("expm",),
    "scenario": (
        "TABLE1",
        "TABLE1_PRINTED_IMPEDANCE",
        "ContactModelError",
        "ContactScenario",
        "FitError",
        "NegativeVirtualStiffnessWarning",
        "StepTooLargeError",
        "Trajectory",
        "UnstableStepWarning",
    ),
    "stability": (
        "DAMPERS",
        "StabilityBound",
        "characteristic_roots",
        "critical_stiffness_map",
        "exact_bound",
        "growth_rate",
        "no_stabilizing_stiffness_reason",
        "pade1_bound",
        "pade_bound",
        "rightmost_root",
        "stability_report",
    ),
}
_MODULE_OF = {name: module for module, names in _PROVIDES.items() for name in names}
__all__ = sorted(_MODULE_OF)


def __getattr__(name: str) -> Any:  # whatever the named module defines
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # looked up once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
