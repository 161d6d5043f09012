"""Φ⁻¹(ε_j) in the task table: :meth:`ObstacleTask.table` carries it as a fourth column,
made once per task, and the compiled tube law and fixed-rate update on a port read it there
instead of computing it for every slot at every evaluation (σ_j and Σ_j beliefs alike)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from stt_drake.bench import anisotropic_field, obstacle_field
from stt_drake.core.belief import ObstacleTask
from stt_drake.core.fixed_rate import BeliefRateBounds, advance, advance_port
from stt_drake.core.tube_terms import evaluation_of


def test_the_table_holds_the_normal_quantile_of_each_epsilon():
    epsilon = np.array([0.05, 0.5, 0.7, 0.925, 0.99, 0.999999])
    p_d = np.full(6, 1.0 - 1e-9)
    table = ObstacleTask(np.full(6, 0.4), epsilon, p_d).table()
    assert table.shape == (6, 4)
    np.testing.assert_array_equal(table[:, :3].T, [np.full(6, 0.4), epsilon, p_d])
    # Φ of the column gives ε back: the normal density is ≤ 0.4, so an error of a few ulps
    # in Φ⁻¹ (|Φ⁻¹| < 5 here) moves Φ by less than 1e-15.
    np.testing.assert_allclose(stats.norm.cdf(table[:, 3]), epsilon, rtol=0, atol=1e-15)


def port_call(law, center, belief, full, table):
    """The compiled port kernel of `law` on `belief`'s port vector with task rows `table`."""
    name = "exact_tube_step_packed" if full else "tube_step_packed"
    kernel, k2, k3, constants, axes = law._kernel_call(name, len(center), belief.count, "pruned")
    return evaluation_of(kernel(center, belief.to_vector(), table, k2, k3, axes, constants), 2)


def field(case: str):
    """(law, centre, belief, full covariance) of the 2D, 50-obstacle bench field `case`."""
    if case == "full covariance":
        return (*anisotropic_field(50, 2), True)
    return (*obstacle_field(50, 2, worst_case=case == "worst"), False)


@pytest.mark.parametrize("case", ["typical", "worst", "full covariance"])
def test_the_port_law_reads_the_tables_quantiles(case):
    """The column is what the kernel uses: without it (NaN, computed per slot) the law is
    the same to rounding; with it shifted, every pruned d̂_j is the bound of the shifted
    quantile (so it was read, not recomputed), and where nothing is pruned (the worst
    field) the quantiles, which only start from it, converge to the same d̂_j."""
    law, center, belief, full = field(case)
    table = belief.task.table()
    given = port_call(law, center, belief, full, table)
    computed_table = table.copy()
    computed_table[:, 3] = np.nan
    computed = port_call(law, center, belief, full, computed_table)
    # ċ, q and θ do not read Φ⁻¹(ε): the same bits.
    np.testing.assert_array_equal(given.center_rate, computed.center_rate)
    np.testing.assert_array_equal(given.avoid_probability, computed.avoid_probability)
    np.testing.assert_array_equal(given.theta, computed.theta)
    # d̂ does: scipy's Φ⁻¹ (the column) and the kernel's (AS 241) agree to a few ulps
    # (|Φ⁻¹| < 3 here: ~1e-15), times σ ≤ 1 m in a bound; a quantile only starts from it
    # and converges to rounding of d̂ (< 30 m: a few 1e-15).
    np.testing.assert_allclose(given.quantile_distance, computed.quantile_distance, atol=2e-14)
    assert abs(given.radius - computed.radius) <= 2e-14

    shift = 0.25
    shifted_table = table.copy()
    shifted_table[:, 3] += shift
    shifted = port_call(law, center, belief, full, shifted_table)
    offset = np.linalg.norm(center - belief.mean, axis=1)
    if full:  # the bound's σ is the projected one, √(uᵀΣu)
        unit = (center - belief.mean) / offset[:, None]
        sigma = np.sqrt(np.einsum("ji,jik,jk->j", unit, belief.covariance, unit))
        prune_above = law.anisotropic_prune_above
    else:
        sigma, prune_above = belief.sigma, law.prune_above
    bound = np.maximum(offset - sigma * (table[:, 3] + shift), 0.0) - belief.radius
    pruned = bound > prune_above
    if case == "worst":  # no slot prunable: the same quantiles from other starts and brackets
        assert not pruned.any()
        np.testing.assert_allclose(shifted.quantile_distance, given.quantile_distance, atol=2e-14)
        return
    assert pruned.sum() >= 30  # the typical fields prune most slots
    # The same arithmetic as the kernel's bound, up to the order of the sum in ‖c − μ_j‖.
    np.testing.assert_allclose(shifted.quantile_distance[pruned], bound[pruned], rtol=1e-14)
    moved = shifted.quantile_distance[pruned] < given.quantile_distance[pruned]
    assert moved.all()


@pytest.mark.parametrize("worst", [False, True], ids=["typical", "worst"])
@pytest.mark.parametrize("n", [2, 3])
def test_the_fixed_rate_update_on_a_port_is_the_update_on_the_arrays(n, worst):
    """The port's update reads Φ⁻¹(ε_j) from the task rows (scipy's), the arrays' update
    computes it (AS 241): the same update to rounding. The sub-steps do not read it; the
    radius bounds differ by σ_j times a few ulps of Φ⁻¹ (< 1e-14 m), or not at all where a
    quantile is computed (it only starts from Φ⁻¹ and converges to rounding)."""
    law, center, belief = obstacle_field(50, n, worst_case=worst, seed=5)
    bounds = BeliefRateBounds(np.full(50, 0.5), np.full(50, 0.02))
    on_port = advance_port(law, center, belief.to_vector(), belief.task, 0.01, bounds)
    on_arrays = advance(law, center, belief, 0.01, bounds)
    np.testing.assert_array_equal(on_port.center, on_arrays.center)
    np.testing.assert_array_equal(on_port.certified, on_arrays.certified)
    np.testing.assert_array_equal(on_port.theta, on_arrays.theta)
    assert on_port.substeps == on_arrays.substeps
    for radius in ("start_radius", "end_radius"):
        assert abs(getattr(on_port, radius) - getattr(on_arrays, radius)) <= 1e-14
