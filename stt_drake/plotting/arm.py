"""Figures of a torque-controlled arm (the Franka): joint torques and funnel errors
(:func:`plot_joint_torques`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from stt_drake.plotting.style import PALETTE
from stt_drake.runlog import RunLog


def plot_joint_torques(log: Mapping[str, Any]) -> Figure:
    """Joint torques and funnel errors of a torque-controlled arm over time.

    Panels: the torque the robot was asked for (controller + gravity compensation, before
    saturation) on the heavy joints and on the wrist joints, each with its ± effort limits
    (dashed) when the log has `effort_limit`; the stage-1 error e₁ = ‖y − c‖/r and the
    largest stage-2 error max_i |e₂,i| (funnel boundary at 1). Windows where an external
    force acts (`external_force` ≠ 0) are shaded; the times the task target switches
    (`task_target`) are dotted.

    Args:
        log: a run log of the arm: `t`, `requested_torque` (T, J) and `funnel_errors`
            (T, 1 + J); optional `effort_limit` (J,), `external_force` (T, 3) and
            `task_target` (T, n).

    Returns:
        The figure: three axes sharing the time axis.
    """
    run = RunLog.of(log)
    t = run.t
    torque = run.rows("requested_torque")
    errors = run.rows("funnel_errors")
    limit = np.asarray(run["effort_limit"], dtype=float) if "effort_limit" in run else None
    joints = torque.shape[1]
    heavy = list(range(min(4, joints)))
    groups = [(heavy, "joints 1-4"), (list(range(len(heavy), joints)), f"joints 5-{joints}")]
    fig = Figure(figsize=(10.0, 8.0), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    colors = colormaps["tab10"](np.arange(joints) % 10)
    for ax, (members, title) in zip(axes[:2], groups, strict=True):
        for i in members:
            ax.plot(t, torque[:, i], color=colors[i], lw=1.2, label=f"joint {i + 1}")
            if limit is not None:
                for sign in (-1.0, 1.0):
                    ax.axhline(sign * limit[i], color=colors[i], ls="--", lw=0.8, alpha=0.7)
        ax.axhline(0.0, color=PALETTE["reference"], lw=0.6)
        ax.set_ylabel("τ (N·m)")
        ax.set_title(f"requested joint torque, {title} (dashed: ± limit)", fontsize=10)
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    ax = axes[2]
    ax.plot(t, errors[:, 0], color=PALETTE["tube"], lw=1.3, label=r"$e_1 = \Vert y-c\Vert/r$")
    ax.plot(
        t,
        np.max(np.abs(errors[:, 1:]), axis=1),
        color=PALETTE["trajectory"],
        lw=1.0,
        label=r"$\max_i |e_{2,i}|$",
    )
    ax.axhline(1.0, color=PALETTE["violation"], ls="--", lw=0.9, label="funnel boundary")
    ax.set_ylim(0.0, 1.1)
    ax.set_ylabel("normalised error")
    ax.set_title("funnel errors (stage 1: task space, stage 2: joint velocities)", fontsize=10)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    ax.set_xlabel("t (s)")
    if "external_force" in run:
        pushed = np.linalg.norm(run.rows("external_force"), axis=1) > 0.0
        for ax in axes:
            ax.fill_between(
                t,
                0,
                1,
                where=pushed,
                transform=ax.get_xaxis_transform(),
                color=PALETTE["violation"],
                alpha=0.15,
                lw=0,
            )
    if "task_target" in run:
        switches = t[1:][np.any(np.diff(run.active_target, axis=0) != 0.0, axis=1)]
        for ax in axes:
            for time in switches:
                ax.axvline(time, color=PALETTE["target"], ls=":", lw=1.0)
    for ax in axes:
        ax.grid(alpha=0.25, lw=0.5)
    name = run.name
    fig.suptitle(f"{name} — joint torques and funnel errors" if name else "joint torques")
    return fig
