"""Tests of stt_drake.plotting on small synthetic run logs."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from stt_drake.belief import ObstacleBelief
from stt_drake.invariants import evaluate_invariants
from stt_drake.plotting import (
    level_set_radius,
    plot_margins,
    plot_snapshots,
    plot_tube_3d,
    reach_time,
    save_run_figures,
)
from stt_drake.probability import avoid_probability

SAMPLES = 50
R_MIN = 0.1
TUBE_RADIUS = 0.3
TARGET_SET_RADIUS = 0.5
SIGMA = np.array([0.1, 0.3, 0.6])
OBSTACLE_RADIUS = np.array([0.4, 0.3, 0.5])
EPSILON = np.array([0.9, 0.8, 0.95])
P_D = np.array([0.9999, 0.999, 0.99])


def make_log(dimension: int = 2) -> dict[str, np.ndarray]:
    """T = 50 samples over 10 s: the centre moves in a straight line from start to target
    in 8 s and stays; y circles it at 0.1 m; three obstacles move linearly."""
    t = np.linspace(0.0, 10.0, SAMPLES)
    start = np.zeros(dimension)
    target = np.array([8.0, 6.0, 1.0][:dimension])
    progress = np.clip(t / 8.0, 0.0, 1.0)[:, None]
    center = start + progress * (target - start)
    wobble = np.zeros((SAMPLES, dimension))
    wobble[:, 0], wobble[:, 1] = 0.1 * np.cos(t), 0.1 * np.sin(t)
    output = center + wobble
    radius = np.full(SAMPLES, TUBE_RADIUS)

    first = np.array([[2.0, 4.0, 0.0], [6.0, 1.0, 0.5], [9.0, 2.0, 1.0]])[:, :dimension]
    velocity = np.array([[0.2, -0.1, 0.0], [-0.1, 0.15, 0.0], [0.0, 0.2, 0.0]])[:, :dimension]
    count = first.shape[0]
    rows, q, d_hat, margins, output_q = [], [], [], [], []
    for k in range(SAMPLES):
        belief = ObstacleBelief(
            mean=first + t[k] * velocity,
            sigma=SIGMA,
            radius=OBSTACLE_RADIUS,
            epsilon=EPSILON,
            p_d=P_D,
        )
        rows.append(belief.to_vector())
        q.append(avoid_probability(center[k], belief.mean, SIGMA, OBSTACLE_RADIUS + R_MIN))
        d_hat.append(np.linalg.norm(center[k] - belief.mean, axis=1) - OBSTACLE_RADIUS)
        sample = evaluate_invariants(output[k], center[k], radius[k], belief, R_MIN)
        margins.append(sample.margins)
        output_q.append(sample.output_avoid_probability)
    return {
        "t": t,
        "output": output,
        "center": center,
        "radius": radius,
        "belief": np.array(rows),
        "avoid_probability": np.array(q),
        "quantile_distance": np.array(d_hat),
        "theta": np.zeros((SAMPLES, count)),
        "control": np.gradient(output, t, axis=0),
        "margins": np.array(margins),
        "output_avoid_probability": np.array(output_q),
        "dimension": np.array(dimension),
        "start": start,
        "initial_set_radius": np.array(0.5),
        "target": target,
        "target_set_radius": np.array(TARGET_SET_RADIUS),
        "r_min": np.array(R_MIN),
        "r_max": np.array(TUBE_RADIUS),
        "name": np.array("synthetic"),
    }


@pytest.fixture(scope="module")
def log() -> dict[str, np.ndarray]:
    return make_log(2)


def circles(ax) -> list[Circle]:
    return [patch for patch in ax.patches if isinstance(patch, Circle)]


def test_level_set_radius_matches_avoid_probability_in_2d_and_3d():
    for dimension in (2, 3):
        for sigma, r_o, level in [(0.1, 0.4, 0.9), (0.6, 0.5, 0.9999), (0.3, 0.3, 0.9)]:
            d = level_set_radius(level, sigma, r_o, dimension)
            point = np.zeros(dimension)
            point[-1] = d
            q = avoid_probability(point, np.zeros((1, dimension)), np.array([sigma]), r_o)
            assert d > 0.0
            assert q[0] == pytest.approx(level, abs=1e-9)


def test_level_set_radius_is_zero_when_even_the_mean_is_safe_enough():
    # σ ≫ r_o: q̂(mean) = P(‖Z‖ ≥ 0.01) ≈ 1 ≥ 0.9, so {q̂ ≤ 0.9} is empty.
    assert level_set_radius(0.9, 10.0, 0.1, 2) == 0.0


def test_snapshots_axes_circles_and_single_legend(log):
    fig = plot_snapshots(log)
    assert isinstance(fig, Figure)
    panels = [ax for ax in fig.axes if ax.get_title().startswith("t = ")]
    assert len(panels) == 3
    assert len(fig.axes) == 4  # + the σ colourbar
    assert fig.axes[-1].get_ylabel() == "σ (m)"
    for ax in panels:
        # per obstacle: {q̂ ≤ p_d}, {q̂ ≤ ε}, nominal disc; plus tube, start, target
        assert len(circles(ax)) == 3 * 3 + 3
        assert ax.get_xlim() == panels[0].get_xlim()
        assert ax.get_ylim() == panels[0].get_ylim()
        assert ax.get_xlabel() == "x (m)"
        assert ax.get_legend() is None
    assert panels[0].get_ylabel() == "y (m)"
    assert len(fig.legends) == 1
    assert panels[0].get_title() == "t = 0.0 s"
    assert panels[-1].get_title() == "t = 10.0 s"


def test_snapshot_level_set_discs_sit_on_their_probability_levels(log):
    picks = [0, 20, SAMPLES - 1]
    fig = plot_snapshots(log, times=[log["t"][k] for k in picks])
    panels = [ax for ax in fig.axes if ax.get_title().startswith("t = ")]
    for ax, k in zip(panels, picks, strict=True):
        belief = ObstacleBelief.from_vector(log["belief"][k], 2)
        assert ax.get_title() == f"t = {log['t'][k]:.1f} s"
        for j in range(belief.count):
            mine = [c for c in circles(ax) if np.allclose(c.center, belief.mean[j])]
            radii = sorted(c.radius for c in mine)
            assert len(radii) == 3
            nominal, dark, light = radii
            assert nominal == pytest.approx(belief.radius[j])
            for disc, level in ((dark, belief.epsilon[j]), (light, belief.p_d[j])):
                direction = np.array([0.6, -0.8])
                boundary = belief.mean[j] + disc * direction
                q = avoid_probability(
                    boundary, belief.mean[j : j + 1], belief.sigma[j : j + 1], belief.radius[j]
                )
                assert q[0] == pytest.approx(level, abs=1e-6)
        tube = [c for c in circles(ax) if np.allclose(c.center, log["center"][k])]
        assert TUBE_RADIUS in [c.radius for c in tube]


def test_tube_3d_axes_and_labels(log):
    fig = plot_tube_3d(log)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2  # the 3D axes + the σ colourbar
    ax = fig.axes[0]
    assert ax.name == "3d"
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("x (m)", "y (m)", "t (s)")
    # min(60, T) tube circles in one collection; one σ-coloured mean path per obstacle;
    # the ε rings of 3 obstacles at every 4th circle time in one more collection
    fig.draw_without_rendering()
    assert len(ax.collections[0].get_segments()) == SAMPLES
    assert len(ax.collections) == 1 + 3 + 1
    assert len(ax.collections[-1].get_segments()) == 3 * len(range(0, SAMPLES, 4))


def test_margins_panels_plot_the_right_columns(log):
    fig = plot_margins(log)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 6
    radius_ax = fig.axes[0]
    assert radius_ax.get_ylabel() == "r (m)"
    levels = {tuple(line.get_ydata()) for line in radius_ax.lines}
    assert (R_MIN, R_MIN) in levels and (TUBE_RADIUS, TUBE_RADIUS) in levels
    for ax, column in zip(fig.axes[1:5], range(4), strict=True):
        curves = [np.asarray(line.get_ydata()) for line in ax.lines]
        assert any(
            c.shape == (SAMPLES,) and np.array_equal(c, log["margins"][:, column]) for c in curves
        ), f"panel {ax.get_title()!r} does not show margins column {column}"
    per_obstacle = fig.axes[5]
    curves = [np.asarray(line.get_ydata()) for line in per_obstacle.lines]
    for j in range(3):
        assert any(np.array_equal(c, log["output_avoid_probability"][:, j]) for c in curves)
        assert any(c.shape == (SAMPLES,) and np.all(c == EPSILON[j]) for c in curves)


def test_reach_time(log):
    distance = np.linalg.norm(log["center"] - log["target"], axis=1)
    inside = distance + TUBE_RADIUS <= TARGET_SET_RADIUS
    k = int(np.argmax(inside))
    assert k > 0 and not inside[k - 1] and inside[k:].all()
    assert reach_time(log) == log["t"][k]
    late = dict(log, target=log["target"] + 5.0)
    assert reach_time(late) is None


def test_save_run_figures_from_an_npz(log, tmp_path):
    np.savez(tmp_path / "log.npz", **log)
    with np.load(tmp_path / "log.npz") as loaded:
        paths = save_run_figures(loaded, tmp_path / "figures")
    assert [p.name for p in paths] == ["snapshots.png", "tube_3d.png", "margins.png"]
    for path in paths:
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert path.stat().st_size > 10_000


def test_three_dimensional_run_writes_margins_only(tmp_path):
    log3 = make_log(3)
    with pytest.raises(ValueError, match="dimension 3"):
        plot_snapshots(log3)
    paths = save_run_figures(log3, tmp_path)
    assert [p.name for p in paths] == ["margins.png"]
    assert paths[0].stat().st_size > 10_000
