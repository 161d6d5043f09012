"""Tests of stt_drake.core.tube (the tube law of paper Sec. 3, with the design fixes of
docs/design.md).

Expected values come from independent references: scipy.stats.ncx2 for q_j and d̂_j,
scipy.special.logsumexp for the soft-min, hand-written formulas from the paper for ċ,
scipy.integrate.solve_ivp for the attraction flow, and bounds derived in the comments.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.optimize import brentq
from scipy.special import logsumexp
from scipy.stats import ncx2

from stt_drake.core import backend
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.circulation import null_space_direction
from stt_drake.core.constants import BOUNDARY_LAYER
from stt_drake.core.probability import ball_avoid_probability
from stt_drake.core.tube import (
    TubeLaw,
    attraction_flow,
    attraction_reach_time,
    default_nu,
    linear_zone_for_step,
    minimum_nu,
    signed_cube_root_attraction,
)

HYPOTHESIS = settings(max_examples=80, deadline=None)


def _belief(mean, sigma, radius, epsilon, p_d) -> ObstacleBelief:
    mean = np.atleast_2d(np.asarray(mean, dtype=float))
    count = mean.shape[0]

    def column(value):
        return np.broadcast_to(np.asarray(value, dtype=float), (count,)).copy()

    return ObstacleBelief(
        mean=mean,
        sigma=column(sigma),
        radius=column(radius),
        epsilon=column(epsilon),
        p_d=column(p_d),
    )


def _law(target, **overrides) -> TubeLaw:
    parameters = dict(
        k1=0.7, k2=0.4, k3=0.4, r_min=0.21, r_max=0.27, nu=20.0, max_center_speed=np.inf
    )
    parameters.update(overrides)
    return TubeLaw(target=np.asarray(target, dtype=float), **parameters)


def _q_reference(center, belief: ObstacleBelief, r_min: float) -> np.ndarray:
    """q_j = 1 − F_{χ'²_n}(((r_o + r_min)/σ)²; λ) through scipy.stats.ncx2.sf."""
    lam = np.sum((center - belief.mean) ** 2, axis=1) / belief.sigma**2
    return ncx2.sf(((belief.radius + r_min) / belief.sigma) ** 2, belief.dimension, lam)


def _d_hat_reference(center, belief: ObstacleBelief) -> np.ndarray:
    """d̂_j = σ sqrt(F⁻¹(1 − ε; λ)) − r_o through scipy.stats.ncx2.ppf (never pruned)."""
    lam = np.sum((center - belief.mean) ** 2, axis=1) / belief.sigma**2
    quantile = ncx2.ppf(1.0 - belief.epsilon, belief.dimension, lam)
    return belief.sigma * np.sqrt(quantile) - belief.radius


def _signed_cube_root(x):
    x = np.asarray(x, dtype=float)
    return np.sign(x) * np.abs(x) ** (1.0 / 3.0)


# --------------------------------------------------------------------------------------
# Soft-min radius
# --------------------------------------------------------------------------------------
d_hat_lists = st.lists(st.floats(-5.0, 5.0), min_size=0, max_size=30)


@HYPOTHESIS
@given(d_hat=d_hat_lists, r_max=st.floats(0.01, 3.0), nu=st.floats(0.1, 1e4))
def test_radius_is_a_lower_soft_min_within_the_log_sum_exp_bound(d_hat, r_max, nu):
    law = _law(np.zeros(2), r_min=0.5 * r_max, r_max=r_max, nu=nu)  # 0 < r_min < r_max
    values = np.array([*d_hat, r_max])
    smallest = float(np.min(values))
    r = law.radius(np.array(d_hat))
    # r = −(1/ν) ln Σ e^{−ν v}: the sum has a term e^{−ν min} and k + 1 terms ≤ it, so
    # min − ln(k+1)/ν ≤ r ≤ min. The upper bound is exact in floating point (the shifted
    # sum is ≥ 1); the lower one holds up to rounding of a few ulps of |min|.
    assert r <= smallest
    assert r >= smallest - np.log(values.size) / nu - 1e-12 * max(1.0, abs(smallest))
    assert r == pytest.approx(-logsumexp(-nu * values) / nu, rel=1e-12, abs=1e-12)


def test_radius_is_close_to_the_minimum_for_large_nu():
    d_hat = np.array([0.8, 0.35, 1.2, 0.36])
    law = _law(np.zeros(2), r_max=0.5, nu=1e6)
    # Within ln(k+1)/ν = ln 5 · 1e-6 of the minimum.
    assert 0.35 - np.log(5) * 1e-6 <= law.radius(d_hat) <= 0.35


def test_radius_does_not_overflow_for_very_negative_distances():
    # e^{−ν d̂} = e^{1e5} overflows unless the minimum is factored out.
    law = _law(np.zeros(2), r_max=0.3, nu=1e3)
    r = law.radius(np.array([-100.0, -100.0, 5.0]))
    assert np.isfinite(r)
    assert r == pytest.approx(-100.0 - np.log(2.0) / 1e3, rel=1e-14)


def test_radius_with_no_obstacles_is_r_max():
    law = _law(np.zeros(2), r_max=0.27, nu=20.0)
    assert law.radius(np.array([])) == 0.27


def test_soft_min_radius_goes_negative_with_many_obstacles_and_small_nu():
    # The trap docs/design.md names: 50 obstacles all at d̂ = r_min = 0.1 with ν = 20.
    # r = r_min − ln(50 + e^{−ν (r_max − r_min)})/ν = 0.1 − ln(50.018...)/20 < 0.
    r_min, r_max, nu = 0.1, 0.27, 20.0
    law = _law(np.zeros(2), r_min=r_min, r_max=r_max, nu=nu)
    r = law.radius(np.full(50, r_min))
    expected = r_min - np.log(50.0 + np.exp(-nu * (r_max - r_min))) / nu
    assert r == pytest.approx(expected, rel=1e-12)
    assert r < 0.0
    assert nu < minimum_nu(50, r_min)


def test_minimum_nu_and_default_nu_formulas():
    assert minimum_nu(50, 0.1) == pytest.approx(np.log(51.0) / 0.1, rel=1e-15)
    assert default_nu(50, 0.1) == pytest.approx(2.0 * np.log(51.0) / 0.1, rel=1e-15)
    assert minimum_nu(0, 0.2) == 0.0  # ln 1 = 0: with no obstacle r = r_max > 0 for any ν


@HYPOTHESIS
@given(
    count=st.integers(0, 100),
    r_min=st.floats(0.01, 1.0),
    r_max_extra=st.floats(1e-3, 1.0),  # r_max > r_min
    spread=st.lists(st.floats(0.0, 2.0), min_size=100, max_size=100),
)
def test_default_nu_keeps_radius_above_half_r_min(count, r_min, r_max_extra, spread):
    # Whenever every d̂_j ≥ r_min (which q_j > ε_j implies), ν = default_nu gives
    # r ≥ r_min − ln(k+1)/(2 ln(k+1)/r_min) = r_min/2.
    nu = default_nu(count, r_min)
    assume(nu > 0.0)  # count = 0: ln 1 = 0; the radius is then r_max, tested elsewhere
    law = _law(np.zeros(2), r_min=r_min, r_max=r_min + r_max_extra, nu=nu)
    d_hat = r_min + np.array(spread[:count])
    assert law.radius(d_hat) >= 0.5 * r_min - 1e-12


@pytest.mark.parametrize("count", [1, 5, 50, 500])
def test_nu_around_minimum_nu_with_all_obstacles_at_r_min(count):
    r_min = 0.1
    d_hat = np.full(count, r_min)
    # Worst case r_max = r_min: r = r_min − ln(k+1)/ν exactly. The radius reads only r_max,
    # ν and d̂, so the laws take r_max = 0.1 with a smaller r_min of their own (a law needs
    # 0 < r_min < r_max).
    def worst_case(nu: float) -> TubeLaw:
        return _law(np.zeros(2), r_min=0.5 * r_min, r_max=r_min, nu=nu)

    assert worst_case(minimum_nu(count, r_min)).radius(d_hat) == pytest.approx(0.0, abs=1e-15)
    assert worst_case(0.99 * minimum_nu(count, r_min)).radius(d_hat) < 0.0
    assert worst_case(1.01 * minimum_nu(count, r_min)).radius(d_hat) > 0.0
    safe = _law(np.zeros(2), r_min=r_min, r_max=0.3, nu=default_nu(count, r_min))
    assert safe.radius(d_hat) >= 0.5 * r_min


# --------------------------------------------------------------------------------------
# evaluate
# --------------------------------------------------------------------------------------
def test_evaluate_without_active_obstacles_is_pure_attraction():
    law = _law([4.0, -1.0])
    belief = _belief([[30.0, 0.0], [-20.0, 5.0]], 0.2, 0.3, 0.9, 0.99)
    center = np.array([0.5, 1.5])
    evaluation = law.evaluate(center, belief)
    assert np.all(evaluation.avoid_probability > belief.p_d)  # really inactive
    np.testing.assert_array_equal(evaluation.theta, 0.0)
    # One cube root (≤ 1 ulp in a libm, but the compiled kernel's and numpy's may differ by
    # a few ulps between CPUs) and one product, against pow(|e|, 1/3): 1e-14 ≈ 45 ulps.
    np.testing.assert_allclose(
        evaluation.center_rate, 0.7 * _signed_cube_root(law.target - center), rtol=1e-14
    )


def _mixed_belief_2d() -> ObstacleBelief:
    # Obstacle 0: inside the active layer (ε < q ≤ p_d); 1: far (q > p_d, and pruned by
    # the radius law); 2: active, another side; 3: q ≈ 1 with p_d = 1, θ = 0 exactly.
    return _belief(
        mean=[[1.0, 0.3], [9.0, 9.0], [0.1, -0.7], [-40.0, 0.0]],
        sigma=[0.15, 0.1, 0.2, 0.1],
        radius=[0.2, 0.3, 0.1, 0.2],
        epsilon=[0.6, 0.9, 0.7, 0.9],
        p_d=[0.99, 0.99, 0.999, 1.0],
    )


def test_evaluate_probabilities_and_switching_gains():
    law = _law([3.0, 0.0])
    belief = _mixed_belief_2d()
    center = np.array([0.5, 0.0])
    evaluation = law.evaluate(center, belief)
    q = evaluation.avoid_probability
    np.testing.assert_allclose(q, _q_reference(center, belief, law.r_min), rtol=0, atol=1e-12)
    # The configuration really exercises both branches.
    assert np.all(q[[0, 2]] > belief.epsilon[[0, 2]]) and np.all(q[[0, 2]] <= belief.p_d[[0, 2]])
    assert q[1] > belief.p_d[1]
    expected_theta = np.where(q <= belief.p_d, 1.0 / q - 1.0 / belief.p_d, 0.0)
    np.testing.assert_array_equal(evaluation.theta, expected_theta)
    assert evaluation.theta[3] == 0.0


def test_evaluate_center_rate_matches_the_design_formula_2d():
    law = _law([3.0, 0.0], k2=np.array([0.4, 0.5, 0.6, 0.7]), k3=np.array([0.1, 0.2, 0.3, 0.4]))
    belief = _mixed_belief_2d()
    center = np.array([0.5, 0.0])
    q = _q_reference(center, belief, law.r_min)
    theta = np.where(q <= belief.p_d, 1.0 / q - 1.0 / belief.p_d, 0.0)
    expected = 0.7 * _signed_cube_root(law.target - center)
    for j in range(belief.count):
        m = (center - belief.mean[j]) / (q[j] - belief.epsilon[j])
        v = np.array([-m[1], m[0]])  # +90°
        expected = expected + (law.k2[j] * m + law.k3[j] * v) * theta[j]
    # 1/(q − ε) amplifies the 1e-14 error of q by at most 1/0.05 here: 1e-10 relative.
    np.testing.assert_allclose(law.evaluate(center, belief).center_rate, expected, rtol=1e-10)


def test_evaluate_m_points_away_from_the_obstacle_and_v_is_its_rotation_2d():
    belief = _belief([[1.0, 0.3]], 0.15, 0.2, 0.6, 0.99)
    center = np.array([0.5, 0.0])
    target = np.array([3.0, 0.0])
    attraction = 0.7 * _signed_cube_root(target - center)
    q = _q_reference(center, belief, 0.21)[0]
    theta = 1.0 / q - 1.0 / 0.99
    assert theta > 0.0
    away = center - belief.mean[0]
    m_expected = away / (q - 0.6)

    only_m = _law(target, k2=0.4, k3=0.0).evaluate(center, belief).center_rate - attraction
    np.testing.assert_allclose(only_m, 0.4 * theta * m_expected, rtol=1e-10)
    assert np.dot(only_m, away) > 0.0  # away from the obstacle mean
    cross = only_m[0] * away[1] - only_m[1] * away[0]
    assert abs(cross) <= 1e-12 * np.linalg.norm(only_m) * np.linalg.norm(away)

    # k2 > 0 in every law: the v-term is what k3 = 0.4 adds to the same law with k3 = 0.
    both = _law(target, k2=0.4, k3=0.4).evaluate(center, belief).center_rate
    only_v = both - attraction - only_m
    rotated = np.array([-m_expected[1], m_expected[0]])
    np.testing.assert_allclose(only_v, 0.4 * theta * rotated, rtol=1e-10)
    assert abs(np.dot(only_v, away)) <= 1e-12 * np.linalg.norm(only_v) * np.linalg.norm(away)


def test_evaluate_center_rate_3d():
    belief = _belief([[1.0, 0.2, -0.1]], 0.2, 0.25, 0.7, 0.995)
    center = np.array([0.55, 0.0, 0.05])
    target = np.array([2.0, 1.0, 0.5])
    k2, k3 = 0.4, 0.3
    law = _law(target, k2=k2, k3=k3)
    q = _q_reference(center, belief, law.r_min)[0]
    theta = 1.0 / q - 1.0 / 0.995
    assert q > 0.7 and theta > 0.0
    m = (center - belief.mean[0]) / (q - 0.7)
    goal = target - center
    # v: the unit part of the goal direction orthogonal to m, scaled to |m|.
    goal_perp = goal - np.dot(goal, m) / np.dot(m, m) * m
    v = goal_perp / np.linalg.norm(goal_perp) * np.linalg.norm(m)
    expected = 0.7 * _signed_cube_root(goal) + (k2 * m + k3 * v) * theta
    np.testing.assert_allclose(law.evaluate(center, belief).center_rate, expected, rtol=1e-10)


def test_evaluate_radius_and_distances_match_unpruned_references():
    law = _law([3.0, 0.0])
    belief = _mixed_belief_2d()
    center = np.array([0.5, 0.0])
    evaluation = law.evaluate(center, belief)
    exact = _d_hat_reference(center, belief)
    # Unpruned values agree with scipy's ppf to the root-finders' accuracy (1e-9 relative,
    # see test_probability); anything else was pruned.
    pruned = ~np.isclose(
        evaluation.quantile_distance + belief.radius, exact + belief.radius, rtol=1e-9, atol=0
    )
    assert np.any(pruned)  # the test really covers pruning
    # The far obstacles may come back as a lower bound, above r_max + 40/ν ...
    threshold = law.r_max + 40.0 / law.nu
    assert np.all(~pruned | (evaluation.quantile_distance > threshold))
    assert np.all(evaluation.quantile_distance <= exact + 1e-9 * (exact + belief.radius))
    # ... which leaves the radius exact: their weight is below e^{−40} of the r_max term.
    expected_radius = -logsumexp(-law.nu * np.append(exact, law.r_max)) / law.nu
    assert evaluation.radius == pytest.approx(expected_radius, rel=1e-12)
    assert evaluation.radius <= min(law.r_max, np.min(exact))


def test_evaluate_past_the_barrier_recovers_at_the_bounded_speed():
    # A centre with q < ε (a belief jump; the monitor reports it): no floored gap, no jump
    # of the centre, but ċ = v_c along c − μ, the direction in which q grows fastest.
    belief = _belief([[0.3, 0.0]], 0.1, 0.2, 0.9, 0.99)
    center = np.zeros(2)
    law = replace(_law([3.0, 0.0], k3=0.0), max_center_speed=0.8)
    for path in (False, True):
        with backend.pure_numpy(path):
            evaluation = law.evaluate(center, belief)
        assert evaluation.avoid_probability[0] < 0.9
        np.testing.assert_allclose(evaluation.center_rate, [-0.8, 0.0], rtol=1e-14, atol=1e-15)
    # Without a finite v_c a recovery has no speed: the rate is not finite (the Drake
    # system stops the run and names v_c).
    assert not np.all(np.isfinite(_law([3.0, 0.0], k3=0.0).evaluate(center, belief).center_rate))


def _saturated_paper_law_2d(law: TubeLaw, center, belief: ObstacleBelief) -> np.ndarray:
    """Eq. (4) by hand (attraction + Σ θ_j (k2 m_j + k3 v_j), v_j = m_j turned +90°),
    scaled down to v_c: the law without its boundary layer."""
    q = _q_reference(center, belief, law.r_min)
    rate = law.k1 * _signed_cube_root(law.target - center)
    for j in range(belief.count):
        if q[j] <= belief.p_d[j]:
            theta = 1.0 / q[j] - 1.0 / belief.p_d[j]
            m = (center - belief.mean[j]) / (q[j] - belief.epsilon[j])
            rate = rate + theta * (law.k2 * m + law.k3 * np.array([-m[1], m[0]]))
    speed = np.linalg.norm(rate)
    return rate * min(1.0, law.max_center_speed / speed)


def _distance_at_gap(belief: ObstacleBelief, r_min: float, gap: float) -> float:
    """The distance from the (single) mean at which q − ε = `gap` (scipy's ncx2 + brentq)."""
    sigma, n = belief.sigma[0], belief.dimension
    threshold = ((belief.radius[0] + r_min) / sigma) ** 2

    def excess(d):
        return ncx2.sf(threshold, n, (d / sigma) ** 2) - belief.epsilon[0] - gap

    return brentq(excess, 1e-6, 10.0, xtol=1e-15, rtol=1e-15)


def test_boundary_layer_blends_the_law_into_the_escape_and_is_continuous():
    """Above the layer ċ is the paper's saturated law; inside it (gap = δ/2, w = 1/2)
    (1 − w)·law + w·v_c·(c − μ)/‖c − μ‖; at the ε level set the escape alone, reached
    continuously from above. Before the layer the saturated law left the level set 45°
    off the normal (k2 = k3) and switched to the radial recovery below it: a jump of
    ~0.77 v_c that made the integrator chatter."""
    belief = _belief([[1.0, 0.0]], 0.1, 0.2, 0.9, 0.99)
    law = replace(_law([3.0, 0.4], k2=0.4, k3=0.4), max_center_speed=0.8)
    width = BOUNDARY_LAYER * (0.99 - 0.9)
    direction = np.array([-0.6, -0.8])  # from the mean, not along the goal

    def at_gap(gap):
        return belief.mean[0] + _distance_at_gap(belief, law.r_min, gap) * direction

    for compiled in (True, False):
        with backend.pure_numpy(not compiled):
            above = at_gap(1.01 * width)
            np.testing.assert_allclose(
                law.evaluate(above, belief).center_rate,
                _saturated_paper_law_2d(law, above, belief),
                rtol=1e-9,
            )
            inside = at_gap(0.5 * width)
            expected = 0.5 * _saturated_paper_law_2d(law, inside, belief) + 0.5 * 0.8 * direction
            np.testing.assert_allclose(
                law.evaluate(inside, belief).center_rate, expected, rtol=1e-8, atol=1e-12
            )
            # At gap 1e-9 the law keeps a share 1e-9/δ ≈ 1.1e-7 of |law − escape| ≤ 1.6 m/s.
            just_above = law.evaluate(at_gap(1e-9), belief).center_rate
            just_below = law.evaluate(at_gap(-1e-9), belief).center_rate
            np.testing.assert_allclose(just_below, 0.8 * direction, rtol=1e-12, atol=1e-15)
            assert np.linalg.norm(just_above - just_below) < 1e-6
    old_jump = _saturated_paper_law_2d(law, at_gap(1e-9), belief) - 0.8 * direction
    assert np.linalg.norm(old_jump) > 0.5  # what the layer removed


def test_boundary_layer_escapes_a_pinch_between_two_level_sets():
    """Two obstacles 120° apart seen from c, obstacle 0 at its ε level set, obstacle 1
    inside its layer: the escape raises both q (ċ·(c − μ_j) > 0 for both); the old
    recovery (obstacle 0 alone) drove the centre into obstacle 1's level set."""
    first = _belief([[1.0, 0.0]], 0.1, 0.2, 0.9, 0.99)
    law = replace(_law([0.0, 5.0], k2=0.03, k3=0.03), max_center_speed=1.0)
    d0 = _distance_at_gap(first, law.r_min, 0.0)
    d1 = _distance_at_gap(first, law.r_min, 0.3 * BOUNDARY_LAYER * (0.99 - 0.9))
    u0 = np.array([1.0, 0.0])
    u1 = np.array([np.cos(2 * np.pi / 3), np.sin(2 * np.pi / 3)])
    center = np.zeros(2)
    belief = _belief([center - d0 * u0, center - d1 * u1], 0.1, 0.2, 0.9, 0.99)
    q = _q_reference(center, belief, law.r_min)
    assert abs(q[0] - 0.9) < 1e-12 and 0.9 < q[1] < 0.9 + BOUNDARY_LAYER * 0.09
    for compiled in (True, False):
        with backend.pure_numpy(not compiled):
            rate = law.evaluate(center, belief).center_rate
        assert rate @ u0 > 0.0 and rate @ u1 > 0.0
        # w_0 = 1 up to q's 1e-12 error over δ = 0.009, so the law's share is ≤ 2e-10.
        assert np.linalg.norm(rate) == pytest.approx(1.0, rel=1e-9)
    assert u0 @ u1 < 0.0  # the recovery along u0 alone lowered q_1


def test_center_speed_is_saturated_at_max_center_speed():
    belief = _belief([[1.6, 0.05]], 0.1, 0.2, 0.9, 0.9999)
    law = replace(_law([3.0, 0.0]), max_center_speed=0.3)
    for x in np.linspace(0.0, 0.9, 10):
        center = np.array([x, 0.0])
        free = _law([3.0, 0.0]).evaluate(center, belief)
        assert free.avoid_probability[0] > 0.9  # no recovery: the law's own ċ
        for path in (False, True):
            with backend.pure_numpy(path):
                capped = law.evaluate(center, belief)
            speed = np.linalg.norm(free.center_rate)
            expected = free.center_rate * min(1.0, 0.3 / speed)
            np.testing.assert_allclose(capped.center_rate, expected, rtol=1e-12, atol=1e-15)


# --------------------------------------------------------------------------------------
# null_space_direction
# --------------------------------------------------------------------------------------
def test_null_space_direction_2d_is_rotation_by_plus_90_degrees():
    m = np.array([[1.0, 0.0], [0.0, 2.0], [-3.0, 4.0]])
    v = null_space_direction(m, np.array([5.0, 5.0]))
    np.testing.assert_array_equal(v, [[0.0, 1.0], [-2.0, 0.0], [-4.0, -3.0]])


def test_null_space_direction_1d_is_zero():
    np.testing.assert_array_equal(null_space_direction(np.array([[2.0], [-1.0]]), np.ones(1)), 0)


# Components below 1e-100 are flushed to 0: their squares are subnormal, where even the
# norm loses digits (a goal direction of 1e-157 m has no physical meaning).
vectors3 = st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3).map(
    lambda v: np.where(np.abs(v) < 1e-100, 0.0, v)
)


