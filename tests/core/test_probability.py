"""Tests of stt_drake.core.probability against independent references.

References used here, none of them the code under test:
* ``scipy.stats.ncx2`` (sf, ppf, isf) through its public ``rv_continuous`` interface;
* a direct quadrature of the density of ‖Z‖, Z ~ N(a·e, I_n) (the noncentral chi density
  written with Bessel functions), which does not use Boost's noncentral chi-square at all —
  needed because for n = 2, 4, 5 the module calls the very Boost ufunc that ncx2 wraps, so the
  ncx2 comparison only checks the wiring (b², a² and the argument order) there;
* Monte Carlo sampling with fixed seeds, compared within 5 binomial standard errors
  (a two-sided 5σ band: a correct implementation fails it with probability ≈ 6e-7 per check).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, special
from scipy.stats import ncx2

from stt_drake.core.probability import (
    avoid_probability,
    ball_avoid_probability,
    noncentral_chi_isf,
    noncentral_chi_sf,
    quantile_distance,
)

DIMENSIONS = [1, 2, 3, 4, 5]
# Offsets a = ‖x − μ‖/σ: exactly 0, a denormal-looking 1e-12, and large ones up to
# a ≈ 316 (λ = a² = 1e5).
OFFSETS = [0.0, 1e-12, 1e-3, 0.5, 1.0, 2.5, 10.0, 40.0, 100.0, np.sqrt(1e5)]
# Survival probabilities the thresholds are placed at: from 1 − 1e-6 down to 1e-6.
LEVELS = [1.0 - 1e-6, 0.99, 0.9, 0.5, 0.1, 1e-2, 1e-4, 1e-6]
# Absolute accuracy required of the survival function. Double precision rounding of
# probabilities near 1 is 1.1e-16; the closed forms and Boost both reach ~1e-14 here.
SF_ATOL = 1e-12
# Number of standard errors allowed in Monte Carlo comparisons.
MC_SIGMAS = 5.0

HYPOTHESIS = settings(max_examples=80, deadline=None)


# --------------------------------------------------------------------------------------
# Independent references
# --------------------------------------------------------------------------------------
def _chi_density(r: float, a: float, n: int) -> float:
    """Density of ‖Z‖ for Z ~ N(a e, I_n), via the modified Bessel function I_{n/2−1}.

    f(r) = r (r/a)^{n/2−1} exp(−(r² + a²)/2) I_{n/2−1}(a r), written with the exponentially
    scaled ive so nothing overflows at a ≈ 300: exp(−(r² + a²)/2) I(ar) = exp(−(r−a)²/2) ive(ar).
    At a = 0 it is the central chi density.
    """
    if r <= 0.0:
        return 0.0
    if a == 0.0:
        log_f = (n - 1) * np.log(r) - 0.5 * r * r - (0.5 * n - 1) * np.log(2.0)
        return float(np.exp(log_f - special.gammaln(0.5 * n)))
    order = 0.5 * n - 1.0
    return float(r * (r / a) ** order * np.exp(-0.5 * (r - a) ** 2) * special.ive(order, a * r))


def _quadrature_sf(b: float, a: float, n: int) -> float:
    """P(‖Z‖ ≥ b) by adaptive quadrature of the density (the shorter tail is integrated)."""
    options = {"epsabs": 1e-15, "epsrel": 1e-13, "limit": 200}
    if b >= a:
        value, _ = integrate.quad(_chi_density, b, b + 40.0, args=(a, n), **options)
        return value
    value, _ = integrate.quad(_chi_density, max(a - 40.0, 0.0), b, args=(a, n), **options)
    return 1.0 - value


def _thresholds(a: float, n: int) -> list[float]:
    """Thresholds b whose exact survival probabilities are the LEVELS (via scipy's isf)."""
    return [float(np.sqrt(ncx2.isf(p, n, a * a))) for p in LEVELS]


def _monte_carlo_avoid(point, mean, sigma, radius, samples, seed):
    """Fraction of O_j ~ N(mean_j, sigma_j² I) with ‖point_j − O_j‖ ≥ radius_j (per j)."""
    rng = np.random.default_rng(seed)
    mean = np.asarray(mean, dtype=float)
    draws = mean[None] + sigma[None, :, None] * rng.standard_normal((samples, *mean.shape))
    distance = np.linalg.norm(np.asarray(point, dtype=float) - draws, axis=-1)
    return np.mean(distance >= radius, axis=0)


def _assert_within_binomial_error(estimate, probability, samples):
    standard_error = np.sqrt(probability * (1.0 - probability) / samples)
    assert np.all(np.abs(estimate - probability) <= MC_SIGMAS * standard_error), (
        estimate,
        probability,
        standard_error,
    )


def _q(distance: float, radius: float, sigma: float, n: int) -> float:
    """q for one obstacle at the origin and the point (distance, 0, ..., 0)."""
    point = np.zeros(n)
    point[0] = distance
    value = avoid_probability(point, np.zeros((1, n)), np.array([sigma]), np.array([radius]))
    return float(value[0])


# --------------------------------------------------------------------------------------
# noncentral_chi_sf
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", DIMENSIONS)
def test_noncentral_chi_sf_matches_scipy_ncx2(n):
    for a in OFFSETS:
        for b in _thresholds(a, n):
            expected = ncx2.sf(b * b, n, a * a)
            got = noncentral_chi_sf(b, a, n)
            assert abs(got - expected) <= SF_ATOL, (n, a, b, got, expected)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_noncentral_chi_sf_matches_quadrature_of_the_density(n):
    for a in OFFSETS:
        for b in _thresholds(a, n):
            expected = _quadrature_sf(b, a, n)
            got = noncentral_chi_sf(b, a, n)
            assert abs(got - expected) <= SF_ATOL, (n, a, b, got, expected)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_noncentral_chi_sf_at_zero_offset_is_the_central_chi_square(n):
    # a = 0: ‖Z‖² ~ χ²_n, whose sf is the regularised upper incomplete gamma Q(n/2, b²/2).
    b = np.array([0.0, 0.1, 0.7, 1.5, 3.0, 6.0])
    expected = special.gammaincc(0.5 * n, 0.5 * b * b)
    np.testing.assert_allclose(noncentral_chi_sf(b, 0.0, n), expected, rtol=0, atol=SF_ATOL)
    # a = 1e-12 is continuous with a = 0 (the n = 3 closed form divides by a).
    np.testing.assert_allclose(noncentral_chi_sf(b, 1e-12, n), expected, rtol=0, atol=SF_ATOL)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_noncentral_chi_sf_at_zero_threshold_is_one(n):
    for a in OFFSETS:
        assert noncentral_chi_sf(0.0, a, n) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_noncentral_chi_sf_tiny_thresholds(n):
    # Tiny b (b² down to underflow) at small and large offsets. Two bounds on 1 − sf:
    # ‖Z‖ ≥ Z·e gives Φ(b − a); the noncentral law is stochastically larger than the central
    # one (Anderson), and P(‖Z₀‖ ≤ b) ≤ P(|Z₀,₁| ≤ b) ≤ 2bφ(0) = b·sqrt(2/π).
    for a in [0.0, 0.5, 25.0, 300.0]:
        for b in [1e-170, 1e-100, 1e-10, 1e-6, 1e-4]:
            got = noncentral_chi_sf(b, a, n)
            bound = min(special.ndtr(b - a), b * np.sqrt(2.0 / np.pi))
            assert 1.0 - bound - 1e-16 <= got <= 1.0, (n, a, b, got)
            assert got == pytest.approx(_quadrature_sf(b, a, n), abs=SF_ATOL)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_noncentral_chi_sf_propagates_nan(n):
    # A NaN belief must surface as a NaN probability (callers detect it), never as 1.
    assert np.isnan(noncentral_chi_sf(1.0, np.nan, n))
    assert np.isnan(noncentral_chi_sf(np.nan, 2.0, n))
    values = noncentral_chi_sf(np.array([1.0, 1.0]), np.array([np.nan, 2.0]), n)
    assert np.isnan(values[0])
    assert values[1] == pytest.approx(ncx2.sf(1.0, n, 4.0), abs=SF_ATOL)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_noncentral_chi_sf_broadcasts_like_elementwise_calls(n):
    b = np.array([[0.5], [1.0], [4.0]])
    a = np.array([0.0, 1e-12, 2.0, 30.0])
    table = noncentral_chi_sf(b, a, n)
    assert table.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            assert table[i, j] == pytest.approx(ncx2.sf(b[i, 0] ** 2, n, a[j] ** 2), abs=SF_ATOL)


# --------------------------------------------------------------------------------------
# avoid_probability and ball_avoid_probability
# --------------------------------------------------------------------------------------
# Obstacles chosen so every avoidance probability lies well inside (0, 1) (checked below),
# where a Monte Carlo comparison is informative.
OBSTACLES = {
    2: dict(
        mean=np.array([[1.0, 0.5], [-0.3, 0.2], [0.0, -2.0], [1.0, 1.0]]),
        sigma=np.array([0.5, 0.3, 1.0, 0.8]),
        radius=np.array([0.6, 0.4, 2.0, 1.0]),
    ),
    3: dict(
        mean=np.array([[1.0, 0.5, 0.0], [-0.3, 0.2, 0.4], [0.0, -2.0, 1.0], [1.0, 1.0, -0.5]]),
        sigma=np.array([0.5, 0.3, 1.0, 0.8]),
        radius=np.array([0.9, 0.5, 2.4, 1.4]),
    ),
}
MC_SAMPLES = 200_000


@pytest.mark.parametrize("n", [2, 3])
def test_avoid_probability_matches_monte_carlo_for_a_single_point(n):
    obstacles = OBSTACLES[n]
    point = np.linspace(0.1, 0.4, n)
    q = avoid_probability(point, **obstacles)
    assert q.shape == (4,)
    assert np.all((q > 0.05) & (q < 0.95))  # the comparison below is then informative
    estimate = _monte_carlo_avoid(
        point, obstacles["mean"], obstacles["sigma"], obstacles["radius"], MC_SAMPLES, seed=n
    )
    _assert_within_binomial_error(estimate, q, MC_SAMPLES)


@pytest.mark.parametrize("n", [2, 3])
def test_avoid_probability_matches_monte_carlo_for_one_point_per_obstacle(n):
    obstacles = OBSTACLES[n]
    points = obstacles["mean"] + np.array([0.4, -0.3, 0.9, 0.2])[:, None] * np.ones(n) / np.sqrt(n)
    q = avoid_probability(points, **obstacles)
    assert q.shape == (4,)
    assert np.all((q > 0.05) & (q < 0.95))
    estimate = _monte_carlo_avoid(
        points, obstacles["mean"], obstacles["sigma"], obstacles["radius"], MC_SAMPLES, seed=10 + n
    )
    _assert_within_binomial_error(estimate, q, MC_SAMPLES)


@pytest.mark.parametrize("n", [2, 3])
def test_avoid_probability_point_layouts_agree_with_per_obstacle_calls(n):
    obstacles = OBSTACLES[n]
    rng = np.random.default_rng(7)
    single = rng.normal(size=n)
    per_obstacle = rng.normal(size=(4, n))
    np.testing.assert_array_equal(
        avoid_probability(single, **obstacles),
        avoid_probability(np.tile(single, (4, 1)), **obstacles),
    )
    batched = avoid_probability(per_obstacle, **obstacles)
    for j in range(4):
        one = avoid_probability(
            per_obstacle[j],
            obstacles["mean"][j : j + 1],
            obstacles["sigma"][j : j + 1],
            obstacles["radius"][j : j + 1],
        )
        distance = np.linalg.norm(per_obstacle[j] - obstacles["mean"][j])
        reference = ncx2.sf(
            (obstacles["radius"][j] / obstacles["sigma"][j]) ** 2,
            n,
            (distance / obstacles["sigma"][j]) ** 2,
        )
        assert batched[j] == one[0]
        assert batched[j] == pytest.approx(reference, abs=SF_ATOL)


def test_avoid_probability_accepts_a_scalar_radius():
    obstacles = OBSTACLES[2]
    point = np.array([0.2, -0.1])
    np.testing.assert_array_equal(
        avoid_probability(point, obstacles["mean"], obstacles["sigma"], 0.7),
        avoid_probability(point, obstacles["mean"], obstacles["sigma"], np.full(4, 0.7)),
    )


@pytest.mark.parametrize("n", [2, 3])
def test_ball_avoid_probability_adds_the_ball_radius(n):
    obstacles = OBSTACLES[n]
    center = np.full(n, 0.25)
    for ball_radius in [0.0, 0.05, 0.3]:
        np.testing.assert_array_equal(
            ball_avoid_probability(center, ball_radius, **obstacles),
            avoid_probability(
                center, obstacles["mean"], obstacles["sigma"], obstacles["radius"] + ball_radius
            ),
        )


def test_ball_avoid_probability_matches_monte_carlo_of_ball_contact():
    # The ball B(c, r) touches B(O, r_o) iff ‖c − O‖ < r_o + r: sample and count misses.
    obstacles = OBSTACLES[3]
    center = np.array([0.3, -0.2, 0.1])
    ball_radius = 0.25
    q = ball_avoid_probability(center, ball_radius, **obstacles)
    assert np.all((q > 0.05) & (q < 0.95))
    estimate = _monte_carlo_avoid(
        center,
        obstacles["mean"],
        obstacles["sigma"],
        obstacles["radius"] + ball_radius,
        MC_SAMPLES,
        seed=21,
    )
    _assert_within_binomial_error(estimate, q, MC_SAMPLES)


# --------------------------------------------------------------------------------------
# Hypothesis properties of q
# --------------------------------------------------------------------------------------
# Monotonicity can only be asserted up to the kernel's own accuracy (≈1e-14, see the
# comparisons above); this slack is rounding, not modelling error.
MONOTONE_SLACK = 1e-13

distances = st.floats(0.0, 6.0)
radii = st.floats(0.0, 3.0)
sigmas = st.floats(0.01, 5.0)
dims = st.sampled_from(DIMENSIONS)


@HYPOTHESIS
@given(n=dims, d1=distances, d2=distances, radius=radii, sigma=sigmas)
def test_q_is_non_decreasing_in_distance(n, d1, d2, radius, sigma):
    near, far = sorted((d1, d2))
    assert _q(near, radius, sigma, n) <= _q(far, radius, sigma, n) + MONOTONE_SLACK


@HYPOTHESIS
@given(n=dims, distance=distances, r1=radii, r2=radii, sigma=sigmas)
def test_q_is_non_increasing_in_collision_radius(n, distance, r1, r2, sigma):
    small, large = sorted((r1, r2))
    assert _q(distance, large, sigma, n) <= _q(distance, small, sigma, n) + MONOTONE_SLACK


# Offsets a = D/σ up to 1e5 (λ up to 1e10). Beyond a ≈ 2e5 the Boost series behind the
# n = 2, 4, 5 kernel stops converging near b ≈ a (it warns and returns wrong values); the
# numpy reference takes its large-offset forms from LARGE_OFFSET = 1e5 on (tested below).
@HYPOTHESIS
@given(
    n=dims,
    distance=st.floats(0.0, 1e3),
    radius=st.floats(0.0, 1e3),
    sigma=st.floats(1e-2, 1e3),
)
def test_q_is_a_probability(n, distance, radius, sigma):
    assert 0.0 <= _q(distance, radius, sigma, n) <= 1.0


@HYPOTHESIS
@given(
    n=st.sampled_from([2, 3]),
    direction=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
    distance=distances,
    radius=radii,
    sigma=sigmas,
)
def test_q_depends_on_the_point_only_through_its_distance(n, direction, distance, radius, sigma):
    direction = np.array(direction[:n])
    length = np.linalg.norm(direction)
    if length < 1e-3:
        direction, length = np.eye(n)[0], 1.0
    point = np.array([0.3, -1.0, 2.0][:n]) + distance * direction / length
    mean = np.array([[0.3, -1.0, 2.0][:n]])
    q = avoid_probability(point, mean, np.array([sigma]), np.array([radius]))[0]
    assert q == pytest.approx(_q(distance, radius, sigma, n), abs=1e-12)


# Dependence on sigma (derived, so the test asserts only what is true).
# Write O = μ + σW, W ~ N(0, I), D = ‖x − μ‖, s = 1/σ. A collision is W ∈ sK with
# K = B(D e, R). By the change of variables w = s·y,
#     d/ds P(W ∈ sK) = (1/s) ∫_{sK} (n − ‖w‖²) φ(w) dw.
# * D ≤ R: K contains 0, so the sets sK are nested increasing in s; the collision
#   probability grows as σ shrinks, i.e. q is non-decreasing in σ.
# * D > R and s(D − R) ≥ √n, i.e. σ ≤ (D − R)/√n: all of sK has ‖w‖² ≥ n, the derivative is
#   ≤ 0, so the collision probability grows with σ: q is non-increasing in σ (the "far
#   point" regime).
# * σ ≥ (D + R)/√n: all of sK has ‖w‖² ≤ n, so q is non-decreasing in σ again.
# So for a point outside the buffered radius q is NOT monotone in σ: it falls from 1 and
# comes back towards 1 (checked explicitly below).
@HYPOTHESIS
@given(
    n=dims,
    excess=st.floats(0.05, 5.0),
    radius=radii,
    f1=st.floats(0.01, 1.0),
    f2=st.floats(0.01, 1.0),
)
def test_q_is_non_increasing_in_sigma_for_a_far_point(n, excess, radius, f1, f2):
    distance = radius + excess
    sigma_limit = excess / np.sqrt(n)
    small, large = sorted((f1 * sigma_limit, f2 * sigma_limit))
    assert _q(distance, radius, large, n) <= _q(distance, radius, small, n) + MONOTONE_SLACK


@HYPOTHESIS
@given(n=dims, distance=st.floats(0.0, 3.0), extra=radii, s1=sigmas, s2=sigmas)
def test_q_is_non_decreasing_in_sigma_inside_the_collision_radius(n, distance, extra, s1, s2):
    radius = distance + extra
    small, large = sorted((s1, s2))
    assert _q(distance, radius, small, n) <= _q(distance, radius, large, n) + MONOTONE_SLACK


@HYPOTHESIS
@given(n=dims, distance=distances, radius=radii, f1=st.floats(1.0, 50.0), f2=st.floats(1.0, 50.0))
def test_q_is_non_decreasing_in_sigma_for_very_large_sigma(n, distance, radius, f1, f2):
    sigma_floor = max((distance + radius) / np.sqrt(n), 1e-3)
    small, large = sorted((f1 * sigma_floor, f2 * sigma_floor))
    assert _q(distance, radius, small, n) <= _q(distance, radius, large, n) + MONOTONE_SLACK


@pytest.mark.parametrize("n", [2, 3])
def test_q_is_not_monotone_in_sigma_outside_the_collision_radius(n):
    distance, radius = 1.0, 0.5
    tight, middle, loose = (_q(distance, radius, s, n) for s in (0.05, 0.5, 20.0))
    for sigma, value in [(0.05, tight), (0.5, middle), (20.0, loose)]:
        assert value == pytest.approx(
            ncx2.sf((radius / sigma) ** 2, n, (distance / sigma) ** 2), abs=SF_ATOL
        )
    assert middle < tight
    assert middle < loose


# --------------------------------------------------------------------------------------
# quantile_distance
# --------------------------------------------------------------------------------------
def _random_obstacles(rng, count, n):
    mean = 3.0 * rng.normal(size=(count, n))
    sigma = np.exp(rng.uniform(np.log(0.01), np.log(2.0), count))
    radius = rng.uniform(0.0, 1.0, count)
    epsilon = rng.uniform(0.5, 0.9999, count)
    return mean, sigma, radius, epsilon


@pytest.mark.parametrize("n", DIMENSIONS)
def test_quantile_distance_matches_scipy_ppf(n):
    rng = np.random.default_rng(100 + n)
    for _ in range(20):
        point = 3.0 * rng.normal(size=n)
        mean, sigma, radius, epsilon = _random_obstacles(rng, 6, n)
        d_hat = quantile_distance(point, mean, sigma, radius, epsilon)
        lam = np.sum((point - mean) ** 2, axis=1) / sigma**2
        quantile = sigma * np.sqrt(ncx2.ppf(1.0 - epsilon, n, lam))
        # Both sides are iterative root-finds (Boost's isf here, scipy's ppf there), each
        # with its own stopping tolerance (observed agreement ~1e-11 relative); 1e-9 relative
        # on the quantile σ·s is far below anything the tube needs.
        np.testing.assert_allclose(d_hat + radius, quantile, rtol=1e-9, atol=0)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_quantile_distance_defining_property(n):
    # P(‖x − O‖ ≥ r_o + d̂) = ε, evaluated with the survival function (closed forms for
    # n = 1, 3 so not the same code as the quantile) and with scipy's ncx2.sf.
    rng = np.random.default_rng(200 + n)
    for _ in range(20):
        point = 3.0 * rng.normal(size=n)
        mean, sigma, radius, epsilon = _random_obstacles(rng, 6, n)
        d_hat = quantile_distance(point, mean, sigma, radius, epsilon)
        offset = np.linalg.norm(point - mean, axis=1) / sigma
        threshold = (radius + d_hat) / sigma
        # The sf's slope is at most ~0.6 (a chi density), times a quantile accurate to
        # ~1e-11: 1e-10 absolute.
        np.testing.assert_allclose(
            noncentral_chi_sf(threshold, offset, n), epsilon, rtol=0, atol=1e-10
        )
        np.testing.assert_allclose(ncx2.sf(threshold**2, n, offset**2), epsilon, rtol=0, atol=1e-10)


@pytest.mark.parametrize("n", [2, 3])
def test_quantile_distance_defining_property_by_monte_carlo(n):
    obstacles = OBSTACLES[n]
    point = np.linspace(-0.2, 0.3, n)
    epsilon = np.array([0.6, 0.8, 0.9, 0.97])
    d_hat = quantile_distance(point, **obstacles, epsilon=epsilon)
    estimate = _monte_carlo_avoid(
        point,
        obstacles["mean"],
        obstacles["sigma"],
        obstacles["radius"] + d_hat,
        MC_SAMPLES,
        seed=30 + n,
    )
    _assert_within_binomial_error(estimate, epsilon, MC_SAMPLES)


@pytest.mark.parametrize("n", [2, 3])
def test_quantile_distance_at_the_obstacle_mean_and_far_away(n):
    # At the mean (λ = 0) the quantile is the central chi-square one.
    mean = np.zeros((1, n))
    sigma, radius, epsilon = np.array([0.3]), np.array([0.2]), np.array([0.95])
    d_hat = quantile_distance(np.zeros(n), mean, sigma, radius, epsilon)
    expected = sigma * np.sqrt(special.gammainccinv(0.5 * n, epsilon) * 2.0) - radius
    np.testing.assert_allclose(d_hat, expected, rtol=1e-10)
    # Very far, ‖Z‖ ≈ a + N(0, 1) along e, so d̂ → D − σΦ⁻¹(ε) − r_o (+ O(σ²/D)).
    far = np.zeros(n)
    far[0] = 1e3
    d_hat = quantile_distance(far, mean, sigma, radius, epsilon)
    expected = 1e3 - sigma * special.ndtri(epsilon) - radius
    # The curvature correction is (n − 1)σ²/(2D) ≈ 4.5e-5·(n − 1) here.
    np.testing.assert_allclose(d_hat, expected, rtol=0, atol=(n - 1) * 1e-4 + 1e-9)


@HYPOTHESIS
@given(
    n=st.sampled_from([2, 3, 5]),
    seed=st.integers(0, 2**32 - 1),
    prune_above=st.floats(-1.0, 5.0),
)
def test_quantile_distance_pruning_returns_a_lower_bound_above_the_threshold(n, seed, prune_above):
    rng = np.random.default_rng(seed)
    point = 3.0 * rng.normal(size=n)
    mean, sigma, radius, epsilon = _random_obstacles(rng, 8, n)
    exact = quantile_distance(point, mean, sigma, radius, epsilon)
    pruned = quantile_distance(point, mean, sigma, radius, epsilon, prune_above=prune_above)
    same = pruned == exact
    # A pruned value is a lower bound of the exact one (up to the exact one's root-finding
    # accuracy, 1e-9 relative as above) and still above the threshold.
    assert np.all(same | ((pruned <= exact + 1e-9 * (exact + radius)) & (pruned > prune_above)))


def test_quantile_distance_pruning_skips_far_obstacles_only():
    # One obstacle very close and one very far: the far one is pruned, the close one not.
    mean = np.array([[0.5, 0.0], [50.0, 0.0]])
    sigma, radius, epsilon = np.array([0.2, 0.2]), np.array([0.1, 0.1]), np.array([0.9, 0.9])
    exact = quantile_distance(np.zeros(2), mean, sigma, radius, epsilon)
    pruned = quantile_distance(np.zeros(2), mean, sigma, radius, epsilon, prune_above=2.0)
    assert pruned[0] == exact[0]
    # Pruned value: the bound σ(a − Φ⁻¹(ε)) − r_o from ‖Z‖ ≥ Z·e.
    bound = 0.2 * (50.0 / 0.2 - special.ndtri(0.9)) - 0.1
    assert pruned[1] == pytest.approx(bound, rel=1e-14)
    assert 2.0 < pruned[1] <= exact[1]


# --------------------------------------------------------------------------- large offsets


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("a", [1e5, 3e5, 1e6])
def test_numpy_reference_is_finite_and_accurate_at_large_offsets(n, a):
    """σ tiny against the distance (a = D/σ ≥ LARGE_OFFSET): Boost's and cdflib's series
    returned NaN or wrong values there (the "non-finite tube law" of σ = 1e-6). The numpy
    reference now matches the compiled kernel's exact sf to 1e-10, and its quantile is the
    conservative lower bound a − Φ⁻¹(ε), at most (n − 1)/(2a) below the exact one."""
    from stt_drake.core import backend
    from stt_drake.core.probability import LARGE_OFFSET

    assert a >= LARGE_OFFSET
    b = a + np.array([-8.0, -3.0, -1.0, 0.0, 0.5, 1.0, 3.0, 8.0, 30.0])
    offsets = np.full(b.shape, a)
    eps = np.array([1e-6, 0.01, 0.5, 0.9, 0.9999, 1.0 - 1e-9])
    with backend.pure_numpy(False):
        sf_exact = noncentral_chi_sf(b, offsets, n)
        isf_exact = noncentral_chi_isf(eps, np.full(eps.shape, a), n)
    with backend.pure_numpy():
        sf = noncentral_chi_sf(b, offsets, n)
        isf = noncentral_chi_isf(eps, np.full(eps.shape, a), n)
    assert np.all(np.isfinite(sf)) and np.all(np.isfinite(isf))
    np.testing.assert_allclose(sf, sf_exact, rtol=0, atol=1e-10)
    below = isf_exact - isf
    assert np.all(below >= -1e-9), below
    assert np.all(below <= (n - 1) / (2.0 * a) * (1.0 + 1e-3) + 1e-9), below
