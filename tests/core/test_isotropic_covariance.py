"""A full covariance that is σ²I to rounding (stt_drake.core.constants.ISOTROPIC_RTOL) takes
the noncentral χ law instead of the contour integral: which Σ do, and that the law's q_j and
d̂_j there agree with the contour integral at the Σ itself (an independent evaluation, numpy)
within the total-variation bound the constant's comment derives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stt_drake.core import anisotropic, backend
from stt_drake.core._anisotropic_tube import isotropic_variance as compiled_isotropic_variance
from stt_drake.core.anisotropic_tube import isotropic_variance
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.constants import ISOTROPIC_RTOL
from tests.core.test_anisotropic_tube import make_law

SEED = 20261127


def both_rules(covariance: np.ndarray) -> float | None:
    """The numpy rule's answer, after checking that the compiled rule gives the same one."""
    variance = isotropic_variance(covariance)
    compiled = compiled_isotropic_variance(np.ascontiguousarray(covariance, dtype=float))
    if variance is None:
        assert math.isnan(compiled)
    else:
        assert compiled == pytest.approx(variance, rel=1e-15)
    return variance


@pytest.mark.parametrize("n", [2, 3])
def test_which_covariances_count_as_isotropic(n):
    sigma2 = 0.0372
    assert both_rules(sigma2 * np.eye(n)) == pytest.approx(sigma2, rel=1e-15)
    # A Kalman filter's rounding (the omni_tracked scenario's Σ differ from σ²I by ~1e-16).
    rounding = sigma2 * np.eye(n)
    rounding[0, 0] *= 1 + 2e-16
    rounding[0, 1] = rounding[1, 0] = 6e-21
    assert both_rules(rounding) == pytest.approx(sigma2, rel=1e-15)
    # Just outside the tolerance, on the diagonal (tr/n moves by δ/n: the entry deviates by
    # δ(1 − 1/n) ≥ δ/2) or off it: the contour integral.
    for i, k in [(0, 0), (0, 1), (n - 1, 0)]:
        outside = sigma2 * np.eye(n)
        outside[i, k] += 4 * ISOTROPIC_RTOL * sigma2
        outside[k, i] = outside[i, k]
        assert both_rules(outside) is None
    for broken in (np.zeros((n, n)), -sigma2 * np.eye(n), np.full((n, n), np.nan)):
        assert both_rules(broken) is None


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("n", [2, 3])
def test_law_terms_match_the_contour_integral_within_the_tolerance(n, compiled):
    """Σ_j = σ_j²(I + E_j), every |E_j| entry below ISOTROPIC_RTOL/2: q_j and d̂_j of the law
    (noncentral χ at σ² = tr Σ_j/n) against the contour integral at Σ_j itself. q within the
    total-variation bound 1.5·n·ISOTROPIC_RTOL plus the contour's own 1.5e-13; d̂ within
    1e-9 relative, as the reduction to the paper's law is checked."""
    rng = np.random.default_rng(SEED + n)
    law = make_law(n)
    count = 6
    compared = 0
    with backend.pure_numpy(not compiled):
        for _ in range(25):
            sigma = rng.uniform(0.05, 0.4, count)
            noise = rng.uniform(-0.5, 0.5, (count, n, n)) * ISOTROPIC_RTOL
            noise = 0.5 * (noise + noise.transpose(0, 2, 1))
            covariance = sigma[:, None, None] ** 2 * (np.eye(n)[None] + noise)
            belief = ObstacleBelief(
                mean=rng.uniform(0.0, 4.0, (count, n)),
                sigma=sigma,
                radius=rng.uniform(0.1, 0.3, count),
                epsilon=rng.uniform(0.7, 0.95, count),
                p_d=np.full(count, 0.9999),
                covariance=covariance,
            )
            assert all(isotropic_variance(matrix) is not None for matrix in covariance)
            near = rng.integers(count)  # a centre in obstacle `near`'s layer: q computed
            direction = rng.normal(size=n)
            reach = belief.radius[near] + law.r_min + sigma[near] * rng.uniform(0.5, 3.0)
            center = belief.mean[near] + reach * direction / np.linalg.norm(direction)
            evaluation = law.evaluate(center, belief, prune=False)
            for j in range(count):
                q = evaluation.avoid_probability[j]
                if q <= belief.p_d[j]:  # computed (above p_d it is the pruning bound)
                    contour = anisotropic.avoid_probability(
                        center, belief.mean[j], covariance[j], belief.radius[j] + law.r_min
                    )
                    assert abs(q - contour) <= 1.5 * n * ISOTROPIC_RTOL + 1.5e-13
                    compared += 1
                contour = anisotropic.quantile_distance(
                    center, belief.mean[j], covariance[j], belief.radius[j], belief.epsilon[j]
                )
                assert evaluation.quantile_distance[j] == pytest.approx(contour, rel=1e-9, abs=1e-9)
    assert compared > 20  # q was computed, not only bounded