@HYPOTHESIS
@given(m=vectors3, goal=vectors3)
def test_null_space_direction_3d_is_orthogonal_with_equal_norm(m, goal):
    norm_m = np.linalg.norm(m)
    assume(norm_m > 1e-3)
    v = null_space_direction(m[None], goal)[0]
    # The orthogonal part is formed by cancellation; with the code's parallelism cut at
    # 1e-6 its relative accuracy is ≥ 2.2e-16/1e-6 ≈ 2e-10, so 1e-9 relative.
    assert abs(np.dot(v, m)) <= 1e-9 * norm_m**2
    assert np.linalg.norm(v) == pytest.approx(norm_m, rel=1e-12)
    # When the goal direction is well away from m, v lies in their plane, on the goal's side.
    # (A goal whose squared norm underflows counts as no goal direction at all.)
    norm_goal = np.linalg.norm(goal)
    sine = np.linalg.norm(np.cross(goal / max(norm_goal, 1e-300), m / norm_m))
    if norm_goal > 1e-150 and sine > 1e-3:
        assert abs(np.dot(np.cross(m, goal), v)) <= 1e-9 * norm_m**2 * np.linalg.norm(goal)
        assert np.dot(v, goal) > 0.0


@pytest.mark.parametrize(
    "m, goal",
    [
        ([1.0, 2.0, 2.0], [2.0, 4.0, 4.0]),  # goal ∥ m: falls back to e_z
        ([1.0, 2.0, 2.0], [-0.5, -1.0, -1.0]),  # goal anti-parallel to m
        ([1.0, 2.0, 2.0], [0.0, 0.0, 0.0]),  # c = η: no goal direction at all
        ([0.0, 0.0, 3.0], [0.0, 0.0, 1.0]),  # goal ∥ m ∥ e_z: falls back to e_x
    ],
)
def test_null_space_direction_3d_fallback_axis(m, goal):
    m, goal = np.array(m), np.array(goal)
    v = null_space_direction(m[None], goal)[0]
    assert abs(np.dot(v, m)) <= 1e-12 * np.dot(m, m)
    assert np.linalg.norm(v) == pytest.approx(np.linalg.norm(m), rel=1e-12)
    axis = np.array([0.0, 0.0, 1.0]) if m[2] != np.linalg.norm(m) else np.array([1.0, 0.0, 0.0])
    # v is the fallback axis' part orthogonal to m, so it lies in span(m, axis), on its side.
    assert abs(np.dot(np.cross(m, axis), v)) <= 1e-12 * np.dot(m, m)
    assert np.dot(v, axis) > 0.0


