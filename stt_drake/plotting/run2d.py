"""Figures of a 2D run: top-view snapshots (:func:`plot_snapshots`) and the tube in
(x, y, t) (:func:`plot_tube_3d`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from stt_drake.plotting.instants import panel_grid, snapshot_plan, snapshot_title
from stt_drake.plotting.style import (
    _MANY_OBSTACLES,
    PALETTE,
    _obstacle_colors,
    _obstacle_discs,
    _sigma_colorbar,
    anisotropic_levels,
)
from stt_drake.runlog import RunLog

#: Snapshot panels a row holds.
_COLUMNS = 4
#: Alpha of the {q̂ ≤ p_d} and {q̂ ≤ ε} discs.
_LIGHT_ALPHA, _DARK_ALPHA = 0.14, 0.38


def _snapshot_limits(run: RunLog, indices: Sequence[int], extents: np.ndarray) -> np.ndarray:
    """[[x_lo, x_hi], [y_lo, y_hi]] covering everything drawn in any snapshot, with a pad."""
    points = [run.output[:, :2], run.center[:, :2]]
    lows = [
        run.center[:, :2] - run.radius[:, None],
        run.start[None, :2] - run.initial_set_radius,
        run.target[None, :2] - run.target_set_radius,
    ]
    highs = [
        run.center[:, :2] + run.radius[:, None],
        run.start[None, :2] + run.initial_set_radius,
        run.target[None, :2] + run.target_set_radius,
    ]
    for k, index in enumerate(indices):
        mean = run.shown_mean[index, :, :2]
        reach = extents[k][:, None]
        lows.append(mean - reach)
        highs.append(mean + reach)
    low = np.nanmin(np.vstack([*points, *lows]), axis=0)
    high = np.nanmax(np.vstack([*points, *highs]), axis=0)
    pad = 0.05 * np.max(high - low) + 1e-9
    return np.column_stack([low - pad, high + pad])


def _draw_anisotropic_levels(
    ax: Any, run: RunLog, index: int, j: int, color: Any, light: float
) -> None:
    """{q̂_j ≤ p_d_j} and {q̂_j ≤ ε_j} of a full covariance as filled contours of the exact
    q̂_j, on a grid 1.5× the σ_max disc of {q̂_j ≤ p_d_j} (`light`) in half-width."""
    extent = 1.5 * (light if np.isfinite(light) else run.obstacle_radius[index, j])
    x, y, q = anisotropic_levels(run, index, j, max(extent, 1e-3))
    for level, alpha in ((run.p_d[index, j], _LIGHT_ALPHA), (run.epsilon[index, j], _DARK_ALPHA)):
        if np.min(q) <= level:
            ax.contourf(x, y, q, levels=[-1.0, float(level)], colors=[color], alpha=alpha, zorder=1)


def plot_snapshots(
    log: Mapping[str, Any],
    times: Sequence[float] | None = None,
    invariants: Mapping[str, Mapping[str, Any]] | None = None,
) -> Figure:
    """Top view of a 2D run at a few instants, one panel per instant.

    Each panel shows, for every obstacle, the discs {q̂_j ≤ p_d_j} (light) and
    {q̂_j ≤ ε_j} (darker) of the point avoidance probability q̂_j(x) = P(‖x − O_j‖ ≥ r_o_j)
    (with full covariances: their exact shapes, filled contours of q̂_j; colour by σ_max),
    the nominal disc B(mean_j, r_o_j) (outline) and the mean's path so far (dotted), all
    coloured by σ_j; the tube Γ(t) = B(c, r); the output path and the centre path so far;
    the start and target sets. Panels share limits and use equal aspect.

    Args:
        log: a run log (see :mod:`stt_drake.plotting`) with dimension 2.
        times: instants in seconds (each snapped to the nearest sample). Default: the
            start, the time of each guarantee's worst margin and the end
            (:func:`~stt_drake.plotting.instants.snapshot_plan`); a panel's title names the
            guarantees whose worst margin it shows.
        invariants: ``metrics.json``'s ``invariants`` (the worst-margin times); None:
            found in the logged margins.

    Returns:
        The figure: one axes per instant (at most four a row) plus a σ colourbar (when
        there are obstacles).
    """
    run = RunLog.of(log)
    if run.dimension != 2:
        raise ValueError(f"plot_snapshots draws 2D runs; this run has dimension {run.dimension}")
    plan = snapshot_plan(run, times, invariants)
    indices = [index for index, _ in plan]
    discs = [_obstacle_discs(run, index) for index in indices]
    # Limits cover the ε discs; the wider p_d discs may run off the panel.
    extents = [
        np.maximum(np.where(np.isfinite(d[:, 1]), d[:, 1], 0.0), run.obstacle_radius[i])
        for d, i in zip(discs, indices, strict=True)
    ]
    limits = _snapshot_limits(run, indices, np.array(extents).reshape(len(indices), run.count))
    norm, cmap = _obstacle_colors(run)

    rows, columns = panel_grid(len(indices), _COLUMNS)
    fig = Figure(figsize=(4.2 * columns + 1.2, 4.6 * rows + 1.4), layout="constrained")
    grid = fig.subplots(rows, columns, sharex=True, sharey=True, squeeze=False)
    for ax in grid.ravel()[len(indices) :]:
        ax.remove()
    axes = grid.ravel()[: len(indices)]
    for ax, (index, names), disc in zip(axes, plan, discs, strict=True):
        for j in np.flatnonzero(run.active[index]):
            color = cmap(norm(run.sigma[index, j]))
            center = run.mean[index, j]
            light, dark = disc[j]
            if run.covariance is not None:  # the exact, non-circular level sets
                _draw_anisotropic_levels(ax, run, index, j, color, light)
            else:
                if np.isfinite(light):
                    ax.add_patch(
                        Circle(center, light, fc=color, alpha=_LIGHT_ALPHA, lw=0, zorder=1)
                    )
                if np.isfinite(dark):
                    ax.add_patch(Circle(center, dark, fc=color, alpha=_DARK_ALPHA, lw=0, zorder=1))
            ax.add_patch(
                Circle(center, run.obstacle_radius[index, j], fc="none", ec=color, lw=1.4, zorder=3)
            )
            ax.plot(*run.shown_mean[: index + 1, j].T, ls=":", lw=0.9, color=color, zorder=2)
            ax.annotate(str(j), center, ha="center", va="center", fontsize=7, color=color, zorder=3)
        ax.add_patch(
            Circle(run.start, run.initial_set_radius, fc="none", ec=PALETTE["start"], lw=1.3)
        )
        ax.add_patch(
            Circle(run.target, run.target_set_radius, fc="none", ec=PALETTE["target"], lw=1.3)
        )
        ax.add_patch(
            Circle(
                run.center[index],
                max(run.radius[index], 0.0),
                fc=PALETTE["tube"],
                ec=PALETTE["tube"],
                alpha=0.3,
                lw=1.2,
                zorder=4,
            )
        )
        ax.plot(*run.center[: index + 1].T, ls="--", lw=0.8, color=PALETTE["tube"], zorder=4)
        ax.plot(*run.output[: index + 1].T, lw=1.4, color=PALETTE["trajectory"], zorder=5)
        ax.plot(*run.output[index], "o", ms=3.5, color=PALETTE["trajectory"], zorder=6)
        ax.set_xlim(limits[0])
        ax.set_ylim(limits[1])
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(snapshot_title(run.t[index], names), fontsize=10)
        ax.set_xlabel("x (m)")
        ax.grid(alpha=0.25, lw=0.5)
    for ax in grid[:, 0]:
        ax.set_ylabel("y (m)")

    sample = cmap(0.6)
    handles = [
        Line2D([], [], color=PALETTE["trajectory"], lw=1.4, label="output y"),
        Line2D([], [], color=PALETTE["tube"], ls="--", lw=0.8, label="tube centre c"),
        Patch(
            fc=PALETTE["tube"], ec=PALETTE["tube"], alpha=0.3, label=r"tube $\Gamma(t) = B(c, r)$"
        ),
        Patch(fc="none", ec=PALETTE["start"], label="start set"),
        Patch(fc="none", ec=PALETTE["target"], label="target set"),
        Patch(fc="none", ec=sample, lw=1.4, label=r"obstacle $B(\mu_j, r_{o,j})$"),
        Patch(fc=sample, alpha=_DARK_ALPHA, label=r"$\hat{q}_j \leq \varepsilon_j$"),
        Patch(fc=sample, alpha=_LIGHT_ALPHA, label=r"$\hat{q}_j \leq p_{d,j}$"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncol=4, fontsize=8, frameon=False)
    if run.count:
        _sigma_colorbar(fig, run, axes.tolist())
    if run.name:
        fig.suptitle(run.name)
    return fig


def plot_tube_3d(log: Mapping[str, Any], circles: int = 60) -> Figure:
    """The tube in (x, y, t): stacked tube circles, the output path and obstacle mean paths.

    Obstacle mean paths are coloured by σ_j; thin rings show the boundary of
    {q̂_j ≤ ε_j} at every 4th tube-circle time. With more than :data:`_MANY_OBSTACLES`
    obstacles the paths are thinner and fainter and the rings every 8th circle time.

    Args:
        log: a run log (see :mod:`stt_drake.plotting`) with dimension 2.
        circles: about how many tube circles to draw, evenly spread over the samples.

    Returns:
        The figure: one 3D axes plus a σ colourbar (when there are obstacles).
    """
    run = RunLog.of(log)
    if run.dimension != 2:
        raise ValueError(f"plot_tube_3d draws 2D runs; this run has dimension {run.dimension}")
    norm, cmap = _obstacle_colors(run)
    fig = Figure(figsize=(7.5, 6.5), layout="constrained")
    ax = fig.add_subplot(projection="3d")

    angle = np.linspace(0.0, 2.0 * np.pi, 73)
    ring = np.column_stack([np.cos(angle), np.sin(angle)])
    picks = np.unique(np.linspace(0, run.t.size - 1, min(circles, run.t.size)).round().astype(int))
    tube_rings = [
        np.column_stack(
            [run.center[i] + max(run.radius[i], 0.0) * ring, np.full(angle.size, run.t[i])]
        )
        for i in picks
    ]
    ax.add_collection3d(Line3DCollection(tube_rings, colors=PALETTE["tube"], lw=0.7, alpha=0.55))
    for center, set_radius, time, key in (
        (run.start, run.initial_set_radius, run.t[0], "start"),
        (run.target, run.target_set_radius, run.t[-1], "target"),
    ):
        ax.plot(*(center + set_radius * ring).T, np.full(angle.size, time), color=PALETTE[key])
    # Many obstacles: thinner, fainter paths and sparser rings keep the tube and y readable.
    many = run.count > _MANY_OBSTACLES
    path_lw, path_alpha = (1.0, 0.55) if many else (2.0, 1.0)
    ring_lw, ring_alpha, ring_stride = (0.4, 0.3, 8) if many else (0.6, 0.6, 4)
    ax.plot(*run.output.T, run.t, color=PALETTE["trajectory"], lw=2.0 if many else 1.5)
    for j in range(run.count):
        path = np.column_stack([run.shown_mean[:, j], run.t])
        segments = np.stack([path[:-1], path[1:]], axis=1)
        sigma_mid = 0.5 * (run.shown_sigma[:-1, j] + run.shown_sigma[1:, j])
        ax.add_collection3d(
            Line3DCollection(segments, colors=cmap(norm(sigma_mid)), lw=path_lw, alpha=path_alpha)
        )
    # The {q̂_j ≤ ε_j} discs as rings at every 4th (8th when many) tube time: the clearance
    # the output needs.
    obstacle_rings, ring_colors = [], []
    for i in picks[::ring_stride]:
        for j, disc in enumerate(_obstacle_discs(run, i)[:, 1]):
            if run.active[i, j] and np.isfinite(disc) and disc > 0.0:
                obstacle_rings.append(
                    np.column_stack([run.mean[i, j] + disc * ring, np.full(angle.size, run.t[i])])
                )
                ring_colors.append(cmap(norm(run.sigma[i, j])))
    if obstacle_rings:
        ax.add_collection3d(
            Line3DCollection(obstacle_rings, colors=ring_colors, lw=ring_lw, alpha=ring_alpha)
        )

    points = [run.output, run.center - run.radius.max(initial=0.0), run.center + run.radius.max()]
    points += [run.start - run.initial_set_radius, run.start + run.initial_set_radius]
    points += [run.target - run.target_set_radius, run.target + run.target_set_radius]
    if run.count:
        points.append(run.shown_mean.reshape(-1, 2))
    everything = np.vstack(points)
    ax.set_xlim(np.nanmin(everything[:, 0]), np.nanmax(everything[:, 0]))
    ax.set_ylim(np.nanmin(everything[:, 1]), np.nanmax(everything[:, 1]))
    ax.set_zlim(run.t[0], run.t[-1])
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("t (s)")
    ax.view_init(elev=22, azim=-60)
    handles = [
        Line2D([], [], color=PALETTE["tube"], lw=0.9, label=r"tube $\Gamma(t)$"),
        Line2D([], [], color=PALETTE["trajectory"], lw=2.0 if many else 1.5, label="output y"),
        Line2D(
            [], [], color=cmap(0.6), lw=path_lw, alpha=path_alpha, label=r"obstacle mean $\mu_j$"
        ),
        Line2D(
            [],
            [],
            color=cmap(0.6),
            lw=max(ring_lw, 0.6),
            alpha=max(ring_alpha, 0.6),
            label=r"$\hat{q}_j = \varepsilon_j$ ring",
        ),
        Line2D([], [], color=PALETTE["start"], label="start set (t = 0)"),
        Line2D([], [], color=PALETTE["target"], label="target set (t end)"),
    ]
    ax.legend(handles=handles, loc="upper left", fontsize=8)
    if run.count:
        _sigma_colorbar(fig, run, ax, shrink=0.6, pad=0.08)
    if run.name:
        ax.set_title(run.name)
    return fig
