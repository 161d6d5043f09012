"""The real-time (fixed-rate) tube's guarantee, bounded centre speed, recovery and the 3D
circulation axes (stt_drake.core.tube, "Discrete-time guarantee").

References are independent of the code under test: scipy.stats.ncx2 for every avoidance
probability of a *true* belief, Monte Carlo sampling of obstacle centres, and the closed
forms written in the comments.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import ncx2

from stt_drake.core import backend
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.circulation import carry_circulation, null_space_direction
from stt_drake.core.fixed_rate import BeliefRateBounds
from stt_drake.core.probability import period_avoid_probability, segment_avoid_lower_bound
from stt_drake.core.tube import TubeLaw

RNG_SEED = 20261122


def q_true(point, mean, sigma, radius) -> float:
    """P(‖point − O‖ ≥ radius), O ~ N(mean, σ² I), through scipy's noncentral χ²."""
    point, mean = np.asarray(point, float), np.asarray(mean, float)
    lam = float(np.sum((point - mean) ** 2)) / sigma**2
    return float(ncx2.sf((radius / sigma) ** 2, len(point), lam))


def belief(mean, sigma, radius=0.2, epsilon=0.9, p_d=0.9999) -> ObstacleBelief:
    mean = np.atleast_2d(np.asarray(mean, dtype=float))
    count = len(mean)

    def column(value):
        return np.broadcast_to(np.asarray(value, dtype=float), (count,)).copy()

    return ObstacleBelief(mean, column(sigma), column(radius), column(epsilon), column(p_d))


def law(target, **overrides) -> TubeLaw:
    parameters = dict(
        k1=0.7, k2=0.4, k3=0.4, r_min=0.1, r_max=0.27, nu=40.0, max_center_speed=np.inf
    )
    parameters.update(overrides)
    return TubeLaw(target=np.asarray(target, dtype=float), **parameters)


# --------------------------------------------------------------------------------------
# The period lower bound of q
# --------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("n", [2, 3])
def test_period_bound_is_below_q_of_every_reachable_belief(n):
    """Q(x) ≤ q(x; μ', σ') for every μ' within Δ of μ and σ' in [σ − s̄τ, σ + s̄τ]: sampled
    beliefs, including the worst mean (shifted by Δ straight at x) and both σ extremes."""
    rng = np.random.default_rng(RNG_SEED + n)
    checked = 0
    for _ in range(300):
        mean = rng.uniform(-1, 1, n)
        point = mean + rng.normal(size=n) * rng.uniform(0.1, 2.0)
        sigma = rng.uniform(0.03, 1.0)
        radius = rng.uniform(0.05, 0.6)
        speed, sigma_rate, horizon = rng.uniform(0, 2), rng.uniform(0, 0.3), rng.uniform(0, 0.2)
        bounds = BeliefRateBounds(np.array([speed]), np.array([sigma_rate]))
        reach, spread = bounds.inflation(np.array([sigma]), horizon)
        if not np.isfinite(spread[0]):
            continue
        bound = period_avoid_probability(
            point, mean[None], np.array([sigma]), np.array([radius]), reach, spread
        )[0]
        toward = point - mean
        toward = toward / np.linalg.norm(toward)
        low, high = sigma - sigma_rate * horizon, sigma + sigma_rate * horizon
        means = [mean + reach[0] * toward, mean] + [
            mean + reach[0] * rng.uniform() ** (1 / n) * unit
            for unit in rng.normal(size=(8, n)) / 1.0
            if np.linalg.norm(unit) > 0
        ]
        for other_mean in means:
            shift = other_mean - mean
            if np.linalg.norm(shift) > reach[0]:  # keep the sample inside the reach ball
                other_mean = mean + shift / np.linalg.norm(shift) * reach[0]
            for other_sigma in (low, sigma, high, rng.uniform(low, high)):
                # 1e-12: the two sides are computed by different noncentral-χ² codes.
                assert bound <= q_true(point, other_mean, other_sigma, radius) + 1e-12
                checked += 1
    assert checked > 5000


