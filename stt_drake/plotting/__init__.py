"""Matplotlib figures from a run log (pure numpy/matplotlib; no Drake).

A *run log* is any mapping (a dict, or ``np.load("log.npz")``) with the keys

========================== =============================================================
key                        contents (T samples, m obstacles, n = dimension)
========================== =============================================================
t                          (T,) seconds
output, center             (T, n) robot output y and tube centre c
radius                     (T,) tube radius r
belief                     (T, m·(n+4)) obstacle-major records [mean, σ, r_o, ε, p_d]
avoid_probability          (T, m) q_j at the centre
quantile_distance, theta   (T, m)
control                    (T, n)
margins                    (T, 5) in ``stt_drake.core.invariants.INVARIANT_NAMES`` order
output_avoid_probability   (T, m) P(‖y − O_j‖ ≥ r_o_j)
dimension, start, target,  scalars / (n,) arrays describing the task
initial_set_radius,
target_set_radius, r_min
name                       str (a 0-d array in an npz)
r_max                      optional: drawn as a reference in :func:`plot_margins`
========================== =============================================================

Every function returns a :class:`matplotlib.figure.Figure` built without pyplot, so it
works headless (no backend is touched) and displays in notebooks as-is. All figures share
one visual language, :data:`PALETTE`.

The obstacle uncertainty is drawn as the sub-level sets of the point avoidance probability
q̂_j(x) = P(‖x − O_j‖ ≥ r_o_j): {q̂_j ≤ p_d_j} (light, where the tube starts to react) and
{q̂_j ≤ ε_j} (darker, what the robot's output must stay out of). q̂_j grows with the
distance to the mean, so both sets are discs around the mean; their radii come from a 1-D
root find (:func:`level_set_radius`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Colormap, ListedColormap, Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch
from mpl_toolkits.mplot3d.art3d import Line3DCollection
from scipy.optimize import brentq

from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.invariants import tube_reach_time
from stt_drake.core.probability import noncentral_chi_sf

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
#: Alpha of the {q̂ ≤ p_d} and {q̂ ≤ ε} discs.
_LIGHT_ALPHA, _DARK_ALPHA = 0.14, 0.38
#: Markers that tell obstacles apart in line plots when their σ colours coincide.
_OBSTACLE_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "*")
#: Up to this many obstacles the per-obstacle margin panel has a legend, beyond it a σ
#: colourbar; it is also how many of the most critical obstacles its y axis keeps in view.
_LEGEND_MAX = 6
#: Beyond this many obstacles the 3D tube plot draws them thinner, fainter and sparser.
_MANY_OBSTACLES = 10
#: Panels of :func:`plot_margins` for margins columns 0..3: (column, title, y label).
_MARGIN_PANELS = (
    (0, "output in tube", r"$r - \Vert y - c\Vert$ (m)"),
    (1, "centre avoidance", r"$\min_j\, q_j(c) - \varepsilon_j$"),
    (2, "tube avoidance", r"$\min_j\, P(B(c,r) \cap O_j = \emptyset) - \varepsilon_j$"),
    (3, "output avoidance", r"$\min_j\, \hat{q}_j(y) - \varepsilon_j$"),
)


@dataclass(frozen=True)
class _Run:
    """A run log decoded once (npz members are re-read from the zip on every access)."""

    name: str
    dimension: int
    t: np.ndarray  # (T,)
    output: np.ndarray  # (T, n)
    center: np.ndarray  # (T, n)
    radius: np.ndarray  # (T,)
    mean: np.ndarray  # (T, m, n)
    sigma: np.ndarray  # (T, m)
    obstacle_radius: np.ndarray  # (T, m)
    epsilon: np.ndarray  # (T, m)
    p_d: np.ndarray  # (T, m)
    margins: np.ndarray  # (T, 5)
    output_avoid_probability: np.ndarray  # (T, m)
    start: np.ndarray  # (n,)
    initial_set_radius: float
    target: np.ndarray  # (n,)
    target_set_radius: float
    r_min: float
    r_max: float | None

    @property
    def count(self) -> int:
        return self.sigma.shape[1]


def _decode(log: Mapping[str, Any] | _Run) -> _Run:
    if isinstance(log, _Run):
        return log
    dimension = int(np.asarray(log["dimension"]))
    t = np.asarray(log["t"], dtype=float)
    samples = t.shape[0]
    belief_rows = np.asarray(log["belief"], dtype=float).reshape(samples, -1)
    # One from_vector call on all rows: its (T·m, n+4) table, reshaped back to (T, m, ...).
    belief = ObstacleBelief.from_vector(belief_rows.ravel(), dimension)
    count = belief.count // samples if samples else 0
    name = np.asarray(log["name"]).item() if "name" in log else ""
    r_max = float(np.asarray(log["r_max"])) if "r_max" in log else None
    return _Run(
        name=str(name),
        dimension=dimension,
        t=t,
        output=np.asarray(log["output"], dtype=float).reshape(samples, dimension),
        center=np.asarray(log["center"], dtype=float).reshape(samples, dimension),
        radius=np.asarray(log["radius"], dtype=float).reshape(samples),
        mean=belief.mean.reshape(samples, count, dimension),
        sigma=belief.sigma.reshape(samples, count),
        obstacle_radius=belief.radius.reshape(samples, count),
        epsilon=belief.epsilon.reshape(samples, count),
        p_d=belief.p_d.reshape(samples, count),
        margins=np.asarray(log["margins"], dtype=float).reshape(samples, -1),
        output_avoid_probability=np.asarray(log["output_avoid_probability"], dtype=float).reshape(
            samples, count
        ),
        start=np.asarray(log["start"], dtype=float).reshape(dimension),
        initial_set_radius=float(np.asarray(log["initial_set_radius"])),
        target=np.asarray(log["target"], dtype=float).reshape(dimension),
        target_set_radius=float(np.asarray(log["target_set_radius"])),
        r_min=float(np.asarray(log["r_min"])),
        r_max=r_max,
    )


def level_set_radius(level: float, sigma: float, radius: float, dimension: int) -> float:
    """Distance d from the mean at which q̂(x) = P(‖x − O‖ ≥ radius) equals `level`.

    q̂ depends on x only through d = ‖x − mean‖ and grows with it, so {q̂ ≤ level} is the
    closed disc (ball) of radius d around the mean.

    Args:
        level: probability in (0, 1].
        sigma: standard deviation of the obstacle centre per axis (> 0), metres.
        radius: obstacle radius r_o (≥ 0), metres.
        dimension: n.

    Returns:
        d in metres: 0 if even the mean has q̂ ≥ level (the set is empty or a point);
        ``inf`` if q̂ < level everywhere (the set is the whole space).
    """
    threshold = radius / sigma

    def gap(offset: float) -> float:
        return float(noncentral_chi_sf(threshold, offset, dimension)) - level

    if gap(0.0) >= 0.0:
        return 0.0
    upper = threshold + np.sqrt(dimension) + 10.0
    for _ in range(60):
        if gap(upper) >= 0.0:
            break
        upper *= 2.0
    else:
        return float("inf")
    return sigma * brentq(gap, 0.0, upper, xtol=1e-13, rtol=8.0 * np.finfo(float).eps)


def _obstacle_colors(run: _Run) -> tuple[Normalize, Colormap]:
    """The σ → colour map shared by every figure of a run."""
    base = colormaps[PALETTE["obstacle_cmap"]]
    cmap = ListedColormap(base(np.linspace(*_CMAP_RANGE, 256)), name="obstacle_sigma")
    if run.count == 0:
        return Normalize(0.0, 1.0), cmap
    low, high = float(np.min(run.sigma)), float(np.max(run.sigma))
    if high - low < 1e-12 * max(abs(high), 1.0):
        low, high = low * 0.5, high * 1.5 if high > 0 else 1.0
    return Normalize(low, high), cmap


def _sigma_colorbar(
    fig: Figure, run: _Run, axes: Any, shrink: float = 0.8, pad: float = 0.02
) -> None:
    norm, cmap = _obstacle_colors(run)
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=axes, shrink=shrink, pad=pad)
    bar.set_label("σ (m)")


def decode_log(log: Mapping[str, Any]) -> _Run:
    """A run log decoded once into arrays (obstacle beliefs unpacked per sample); the
    figures and :mod:`stt_drake.replay` draw from it."""
    return _decode(log)


def obstacle_colors(log: Mapping[str, Any]) -> tuple[Normalize, Colormap]:
    """The σ → colour map of a run's obstacles (the one every figure and the replay use)."""
    return _obstacle_colors(_decode(log))


