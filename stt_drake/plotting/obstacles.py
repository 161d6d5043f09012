"""The per-obstacle panels of the margins figure: the output's collision probability on a
log axis (:func:`draw_collision_probability`) and its distance to each obstacle
(:func:`draw_obstacle_distance`).

Each shown obstacle has one colour of its own (:func:`obstacle_line_colors`) in both
panels, and is labelled "obstacle j" (0-based, as in the scenario and the metrics). With
more than :data:`SHOWN_MAX` obstacles the most critical ones are drawn in colour
(:func:`critical_obstacles`) and the others as thin grey lines.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.lines import Line2D

from stt_drake.plotting.style import PALETTE
from stt_drake.runlog import RunLog

#: Smallest collision probability the log axis shows; below it (and 0) is drawn at it.
COLLISION_FLOOR = 1e-12
#: Obstacles drawn in colour and named in the legends; the others are thin grey lines.
SHOWN_MAX = 6
#: Colour of the obstacles beyond :data:`SHOWN_MAX`.
_OTHERS = "#b0b0b0"


def obstacle_line_colors(count: int) -> list[Any]:
    """One distinct colour per shown obstacle, in the order they are shown."""
    return [colormaps["tab10"](k % 10) for k in range(count)]


def collision_probability(run: RunLog) -> np.ndarray:
    """(T, m) P(‖y − O_j‖ < r_o_j) = 1 − q̂_j(y), at least :data:`COLLISION_FLOOR`; NaN
    where slot j held no track."""
    probability = np.clip(1.0 - run.output_avoid_probability, COLLISION_FLOOR, 1.0)
    return np.where(run.active, probability, np.nan)


def critical_obstacles(run: RunLog) -> np.ndarray:
    """Indices (ascending) of the at most :data:`SHOWN_MAX` obstacles with the highest peak
    collision probability of the output, ties broken by the closest approach."""
    if run.count <= SHOWN_MAX:
        return np.arange(run.count)
    peak = np.nan_to_num(np.nanmax(collision_probability(run), axis=0, initial=0.0), nan=0.0)
    closest = np.nan_to_num(np.nanmin(run.mean_clearance, axis=0, initial=np.inf), nan=np.inf)
    order = np.lexsort((closest, -peak))  # the last key sorts first
    return np.sort(order[:SHOWN_MAX])


def _draw_others(ax: Any, t: np.ndarray, values: np.ndarray, shown: np.ndarray) -> int:
    """The obstacles not in `shown` as thin grey lines; returns how many there are."""
    others = np.setdiff1d(np.arange(values.shape[1]), shown)
    for j in others:
        ax.plot(t, values[:, j], color=_OTHERS, lw=0.6, alpha=0.7, zorder=2)
    return others.size


def _legend(ax: Any, handles: list[Any], hidden: int) -> None:
    if hidden:
        handles.append(Line2D([], [], color=_OTHERS, lw=0.6, label=f"{hidden} other obstacles"))
    ax.legend(
        handles=handles,
        fontsize=7,
        loc="center left",
        bbox_to_anchor=(1.01, 0.5),
        frameon=False,
        handlelength=2.0,
    )


def draw_collision_probability(ax: Any, run: RunLog, shown: np.ndarray) -> None:
    """The output's collision probability with each obstacle over time on a log axis, with
    each obstacle's bound 1 − ε_j (dashed, same colour): the output avoidance guarantee
    (Definition 2.3) holds while every curve stays below its dashed line."""
    ax.set_title(
        f"output collision probability per obstacle (floor {COLLISION_FLOOR:g})", fontsize=10
    )
    ax.set_ylabel(r"$1 - \hat{q}_j(y) = P(\Vert y - O_j\Vert < r_{o,j})$", fontsize=8)
    ax.set_yscale("log")
    ax.set_ylim(0.3 * COLLISION_FLOOR, 3.0)
    if run.count == 0:
        return
    probability = collision_probability(run)
    bound = np.where(run.active, 1.0 - run.epsilon, np.nan)
    hidden = _draw_others(ax, run.t, probability, shown)
    handles = []
    for j, color in zip(shown, obstacle_line_colors(shown.size), strict=True):
        line = ax.plot(run.t, probability[:, j], color=color, lw=1.3, zorder=3)[0]
        ax.plot(run.t, bound[:, j], color=color, ls="--", lw=0.9, zorder=3)
        line.set_label(f"obstacle {j}: 1 − ε = {1.0 - run.epsilon[-1, j]:.3g}")
        handles.append(line)
    handles.append(
        Line2D([], [], color=PALETTE["reference"], ls="--", lw=0.9, label="dashed: 1 − ε_j")
    )
    _legend(ax, handles, hidden)


def draw_obstacle_distance(ax: Any, run: RunLog, shown: np.ndarray) -> None:
    """The output's distance to each obstacle's surface at its mean, ‖y − μ_j‖ − r_o_j,
    over time, with 0 (touching the nominal obstacle) marked and each shown obstacle's
    closest approach dotted."""
    ax.set_title("distance from the output to each obstacle (at its mean)", fontsize=10)
    ax.set_ylabel(r"$\Vert y - \mu_j\Vert - r_{o,j}$ (m)", fontsize=9)
    ax.axhline(0.0, color=PALETTE["violation"], lw=0.9, zorder=2)
    if run.count == 0:
        return
    distance = run.mean_clearance
    hidden = _draw_others(ax, run.t, distance, shown)
    handles = []
    for j, color in zip(shown, obstacle_line_colors(shown.size), strict=True):
        handles += ax.plot(run.t, distance[:, j], color=color, lw=1.3, label=f"obstacle {j}")
        if np.any(np.isfinite(distance[:, j])):
            k = int(np.nanargmin(distance[:, j]))
            ax.plot(run.t[k], distance[k, j], "o", ms=4, color=color, zorder=4)
    handles.append(Line2D([], [], color=PALETTE["violation"], lw=0.9, label="0: touching"))
    if hidden:  # keep the closest obstacles in view
        closest = np.nanmin(distance[:, shown])
        top = np.nanmax(distance[:, shown])
        ax.set_ylim(min(closest, 0.0) - 0.05 * (top - closest), top)
    _legend(ax, handles, hidden)