def test_period_bound_is_exact_for_a_translating_belief():
    """With σ constant (γ = 0) the bound is attained: the mean shifted by Δ towards x."""
    mean, point, sigma, radius, reach = np.zeros(2), np.array([0.9, 0.4]), 0.2, 0.3, 0.25
    bound = period_avoid_probability(
        point, mean[None], np.array([sigma]), np.array([radius]), np.array([reach]), np.zeros(1)
    )[0]
    worst = mean + reach * point / np.linalg.norm(point)
    assert bound == pytest.approx(q_true(point, worst, sigma, radius), rel=1e-12, abs=1e-15)


def test_period_bound_monte_carlo():
    """10⁶ sampled obstacle centres of a belief at the edge of the bounds (mean moved,
    σ shrunk) collide less often than the bound allows (3 standard errors)."""
    rng = np.random.default_rng(RNG_SEED)
    point, mean, sigma, radius = np.array([0.7, 0.2, 0.1]), np.zeros(3), 0.25, 0.3
    bounds = BeliefRateBounds(np.array([0.5]), np.array([0.4]))
    reach, spread = bounds.inflation(np.array([sigma]), 0.1)
    bound = period_avoid_probability(
        point, mean[None], np.array([sigma]), np.array([radius]), reach, spread
    )[0]
    moved = mean + np.array([0.05, 0.0, 0.0])  # 0.05 = Δ, along x
    shrunk = sigma - 0.04  # σ − s̄τ
    samples = moved + shrunk * rng.standard_normal((1_000_000, 3))
    avoided = np.mean(np.linalg.norm(samples - point, axis=1) >= radius)
    standard_error = np.sqrt(avoided * (1 - avoided) / len(samples))
    assert avoided >= bound - 3 * standard_error
    assert bound < avoided  # a lower bound, not an identity, here (σ changes)


def test_inflation_closed_form_and_infinite_spread():
    bounds = BeliefRateBounds(np.array([0.5, 1.0, 0.0]), np.array([0.1, 0.0, 1.0]))
    reach, spread = bounds.inflation(np.array([0.2, 0.3, 0.05]), 0.1)
    # Δ = v̄τ: one product each, so rtol 1e-15 (≈ 4.5 ulp) is a few roundings, not bitwise.
    np.testing.assert_allclose(reach, [0.05, 0.1, 0.0], rtol=1e-15)
    # γ = σ/(σ − s̄τ) − 1: 0.2/0.19 − 1; 0; and σ − s̄τ < 0 → σ could reach 0: infinite.
    np.testing.assert_allclose(spread[:2], [0.2 / 0.19 - 1.0, 0.0], rtol=1e-14)
    assert spread[2] == np.inf


def test_translation_bounds_compose():
    """Q^h from any mean reachable after one period ≥ Q^{2h} from the first mean: what makes
    every period's start certified when the previous update kept Q^{2h} > ε."""
    rng = np.random.default_rng(RNG_SEED + 7)
    sigma, radius, speed, h = np.array([0.15]), np.array([0.35]), np.array([0.8]), 0.05
    bounds = BeliefRateBounds(speed, np.zeros(1))
    for _ in range(500):
        mean = rng.uniform(-1, 1, 2)
        point = rng.uniform(-2, 2, 2)
        step = rng.normal(size=2)
        later = mean + step / np.linalg.norm(step) * speed[0] * h * rng.uniform()
        two = period_avoid_probability(
            point, mean[None], sigma, radius, *bounds.inflation(sigma, 2 * h)
        )[0]
        one = period_avoid_probability(
            point, later[None], sigma, radius, *bounds.inflation(sigma, h)
        )[0]
        assert one >= two - 1e-14


def test_segment_bound_is_below_the_bound_at_every_point_of_the_segment():
    rng = np.random.default_rng(RNG_SEED + 3)
    for _ in range(200):
        means = rng.uniform(-1, 1, (3, 2))
        sigma, radius = rng.uniform(0.05, 0.5, 3), rng.uniform(0.1, 0.4, 3)
        reach, spread = rng.uniform(0, 0.1, 3), rng.uniform(0, 0.2, 3)
        start, end = rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2)
        lower = segment_avoid_lower_bound(start, end, means, sigma, radius, reach, spread)
        for s in np.linspace(0, 1, 101):
            point = start + s * (end - start)
            pointwise = period_avoid_probability(point, means, sigma, radius, reach, spread)
            assert np.all(lower <= pointwise + 1e-14)