def test_null_space_direction_3d_vectorised_rows_are_independent():
    rng = np.random.default_rng(5)
    m = rng.normal(size=(6, 3))
    goal = rng.normal(size=3)
    batched = null_space_direction(m, goal)
    for j in range(6):
        np.testing.assert_array_equal(batched[j], null_space_direction(m[j : j + 1], goal)[0])


@pytest.mark.parametrize("goal", [[1.0, 0.0, 0.0], [0.3, -1.0, 0.2]])
def test_null_space_direction_3d_varies_continuously_along_a_path(goal):
    # m sweeps a full circle (with a varying length) that never becomes parallel to the goal.
    goal = np.array(goal)
    angles = np.linspace(0.0, 2.0 * np.pi, 4001)
    tilt = np.cross(goal, [0.0, 0.0, 1.0])
    tilt /= np.linalg.norm(tilt)
    other = np.cross(goal / np.linalg.norm(goal), tilt)
    unit_path = (
        0.5 * goal / np.linalg.norm(goal)
        + np.cos(angles)[:, None] * tilt
        + np.sin(angles)[:, None] * other
    )
    unit_path /= np.linalg.norm(unit_path, axis=1, keepdims=True)
    lengths = 1.0 + 0.5 * np.sin(3.0 * angles)
    m = unit_path * lengths[:, None]
    v = null_space_direction(m, goal)
    unit_v = v / lengths[:, None]
    # d(v/|v|) = P⊥ dw/|w| with w = g − (g·u)u, |dw| ≤ 2|g||du|, and here
    # |w| = |g| sin∠(g, u) = |g|/sqrt(1.25): |Δ(v/|v|)| ≤ 2·sqrt(1.25)|Δu| to first order.
    # A flip would be a jump of ~2, far above these steps of ~1.6e-3.
    step_u = np.linalg.norm(np.diff(unit_path, axis=0), axis=1)
    step_v = np.linalg.norm(np.diff(unit_v, axis=0), axis=1)
    assert np.all(step_v <= 2.0 * np.sqrt(1.25) * step_u * 1.01)
    assert np.max(step_v) < 1e-2


