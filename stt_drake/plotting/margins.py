"""The radius and guarantee margins of a run over time (:func:`plot_margins`), any
dimension."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from stt_drake.plotting.style import PALETTE, _obstacle_colors, _sigma_colorbar
from stt_drake.runlog import RunLog

#: Markers that tell obstacles apart in line plots when their σ colours coincide.
_OBSTACLE_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "*")
#: Up to this many obstacles the per-obstacle margin panel has a legend, beyond it a σ
#: colourbar; it is also how many of the most critical obstacles its y axis keeps in view.
_LEGEND_MAX = 6
#: Panels of :func:`plot_margins` for margins columns 0..3: (column, title, y label).
_MARGIN_PANELS = (
    (0, "output in tube", r"$r - \Vert y - c\Vert$ (m)"),
    (1, "centre avoidance", r"$\min_j\, q_j(c) - \varepsilon_j$"),
    (2, "tube avoidance", r"$\min_j\, P(B(c,r) \cap O_j = \emptyset) - \varepsilon_j$"),
    (3, "output avoidance", r"$\min_j\, \hat{q}_j(y) - \varepsilon_j$"),
)


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


def _plot_obstacle_margins(fig: Figure, ax: Any, run: RunLog) -> None:
    """Each obstacle's output avoidance margin q̂_j(y) − ε_j over time, coloured by σ̄_j.

    ≤ :data:`_LEGEND_MAX` obstacles: a "#j" legend (0-based, as in the scenario and
    metrics); more: a σ colourbar. The y axis spans from min(0, lowest margin) up to about
    twice the :data:`_LEGEND_MAX`-th lowest per-obstacle minimum (never beyond the largest
    margin), so the curves near zero stay readable; obstacles that never come down into
    view are counted in a note.
    """
    ax.set_title("output avoidance margin per obstacle", fontsize=10)
    ax.set_ylabel(r"$\hat{q}_j(y) - \varepsilon_j$", fontsize=9)
    ax.axhline(0.0, color=PALETTE["reference"], lw=0.8, zorder=2)
    if run.count == 0:
        return
    norm, cmap = _obstacle_colors(run)
    margin = run.output_avoid_probability - run.epsilon  # (T, m)
    sigma_bar = np.nanmean(np.where(run.active, run.sigma, np.nan), axis=0)
    few = run.count <= _LEGEND_MAX
    for j in range(run.count):
        style: dict[str, Any] = {"lw": 1.1, "alpha": 0.85}
        if few:
            style = {
                "lw": 1.3,
                "marker": _OBSTACLE_MARKERS[j % len(_OBSTACLE_MARKERS)],
                "ms": 4,
                "markevery": max(run.t.size // 8, 1),
                "label": rf"#{j}, $\bar{{\sigma}}$ = {sigma_bar[j]:.2g} m",
            }
        ax.plot(run.t, margin[:, j], color=cmap(norm(sigma_bar[j])), zorder=3, **style)
    # Below zero the output is inside {q̂_j ≤ ε_j}: the guarantee is violated.
    ax.axhspan(-2.0, 0.0, color=PALETTE["violation"], alpha=0.07, lw=0, zorder=0)

    finite = np.isfinite(margin)
    if np.any(finite):
        lowest = np.min(np.where(finite, margin, np.inf), axis=0)  # (m,) per-obstacle minimum
        lowest = lowest[np.isfinite(lowest)]
        bottom = min(float(np.min(lowest)), 0.0)
        highest = float(np.max(margin[finite]))
        critical = max(float(np.sort(lowest)[min(_LEGEND_MAX, lowest.size) - 1]), 0.0)
        top = min(highest, critical + (critical - bottom))
        if top <= bottom:
            top = max(highest, bottom + 1e-3)
        span = top - bottom
        ax.set_ylim(bottom - 0.08 * span, top + 0.05 * span)
        hidden = int(np.sum(lowest > top + 0.05 * span))
        if hidden:
            _corner_note(
                ax, f"{hidden} of {run.count} obstacles stay above this axis", 0.02, zorder=5
            )
    if few:
        ax.legend(
            fontsize=7,
            loc="center left",
            bbox_to_anchor=(1.01, 0.5),
            frameon=False,
            handlelength=1.6,
        )
    else:
        _sigma_colorbar(fig, run, ax, shrink=0.95, pad=0.01)


def plot_margins(log: Mapping[str, Any]) -> Figure:
    """The radius and every guarantee's margin over time (works for any dimension).

    Panels: r(t) with r_min (and r_max when the log has it) — the radius_positive margin;
    output in tube (metres); the centre, tube and output avoidance probability margins;
    and each obstacle's output avoidance margin q̂_j(y) − ε_j, coloured by its mean σ
    (see :func:`_plot_obstacle_margins`). A margin below zero is a violated guarantee
    (shaded red).

    Returns:
        The figure: six axes in a 3 × 2 grid sharing the time axis, plus a σ colourbar
        when there are more than :data:`_LEGEND_MAX` obstacles.
    """
    run = RunLog.of(log)
    fig = Figure(figsize=(10.5, 8.0), layout="constrained")
    axes = fig.subplots(3, 2, sharex=True)
    flat = axes.ravel()

    ax = flat[0]
    ax.plot(run.t, run.radius, color=PALETTE["tube"], lw=1.4, label="r")
    ax.axhline(0.0, color=PALETTE["reference"], lw=0.8)
    ax.axhline(run.r_min, color=PALETTE["reference"], ls="--", lw=0.9, label="r_min")
    if run.r_max is not None:
        ax.axhline(run.r_max, color=PALETTE["reference"], ls=":", lw=0.9, label="r_max")
    ax.set_title("tube radius (radius positive)", fontsize=10)
    ax.set_ylabel("r (m)")
    ax.legend(fontsize=7, loc="best")

    for ax, (column, title, label) in zip(flat[1:5], _MARGIN_PANELS, strict=True):
        _plot_margin(ax, run.t, run.margins[:, column])
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(label, fontsize=9)

    _plot_obstacle_margins(fig, flat[5], run)

    for ax in flat:
        ax.grid(alpha=0.25, lw=0.5)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    fig.suptitle(f"{run.name} — guarantee margins" if run.name else "guarantee margins")
    return fig