def reach_time(log: Mapping[str, Any]) -> float | None:
    """First logged time after which the tube stays inside the target set, else None.

    The tube B(c, r) is inside the target ball when ‖c − target‖ + r ≤ target radius.
    """
    run = _decode(log)
    return tube_reach_time(run.t, run.center, run.radius, run.target, run.target_set_radius)


def _default_times(run: _Run) -> list[float]:
    t_reach = reach_time(run)
    t0, t_end = float(run.t[0]), float(run.t[-1])
    middle = 0.5 * (t0 + t_reach) if t_reach is not None and t_reach > t0 else 0.5 * (t0 + t_end)
    return [t0, middle, t_end]


def _nearest_index(t: np.ndarray, time: float) -> int:
    return int(np.argmin(np.abs(t - time)))


def _snapshot_limits(run: _Run, indices: Sequence[int], extents: np.ndarray) -> np.ndarray:
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
        mean = run.mean[index, :, :2]
        reach = extents[k][:, None]
        lows.append(mean - reach)
        highs.append(mean + reach)
    low = np.min(np.vstack([*points, *lows]), axis=0)
    high = np.max(np.vstack([*points, *highs]), axis=0)
    pad = 0.05 * np.max(high - low) + 1e-9
    return np.column_stack([low - pad, high + pad])