# --------------------------------------------------------------------------------------
# Attraction flow and reach time
# --------------------------------------------------------------------------------------
def _paper_closed_form(center_1, target, k1, elapsed):
    """Eq. (13) per component with the signed powers of docs/design.md:
    c(t) = η − sign(η − c₁)·max(|η − c₁|^{2/3} − (2/3)k1 (t − t₁), 0)^{3/2}."""
    error = target - center_1
    inner = np.abs(error) ** (2.0 / 3.0) - (2.0 / 3.0) * k1 * elapsed
    return target - np.sign(error) * np.maximum(inner, 0.0) ** 1.5


def test_attraction_flow_matches_the_paper_closed_form():
    target = np.array([4.0, -1.0, 0.25])
    center = np.array([0.0, 2.0, 0.25])
    for elapsed in [0.0, 0.1, 1.0, 2.5, 4.0, 10.0]:
        np.testing.assert_allclose(
            center + attraction_flow(target - center, 0.7, elapsed),
            _paper_closed_form(center, target, 0.7, elapsed),
            rtol=1e-14,
            atol=1e-14,
        )


def test_attraction_flow_matches_numerical_integration():
    # The ODE ċ = k1 cbrt(η − c) integrated by RK45 at tight tolerance, stopped before the
    # first component arrives (the field is not Lipschitz at η).
    k1 = 0.7
    error = np.array([4.0, -2.0, 1.0])
    horizon = 0.9 * 3.0 * 1.0 / (2.0 * k1)  # 90% of the smallest component's reach time
    solution = solve_ivp(
        lambda _t, e: -k1 * _signed_cube_root(e),
        (0.0, horizon),
        error,
        rtol=1e-11,
        atol=1e-12,
        dense_output=True,
    )
    for t in np.linspace(0.0, horizon, 7):
        remaining = error - attraction_flow(error, k1, t)
        np.testing.assert_allclose(remaining, solution.sol(t), rtol=1e-8, atol=1e-9)