# --------------------------------------------------------------------------------------
# The fixed-rate update against a moving belief
# --------------------------------------------------------------------------------------
def crossing_obstacle(t: float) -> np.ndarray:
    """A mean crossing the straight path (0,0) → (4,0) at 1.2 m/s, heading at the centre."""
    return np.array([2.6, 1.6]) + t * np.array([-0.6, -1.04])


@pytest.mark.slow
@pytest.mark.parametrize("rate_hz", [10.0, 20.0, 50.0, 100.0])
@pytest.mark.parametrize("compiled", [True, False])
def test_fixed_rate_update_keeps_q_above_epsilon_between_updates(rate_hz, compiled):
    """The old update held the belief frozen over the period and let an approaching obstacle
    drive q below ε between updates. Now q(c(t), t) > ε at every instant (checked on a
    dense grid with scipy, c(t) the interpolated output), |ċ| ≤ v_c, and the interpolated
    radius r(t) is continuous across updates, positive and never above the exact d̂ at
    (c(t), belief(t)) (scipy's ncx2 quantile), so the whole ball keeps P ≥ ε."""
    h = 1.0 / rate_hz
    speed = float(np.linalg.norm([0.6, 1.04]))
    tube = law([4.0, 0.0], max_center_speed=2.5)
    bounds = BeliefRateBounds(np.array([speed]), np.zeros(1))
    sigma, radius, epsilon = 0.08, 0.25, 0.95
    center, worst, worst_radius, acted = np.zeros(2), np.inf, np.inf, 0
    tube_radius = np.nan
    with backend.pure_numpy(not compiled):
        for k in range(int(10.0 / h)):
            t_k = k * h
            now = belief(crossing_obstacle(t_k), sigma, radius, epsilon)
            update = tube.advance(center, now, h, bounds, radius=tube_radius)
            assert update.certified.all()
            assert np.linalg.norm(update.center - center) <= 2.5 * h * (1 + 1e-12)
            if k > 0:
                assert update.start_radius == tube_radius  # no jump of r at the update
            acted += tube.evaluate(center, now).theta[0] > 0
            for s in np.linspace(0.0, 1.0, 11):
                c = center + s * (update.center - center)
                mean = crossing_obstacle(t_k + s * h)
                q = q_true(c, mean, sigma, radius + tube.r_min)
                worst = min(worst, q - epsilon)
                r = update.start_radius + s * (update.end_radius - update.start_radius)
                lam = float(np.sum((c - mean) ** 2)) / sigma**2
                d_hat = sigma * np.sqrt(ncx2.ppf(1.0 - epsilon, 2, lam)) - radius
                worst_radius = min(worst_radius, d_hat - r)
                assert r > 0.0
            center, tube_radius = update.center, update.end_radius
    assert acted > 0  # the obstacle really came close
    assert worst > 0.0
    assert worst_radius >= -1e-9  # r ≤ d̂ up to scipy's quantile accuracy
    assert np.linalg.norm(center - tube.target) < 0.05  # and the tube still got there


def test_end_radius_bound_keeps_the_linear_radius_under_the_lipschitz_envelope():
    """For random r_k ≤ D0, D ≤ D0 and ℓ: the linear radius from r_k to the bound stays
    under max(D0 − sℓ, D) on a dense grid of s, and 1 mm more crosses it somewhere (the
    bound is the largest such end radius)."""
    from stt_drake.core.fixed_rate import end_radius_bound

    rng = np.random.default_rng(RNG_SEED)
    s = np.linspace(0.0, 1.0, 2001)
    for _ in range(500):
        at_start = rng.uniform(0.1, 1.0)
        on_segment = rng.uniform(-0.2, at_start)
        start_radius = rng.uniform(0.01, at_start)
        length = rng.uniform(0.0, 1.0)
        end = float(
            end_radius_bound(start_radius, np.array([at_start]), np.array([on_segment]), length)[0]
        )
        envelope = np.maximum(at_start - s * length, on_segment)
        radius = start_radius + s * (end - start_radius)
        assert np.all(radius <= envelope + 1e-12)
        larger = start_radius + s * (end + 1e-3 - start_radius)
        assert np.any(larger > envelope)


