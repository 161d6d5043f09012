"""True-obstacle campaigns with full covariances (issue 13): the sampled true centres are
N(μ, Σ) (their collision frequency matches the exact generalized chi-square probability,
and not the isotropic σ_max one), and the isotropic path draws exactly what it drew before."""

from __future__ import annotations

import numpy as np
import pytest

from stt_drake.campaign.sampling import ClosedLoop, run_seed, sample_true_obstacles, sample_xi
from stt_drake.core import anisotropic

ANGLE = np.pi / 6
ROTATION = np.array([[np.cos(ANGLE), -np.sin(ANGLE)], [np.sin(ANGLE), np.cos(ANGLE)]])
SIGMA = ROTATION @ np.diag([0.5**2, 0.1**2]) @ ROTATION.T


def single_point_loop(point: np.ndarray, covariance: np.ndarray | None, sigma: float) -> ClosedLoop:
    """One logged instant: the output at `point`, one obstacle of radius 0.3 m at the origin."""
    return ClosedLoop(
        t=np.array([0.0]),
        output=point[None],
        center=point[None],
        radius=np.array([0.05]),
        mean=np.zeros((1, 1, 2)),
        sigma=np.array([[sigma]]),
        obstacle_radius=np.array([[0.3]]),
        epsilon=np.array([0.9]),
        covariance=None if covariance is None else covariance[None, None],
    )


def collision_frequency(loop: ClosedLoop, runs: int) -> float:
    pairs = [(i, run_seed(7, i)) for i in range(runs)]
    records = sample_true_obstacles(loop, "static", 1.0, pairs)
    return float(np.mean([bool(record["output"][0]) for record in records]))


@pytest.mark.slow
def test_true_centres_follow_the_full_covariance():
    # A point along the long axis, 0.6 m out: P(collision) ≈ 0.4 with Σ, far from σ_max·I's.
    point = 0.6 * ROTATION[:, 0]
    exact = anisotropic.collision_probability(point, np.zeros(2), SIGMA, 0.3)
    isotropic = anisotropic.collision_probability(point, np.zeros(2), 0.25 * np.eye(2), 0.3)
    runs = 40_000
    frequency = collision_frequency(single_point_loop(point, SIGMA, 0.5), runs)
    error = np.sqrt(exact * (1 - exact) / runs)
    assert abs(frequency - exact) < 5 * error  # binomial: 5 standard errors
    assert abs(isotropic - exact) > 20 * error  # and the check can tell Σ from σ_max² I
    model = single_point_loop(point, SIGMA, 0.5).collision_probability()["output"][0, 0]
    np.testing.assert_allclose(model, exact, rtol=1e-12)


def test_isotropic_sampling_is_unchanged():
    """σ_j·ξ_j exactly as before full covariances existed (the old expression, copied)."""
    rng = np.random.default_rng(3)
    times = np.linspace(0.0, 1.0, 6)
    loop = ClosedLoop(
        t=times,
        output=rng.uniform(-1, 1, (6, 2)),
        center=rng.uniform(-1, 1, (6, 2)),
        radius=np.full(6, 0.2),
        mean=rng.uniform(-1, 1, (6, 3, 2)),
        sigma=rng.uniform(0.1, 0.5, (6, 3)),
        obstacle_radius=np.full((6, 3), 0.3),
        epsilon=np.full(3, 0.9),
    )
    pairs = [(i, run_seed(11, i)) for i in range(200)]
    records = sample_true_obstacles(loop, "ou", 0.5, pairs)
    xi = sample_xi([seed for _, seed in pairs], times, (3, 2), "ou", 0.5)
    old = loop.sigma[None, :, :, None] * xi
    gap = (loop.output[:, None, :] - loop.mean)[None] - old
    hit = np.einsum("rtjk,rtjk->rjt", gap, gap) < (loop.obstacle_radius**2).T[None]
    for r, record in enumerate(records):
        for j in range(3):
            expected = np.nonzero(hit[r, j])[0]
            covered = [k for start, stop in record["output"][j] for k in range(start, stop)]
            assert covered == list(expected)
    assert any(any(record["output"]) for record in records)  # some collisions to compare


def test_closed_loop_with_covariance_saves_and_loads(tmp_path):
    loop = single_point_loop(np.array([0.6, 0.0]), SIGMA, 0.5)
    loop.save(tmp_path / "loop.npz")
    again = ClosedLoop.load(tmp_path / "loop.npz")
    np.testing.assert_array_equal(again.covariance, loop.covariance)
    isotropic = single_point_loop(np.array([0.6, 0.0]), None, 0.5)
    isotropic.save(tmp_path / "iso.npz")
    assert ClosedLoop.load(tmp_path / "iso.npz").covariance is None
