"""Tests of stt_drake.plotting on small synthetic run logs."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from matplotlib.colors import to_rgba, to_rgba_array
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.invariants import evaluate_invariants
from stt_drake.core.probability import avoid_probability
from stt_drake.plotting import (
    PALETTE,
    level_set_radius,
    plot_margins,
    plot_snapshots,
    plot_snapshots_3d,
    plot_tube_3d,
    reach_time,
    save_run_figures,
    snapshot_times,
)
from stt_drake.runlog import RunLog

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
    first = np.array([[2.0, 4.0, 0.0], [6.0, 1.0, 0.5], [9.0, 2.0, 1.0]])[:, :dimension]
    velocity = np.array([[0.2, -0.1, 0.0], [-0.1, 0.15, 0.0], [0.0, 0.2, 0.0]])[:, :dimension]
    return build_log(dimension, first, velocity, SIGMA, OBSTACLE_RADIUS, EPSILON, P_D)


def make_cluttered_log(count: int = 50, seed: int = 7) -> dict[str, np.ndarray]:
    """The same 2D motion among `count` random obstacles (some cross the path)."""
    rng = np.random.default_rng(seed)
    first = rng.uniform([-2.0, -2.0], [10.0, 8.0], size=(count, 2))
    velocity = rng.uniform(-0.2, 0.2, size=(count, 2))
    return build_log(
        2,
        first,
        velocity,
        sigma=rng.uniform(0.05, 1.0, count),
        obstacle_radius=rng.uniform(0.1, 0.5, count),
        epsilon=rng.uniform(0.7, 0.98, count),
        p_d=np.full(count, 0.999),
    )


def build_log(
    dimension: int,
    first: np.ndarray,
    velocity: np.ndarray,
    sigma: np.ndarray,
    obstacle_radius: np.ndarray,
    epsilon: np.ndarray,
    p_d: np.ndarray,
) -> dict[str, np.ndarray]:
    """A run log whose obstacle j starts at first[j] and moves at velocity[j]."""
    t = np.linspace(0.0, 10.0, SAMPLES)
    start = np.zeros(dimension)
    target = np.array([8.0, 6.0, 1.0][:dimension])
    progress = np.clip(t / 8.0, 0.0, 1.0)[:, None]
    center = start + progress * (target - start)
    wobble = np.zeros((SAMPLES, dimension))
    wobble[:, 0], wobble[:, 1] = 0.1 * np.cos(t), 0.1 * np.sin(t)
    output = center + wobble
    radius = np.full(SAMPLES, TUBE_RADIUS)
    count = first.shape[0]
    rows, q, d_hat, margins, output_q = [], [], [], [], []
    for k in range(SAMPLES):
        belief = ObstacleBelief(
            mean=first + t[k] * velocity,
            sigma=sigma,
            radius=obstacle_radius,
            epsilon=epsilon,
            p_d=p_d,
        )
        rows.append(belief.to_vector())
        q.append(avoid_probability(center[k], belief.mean, sigma, obstacle_radius + R_MIN))
        d_hat.append(np.linalg.norm(center[k] - belief.mean, axis=1) - obstacle_radius)
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
        "obstacle_radius": np.broadcast_to(obstacle_radius, count).astype(float),
        "epsilon": np.broadcast_to(epsilon, count).astype(float),
        "p_d": np.broadcast_to(p_d, count).astype(float),
    }


@pytest.fixture(scope="module")
def log() -> dict[str, np.ndarray]:
    return make_log(2)


@pytest.fixture(scope="module")
def cluttered_log() -> dict[str, np.ndarray]:
    return make_cluttered_log(50)


def circles(ax) -> list[Circle]:
    return [patch for patch in ax.patches if isinstance(patch, Circle)]


def test_snapshots_axes_circles_and_single_legend(log):
    fig = plot_snapshots(log, times=[0.0, 5.0, 10.0])
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
        # obstacle labels are 0-based, like the scenario and the metrics
        assert sorted(text.get_text() for text in ax.texts) == ["0", "1", "2"]
    assert panels[0].get_ylabel() == "y (m)"
    assert len(fig.legends) == 1
    assert panels[0].get_title().splitlines()[0] == "t = 0.00 s"
    assert panels[-1].get_title().splitlines()[0] == "t = 10.00 s"


def test_snapshot_level_set_discs_sit_on_their_probability_levels(log):
    picks = [0, 20, SAMPLES - 1]
    fig = plot_snapshots(log, times=[log["t"][k] for k in picks])
    panels = [ax for ax in fig.axes if ax.get_title().startswith("t = ")]
    for ax, k in zip(panels, picks, strict=True):
        belief = RunLog.of(log).belief_at(k)
        assert ax.get_title().splitlines()[0] == f"t = {log['t'][k]:.2f} s"
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
    assert len(fig.axes) == 7
    radius_ax = fig.axes[0]
    assert radius_ax.get_ylabel() == "r (m)"
    levels = {tuple(line.get_ydata()) for line in radius_ax.lines}
    assert (R_MIN, R_MIN) in levels and (TUBE_RADIUS, TUBE_RADIUS) in levels
    for ax, column in zip(fig.axes[1:5], range(4), strict=True):
        curves = [np.asarray(line.get_ydata()) for line in ax.lines]
        assert any(
            c.shape == (SAMPLES,) and np.array_equal(c, log["margins"][:, column]) for c in curves
        ), f"panel {ax.get_title()!r} does not show margins column {column}"


@pytest.mark.slow
def test_many_obstacles_save_run_figures_emits_no_warning(cluttered_log, tmp_path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        paths = save_run_figures(cluttered_log, tmp_path)
    assert [str(w.message) for w in caught] == []
    assert [p.name for p in paths] == ["snapshots.png", "tube_3d.png", "margins.png"]


def test_tube_3d_thins_many_obstacle_paths(log, cluttered_log):
    def mean_paths(fig):
        ax = fig.axes[0]
        return ax.collections[1:-1]  # between the tube circles and the ε rings

    few, many = mean_paths(plot_tube_3d(log)), mean_paths(plot_tube_3d(cluttered_log))
    assert len(few) == 3 and len(many) == 50
    assert max(c.get_linewidth().max() for c in many) < min(c.get_linewidth().min() for c in few)
    assert all(c.get_alpha() is not None and c.get_alpha() < 1.0 for c in many)


def test_reach_time(log):
    distance = np.linalg.norm(log["center"] - log["target"], axis=1)
    inside = distance + TUBE_RADIUS <= TARGET_SET_RADIUS
    k = int(np.argmax(inside))
    assert k > 0 and not inside[k - 1] and inside[k:].all()
    assert reach_time(log) == log["t"][k]
    late = dict(log, target=log["target"] + 5.0)
    assert reach_time(late) is None


@pytest.mark.slow
def test_save_run_figures_from_an_npz(log, tmp_path):
    np.savez(tmp_path / "log.npz", **log)
    with np.load(tmp_path / "log.npz") as loaded:
        paths = save_run_figures(loaded, tmp_path / "figures")
    assert [p.name for p in paths] == ["snapshots.png", "tube_3d.png", "margins.png"]
    for path in paths:
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert path.stat().st_size > 10_000


@pytest.mark.slow
def test_three_dimensional_run_writes_3d_snapshots_and_margins(tmp_path):
    log3 = make_log(3)
    with pytest.raises(ValueError, match="dimension 3"):
        plot_snapshots(log3)
    with pytest.raises(ValueError, match="dimension 2"):
        plot_snapshots_3d(make_log(2))
    paths = save_run_figures(log3, tmp_path)
    assert [p.name for p in paths] == ["snapshots.png", "margins.png"]
    for path in paths:
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert path.stat().st_size > 10_000


def lines_3d(ax) -> list[np.ndarray]:
    """(3, M) data of every 3D line of an axes."""
    return [np.asarray(line.get_data_3d(), dtype=float) for line in ax.lines]


def sphere_lines(ax, center, radius, color) -> list[np.ndarray]:
    """Lines of `color` whose every point lies on the sphere B(center, radius)."""
    found = []
    for line, data in zip(ax.lines, lines_3d(ax), strict=True):
        points = data[:, np.all(np.isfinite(data), axis=0)].T
        if to_rgba(line.get_color()) != to_rgba(color) or len(points) < 20:
            continue
        if np.allclose(np.linalg.norm(points - center, axis=1), radius, rtol=0, atol=1e-9):
            found.append(points)
    return found


def test_snapshots_3d_draw_tube_paths_and_obstacles_at_each_instant():
    log3 = make_log(3)
    picks = [0, 20, SAMPLES - 1]
    fig = plot_snapshots_3d(log3, times=[log3["t"][k] for k in picks])
    panels = [ax for ax in fig.axes if ax.name == "3d"]
    assert len(panels) == 3
    assert len(fig.axes) == 4 and fig.axes[-1].get_ylabel() == "σ (m)"
    assert len(fig.legends) == 1
    for ax, k in zip(panels, picks, strict=True):
        assert ax.get_title().splitlines()[0] == f"t = {log3['t'][k]:.2f} s"
        assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("x (m)", "y (m)", "z (m)")
        for get in ("get_xlim", "get_ylim", "get_zlim"):
            assert getattr(ax, get)() == getattr(panels[0], get)()
        # one cube: equal spans, holding the start and target sets
        spans = [np.diff(getattr(ax, get)())[0] for get in ("get_xlim", "get_ylim", "get_zlim")]
        assert np.allclose(spans, spans[0])
        for point, radius in ((log3["start"], 0.5), (log3["target"], TARGET_SET_RADIUS)):
            for axis, get in enumerate(("get_xlim", "get_ylim", "get_zlim")):
                low, high = getattr(ax, get)()
                assert low <= point[axis] - radius and point[axis] + radius <= high
        # obstacle labels (0-based) at the means of that instant
        belief = RunLog.of(log3).belief_at(k)
        labels = {text.get_text(): np.array(text.get_position_3d()) for text in ax.texts}
        assert sorted(labels) == ["0", "1", "2"]
        for j in range(belief.count):
            np.testing.assert_allclose(labels[str(j)], belief.mean[j], atol=1e-12)
        # the path so far, the tube as a wireframe sphere B(c, r), start and target sets
        assert any(
            data.shape == (3, k + 1) and np.array_equal(data, log3["output"][: k + 1].T)
            for data in lines_3d(ax)
        )
        assert sphere_lines(ax, log3["center"][k], TUBE_RADIUS, PALETTE["tube"])
        assert sphere_lines(ax, log3["start"], 0.5, PALETTE["start"])
        assert sphere_lines(ax, log3["target"], TARGET_SET_RADIUS, PALETTE["target"])
        # one sphere surface per obstacle, darker for larger σ (Reds)
        surfaces = ax.collections
        assert len(surfaces) == belief.count
        # and one wireframe sphere per obstacle on its ε level set {q̂_j ≤ ε_j} (when that
        # set is bounded and larger than the obstacle)
        drawn = 0
        for j in range(belief.count):
            level = level_set_radius(belief.epsilon[j], belief.sigma[j], belief.radius[j], 3)
            shown = belief.radius[j] < level < np.inf
            drawn += shown
            on_level_set = [
                line
                for line, data in zip(ax.lines, lines_3d(ax), strict=True)
                if data.shape[1] >= 20
                and np.allclose(
                    np.linalg.norm(
                        data[:, np.all(np.isfinite(data), axis=0)].T - belief.mean[j], axis=1
                    ),
                    level,
                    rtol=0,
                    atol=1e-9,
                )
            ]
            assert len(on_level_set) == int(shown), j
        assert drawn >= 1
        brightness = [np.mean(to_rgba_array(s.get_facecolor())[:, :3]) for s in surfaces]
        assert np.argsort(brightness).tolist() == np.argsort(-SIGMA).tolist()


def test_snapshots_3d_drop_labels_when_many_obstacles():
    rng = np.random.default_rng(3)
    count = 12
    log3 = build_log(
        3,
        rng.uniform(0.0, 8.0, size=(count, 3)),
        rng.uniform(-0.1, 0.1, size=(count, 3)),
        sigma=rng.uniform(0.05, 0.5, count),
        obstacle_radius=np.full(count, 0.3),
        epsilon=np.full(count, 0.9),
        p_d=np.full(count, 0.999),
    )
    fig = plot_snapshots_3d(log3)
    panels = [ax for ax in fig.axes if ax.name == "3d"]
    assert len(panels) == len(snapshot_times(log3))
    for ax in panels:
        assert not ax.texts
        assert len(ax.collections) == count