@HYPOTHESIS
@given(
    error=st.lists(st.floats(-100.0, 100.0), min_size=1, max_size=4).map(np.array),
    k1=st.floats(0.01, 10.0),
    duration=st.floats(0.0, 1e3),
)
def test_attraction_flow_never_overshoots(error, k1, duration):
    change = attraction_flow(error, k1, duration)
    # What is left, η − c(t) = error − change, keeps the sign of the initial error or is
    # exactly 0: the centre never crosses η. Its size never grows beyond rounding:
    # (|e|^{2/3})^{3/2} is |e|^{1+δ} with δ ~ eps (2/3 is not a double), a relative error
    # ~ eps·|ln|e||, so at duration 0 the change can be a rounding-size step backwards
    # (−7e-18 for e = 1/64), not an overshoot.
    left = error - change
    assert np.all(left * error >= 0.0)
    rounding = 4.0 * np.finfo(float).eps * (2.0 + np.abs(np.log(np.abs(error) + 1e-300)))
    assert np.all(np.abs(left) <= np.abs(error) * (1.0 + rounding))


@HYPOTHESIS
@given(
    error=st.lists(st.floats(-100.0, 100.0), min_size=1, max_size=4).map(np.array),
    k1=st.floats(0.01, 10.0),
)
def test_attraction_flow_reaches_the_target_at_reach_time(error, k1):
    assume(np.max(np.abs(error)) > 1e-6)
    t_c = attraction_reach_time(error, k1)
    assert t_c == pytest.approx(np.max(3.0 * np.abs(error) ** (2.0 / 3.0) / (2.0 * k1)))
    np.testing.assert_allclose(attraction_flow(error, k1, t_c), error, rtol=1e-12, atol=0)
    # ... and not before: the slowest component still has a gap at 0.99 t_c.
    slowest = np.argmax(np.abs(error))
    early = attraction_flow(error, k1, 0.99 * t_c)
    assert abs(early[slowest]) < abs(error[slowest])


