"""Plots of a 6-DOF run (`dockhil plot --6dof`): the F/T wrench, the relative pose of the chaser's
interface in the target's, and both bodies' angular velocities, from a bag of launch/hil6.yaml."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dockhil.analysis.plots.figure_file import save_figure
from dockhil.errors import DockhilError


@dataclass
class Series6:
    """Per-tick arrays of a 6-DOF bag, each with its own time [s] (header stamps).
    force, torque (n, 3): the F/T reading on the target, sensor frame [N, N m];
    position (n, 3) [m], rotation (n, 3) [rad, rotation vector]: A's pose in B (the robot command);
    omega (n, 2, 3): chaser and target angular velocities, world [rad/s]."""

    t_ft: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    t_pose: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    t_state: np.ndarray
    omega: np.ndarray


def series6(path: str) -> Series6:
    from dockhil.bags.reader import BagReader
    from dockhil.contact.rotations import quat_to_rotvec

    ft, pose, state = [], [], []
    with BagReader(path) as bag:
        for topic, _t, msg in bag.decoded(["/ft/wrench", "/robot/command", "/satellite/state"]):
            if topic == "/ft/wrench":
                f, m = msg.wrench.force, msg.wrench.torque
                ft.append((msg.header.stamp, f.x, f.y, f.z, m.x, m.y, m.z))
            elif topic == "/robot/command":
                p, o = msg.pose.position, msg.pose.orientation
                pose.append((msg.header.stamp, p.x, p.y, p.z, *quat_to_rotvec((o.x, o.y, o.z, o.w))))
            elif len(msg.bodies) >= 2:
                w = [b.twist.angular for b in msg.bodies[:2]]
                state.append((msg.header.stamp, w[0].x, w[0].y, w[0].z, w[1].x, w[1].y, w[1].z))
    if not state or not pose:
        raise DockhilError(
            f"{path}: no /satellite/state or /robot/command messages; record a 6-DOF run"
            " (launch/hil6.yaml with --bag) to plot it"
        )
    ft_a = np.array(sorted(ft)).reshape(-1, 7)
    pose_a, state_a = np.array(sorted(pose)), np.array(sorted(state))
    return Series6(
        ft_a[:, 0],
        ft_a[:, 1:4],
        ft_a[:, 4:7],
        pose_a[:, 0],
        pose_a[:, 1:4],
        pose_a[:, 4:7],
        state_a[:, 0],
        state_a[:, 1:].reshape(-1, 2, 3),
    )


def separation(s: Series6) -> float | None:
    """The time the bodies part: the first F/T sample after contact whose force and torque are 0."""
    acting = np.any(s.force != 0.0, axis=1) | np.any(s.torque != 0.0, axis=1)
    touched = np.flatnonzero(acting)
    if touched.size == 0:
        return None
    after = np.flatnonzero(~acting[touched[0] :])
    return float(s.t_ft[touched[0] + after[0]]) if after.size else None


def plot6(
    bags: list[str],
    png: str,
    labels: list[str] | None = None,
    title: str = "6-DOF contact: wrench, relative pose, angular rates",
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(5, 1, sharex=True, figsize=(8, 13.5))
    for i, path in enumerate(bags):
        s = series6(path)
        # One run: its name is the title's, and each curve is named by its axis alone.
        label = "" if len(bags) == 1 else (labels[i] if labels else path.rsplit("/", 1)[-1]) + ": "
        for j, c in enumerate("xyz"):
            axes[0].plot(s.t_ft, s.force[:, j], label=f"{label}F{c}")
            axes[1].plot(s.t_ft, s.torque[:, j], label=f"{label}T{c}")
            axes[2].plot(s.t_pose, s.position[:, j], label=f"{label}{c}")
            axes[3].plot(s.t_pose, s.rotation[:, j], label=f"{label}r{c}")
            for b, body in enumerate(("chaser", "target")):
                axes[4].plot(s.t_state, s.omega[:, b, j], label=f"{label}{body} w{c}")
        parted = separation(s)
        if parted is not None:  # the wrench ends there: the torque's drop to 0 is the contact's end
            for k, ax in enumerate(axes):
                ax.axvline(parted, color="0.3", ls=":", lw=1.0, label=f"{label}separation" if k < 2 else None)
    for ax, text in zip(
        axes,
        (
            "F/T force on target, sensor axes [N]",
            "F/T torque, sensor axes [N m]",
            "A in B: position [m]",
            "A in B: rotation vector [rad]",
            "angular velocity, world [rad/s]",
        ),
    ):
        ax.set_ylabel(text, fontsize=8)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7 if len(bags) == 1 else 6, ncol=3 if len(bags) > 1 else 4)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, png)