def test_frozen_belief_update_is_unsafe_with_the_same_obstacle():
    """The trap this fixes: the same update with the belief declared still (no rate
    bounds) lets q fall below ε between 10 Hz updates."""
    h, sigma, radius, epsilon = 0.1, 0.08, 0.25, 0.95
    tube = law([4.0, 0.0], max_center_speed=2.5)
    center, worst = np.zeros(2), np.inf
    for k in range(60):
        now = belief(crossing_obstacle(k * h), sigma, radius, epsilon)
        update = tube.advance(center, now, h, BeliefRateBounds.still(1))
        for s in np.linspace(0.0, 1.0, 11):
            c = center + s * (update.center - center)
            q = q_true(c, crossing_obstacle((k + s) * h), sigma, radius + tube.r_min)
            worst = min(worst, q - epsilon)
        center = update.center
    assert worst < 0.0


def test_update_recovers_from_a_belief_jump_at_the_bounded_speed():
    """A belief that jumps onto the centre: the period is not certified, the centre moves
    exactly v_c·h away along c − μ (no jump, no floored gap) and the certificate comes back
    once q > ε again."""
    h, v_c = 0.02, 1.0
    tube = law([4.0, 0.0], max_center_speed=v_c)
    jumped = belief([[1.0, -0.05]], 0.1, 0.2, 0.9)
    center = np.array([1.0, 0.0])
    history = []
    for compiled in (True, False):
        with backend.pure_numpy(not compiled):
            update = tube.advance(center, jumped, h, BeliefRateBounds.still(1))
        assert not update.certified[0]
        np.testing.assert_allclose(
            update.center, center + np.array([0.0, v_c * h]), rtol=0, atol=1e-12
        )
    for _ in range(100):
        update = tube.advance(center, jumped, h, BeliefRateBounds.still(1))
        assert np.linalg.norm(update.center - center) <= v_c * h * (1 + 1e-12)
        history.append(bool(update.certified[0]))
        center = update.center
    first = history.index(True)
    assert first > 0 and all(history[first:])  # recovered, and stays certified
    assert q_true(center, [1.0, -0.05], 0.1, 0.3) > 0.9


def random_updates(rng: np.random.Generator, tube: TubeLaw, n: int, count: int):
    """`count` random (belief of 4 obstacles, rate bounds, centre, 3D circulation axes)."""
    for _ in range(count):
        now = belief(rng.uniform(0, 4, (4, n)), rng.uniform(0.03, 0.4, 4), 0.2, 0.9)
        bounds = BeliefRateBounds(rng.uniform(0, 1, 4), rng.uniform(0, 0.1, 4))
        center = rng.uniform(0, 4, n)
        axes = None
        if n == 3:
            axes = carry_circulation(
                np.zeros((4, 3)), center, now.mean, np.ones(4, bool), tube.target - center
            )
        yield now, bounds, center, axes


