"""6-DOF science: torque-free conservation over a long run, steps per second of
the contact loops, and the hybrid loop's error against the ideal contact with
and without the robot delay. Prints one JSON object.

    python3 bench/sixdof.py [--seconds 1000] [--order4-seconds 200]

The torque-free run is a 750 kg body with a full (non-diagonal) inertia
spinning at 0.3 rad/s, stepped at 1 kHz; the drift is the slope of a
straight-line fit of the relative energy error over time, extrapolated to
1000 s, next to the largest error seen. The last part is the linearised
6-DOF hybrid loop of the contact case: its rightmost root and the factor on
the passive stiffness at which the delay makes it unstable, with the axis
that leads the crossing mode.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from dockhil.contact.contact6 import Contact6, simulate_contact6
from dockhil.contact.hybrid6 import simulate_hybrid6
from dockhil.contact.impedance6 import interface_mobilities
from dockhil.contact.rigid import Motion, free_step
from dockhil.contact.rigidbody import BodyState, RigidBody
from dockhil.contact.rotations import quat_from_rotvec
from dockhil.contact.stability6 import hybrid_loop6, rightmost, stiffness_margin

INERTIA = np.array([[1200.0, 30.0, -10.0], [30.0, 900.0, 20.0], [-10.0, 20.0, 1500.0]])


def torque_free(seconds: float, order: int, dt: float = 1e-3) -> dict:
    body = RigidBody(750.0, INERTIA, com=[0.1, 0.0, 0.05], interface_position=[1.0, 0.0, 0.0])
    state = BodyState([0, 0, 0], quat_from_rotvec([0.3, -0.2, 0.1]), [0.01, 0, 0], [0.05, 0.3, -0.02])
    m = Motion.from_state(body, state)
    e0, l0 = m.kinetic_energy(), m.angular_momentum()
    steps = int(round(seconds / dt))
    every = max(1, steps // 2000)
    times, energy, momentum, unit = [], [], [], []
    start = time.perf_counter()
    for i in range(1, steps + 1):
        free_step(m, dt, order)
        if i % every == 0:
            times.append(i * dt)
            energy.append(m.kinetic_energy() / e0 - 1.0)
            momentum.append(float(np.linalg.norm(m.angular_momentum() - l0) / np.linalg.norm(l0)))
            unit.append(abs(math.sqrt(sum(c * c for c in m.q)) - 1.0))
    wall = time.perf_counter() - start
    slope = float(np.polyfit(times, energy, 1)[0])
    return {
        "order": order,
        "seconds": seconds,
        "dt": dt,
        "steps_per_s": steps / wall,
        "energy_max_rel_error": float(np.max(np.abs(energy))),
        "energy_drift_per_1000s": slope * 1000.0,
        "angular_momentum_max_rel_error": float(np.max(momentum)),
        "quaternion_norm_max_error": float(np.max(unit)),
    }


def off_axis_case():
    i1 = np.array([[40.0, 2, -1], [2, 50, 3], [-1, 3, 60]])
    i2 = np.array([[80.0, -4, 2], [-4, 70, 1], [2, 1, 90]])
    chaser = RigidBody(
        100.0,
        i1,
        com=[0.05, 0.02, 0],
        interface_position=[1.0, 0.1, -0.05],
        interface_orientation=quat_from_rotvec([0, 0, 0.05]),
    )
    target = RigidBody(
        200.0, i2, interface_position=[-1.0, 0.0, 0.0], interface_orientation=quat_from_rotvec([0.02, 0, 0])
    )
    s1 = BodyState([-1.951, 0.3, 0.1], quat_from_rotvec([0.01, 0.02, -0.03]), [0.05, 0.01, 0], [0.02, -0.03, 0.05])
    s2 = BodyState([0.0, 0.3, 0.1], (0, 0, 0, 1), [0, 0, 0.0], [0, 0.02, 0])
    k = np.diag([1000.0, 400, 500, 150, 120, 100])
    k[0, 4] = k[4, 0] = 50.0
    k[1, 5] = k[5, 1] = -40.0
    ideal = Contact6(k, np.diag([20.0, 5, 5, 2, 2, 2]))
    passive = Contact6(np.diag([600.0, 200, 200, 80, 60, 50]))
    return chaser, target, s1, s2, ideal, passive


def errors(ideal, hybrid) -> dict:
    out = {
        "peak_force_rel": hybrid.peak("force") / ideal.peak("force") - 1.0,
        "peak_torque_rel": hybrid.peak("torque") / ideal.peak("torque") - 1.0,
    }
    for j, body in enumerate(("chaser", "target")):
        for name, key in (("velocities", "v"), ("omegas", "w")):
            a, b = getattr(ideal, name), getattr(hybrid, name)
            change = np.linalg.norm(a[-1, j] - a[0, j])
            out[f"{body}_exit_{key}_rel"] = float(np.linalg.norm(a[-1, j] - b[-1, j]) / change)
    return {k: float(v) for k, v in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1000.0, help="torque-free run, order 2 [s]")
    parser.add_argument("--order4-seconds", type=float, default=200.0, help="torque-free run, order 4 [s]")
    args = parser.parse_args()
    result = {"torque_free": [torque_free(args.seconds, 2), torque_free(args.order4_seconds, 4)]}

    chaser, target, s1, s2, ideal, passive = off_axis_case()
    start = time.perf_counter()
    ref = simulate_contact6(chaser, target, s1, s2, ideal, dt=1e-3, t_end=1.2)
    ideal_rate = (ref.t.size - 1) / (time.perf_counter() - start)
    start = time.perf_counter()
    hyb = simulate_hybrid6(chaser, target, s1, s2, ideal, passive, dt=1e-3, t_end=1.2)
    hybrid_rate = (hyb.t.size - 1) / (time.perf_counter() - start)
    delayed = simulate_hybrid6(chaser, target, s1, s2, ideal, passive, dt=1e-3, t_end=1.2, delay_ticks=32)
    result["contact_steps_per_s"] = {"ideal_order4_event_located": ideal_rate, "hybrid_sampled_order4": hybrid_rate}
    result["hybrid_vs_ideal_1kHz"] = {"no_delay": errors(ref, hyb), "delay_32ms": errors(ref, delayed)}
    result["contact"] = {
        "onset_s": ref.onset,
        "exit_s": ref.exit,
        "peak_force_N": ref.peak("force"),
        "peak_torque_Nm": ref.peak("torque"),
        "momentum_rel_drift": float(
            np.max(np.linalg.norm(ref.momentum - ref.momentum[0], axis=1)) / np.linalg.norm(ref.momentum[0])
        ),
        "angular_momentum_rel_drift": float(
            np.max(np.linalg.norm(ref.angular_momentum - ref.angular_momentum[0], axis=1))
            / np.linalg.norm(ref.angular_momentum[0])
        ),
    }
    # The same contact's linearised hybrid loop: which mode the delay destabilises first.
    g1, g2 = interface_mobilities(chaser, target, s1, s2)
    result["stability_6dof"] = []
    for h in (0.016, 0.032):
        loop = hybrid_loop6(ideal, passive, g1, g2, h)
        start = time.perf_counter()
        root = rightmost(loop)
        margin = stiffness_margin(loop)
        result["stability_6dof"].append(
            {
                "h_s": h,
                "rightmost_root": [root.s.real, root.s.imag],
                "rightmost_axis": root.axis,
                "passive_stiffness_margin": margin.alpha,
                "crossing_rad_s": margin.omega,
                "limiting_axis": None if margin.root is None else margin.root.axis,
                "seconds": time.perf_counter() - start,
            }
        )
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
