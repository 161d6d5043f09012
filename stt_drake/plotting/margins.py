"""The radius and guarantee margins of a run over time (:func:`plot_margins`), any
dimension."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from stt_drake.plotting.obstacles import (
    critical_obstacles,
    draw_collision_probability,
    draw_obstacle_distance,
)
from stt_drake.plotting.style import PALETTE
from stt_drake.runlog import RunLog

#: Panels of :func:`plot_margins` for margins columns 0..3: (column, title, y label).
_MARGIN_PANELS = (
    (0, "output in tube", r"$r - \Vert y - c\Vert$ (m)"),
    (1, "centre avoidance", r"$\min_j\, q_j(c) - \varepsilon_j$"),
    (2, "tube avoidance", r"$\min_j\, P(B(c,r) \cap O_j = \emptyset) - \varepsilon_j$"),
    (3, "output avoidance", r"$\min_j\, \hat{q}_j(y) - \varepsilon_j$"),
)


#: The radius panel's legend, above the curve in the room :data:`_RADIUS_HEADROOM` leaves.
_RADIUS_LEGEND: dict[str, Any] = {"fontsize": 6.5, "loc": "upper center", "framealpha": 0.9}
#: Top of the radius panel's y axis over the largest of r, r_max and r_min.
_RADIUS_HEADROOM = 1.9


def _plot_margin(ax: Any, t: np.ndarray, margin: np.ndarray) -> None:
    """A margin curve with its zero line, negative stretches shaded, and its minimum marked."""
    finite = np.isfinite(margin)
    ax.axhline(0.0, color=PALETTE["reference"], lw=0.8)
    ax.plot(t[finite], margin[finite], color=PALETTE["margin"], lw=1.3)
    if not np.any(finite):
        return
    ax.fill_between(
        t,
        0.0,
        np.where(finite, margin, 0.0),
        where=finite & (margin < 0.0),
        interpolate=True,
        color=PALETTE["violation"],
        alpha=0.3,
        lw=0,
    )
    worst = int(np.argmin(np.where(finite, margin, np.inf)))
    ax.plot(t[worst], margin[worst], "o", ms=4, color=PALETTE["violation"])
    _corner_note(ax, f"min {margin[worst]:.3g} at t = {t[worst]:.1f} s", height=0.05)


def _corner_note(ax: Any, text: str, height: float, zorder: float | None = None) -> None:
    """A small boxed note in the lower-right corner of `ax` (axes coordinates)."""
    ax.text(
        0.98,
        height,
        text,
        transform=ax.transAxes,
        ha="right",
        va="bottom",
        fontsize=7,
        bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.8},
        zorder=zorder,
    )


def _draw_radius(ax: Any, run: RunLog) -> None:
    """r(t) with r_min, r_max and the recovery episodes, each explained in the legend.

    r is the soft-min of r_max and the distances d̂_j to the ε level sets (Eq. (14)).
    r_min is the buffer of the centre's avoidance probability q_j(c) = P(‖c − O_j‖ ≥
    r_o_j + r_min): while every q_j(c) > ε_j each d̂_j exceeds r_min, so r stays above
    r_min − ln(n_o + 1)/ν (> 0: Theorem 3.2 (iii)); near an obstacle the soft-min takes r
    below r_min by less than ln(n_o + 1)/ν, further only while recovering."""
    ax.plot(run.t, run.radius, color=PALETTE["tube"], lw=1.4, label="r(t)")
    ax.axhline(0.0, color=PALETTE["reference"], lw=0.8)
    if run.r_max is not None:
        ax.axhline(
            run.r_max,
            color=PALETTE["reference"],
            ls=":",
            lw=0.9,
            label=f"r_max = {run.r_max:.3g} m: the radius away from obstacles",
        )
    ax.axhline(
        run.r_min,
        color=PALETTE["reference"],
        ls="--",
        lw=0.9,
        label=f"r_min = {run.r_min:.3g} m: the centre's buffer in q_j(c);\n"
        "near an obstacle r may dip below it by < ln(n_o + 1)/ν\n"
        "(the soft-min), further only while recovering",
    )
    if "recovery" in run and np.any(run.recovery):
        ax.fill_between(
            run.t,
            0,
            1,
            where=np.any(run.recovery, axis=1),
            transform=ax.get_xaxis_transform(),
            color=PALETTE["violation"],
            alpha=0.15,
            lw=0,
        )
        handles, _ = ax.get_legend_handles_labels()
        recovering = Patch(
            color=PALETTE["violation"], alpha=0.15, label="recovering: some q_j(c) ≤ ε_j"
        )
        ax.legend(handles=[*handles, recovering], **_RADIUS_LEGEND)
    else:
        ax.legend(**_RADIUS_LEGEND)
    # Room above the curve for the legend.
    top = max(float(np.nanmax(run.radius)), run.r_max or 0.0, run.r_min)
    ax.set_ylim(top=_RADIUS_HEADROOM * top)
    ax.set_title("tube radius (radius positive)", fontsize=10)
    ax.set_ylabel("r (m)")


def plot_margins(log: Mapping[str, Any]) -> Figure:
    """The radius, every guarantee's margin and the obstacles over time (any dimension).

    Panels: r(t) with r_min and r_max, their meaning in the legend
    (:func:`_draw_radius`); output in tube (metres); the centre, tube and output avoidance
    probability margins (a margin below zero is a violated guarantee, shaded red); the
    output's collision probability with each obstacle on a log axis against 1 − ε_j
    (:func:`~stt_drake.plotting.obstacles.draw_collision_probability`); and, across the
    bottom, the output's distance to each obstacle's surface
    (:func:`~stt_drake.plotting.obstacles.draw_obstacle_distance`).

    Returns:
        The figure: seven axes sharing the time axis (a 4 × 2 grid, the last row one
        wide axes).
    """
    run = RunLog.of(log)
    fig = Figure(figsize=(11.5, 10.5), layout="constrained")
    grid = fig.add_gridspec(4, 2)
    first = fig.add_subplot(grid[0, 0])
    axes = [first] + [
        fig.add_subplot(grid[row, column], sharex=first)
        for row, column in ((0, 1), (1, 0), (1, 1), (2, 0), (2, 1), (3, slice(None)))
    ]
    _draw_radius(axes[0], run)
    for ax, (column, title, label) in zip(axes[1:5], _MARGIN_PANELS, strict=True):
        _plot_margin(ax, run.t, run.margins[:, column])
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(label, fontsize=9)
    shown = critical_obstacles(run)
    draw_collision_probability(axes[5], run, shown)
    draw_obstacle_distance(axes[6], run, shown)
    for ax in axes:
        ax.grid(alpha=0.25, lw=0.5)
    for ax in axes[:4]:
        ax.tick_params(labelbottom=False)
    for ax in axes[4:]:
        ax.set_xlabel("t (s)")
    fig.suptitle(f"{run.name} — guarantee margins" if run.name else "guarantee margins")
    return fig