def test_attraction_flow_composes_like_a_flow():
    k1 = 0.7
    target = np.array([4.0, -1.0])
    start = np.array([0.0, 1.5])
    for total in [0.5, 3.0, 20.0]:
        one_step = start + attraction_flow(target - start, k1, total)
        center = start.copy()
        for _ in range(1000):
            center = center + attraction_flow(target - center, k1, total / 1000)
        np.testing.assert_allclose(center, one_step, rtol=0, atol=1e-12)


def test_attraction_flow_has_the_field_as_its_derivative():
    k1 = 0.7
    error = np.array([4.0, -2.0, 0.5])
    for t in [0.0, 0.5, 1.5]:
        h = 1e-6
        rate = (attraction_flow(error, k1, t + h) - attraction_flow(error, k1, t - h)) / (2 * h)
        remaining = error - attraction_flow(error, k1, t)
        if t == 0.0:
            rate = (attraction_flow(error, k1, h) - attraction_flow(error, k1, 0.0)) / h
            np.testing.assert_allclose(rate, k1 * _signed_cube_root(remaining), rtol=1e-5)
        else:
            np.testing.assert_allclose(rate, k1 * _signed_cube_root(remaining), rtol=1e-7)


def test_signed_cube_root_attraction_and_its_linear_zone():
    k1 = 0.7
    error = np.array([-8.0, -1e-3, 0.0, 2e-4, 1.0, 27.0])
    # np.cbrt against pow(|e|, 1/3): two transcendental calls, each a few ulps in the libm
    # or SIMD routine the CPU selects (numpy's AVX-512 ones are not correctly rounded), the
    # 1/3 rounding's eps·|ln e|/3 ≤ 1.2 ulps for |e| ≤ 27, and two products: 1e-14 ≈ 45 ulps
    # (bitwise agreement would depend on the CPU; a wrong power would be off by > 1e-3).
    np.testing.assert_allclose(
        signed_cube_root_attraction(error, k1), k1 * _signed_cube_root(error), rtol=1e-14
    )
    delta = 1e-3
    zoned = signed_cube_root_attraction(error, k1, linear_zone=delta)
    inside = np.abs(error) < delta
    np.testing.assert_allclose(zoned[inside], k1 * error[inside] * delta ** (-2.0 / 3.0))
    np.testing.assert_allclose(zoned[~inside], k1 * _signed_cube_root(error[~inside]))
    # Continuous at |e| = δ: both pieces give k1·δ^{1/3} there.
    edge = signed_cube_root_attraction(np.array([delta * (1 - 1e-12), delta]), k1, delta)
    np.testing.assert_allclose(edge, k1 * delta ** (1.0 / 3.0), rtol=1e-11)
    # δ = (k1 h)^{3/2} makes the linear settle's time constant δ^{2/3}/k1 equal to h.
    h = 0.01
    assert linear_zone_for_step(k1, h) ** (2.0 / 3.0) / k1 == pytest.approx(h, rel=1e-14)


