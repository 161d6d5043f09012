"""Pictures of full covariances (issue 13): the 2D snapshots draw the exact, non-circular
level sets {q̂_j ≤ ε_j} and {q̂_j ≤ p_d_j}."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.contour import QuadContourSet

from stt_drake.core import anisotropic
from stt_drake.plotting import plot_snapshots, plot_snapshots_3d
from stt_drake.plotting.style import LEVEL_GRID, _obstacle_discs, anisotropic_levels
from stt_drake.runlog import RunLog


@pytest.mark.slow
def test_2d_snapshot_draws_the_exact_level_sets(run_scenario):
    """Every vertex of each drawn contour lies within one grid spacing h of the true level
    set q̂_j = level (first-order distance |q̂ − level|/‖∇q̂‖, both exact), h < 6 cm, and the
    ε set is elongated along Σ's long axis (x: σ = 0.5 m) against its short one (0.05 m)."""
    log = RunLog.of(run_scenario("omni_anisotropic").log)
    ax = plot_snapshots(log, times=[0.0]).axes[0]
    contours = [c for c in ax.collections if isinstance(c, QuadContourSet)]
    assert len(contours) == 2 * log.count  # p_d and ε per obstacle, in that order
    discs = _obstacle_discs(log, 0)
    for k, contour in enumerate(contours):
        j = k // 2
        level = log.p_d[0, j] if k % 2 == 0 else log.epsilon[0, j]
        extent = 1.5 * discs[j, 0]  # the grid plot_snapshots contours on
        _x, _y, grid = anisotropic_levels(log, 0, j, extent)
        assert grid.min() <= level < grid[[0, -1], :].min()  # the level set is inside the grid
        h = 2 * extent / (LEVEL_GRID - 1)
        assert h < 0.06
        vertices = np.concatenate([path.vertices for path in contour.get_paths()])
        args = (log.mean[0, j], log.covariance[0, j], float(log.obstacle_radius[0, j]))
        q = anisotropic.avoid_probability(vertices, *args)
        slope = np.linalg.norm(anisotropic.avoid_probability_gradient(vertices, *args), axis=1)
        # first-order distance of each vertex from the true level set q̂ = level
        assert np.all(np.abs(q - level) / slope <= h), (j, level, h)
        if k % 2 == 1:  # the ε set: long along x, short along y
            size = vertices.max(axis=0) - vertices.min(axis=0)
            assert size[0] > 3 * size[1]


@pytest.mark.slow
def test_3d_level_set_wire_lies_on_the_exact_level_set(run_scenario):
    """uav_anisotropic's ε level sets in the 3D snapshot: every wire point has q̂_j = ε_j
    (the radial bisection's 1e-9·σ_max times the slope), and the set reaches farther along
    the flight direction u = (1, 1, 1)/√3 (σ = 0.6 m) than across it (σ = 0.05 m)."""
    from stt_drake.plotting.run3d import _level_set_wire

    log = RunLog.of(run_scenario("uav_anisotropic").log)
    u = np.ones(3) / np.sqrt(3.0)
    for j in range(log.count):
        wire = _level_set_wire(log, 0, j, 4)
        points = wire[:, np.all(np.isfinite(wire), axis=0)].T
        args = (log.mean[0, j], log.covariance[0, j], float(log.obstacle_radius[0, j]))
        q = anisotropic.avoid_probability(points, *args)
        slope = np.linalg.norm(anisotropic.avoid_probability_gradient(points, *args), axis=1)
        assert np.all(np.abs(q - log.epsilon[0, j]) <= 1e-8 * slope + 1e-12)
        offsets = points - log.mean[0, j]
        along = np.abs(offsets @ u)
        across = np.linalg.norm(offsets - np.outer(offsets @ u, u), axis=1)
        assert along.max() > 1.5 * across.max()
    axes = plot_snapshots_3d(log).axes
    assert len(axes) >= 3


@pytest.mark.slow
def test_meshcat_replay_draws_ellipsoids_on_the_principal_axes(tmp_path):
    """uav_anisotropic drawn live (2 s) into a loopback Meshcat: each obstacle node is turned
    so that its local axis k is Σ_j's k-th eigenvector, and the ε / p_d sets' semi-axes are
    the level sets' exact extents along those axes (≥ r_o): long along the flight
    direction, short across."""
    from stt_drake.replay import simulate_live, start_meshcat
    from tests.outputs.test_replay import animation, commands, rotate, short_scenario

    meshcat = start_meshcat()
    try:
        result, path = simulate_live(
            short_scenario("uav_anisotropic", 2.0), tmp_path / "replay.html", meshcat=meshcat
        )
    finally:
        del meshcat
    html = path.read_text()
    assert "/stt/obstacles/0/epsilon_set/shape" in {
        c["path"] for c in commands(html) if c["type"] == "set_object"
    }
    _fps, tracks = animation(html)
    log = RunLog.of(result.log)
    for j in range(log.count):
        covariance, r_o = log.covariance[0, j], float(log.obstacle_radius[0, j])
        _variances, axes = anisotropic.eigen_decomposition(covariance)
        quaternion = np.asarray(tracks[f"/stt/obstacles/{j}"][".quaternion"][0], dtype=float)
        for k in range(3):
            turned = rotate(quaternion, np.eye(3)[k])
            assert abs(turned @ axes[:, k]) == pytest.approx(1.0, abs=1e-9)
        for part, level in (("epsilon_set", log.epsilon[0, j]), ("p_d_set", log.p_d[0, j])):
            scale = np.asarray(tracks[f"/stt/obstacles/{j}/{part}"][".scale"][0], dtype=float)
            extents = anisotropic.level_set_radii(axes.T, covariance, r_o, level)
            np.testing.assert_allclose(scale, np.maximum(extents, r_o), rtol=1e-8)
            assert scale[2] > 1.5 * scale[0]  # λ ascending: axis 2 is the flight direction
