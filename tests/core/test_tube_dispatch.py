"""Tests of the tube law's one dispatch (:meth:`stt_drake.core.tube.TubeLaw.evaluate`): the
compiled kernels it looks up once per law, the one-array result it reads the evaluation
from, and the soft-min radius that skips the terms too small to change it.

References: the numpy reference path (:func:`stt_drake.core.backend.pure_numpy`) and
scipy.special.logsumexp for Eq. (14)."""

from __future__ import annotations

import copy
import pickle
from dataclasses import replace

import numpy as np
import pytest
from scipy.special import logsumexp

from stt_drake.bench.workloads import obstacle_field
from stt_drake.core import _tube, backend


def _same(first, second, rtol=0.0):
    """Every field of two evaluations equal (to `rtol`)."""
    for name in ("center_rate", "avoid_probability", "quantile_distance", "theta"):
        np.testing.assert_allclose(getattr(first, name), getattr(second, name), rtol=rtol)
    np.testing.assert_allclose(first.radius, second.radius, rtol=rtol)


@pytest.mark.parametrize("dimension", [2, 3])
def test_the_looked_up_kernel_follows_the_backend_switch(dimension):
    """A law that ran compiled still runs the numpy reference inside pure_numpy(): the
    table of kernels on the law is bypassed when the numpy path is selected."""
    law, center, belief = obstacle_field(12, dimension, worst_case=True)
    compiled = law.evaluate(center, belief)
    with backend.pure_numpy():
        reference = law.evaluate(center, belief)
    assert type(reference.radius) is float and type(compiled.radius) is float
    _same(compiled, reference, rtol=1e-8)
    assert len(law.__dict__["_kernel_calls"]) == 1  # one lookup, kept


def test_a_moved_target_is_not_served_the_old_constants():
    law, center, belief = obstacle_field(10, 2)
    law.evaluate(center, belief)  # fills the law's table
    moved = law.with_target(np.array([-3.0, 4.0]))
    rebuilt = replace(law, target=np.array([-3.0, 4.0]))
    _same(moved.evaluate(center, belief), rebuilt.evaluate(center, belief))
    assert not np.allclose(
        moved.evaluate(center, belief).center_rate, law.evaluate(center, belief).center_rate
    )


def test_pickle_and_copy_leave_the_kernel_table_behind():
    law, center, belief = obstacle_field(10, 3)
    expected = law.evaluate(center, belief)
    for other in (pickle.loads(pickle.dumps(law)), copy.deepcopy(law)):
        assert "_kernel_calls" not in other.__dict__
        _same(other.evaluate(center, belief), expected)


def test_the_evaluation_fields_are_separate_arrays_of_the_right_length():
    law, center, belief = obstacle_field(7, 2)
    evaluation = law.evaluate(center, belief)
    assert evaluation.center_rate.shape == (2,)
    for name in ("avoid_probability", "quantile_distance", "theta"):
        assert getattr(evaluation, name).shape == (7,)
    assert not np.shares_memory(evaluation.avoid_probability, evaluation.theta)


@pytest.mark.parametrize("dimension", [2, 3])
def test_the_per_obstacle_fields_made_on_first_read_are_the_law_s(dimension):
    """q_j, d̂_j and θ_j of a compiled evaluation are made when first read: read in any
    order, after a pickle or a copy, or through dataclasses.replace, they are the numpy
    reference's, and the record stays frozen."""
    law, center, belief = obstacle_field(9, dimension, worst_case=True)
    with backend.pure_numpy():
        reference = law.evaluate(center, belief)
    evaluation = law.evaluate(center, belief)
    assert evaluation.theta is evaluation.theta  # made once, then kept
    for made in (
        evaluation,
        pickle.loads(pickle.dumps(law.evaluate(center, belief))),
        copy.deepcopy(law.evaluate(center, belief)),
        replace(law.evaluate(center, belief), radius=reference.radius),
    ):
        _same(made, reference, rtol=1e-8)
    with pytest.raises(AttributeError):
        evaluation.avoid_probability = reference.avoid_probability


@pytest.mark.parametrize("seed", range(20))
def test_soft_min_radius_matches_logsumexp_with_skipped_terms(seed):
    """Eq. (14) against scipy: arguments from far below to far above r_max (terms skipped
    as invisible), the minimum at r_max or at a d̂_j, +∞ entries (pruned slots)."""
    rng = np.random.default_rng(seed)
    nu, r_max = rng.uniform(5.0, 200.0), rng.uniform(0.2, 2.0)
    d_hat = r_max + rng.uniform(-1.0, 1.0, 30) * rng.choice([0.01, 0.3, 3.0])
    d_hat[rng.integers(0, 30, 3)] = np.inf
    radius = _tube.soft_min_radius(d_hat, r_max, nu)
    values = np.append(d_hat, r_max)
    expected = -logsumexp(-nu * values) / nu
    assert radius == pytest.approx(expected, rel=1e-14, abs=1e-15)
    assert radius <= min(values.min(), r_max)
    assert np.isnan(_tube.soft_min_radius(np.array([1.0, np.nan]), r_max, nu))


@pytest.mark.parametrize("full_covariance", [False, True])
@pytest.mark.parametrize("dimension", [2, 3])
def test_the_port_entry_reads_the_port_as_the_belief_made_from_it(dimension, full_covariance):
    """evaluate_port (a system's hot path: the kernel reads the port vector in place, slot
    by slot) equals evaluate on the belief made from that port, with some slots inactive
    (their means on the centre: they would dominate if read), and the law on the active
    slots' own arrays (σ_j there from an eigen-decomposition, here in closed form: a few
    ulps), compiled and on the numpy path; an inactive slot reads q = 1, d̂ = +∞, θ = 0."""
    from stt_drake.core.belief import GaussianBelief, ObstacleBelief

    law, center, belief = obstacle_field(12, dimension, worst_case=True, seed=3)
    gaussian = belief.gaussian()
    active = np.ones(12, dtype=bool)
    active[[1, 4, 10]] = False
    mean = gaussian.mean.copy()
    mean[~active] = center
    vector = GaussianBelief(mean, gaussian.covariance, active).to_vector()
    port = ObstacleBelief.from_port(vector, dimension, belief.task, full_covariance)
    subset = ObstacleBelief.of(port.slots, belief.task, full_covariance)
    compiled = law.evaluate_port(center, vector, belief.task, full_covariance)
    _same(law.evaluate(center, port), compiled)  # the one port path
    alone = law.evaluate(center, subset)
    np.testing.assert_allclose(compiled.center_rate, alone.center_rate, rtol=1e-12)
    for field in ("avoid_probability", "quantile_distance", "theta"):
        np.testing.assert_allclose(
            getattr(compiled, field)[active], getattr(alone, field), rtol=1e-12
        )
    assert compiled.radius == pytest.approx(alone.radius, rel=1e-14)
    with backend.pure_numpy():
        reference = law.evaluate_port(center, vector, belief.task, full_covariance)
    _same(compiled, reference, rtol=1e-8)
    assert np.all(compiled.avoid_probability[~active] == 1.0)
    assert np.all(compiled.quantile_distance[~active] == np.inf)
    assert np.all(compiled.theta[~active] == 0.0)
    assert np.all(compiled.theta[active] > 0.0)  # the worst field: every active slot acts