# --------------------------------------------------------------------------------------
# Fixed-rate update: the thin barrier layer
# --------------------------------------------------------------------------------------
THIN_LAYER = dict(mean=[[2.0, 0.02]], sigma=np.sqrt(0.001), radius=0.15, epsilon=0.99, p_d=0.9999)
PERIOD = 0.01
PERIODS = 1500  # 15 s at 100 Hz


def _thin_layer_problem():
    belief = _belief(**THIN_LAYER)
    law = _law([4.0, 0.0], k1=0.7, k2=0.4, k3=0.4, r_min=0.21, r_max=0.27, nu=20.0)
    return law, belief


def test_advance_keeps_q_above_epsilon_through_the_thin_barrier_layer():
    law, belief = _thin_layer_problem()
    center = np.zeros(2)
    margins, radii, tube_margins, active = [], [], [], 0
    for _ in range(PERIODS):
        update = law.advance(center, belief, PERIOD)
        assert update.substeps >= 1
        assert np.all(update.certified)
        center = update.center
        evaluation = law.evaluate(center, belief)
        q = _q_reference(center, belief, law.r_min)[0]
        margins.append(q - belief.epsilon[0])
        radii.append(evaluation.radius)
        active += evaluation.theta[0] > 0.0
        # Theorem 3.2 (ii): the whole tube misses the obstacle with probability ≥ ε (r ≤ d̂; the
        # 1e-10 is the quantile's root-finding accuracy).
        tube_margins.append(
            ball_avoid_probability(
                center, evaluation.radius, belief.mean, belief.sigma, belief.radius
            )[0]
            - belief.epsilon[0]
        )
    assert active > 0  # the avoidance really acted
    assert min(margins) > 0.0
    assert min(radii) > 0.0
    assert min(tube_margins) >= -1e-10
    np.testing.assert_allclose(center, law.target, rtol=0, atol=1e-9)


