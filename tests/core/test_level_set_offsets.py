"""The compiled level-set distance (stt_drake.core._kernels.level_set_offset): against the
numpy root search of stt_drake.core.probability.level_set_radius (scipy's brentq on the
noncentral chi law) and against scipy.stats.ncx2 at the root (an independent law); the
guide's table takes it, and the numpy path takes the reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import ncx2

from stt_drake.core import _kernels, backend
from stt_drake.core.guide import LevelSetRadii
from stt_drake.core.probability import level_set_radius

SEED = 20261127
LEVELS = (0.05, 0.5, 0.8, 0.95, 0.99, 0.9999)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_it_is_the_numpy_root_and_the_level_holds_there(n):
    """The two roots agree within brentq's stop (xtol 1e-13, rtol 8 ulps; Newton stops far
    below it) twice over, plus what the rounding of the residual near level → 1 (a few ulps
    of 1, 1e-15) moves a root where the tail is flat: 1e-15 over ∂P/∂a = f·I_{n/2}/I_{n/2−1}.
    At the root scipy's ncx2 (cdflib) gives the level back to 1e-9 of the smaller tail."""
    rng = np.random.default_rng(SEED + n)
    thresholds = 10.0 ** rng.uniform(-2.0, 2.0, 60)  # β = r_s/σ over the guide's range
    for level in LEVELS:
        offsets = _kernels.level_set_offsets(thresholds, level, n)
        for threshold, offset in zip(thresholds, offsets, strict=True):
            reference = level_set_radius(level, 1.0, threshold, n)
            if offset == 0.0:  # the mean itself keeps the level: nothing to solve
                assert reference <= 2e-13
                assert ncx2.sf(threshold**2, n, 0.0) >= level - 1e-12
                continue
            _sf, _cdf, density, dlog = _kernels.chi_sf_pdf(threshold, offset, n)
            slope = density * (dlog - (n - 1) / threshold + threshold) / offset  # ∂P/∂a
            assert abs(offset - reference) <= 2e-13 * (1.0 + reference) + 1e-15 / slope
            tail = ncx2.sf(threshold**2, n, offset**2)
            assert abs(tail - level) <= 1e-9 * min(level, 1.0 - level)


def test_edge_levels_follow_the_numpy_function():
    for n in (1, 2, 3):
        for level, threshold in [(0.0, 1.0), (-0.5, 1.0), (0.3, 0.0), (1.5, 2.0)]:
            expected = level_set_radius(level, 1.0, threshold, n)  # 0 or inf
            assert _kernels.level_set_offset(threshold, level, n) == expected
        # Level 1: the tail is 1.0 in double on a whole half-line; any point of it is a root.
        offset = _kernels.level_set_offset(2.0, 1.0, n)
        assert _kernels.chi_sf(2.0, offset, n) == 1.0 > _kernels.chi_sf(2.0, 0.5 * offset, n)
        assert math.isnan(_kernels.level_set_offset(math.nan, 0.9, n))
        assert math.isnan(_kernels.level_set_offset(1.0, math.nan, n))


@pytest.mark.parametrize("n", [2, 3])
def test_the_guide_table_is_the_same_on_both_paths(n):
    sigma = np.array([[0.02, 0.1, 0.37, 1.0, 3.0], [0.05, 0.2, 0.5, 2.0, 0.0]])
    r_s = np.full(5, 0.45)
    levels = np.array([0.8, 0.99, 0.9999, 0.8, 0.99])
    compiled = LevelSetRadii(n)(sigma, r_s, levels)
    with backend.pure_numpy():
        reference = LevelSetRadii(n)(sigma, r_s, levels)
    np.testing.assert_allclose(compiled, reference, rtol=1e-12, atol=1e-13)