def _obstacle_discs(run: _Run, index: int) -> np.ndarray:
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


def plot_snapshots(log: Mapping[str, Any], times: Sequence[float] | None = None) -> Figure:
    """Top view of a 2D run at a few instants, one panel per instant.

    Each panel shows, for every obstacle, the discs {q̂_j ≤ p_d_j} (light) and
    {q̂_j ≤ ε_j} (darker) of the point avoidance probability q̂_j(x) = P(‖x − O_j‖ ≥ r_o_j),
    the nominal disc B(mean_j, r_o_j) (outline) and the mean's path so far (dotted), all
    coloured by σ_j; the tube Γ(t) = B(c, r); the output path and the centre path so far;
    the start and target sets. Panels share limits and use equal aspect.

    Args:
        log: a run log (see the module docstring) with dimension 2.
        times: instants in seconds (each snapped to the nearest sample). Default: the
            start, the middle of the reach (halfway to the reach time, or to the end if the
            tube never settles in the target set) and the end.

    Returns:
        The figure: one axes per instant plus a σ colourbar (when there are obstacles).
    """
    run = _decode(log)
    if run.dimension != 2:
        raise ValueError(f"plot_snapshots draws 2D runs; this run has dimension {run.dimension}")
    indices = [_nearest_index(run.t, time) for time in (times or _default_times(run))]
    discs = [_obstacle_discs(run, index) for index in indices]
    # Limits cover the ε discs; the wider p_d discs may run off the panel.
    extents = [
        np.maximum(np.where(np.isfinite(d[:, 1]), d[:, 1], 0.0), run.obstacle_radius[i])
        for d, i in zip(discs, indices, strict=True)
    ]
    limits = _snapshot_limits(run, indices, np.array(extents).reshape(len(indices), run.count))
    norm, cmap = _obstacle_colors(run)

    panels = len(indices)
    fig = Figure(figsize=(4.2 * panels + 1.2, 4.8), layout="constrained")
    axes = fig.subplots(1, panels, sharex=True, sharey=True, squeeze=False)[0]
    for ax, index, disc in zip(axes, indices, discs, strict=True):
        for j in range(run.count):
            color = cmap(norm(run.sigma[index, j]))
            center = run.mean[index, j]
            light, dark = disc[j]
            if np.isfinite(light):
                ax.add_patch(Circle(center, light, fc=color, alpha=_LIGHT_ALPHA, lw=0, zorder=1))
            if np.isfinite(dark):
                ax.add_patch(Circle(center, dark, fc=color, alpha=_DARK_ALPHA, lw=0, zorder=1))
            ax.add_patch(
                Circle(center, run.obstacle_radius[index, j], fc="none", ec=color, lw=1.4, zorder=3)
            )
            ax.plot(*run.mean[: index + 1, j].T, ls=":", lw=0.9, color=color, zorder=2)
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
        ax.set_title(f"t = {run.t[index]:.1f} s")
        ax.set_xlabel("x (m)")
        ax.grid(alpha=0.25, lw=0.5)
    axes[0].set_ylabel("y (m)")

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
        log: a run log (see the module docstring) with dimension 2.
        circles: about how many tube circles to draw, evenly spread over the samples.

    Returns:
        The figure: one 3D axes plus a σ colourbar (when there are obstacles).
    """
    run = _decode(log)
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
        path = np.column_stack([run.mean[:, j], run.t])
        segments = np.stack([path[:-1], path[1:]], axis=1)
        sigma_mid = 0.5 * (run.sigma[:-1, j] + run.sigma[1:, j])
        ax.add_collection3d(
            Line3DCollection(segments, colors=cmap(norm(sigma_mid)), lw=path_lw, alpha=path_alpha)
        )
    # The {q̂_j ≤ ε_j} discs as rings at every 4th (8th when many) tube time: the clearance
    # the output needs.
    obstacle_rings, ring_colors = [], []
    for i in picks[::ring_stride]:
        for j, disc in enumerate(_obstacle_discs(run, i)[:, 1]):
            if np.isfinite(disc) and disc > 0.0:
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
        points.append(run.mean.reshape(-1, 2))
    everything = np.vstack(points)
    ax.set_xlim(everything[:, 0].min(), everything[:, 0].max())
    ax.set_ylim(everything[:, 1].min(), everything[:, 1].max())
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


def _snapshot_cube(run: _Run, pad: float = 0.06) -> np.ndarray:
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


def _main_direction(run: _Run) -> np.ndarray:
    """The direction along which the output path extends most (its first principal axis):
    the start–target line of a straight trip, the transfer of a pick-and-place. Falls back
    to target − start when the path is a point."""
    spread = run.output - np.mean(run.output, axis=0)
    _, singular, axes = np.linalg.svd(spread, full_matrices=False)
    if singular[0] <= 1e-12:
        return run.target - run.start
    return axes[0]


def plot_snapshots_3d(log: Mapping[str, Any], times: Sequence[float] | None = None) -> Figure:
    """A 3D run (the UAV) at a few instants, one 3D panel per instant.

    Each panel shows every obstacle as the sphere B(μ_j, r_o_j) at its mean, coloured by
    σ_j (darker = more uncertain, as in the paper's Fig. of the UAV study) and labelled
    with its index when there are at most :data:`_MANY_OBSTACLES`; the tube
    Γ(t) = B(c, r) as a wireframe sphere; the output path y and the centre path so far;
    the start and target sets as wireframe spheres. Panels share one cube of limits around
    the task (start and target sets, output, tube; obstacles outside it are clipped) and a
    camera looking at the output path's main direction from the side, so detours show.

    Args:
        log: a run log (see the module docstring) with dimension 3.
        times: instants in seconds (each snapped to the nearest sample). Default: the
            start, halfway to the reach time (or to the end) and the end.

    Returns:
        The figure: one 3D axes per instant plus a σ colourbar (when there are obstacles).
    """
    run = _decode(log)
    if run.dimension != 3:
        raise ValueError(f"plot_snapshots_3d draws 3D runs; this run has dimension {run.dimension}")
    indices = [_nearest_index(run.t, time) for time in (times or _default_times(run))]
    limits = _snapshot_cube(run)
    norm, cmap = _obstacle_colors(run)
    many = run.count > _MANY_OBSTACLES
    resolution, surface_alpha = (6, 0.5) if many else (10, 0.6)
    elevation, azimuth = _side_view(np.zeros(3), _main_direction(run))

    panels = len(indices)
    fig = Figure(figsize=(5.2 * panels + 1.2, 5.8), layout="constrained")
    axes = [fig.add_subplot(1, panels, i + 1, projection="3d") for i in range(panels)]
    for ax, index in zip(axes, indices, strict=True):
        for j in range(run.count):
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
        ax.set_title(f"t = {run.t[index]:.1f} s")
        ax.view_init(elev=elevation, azim=azimuth)

    handles = [
        Line2D([], [], color=PALETTE["trajectory"], lw=1.5, label="output y"),
        Line2D([], [], color=PALETTE["tube"], ls="--", lw=0.8, label="tube centre c"),
        Line2D([], [], color=PALETTE["tube"], lw=0.7, label=r"tube $\Gamma(t) = B(c, r)$"),
        Line2D([], [], color=PALETTE["start"], lw=0.8, label="start set"),
        Line2D([], [], color=PALETTE["target"], lw=0.8, label="target set"),
        Patch(fc=cmap(0.6), alpha=surface_alpha, label=r"obstacle $B(\mu_j, r_{o,j})$"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncol=6, fontsize=8, frameon=False)
    if run.count:
        _sigma_colorbar(fig, run, axes, shrink=0.7)
    if run.name:
        fig.suptitle(run.name)
    return fig


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


def _plot_obstacle_margins(fig: Figure, ax: Any, run: _Run) -> None:
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
    sigma_bar = np.mean(run.sigma, axis=0)
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
    run = _decode(log)
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
    t = np.asarray(log["t"], dtype=float)
    torque = np.asarray(log["requested_torque"], dtype=float).reshape(t.size, -1)
    errors = np.asarray(log["funnel_errors"], dtype=float).reshape(t.size, -1)
    limit = np.asarray(log["effort_limit"], dtype=float) if "effort_limit" in log else None
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
    if "external_force" in log:
        pushed = np.linalg.norm(np.asarray(log["external_force"], dtype=float), axis=1) > 0.0
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
    if "task_target" in log:
        target = np.asarray(log["task_target"], dtype=float).reshape(t.size, -1)
        switches = t[1:][np.any(np.diff(target, axis=0) != 0.0, axis=1)]
        for ax in axes:
            for time in switches:
                ax.axvline(time, color=PALETTE["target"], ls=":", lw=1.0)
    for ax in axes:
        ax.grid(alpha=0.25, lw=0.5)
    name = str(np.asarray(log["name"]).item()) if "name" in log else ""
    fig.suptitle(f"{name} — joint torques and funnel errors" if name else "joint torques")
    return fig


def save_run_figures(log: Mapping[str, Any], out_dir: str | Path, dpi: int = 120) -> list[Path]:
    """Write the run's figures as PNGs into `out_dir` (created if needed).

    2D runs: ``snapshots.png``, ``tube_3d.png`` and ``margins.png``; 3D runs:
    ``snapshots.png`` (:func:`plot_snapshots_3d`) and ``margins.png``; other dimensions:
    ``margins.png`` only. Runs of the arm (logs with `requested_torque`) also get
    ``joint_torques.png`` (:func:`plot_joint_torques`).

    Returns:
        The paths written, in that order.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run = _decode(log)  # once: an npz re-reads every member from its zip on each access
    builders: list[tuple[str, Any]] = []
    if run.dimension == 2:
        builders += [("snapshots.png", plot_snapshots), ("tube_3d.png", plot_tube_3d)]
    elif run.dimension == 3:
        builders.append(("snapshots.png", plot_snapshots_3d))
    builders.append(("margins.png", plot_margins))
    if "requested_torque" in log:  # a torque-controlled arm
        builders.append(("joint_torques.png", lambda _: plot_joint_torques(log)))
    written = []
    for filename, build in builders:
        path = out / filename
        build(run).savefig(path, dpi=dpi)
        written.append(path)
    return written