@pytest.mark.parametrize("n", [2, 3])
def test_compiled_and_numpy_updates_agree(n):
    rng = np.random.default_rng(RNG_SEED + 11 * n)
    tube = law(np.full(n, 4.0), max_center_speed=1.5)
    for now, bounds, center, axes in random_updates(rng, tube, n, 150):
        h = rng.choice([0.01, 0.05, 0.1])
        compiled = tube.advance(center, now, h, bounds, axes)
        with backend.pure_numpy():
            reference = tube.advance(center, now, h, bounds, axes)
        # Same arithmetic in a different order: sub-step decisions agree, positions to
        # rounding (1e-9 m leaves room for a few-ulp q difference near a gap threshold).
        np.testing.assert_allclose(compiled.center, reference.center, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(compiled.certified, reference.certified)
        # θ_j at the new centre with the belief itself, as the law's own evaluation there
        # gives it (the 3D circulation axes are carried with it).
        for update in (compiled, reference):
            at_end = tube.evaluate(update.center, now, circulation=axes).theta
            np.testing.assert_allclose(update.theta, at_end, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("n", [2, 3])
def test_an_update_from_a_port_belief_reads_the_vector_alike(n):
    """The fixed-rate tube's belief comes from its port: the packed kernel reads σ_j in
    closed form from the vector and unpacks nothing, and updates as from the arrays."""
    rng = np.random.default_rng(RNG_SEED + 17 * n)
    tube = law(np.full(n, 4.0), max_center_speed=1.5)
    for now, bounds, center, axes in random_updates(rng, tube, n, 60):
        port = ObstacleBelief.from_port(now.to_vector(), n, now.task)
        packed = tube.advance(center, port, 0.05, bounds, axes, radius=0.3)
        assert "_obstacles" not in port.__dict__
        arrays = tube.advance(center, now, 0.05, bounds, axes, radius=0.3)
        # σ_j = √λ_max of σ_j² I in closed form against the given σ_j: one rounding, as
        # above a few-ulp q difference near a gap threshold moves a sub-step end by < 1e-9 m.
        np.testing.assert_allclose(packed.center, arrays.center, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(packed.certified, arrays.certified)
        assert packed.end_radius == pytest.approx(arrays.end_radius, rel=1e-9, abs=1e-12)
        assert packed.start_radius == pytest.approx(arrays.start_radius, rel=1e-9, abs=1e-12)


# --------------------------------------------------------------------------------------
# 3D circulation
# --------------------------------------------------------------------------------------
def test_circulation_chosen_at_activation_points_v_along_the_goal():
    center, mean, goal = np.zeros(3), np.array([[1.0, 0.2, 0.0]]), np.array([5.0, 1.0, 2.0])
    for compiled in (True, False):
        with backend.pure_numpy(not compiled):
            axes = carry_circulation(np.zeros((1, 3)), center, mean, np.array([True]), goal)
        m = center - mean
        v = null_space_direction(m, goal, axes)
        goal_rule = null_space_direction(m, goal)
        np.testing.assert_allclose(v, goal_rule, rtol=1e-12, atol=1e-14)
        # Inactive: the axis is released.
        released = carry_circulation(axes, center, mean, np.array([False]), goal)
        np.testing.assert_array_equal(released, 0.0)


def test_circulation_does_not_flip_across_the_obstacle_target_line():
    """The centre crosses the line through the obstacle mean and the target: the goal rule
    flips v (the chatter the issue reports), the carried axis does not."""
    mean, target = np.array([[2.0, 0.0, 0.0]]), np.array([4.0, 0.0, 0.0])
    path = [np.array([1.5, 0.0, y]) for y in np.linspace(0.2, -0.2, 41)]
    axes = np.zeros((1, 3))
    carried, goal_rule = [], []
    for center in path:
        axes = carry_circulation(axes, center, mean, np.array([True]), target - center)
        m = center - mean
        carried.append(null_space_direction(m, target - center, axes)[0])
        goal_rule.append(null_space_direction(m, target - center)[0])
    carried, goal_rule = np.array(carried), np.array(goal_rule)
    steps = np.einsum("ij,ij->i", carried[1:], carried[:-1])
    norms = np.linalg.norm(carried[1:], axis=1) * np.linalg.norm(carried[:-1], axis=1)
    assert np.min(steps / norms) > 0.99  # consecutive directions within ~8°
    flips = np.einsum("ij,ij->i", goal_rule[1:], goal_rule[:-1]) < 0
    assert flips.any()


@pytest.mark.parametrize("compiled", [True, False])
def test_carrying_the_axes_leaves_the_rate_at_that_centre_unchanged(compiled):
    """Carried at a centre, the axes give the law there the ċ the held ones gave: a carried
    ω_j has ω'_j × m̂_j ∥ ω_j × m̂_j, a chosen one gives the goal rule the law took without
    one (the tube system keeps its memoised evaluation on the strength of this). Held axes
    at random, some 1e-4 rad off m̂_j (below the law's minimum sine: the law took the goal
    rule there, so must the re-chosen axis; carrying it kept the direction ω × m̂ before),
    some zero (none chosen yet); obstacles in their layer ε < q ≤ p_d, so most act."""
    rng = np.random.default_rng(RNG_SEED + 23)
    tube = law(np.full(3, 3.0), k3=1.5)  # ν at its unbounded default: no saturation
    acting = near_parallel = 0
    for _ in range(200):
        sigma = rng.uniform(0.05, 0.3, 5)
        direction = rng.normal(size=(5, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        center = rng.uniform(0, 3, 3)
        distance = 0.3 + sigma * rng.uniform(0.8, 3.0, 5)
        now = belief(center - distance[:, None] * direction, sigma, 0.2, 0.6, 0.999)
        held = rng.normal(size=(5, 3))
        near = rng.random(5) < 0.3
        turned = np.cross(direction, rng.normal(size=(5, 3)))  # ⟂ m̂_j
        turned /= np.linalg.norm(turned, axis=1, keepdims=True)
        held[near] = direction[near] + 1e-4 * turned[near]
        held /= np.linalg.norm(held, axis=1, keepdims=True)
        held[rng.random(5) < 0.2] = 0.0
        with backend.pure_numpy(not compiled):
            before = tube.evaluate(center, now, circulation=held)
            active = before.theta > 0.0
            goal = tube.target - center
            carried = carry_circulation(held, center, now.mean, active, goal)
            after = tube.evaluate(center, now, circulation=carried)
        q, epsilon = before.avoid_probability, now.epsilon
        acts = active & (q > epsilon)
        acting += int(acts.sum())
        near_parallel += int((acts & near).sum())
        # Each obstacle's terms are k2·θ·m_j and k3·θ·v_j with |v_j| = |m_j|: a few
        # roundings each (≤ 10 ulp ≈ 2.2e-15 of the largest), summed: 1e-14 of their sum.
        size = np.linalg.norm(goal) ** (1 / 3) + np.sum(
            np.where(acts, 1.9 * before.theta * distance / np.where(acts, q - epsilon, 1.0), 0.0)
        )
        np.testing.assert_allclose(after.center_rate, before.center_rate, rtol=0, atol=1e-14 * size)
        np.testing.assert_array_equal(after.theta, before.theta)
    assert acting > 300 and near_parallel > 60  # the cases above happened


def test_compiled_and_numpy_tube_step_agree_with_inflation_and_circulation():
    rng = np.random.default_rng(RNG_SEED + 5)
    for n in (2, 3):
        tube = replace(law(np.full(n, 3.0)), max_center_speed=2.0)
        for _ in range(200):
            now = belief(rng.uniform(0, 3, (5, n)), rng.uniform(0.05, 0.5, 5), 0.2, 0.85, 0.999)
            center = rng.uniform(0, 3, n)
            inflation = (rng.uniform(0, 0.2, 5), rng.uniform(0, 0.1, 5))
            axes = rng.normal(size=(5, 3)) if n == 3 else None
            compiled = tube.evaluate(center, now, circulation=axes, inflation=inflation)
            with backend.pure_numpy():
                reference = tube.evaluate(center, now, circulation=axes, inflation=inflation)
            np.testing.assert_allclose(
                compiled.avoid_probability, reference.avoid_probability, rtol=1e-10, atol=1e-13
            )
            np.testing.assert_allclose(
                compiled.center_rate, reference.center_rate, rtol=1e-8, atol=1e-10
            )
            assert np.linalg.norm(compiled.center_rate) <= 2.0 * (1 + 1e-12)


@pytest.mark.parametrize("compiled", [True, False])
def test_update_leaves_an_epsilon_level_set_it_would_slide_along(compiled):
    """A centre on a static obstacle's ε level set with the goal behind the obstacle: the
    law slides round it, so the straight chord to the end of the period's sub-steps cuts
    into the level set. The update used to halve that chord towards c_k, which lies on the
    level set, and never moved again (omni_wall_double_20hz stalled so). Now it pulls back
    to an earlier sub-step's end first: it makes progress, off the level set, and the
    segment keeps q > ε at every point (scipy, dense)."""
    sigma, radius, epsilon, p_d = 0.03, 0.2, 0.9, 0.99
    tube = law([2.0, 0.0], k2=0.4, k3=2.0, r_min=0.1, max_center_speed=1.0)
    now = belief([0.0, 0.0], sigma, radius, epsilon, p_d)
    threshold = ((radius + tube.r_min) / sigma) ** 2
    # Just outside the level set (q − ε = 1e-7), so the update must certify obstacle 0.
    on_level_set = brentq(
        lambda d: ncx2.sf(threshold, 2, (d / sigma) ** 2) - epsilon - 1e-7, 0.1, 1.0, xtol=1e-15
    )
    heading = np.radians(150.0)
    center = on_level_set * np.array([np.cos(heading), np.sin(heading)])
    with backend.pure_numpy(not compiled):
        update = tube.advance(center, now, 0.05, BeliefRateBounds.still(1))
    assert np.linalg.norm(update.center - center) > 1e-3
    for s in np.linspace(0.0, 1.0, 201)[1:]:
        point = center + s * (update.center - center)
        assert q_true(point, [0.0, 0.0], sigma, radius + tube.r_min) > epsilon