def test_naive_fixed_step_euler_crosses_the_barrier():
    # The trap the sub-stepping fixes: explicit Euler with the same 10 ms period.
    law, belief = _thin_layer_problem()
    center = np.zeros(2)
    crossed = False
    for _ in range(PERIODS):
        evaluation = law.evaluate(center, belief)
        if evaluation.avoid_probability[0] <= belief.epsilon[0]:
            crossed = True
            break
        center = center + PERIOD * evaluation.center_rate
    assert crossed
    q = _q_reference(center, belief, law.r_min)[0]
    assert q <= belief.epsilon[0]


def test_advance_without_active_obstacles_is_the_exact_attraction_flow():
    law = _law([4.0, -1.0])
    belief = _belief([[30.0, 30.0]], 0.1, 0.2, 0.9, 0.99)
    center = np.array([0.0, 0.5])
    for duration in [0.01, 1.0, 50.0]:
        for path in (False, True):
            with backend.pure_numpy(path):
                update = law.advance(center, belief, duration)
            # A handful of roundings (a power, a subtraction, a power) on values of order
            # one: agreement to 1e-12, not bitwise (the compiled kernel's libm may differ).
            np.testing.assert_allclose(
                update.center,
                center + attraction_flow(law.target - center, law.k1, duration),
                rtol=1e-12,
                atol=1e-12,
            )
            assert update.substeps == 1
    # A period covered in exactly max_attempts attempts is complete.
    assert law.advance(center, belief, 0.01, max_attempts=1).substeps == 1


def test_advance_zero_duration_does_nothing():
    law, belief = _thin_layer_problem()
    update = law.advance(np.array([0.3, 0.1]), belief, 0.0)
    np.testing.assert_array_equal(update.center, [0.3, 0.1])
    assert update.substeps == 0


def test_advance_with_too_few_attempts_holds_part_way_and_stays_certified():
    law, belief = _thin_layer_problem()
    center = np.zeros(2)
    for _ in range(PERIODS):
        update = law.advance(center, belief, PERIOD)
        if update.substeps > 1:  # this period needed sub-steps
            break
        center = update.center
    else:
        pytest.fail("no period needed sub-steps")
    for path in (False, True):
        with backend.pure_numpy(path):
            short = law.advance(center, belief, PERIOD, max_attempts=1)
        # Fewer attempts than the period needs: the centre moves less, never unsafely.
        assert np.all(short.certified)
        assert np.linalg.norm(short.center - center) < np.linalg.norm(update.center - center)
        assert _q_reference(short.center, belief, law.r_min)[0] > belief.epsilon[0]
