"""The figure of `stt-drake compare` (``comparison.png``): :func:`plot_comparison`, from
the controllers' run logs and the rows of comparison.json (:mod:`stt_drake.compare`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from stt_drake.runlog import RunLog

#: How many times the figure draws the obstacles' means at.
_FIGURE_TIMES = 4
#: The metrics the figure's bar charts show: (row key, title).
_BARS = (
    ("success_rate", "success"),
    ("worst_collision_frequency", "worst collision frequency (99 % CP)"),
    ("t_reach_s", "t_reach (s)"),
    ("path_length_m", "path length (m)"),
    ("min_clearance_m", "min clearance (m)"),
    ("step_us_median", "step (µs, median)"),
)


def plot_comparison(logs: dict[str, RunLog], rows: Sequence[dict[str, Any]]) -> Figure:
    """Left: each controller's output path (x-y plane) over the obstacles' means and radii
    at a few times, the start and the target set; right: a bar per row and metric (a
    missing value, e.g. t_reach never, is left empty)."""
    figure = Figure(figsize=(15, 6.5), layout="constrained")
    left, right = figure.subfigures(1, 2, width_ratios=[1.0, 1.4])
    axes = left.subplots()
    reference = next(iter(logs.values()))
    indices = np.linspace(0, reference.samples - 1, _FIGURE_TIMES).astype(int)
    for shade, k in enumerate(indices):
        alpha = 0.15 + 0.6 * shade / max(len(indices) - 1, 1)
        for j in np.flatnonzero(reference.active[k]):
            mean = reference.mean[k, j]
            axes.add_patch(
                Circle(mean[:2], reference.obstacle_radius[k, j], color="grey", alpha=alpha)
            )
        axes.plot(
            [], [], color="grey", alpha=alpha, lw=6, label=f"obstacles t = {reference.t[k]:.1f} s"
        )
    for name, log in logs.items():
        axes.plot(log.output[:, 0], log.output[:, 1], lw=1.8, label=name)
    axes.add_patch(
        Circle(reference.target[:2], reference.target_set_radius, fill=False, ls="--", color="k")
    )
    axes.plot(*reference.start[:2], "ko", label="start")
    axes.set_aspect("equal")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_title(
        f"{reference.name}: output paths" + (" (x-y)" if reference.dimension == 3 else "")
    )
    axes.legend(fontsize="small", loc="best")

    labels = [
        row["controller"] + (f"\n{row['model_error']}" if row["model_error"] else "")
        for row in rows
    ]
    positions = np.arange(len(rows))
    for bar_axes, (key, title) in zip(right.subplots(2, 3).ravel(), _BARS, strict=True):
        values = np.array([np.nan if row[key] is None else row[key] for row in rows], dtype=float)
        error = None
        if key == "worst_collision_frequency":
            lower = np.array([row["clopper_pearson_lower_99"] for row in rows])
            upper = np.array([row["clopper_pearson_upper_99"] for row in rows])
            error = np.vstack([values - lower, upper - values])
        bar_axes.bar(positions, values, yerr=error, capsize=3, color="C0")
        bar_axes.set_xticks(positions, labels, fontsize="x-small")
        bar_axes.set_title(title, fontsize="small")
    return figure
