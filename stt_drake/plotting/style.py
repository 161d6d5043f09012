"""What every figure of a run log shares: the palette, the σ colours and the obstacles'
level-set discs. The figures read the log through :class:`stt_drake.runlog.RunLog`.

All figures share one visual language, :data:`PALETTE`; obstacles are coloured by σ through
:func:`obstacle_colors`.

The obstacle uncertainty is drawn as the sub-level sets of the point avoidance probability
q̂_j(x) = P(‖x − O_j‖ ≥ r_o_j): {q̂_j ≤ p_d_j} (light, where the tube starts to react) and
{q̂_j ≤ ε_j} (darker, what the robot's output must stay out of). q̂_j grows with the
distance to the mean, so both sets are discs around the mean; their radii come from a 1-D
root find (:func:`level_set_radius`). With a full covariance Σ_j they are not discs: 2D
figures draw them as contours of the exact q̂_j on a grid (:func:`anisotropic_levels`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Colormap, ListedColormap, Normalize
from matplotlib.figure import Figure

from stt_drake.core.invariants import tube_reach_time
from stt_drake.core.probability import level_set_radius
from stt_drake.runlog import RunLog

#: The one visual language of every figure.
PALETTE: dict[str, Any] = {
    "tube": "#1f77b4",  # tube Γ(t) = B(c, r) and the centre path
    "trajectory": "#111111",  # robot output y
    "start": "#2ca02c",  # initial set S
    "target": "#9467bd",  # target set T
    "obstacle_cmap": "Reds",  # obstacles coloured by σ
    "reference": "#7f7f7f",  # zero lines, r_min / r_max
    "margin": "#1f77b4",  # margin curves
    "violation": "#d62728",  # shading where a margin is negative
}

#: Fraction of the obstacle colormap used (the palest end is invisible on white).
_CMAP_RANGE = (0.35, 0.95)
#: Beyond this many obstacles the 3D figures draw them thinner, fainter and sparser.
_MANY_OBSTACLES = 10


def _obstacle_colors(run: RunLog) -> tuple[Normalize, Colormap]:
    """The σ → colour map shared by every figure of a run."""
    base = colormaps[PALETTE["obstacle_cmap"]]
    cmap = ListedColormap(base(np.linspace(*_CMAP_RANGE, 256)), name="obstacle_sigma")
    if run.count == 0:
        return Normalize(0.0, 1.0), cmap
    if not run.active.any():
        return Normalize(0.0, 1.0), cmap
    low, high = float(np.nanmin(run.shown_sigma)), float(np.nanmax(run.shown_sigma))
    if high - low < 1e-12 * max(abs(high), 1.0):
        low, high = low * 0.5, high * 1.5 if high > 0 else 1.0
    return Normalize(low, high), cmap


def _sigma_colorbar(
    fig: Figure, run: RunLog, axes: Any, shrink: float = 0.8, pad: float = 0.02
) -> None:
    norm, cmap = _obstacle_colors(run)
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=axes, shrink=shrink, pad=pad)
    bar.set_label("σ (m)")


def obstacle_colors(log: Mapping[str, Any]) -> tuple[Normalize, Colormap]:
    """The σ → colour map of a run's obstacles (the one every figure and the replay use)."""
    return _obstacle_colors(RunLog.of(log))


def reach_time(log: Mapping[str, Any]) -> float | None:
    """First logged time after which the tube stays inside the target set, else None.

    The tube B(c, r) is inside the target ball when ‖c − target‖ + r ≤ target radius.
    """
    run = RunLog.of(log)
    return tube_reach_time(run.t, run.center, run.radius, run.target, run.target_set_radius)


def _obstacle_discs(run: RunLog, index: int) -> np.ndarray:
    """(m, 2) radii of {q̂ ≤ p_d} and {q̂ ≤ ε} for every obstacle at sample `index`."""
    return np.array(
        [
            [
                level_set_radius(
                    float(level),
                    float(run.sigma[index, j]),
                    float(run.obstacle_radius[index, j]),
                    run.dimension,
                )
                for level in (run.p_d[index, j], run.epsilon[index, j])
            ]
            for j in range(run.count)
        ]
    ).reshape(run.count, 2)


#: Grid points per axis of :func:`anisotropic_levels`.
LEVEL_GRID = 121


def anisotropic_levels(
    run: RunLog, index: int, j: int, extent: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, Y, Q): q̂_j(x) = P(‖x − O_j‖ ≥ r_o_j) for O_j ~ N(μ_j, Σ_j) (exact,
    :mod:`stt_drake.core.anisotropic`) on a LEVEL_GRID² grid of half-width `extent` (m)
    around μ_j at sample `index` of a 2D run with covariances, for contouring its level
    sets."""
    from stt_drake.core import anisotropic

    mean = run.mean[index, j]
    axis = np.linspace(-extent, extent, LEVEL_GRID)
    x, y = np.meshgrid(mean[0] + axis, mean[1] + axis)
    points = np.column_stack([x.ravel(), y.ravel()])
    q = anisotropic.avoid_probability(
        points, mean, run.covariance[index, j], float(run.obstacle_radius[index, j])
    )
    return x, y, np.asarray(q).reshape(x.shape)
