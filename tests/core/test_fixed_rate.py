"""The fixed-rate update on a port vector (stt_drake.core.fixed_rate.advance_port): the
update of the belief the port holds, on the compiled and on the numpy path."""

from __future__ import annotations

import numpy as np
import pytest

from stt_drake.core import backend
from stt_drake.core.belief import GaussianBelief, ObstacleBelief, ObstacleTask
from stt_drake.core.fixed_rate import BeliefRateBounds, advance_port
from stt_drake.core.tube import TubeLaw

RNG_SEED = 20261127
COUNT = 5


def random_port(rng: np.random.Generator, n: int) -> np.ndarray:
    """A port vector of COUNT active slots near the origin, each Σ_j anisotropic (σ_j² =
    λ_max(Σ_j) is what the law reads)."""
    factors = rng.normal(0.0, 0.15, (COUNT, n, n))
    covariance = factors @ factors.transpose(0, 2, 1) + 0.01 * np.eye(n)
    mean = rng.uniform(-1.0, 1.0, (COUNT, n))
    return GaussianBelief(mean, covariance, np.ones(COUNT, dtype=bool)).to_vector()


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("n", [2, 3])
def test_advance_port_is_the_update_of_the_port_belief(n, compiled):
    """advance_port(vector, task) gives what law.advance gives for the belief made from the
    same vector (bit for bit: one kernel, or the same numpy steps), for centres among the
    obstacles, a first update (no radius) and a later one."""
    rng = np.random.default_rng(RNG_SEED + n)
    law = TubeLaw(
        target=np.full(n, 2.0),
        k1=0.7,
        k2=0.4,
        k3=0.3,
        r_min=0.05,
        r_max=0.3,
        nu=60.0,
        max_center_speed=1.5,
    )
    task = ObstacleTask(
        radius=rng.uniform(0.05, 0.2, COUNT),
        epsilon=rng.uniform(0.8, 0.95, COUNT),
        p_d=np.full(COUNT, 0.999),
    )
    moved = 0
    with backend.pure_numpy(not compiled):
        for _ in range(20):
            vector = random_port(rng, n)
            bounds = BeliefRateBounds(rng.uniform(0.0, 0.5, COUNT), rng.uniform(0.0, 0.05, COUNT))
            center = rng.uniform(-1.0, 1.0, n)
            axes = rng.normal(size=(COUNT, 3)) if n == 3 else None
            for radius in (np.nan, 0.1):
                update = advance_port(law, center, vector, task, 0.05, bounds, axes, radius)
                belief = ObstacleBelief.from_port(vector, n, task)
                expected = law.advance(center, belief, 0.05, bounds, axes, radius=radius)
                np.testing.assert_array_equal(update.center, expected.center)
                np.testing.assert_array_equal(update.certified, expected.certified)
                np.testing.assert_array_equal(update.theta, expected.theta)
                assert update.substeps == expected.substeps
                assert update.start_radius == expected.start_radius
                assert update.end_radius == expected.end_radius
                moved += bool(np.any(update.center != center))
    assert moved > 20  # the updates move the centre: the comparison is not of held points
