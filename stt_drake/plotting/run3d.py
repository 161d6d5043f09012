"""Figures of a 3D run (the UAV, the arm's end effector): snapshots in 3D panels
(:func:`plot_snapshots_3d`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from stt_drake.plotting.instants import panel_grid, snapshot_plan, snapshot_title
from stt_drake.plotting.style import (
    _MANY_OBSTACLES,
    PALETTE,
    _obstacle_colors,
    _sigma_colorbar,
    level_set_radius,
)
from stt_drake.runlog import RunLog

#: Snapshot panels a row holds.
_COLUMNS = 3


def _sphere_surface(
    center: np.ndarray, radius: float, resolution: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """X, Y, Z grids of the sphere B(center, radius) for ``plot_surface``."""
    azimuth = np.linspace(0.0, 2.0 * np.pi, 2 * resolution + 1)
    polar = np.linspace(0.0, np.pi, resolution + 1)
    return (
        center[0] + radius * np.outer(np.cos(azimuth), np.sin(polar)),
        center[1] + radius * np.outer(np.sin(azimuth), np.sin(polar)),
        center[2] + radius * np.outer(np.ones_like(azimuth), np.cos(polar)),
    )


def _wire_sphere(center: np.ndarray, radius: float, circles: int = 6) -> np.ndarray:
    """(3, M) points of a wireframe sphere (meridians and parallels, NaN-separated), to draw
    with one ``plot`` call."""
    angle = np.linspace(0.0, 2.0 * np.pi, 61)
    pieces = []
    for azimuth in np.linspace(0.0, np.pi, circles, endpoint=False):  # meridians
        pieces.append(
            np.column_stack(
                [np.cos(azimuth) * np.sin(angle), np.sin(azimuth) * np.sin(angle), np.cos(angle)]
            )
        )
    for polar in np.linspace(0.0, np.pi, circles + 1)[1:-1]:  # parallels
        pieces.append(
            np.column_stack(
                [
                    np.sin(polar) * np.cos(angle),
                    np.sin(polar) * np.sin(angle),
                    np.full(angle.size, np.cos(polar)),
                ]
            )
        )
    gap = np.full((1, 3), np.nan)
    unit = np.vstack([row for piece in pieces for row in (piece, gap)][:-1])
    return (np.asarray(center, dtype=float) + radius * unit).T


def _level_set_wire(run: RunLog, index: int, j: int, circles: int) -> np.ndarray:
    """(3, M) wireframe of the ε level set {q̂_j ≤ ε_j} of a full covariance: the unit
    wireframe's directions u scaled by the exact boundary distance t(u) from the mean
    (:func:`stt_drake.core.anisotropic.level_set_radii`; the set is star-shaped)."""
    from stt_drake.core import anisotropic

    unit = _wire_sphere(np.zeros(3), 1.0, circles)
    finite = np.all(np.isfinite(unit), axis=0)
    radii = np.full(unit.shape[1], np.nan)
    radii[finite] = anisotropic.level_set_radii(
        unit[:, finite].T,
        run.covariance[index, j],
        float(run.obstacle_radius[index, j]),
        float(run.epsilon[index, j]),
    )
    return run.mean[index, j][:, None] + radii * unit


def _snapshot_cube(run: RunLog, pad: float = 0.06) -> np.ndarray:
    """(3, 2) limits of one cube (equal spans) around the task: the start and target sets,
    the output and the tube over the whole run, padded by `pad` times the largest span
    (0.5 m on the UAV's ~8 m scene, 5 cm on the arm's). Obstacles outside it are clipped,
    so a far-away obstacle does not shrink the scene."""
    low = [
        run.output,
        run.center - run.radius[:, None],
        run.start[None] - run.initial_set_radius,
        run.target[None] - run.target_set_radius,
    ]
    high = [
        run.output,
        run.center + run.radius[:, None],
        run.start[None] + run.initial_set_radius,
        run.target[None] + run.target_set_radius,
    ]
    lo, hi = np.min(np.vstack(low), axis=0), np.max(np.vstack(high), axis=0)
    half = (0.5 + pad) * np.max(hi - lo)
    middle = 0.5 * (lo + hi)
    return np.column_stack([middle - half, middle + half])


def _side_view(start: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """(elevation, azimuth) in degrees of a camera looking at the start–target line from
    the side and from above — about along the part of e_z orthogonal to that line, so the
    detours off the straight path show; (20, −60) if the line is vertical."""
    line = np.asarray(target, dtype=float) - np.asarray(start, dtype=float)
    length = float(np.linalg.norm(line))
    up = np.array([0.0, 0.0, 1.0])
    side = up - (up @ line) * line / length**2 if length > 0.0 else up
    if np.linalg.norm(side) < 1e-6:
        return 20.0, -60.0
    side = side / np.linalg.norm(side)
    # Turned 25° about z and lowered to ≤ 35° elevation: a three-quarter view reads as 3D.
    elevation = min(float(np.degrees(np.arcsin(side[2]))), 35.0)
    return elevation, float(np.degrees(np.arctan2(side[1], side[0]))) + 25.0


def _main_direction(run: RunLog) -> np.ndarray:
    """The direction along which the output path extends most (its first principal axis):
    the start–target line of a straight trip, the transfer of a pick-and-place. Falls back
    to target − start when the path is a point."""
    spread = run.output - np.mean(run.output, axis=0)
    _, singular, axes = np.linalg.svd(spread, full_matrices=False)
    if singular[0] <= 1e-12:
        return run.target - run.start
    return axes[0]


def plot_snapshots_3d(
    log: Mapping[str, Any],
    times: Sequence[float] | None = None,
    invariants: Mapping[str, Mapping[str, Any]] | None = None,
) -> Figure:
    """A 3D run (the UAV) at a few instants, one 3D panel per instant.

    Each panel shows every obstacle as the sphere B(μ_j, r_o_j) at its mean, coloured by
    σ_j (darker = more uncertain, as in the paper's Fig. of the UAV study) and labelled
    with its index when there are at most :data:`_MANY_OBSTACLES`, with its ε level set
    {q̂_j ≤ ε_j} as a translucent wireframe sphere in its colour (its exact non-spherical
    shape with full covariances) (when bounded and larger
    than the obstacle); the tube
    Γ(t) = B(c, r) as a wireframe sphere; the output path y and the centre path so far;
    the start and target sets as wireframe spheres. Panels share one cube of limits around
    the task (start and target sets, output, tube; obstacles outside it are clipped) and a
    camera looking at the output path's main direction from the side, so detours show.

    Args:
        log: a run log (see :mod:`stt_drake.plotting`) with dimension 3.
        times: instants in seconds (each snapped to the nearest sample). Default: the
            start, the time of each guarantee's worst margin and the end, as in
            :func:`~stt_drake.plotting.run2d.plot_snapshots`.
        invariants: ``metrics.json``'s ``invariants`` (the worst-margin times); None:
            found in the logged margins.

    Returns:
        The figure: one 3D axes per instant (at most three a row) plus a σ colourbar (when
        there are obstacles).
    """
    run = RunLog.of(log)
    if run.dimension != 3:
        raise ValueError(f"plot_snapshots_3d draws 3D runs; this run has dimension {run.dimension}")
    plan = snapshot_plan(run, times, invariants)
    limits = _snapshot_cube(run)
    norm, cmap = _obstacle_colors(run)
    many = run.count > _MANY_OBSTACLES
    resolution, surface_alpha = (6, 0.5) if many else (10, 0.6)
    elevation, azimuth = _side_view(np.zeros(3), _main_direction(run))

    rows, columns = panel_grid(len(plan), _COLUMNS)
    fig = Figure(figsize=(5.2 * columns + 1.2, 5.2 * rows + 0.8), layout="constrained")
    axes = [fig.add_subplot(rows, columns, i + 1, projection="3d") for i in range(len(plan))]
    level_sets: dict[tuple[float, float, float], float] = {}
    for ax, (index, names) in zip(axes, plan, strict=True):
        for j in np.flatnonzero(run.active[index]):
            color = cmap(norm(run.sigma[index, j]))
            mean = run.mean[index, j]
            ax.plot_surface(
                *_sphere_surface(mean, run.obstacle_radius[index, j], resolution),
                color=color,
                alpha=surface_alpha,
                lw=0,
                shade=True,
                axlim_clip=True,
            )
            # the ε level set {q̂_j ≤ ε_j}, a ball around the mean (drawn when it is
            # bounded and larger than the obstacle)
            if run.covariance is not None:  # its exact, non-spherical shape
                wire = _level_set_wire(run, index, j, 3 if many else 4)
            else:
                key = (float(run.epsilon[index, j]), float(run.sigma[index, j]))
                key += (float(run.obstacle_radius[index, j]),)
                if key not in level_sets:
                    level_sets[key] = level_set_radius(*key, 3)
                level = level_sets[key]
                bounded = np.isfinite(level) and level > run.obstacle_radius[index, j]
                wire = _wire_sphere(mean, level, 3 if many else 4) if bounded else None
            if wire is not None:
                ax.plot(*wire, color=color, lw=0.4, alpha=0.45, axlim_clip=True)
            if not many:
                ax.text(*mean, str(j), fontsize=7, ha="center", va="center", axlim_clip=True)
        for center, set_radius, key in (
            (run.start, run.initial_set_radius, "start"),
            (run.target, run.target_set_radius, "target"),
        ):
            ax.plot(*_wire_sphere(center, set_radius, 4), color=PALETTE[key], lw=0.5, alpha=0.6)
        ax.plot(
            *_wire_sphere(run.center[index], max(run.radius[index], 0.0)),
            color=PALETTE["tube"],
            lw=0.7,
            alpha=0.8,
        )
        ax.plot(*run.center[: index + 1].T, ls="--", lw=0.8, color=PALETTE["tube"])
        ax.plot(*run.output[: index + 1].T, lw=1.5, color=PALETTE["trajectory"])
        ax.plot(*run.output[index, :, None], "o", ms=3.5, color=PALETTE["trajectory"])
        ax.set_xlim(limits[0])
        ax.set_ylim(limits[1])
        ax.set_zlim(limits[2])
        ax.set_box_aspect((1.0, 1.0, 1.0))
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        ax.set_title(snapshot_title(run.t[index], names), fontsize=10)
        ax.view_init(elev=elevation, azim=azimuth)

    handles = [
        Line2D([], [], color=PALETTE["trajectory"], lw=1.5, label="output y"),
        Line2D([], [], color=PALETTE["tube"], ls="--", lw=0.8, label="tube centre c"),
        Line2D([], [], color=PALETTE["tube"], lw=0.7, label=r"tube $\Gamma(t) = B(c, r)$"),
        Line2D([], [], color=PALETTE["start"], lw=0.8, label="start set"),
        Line2D([], [], color=PALETTE["target"], lw=0.8, label="target set"),
        Patch(fc=cmap(0.6), alpha=surface_alpha, label=r"obstacle $B(\mu_j, r_{o,j})$"),
        Line2D([], [], color=cmap(0.6), lw=0.4, label=r"$\{\hat q_j \leq \varepsilon_j\}$"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncol=4, fontsize=8, frameon=False)
    if run.count:
        _sigma_colorbar(fig, run, axes, shrink=0.7)
    if run.name:
        fig.suptitle(run.name)
    return fig
