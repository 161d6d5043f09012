"""The figure of `stt-drake compare` (``comparison.png``): :func:`plot_comparison`, from
the controllers' run logs and the rows of comparison.json (:mod:`stt_drake.compare`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from stt_drake.core.statistics import INCONCLUSIVE
from stt_drake.plotting.certify import VERDICT_COLORS, uncertified_note
from stt_drake.plotting.style import PALETTE
from stt_drake.runlog import RunLog

#: How many times the figure draws the obstacles' means at.
_FIGURE_TIMES = 4
#: Top of the collision frequency axis over the strictest 1 − ε_j and the frequencies.
_COLLISION_HEADROOM = 1.6
#: The metrics the figure's bar charts show: (row key, title).
_BARS = (
    ("success_rate", "success"),
    ("worst_collision_frequency", "worst collision frequency (99 % CP)"),
    ("t_output_in_target_s", "output in target (s)"),
    ("path_length_m", "path length (m)"),
    ("min_clearance_m", "min clearance (m)"),
    ("step_us_median", "step (µs, median)"),
)


def plot_comparison(
    logs: dict[str, RunLog], rows: Sequence[dict[str, Any]], runs: int | None = None
) -> Figure:
    """Left: each controller's output path (x-y plane) over the obstacles' means and radii
    at a few times (each labelled "obstacle j" at the last), the start and the target set;
    right: a bar per row and metric (a missing value, e.g. an output never in the target
    set, is left empty). The collision frequency bars carry their 99 % interval, their
    verdict and the strictest bound 1 − ε_j; with `runs` (each controller's campaign size)
    the figure notes when that many runs cannot certify
    (:func:`~stt_drake.plotting.certify.uncertified_note`)."""
    figure = Figure(figsize=(15, 6.8), layout="constrained")
    left, right = figure.subfigures(1, 2, width_ratios=[1.0, 1.4])
    reference = next(iter(logs.values()))
    _draw_paths(left.subplots(), logs, reference)

    labels = [
        row["controller"] + (f"\n{row['model_error']}" if row["model_error"] else "")
        for row in rows
    ]
    positions = np.arange(len(rows))
    for bar_axes, (key, title) in zip(right.subplots(2, 3).ravel(), _BARS, strict=True):
        values = np.array([np.nan if row[key] is None else row[key] for row in rows], dtype=float)
        if key == "worst_collision_frequency":
            _draw_collision_bars(bar_axes, positions, values, rows, reference)
        else:
            bar_axes.bar(positions, values, color="C0")
        bar_axes.set_xticks(positions, labels, fontsize="x-small")
        bar_axes.set_title(title, fontsize="small")
    note = None if runs is None else uncertified_note(runs, rows)
    if note is not None:
        figure.suptitle(note, color=VERDICT_COLORS[INCONCLUSIVE], fontsize="medium")
    return figure


def _draw_paths(axes: Any, logs: dict[str, RunLog], reference: RunLog) -> None:
    """Each controller's output path over the obstacles at :data:`_FIGURE_TIMES` times."""
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
    last = indices[-1]
    for j in np.flatnonzero(reference.active[last]):
        axes.annotate(
            f"obstacle {j}",
            reference.mean[last, j, :2],
            xytext=(0, 3),
            textcoords="offset points",
            ha="center",
            va="bottom",
            fontsize="x-small",
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


def _draw_collision_bars(
    axes: Any,
    positions: np.ndarray,
    values: np.ndarray,
    rows: Sequence[dict[str, Any]],
    reference: RunLog,
) -> None:
    """The worst collision frequency per row with its 99 % interval and verdict, against
    the strictest bound 1 − ε_j over the obstacles. The y axis stops a little above that
    bound and the frequencies: an interval wider than that (too few runs) runs off it, and
    its upper bound is written with the verdict."""
    lower = np.array([row["clopper_pearson_lower_99"] for row in rows], dtype=float)
    upper = np.array([row["clopper_pearson_upper_99"] for row in rows], dtype=float)
    axes.bar(
        positions, values, yerr=np.vstack([values - lower, upper - values]), capsize=3, color="C0"
    )
    allowed = 1.0 - reference.epsilon[-1]
    strictest = float(np.min(allowed, initial=1.0))
    if allowed.size:
        j = int(np.argmin(allowed))
        axes.axhline(
            strictest,
            color=PALETTE["violation"],
            ls="--",
            lw=1.0,
            label=f"strictest 1 − ε_j: {strictest:.3g} (obstacle {j})",
        )
        axes.legend(fontsize="xx-small", loc="upper left")
    top = _COLLISION_HEADROOM * max(strictest, float(np.nanmax(values, initial=0.0)))
    axes.set_ylim(0.0, top)
    for x, row, high in zip(positions, rows, upper, strict=True):
        words = row["verdict"] + (f"\n99 % upper: {high:.2g}" if high > top else "")
        axes.text(
            x,
            0.35,
            words,
            transform=axes.get_xaxis_transform(),
            ha="center",
            va="center",
            fontsize="xx-small",
            color=VERDICT_COLORS.get(row["verdict"], "black"),
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85},
        )
