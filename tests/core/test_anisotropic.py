"""Tests of stt_drake.core.anisotropic (O ~ N(μ, Σ), full covariance) against independent
references, none of them the code under test:

* ``scipy.stats.ncx2`` / ``chi2`` (Boost and cdflib) for isotropic covariances, where
  ‖c − O‖²/σ² is noncentral chi-square;
* an iterated ``scipy.integrate.quad`` of the Gaussian density over the ball, written here in
  Cartesian eigen-coordinates (outer variables with the arcsine substitution t = ρ sin θ, the
  innermost one — the smallest variance — in closed form with the normal CDF), which shares
  nothing with the module's contour integral; its complement is integrated the same way when
  the avoidance probability is the small one;
* Monte Carlo sampling (10⁶ samples, fixed seeds) within 5 binomial standard errors (a
  correct implementation fails one check with probability ≈ 6e-7);
* central finite differences for the gradient.
"""

from __future__ import annotations

import warnings
from functools import cache

import numpy as np
import pytest
from scipy import integrate, special
from scipy.stats import chi2, ncx2

from stt_drake.core import _anisotropic as kernels
from stt_drake.core import anisotropic, backend
from stt_drake.core.anisotropic import (
    avoid_probability,
    avoid_probability_gradient,
    collision_probability,
    quantile_distance,
)
from stt_drake.core.anisotropic_contour import _saddlepoint_start

#: Absolute accuracy required of probabilities (the module's specification).
ATOL = 1e-10
#: Compiled and numpy paths run the same algorithm: they agree to rounding.
PATHS_ATOL = 1e-12
MC_SIGMAS = 5.0
MC_SAMPLES = 1_000_000
RATIOS = [1.0, 10.0, 1e2, 1e4]
RADIUS = 1.0
#: Largest standard deviation of the grid's obstacles (in units of RADIUS).
SIGMA_MAX = 0.5


# --------------------------------------------------------------------------------------
# Independent reference: iterated quadrature in eigen-coordinates
# --------------------------------------------------------------------------------------
def _interval(mean: float, sigma: float, half_width: float) -> tuple[float, float]:
    """(P(|u| < h), P(|u| ≥ h)) for u ~ N(mean, sigma²), each without cancellation."""
    m = abs(mean)
    upper = (half_width - m) / sigma
    lower = (-half_width - m) / sigma  # ≤ 0
    inside = special.ndtr(upper) - special.ndtr(lower)
    outside = special.ndtr(-upper) + special.ndtr(lower)
    return float(inside), float(outside)


def _quadrature(
    variances: tuple, offset: tuple, radius: float, outside: bool, relative: bool
) -> float:
    """P(Σ u_i² < R²) (or ≥ R² if `outside`) for independent u_i ~ N(offset_i, variances_i),
    by iterated quad over t = ρ sin θ, largest variance outermost, with breakpoints at the
    variables' features; to ~1e-15 absolute, or to 1e-12 relative if `relative` (tails)."""
    order = np.argsort(variances)[::-1]
    sigma = np.sqrt(np.asarray(variances, dtype=float)[order])
    mean = np.asarray(offset, dtype=float)[order]
    n = sigma.size
    abs_tol, rel_tol = (0.0, 1e-12) if relative else (1e-15, 1e-13)

    def level(i: int, rho2: float) -> float:
        if rho2 <= 0.0:
            return 1.0 if outside else 0.0
        rho = np.sqrt(rho2)
        inside_prob, outside_prob = _interval(mean[i], sigma[i], rho)
        if i == n - 1:
            return outside_prob if outside else inside_prob

        def integrand(theta: float) -> float:
            t = rho * np.sin(theta)
            density = np.exp(-0.5 * ((t - mean[i]) / sigma[i]) ** 2) / (
                np.sqrt(2.0 * np.pi) * sigma[i]
            )
            return density * rho * np.cos(theta) * level(i + 1, rho2 - t * t)

        lo = np.arcsin(np.clip((mean[i] - 40.0 * sigma[i]) / rho, -1.0, 1.0))
        hi = np.arcsin(np.clip((mean[i] + 40.0 * sigma[i]) / rho, -1.0, 1.0))
        if hi <= lo:
            return outside_prob if outside else 0.0
        marks = list(
            np.arcsin(np.clip((mean[i] + np.array([-3, -1, 0, 1, 3]) * sigma[i]) / rho, -1, 1))
        )
        # Where the remaining radius √(ρ² − t²) crosses an inner variable's mean ± 3σ.
        for j in range(i + 1, n):
            for edge in abs(mean[j]) + np.array([-3.0, 0.0, 3.0]) * sigma[j]:
                if 0.0 < edge < rho:
                    marks += [np.arccos(edge / rho), -np.arccos(edge / rho)]
        points = sorted({float(p) for p in marks if lo < p < hi}) or None
        value, _ = integrate.quad(
            integrand, lo, hi, points=points, epsabs=abs_tol, epsrel=rel_tol, limit=400
        )
        return value + (outside_prob if outside else 0.0)

    with warnings.catch_warnings():  # quad's roundoff notices at these tight tolerances
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        return level(0, radius * radius)


@cache
def reference_collision(
    variances: tuple, offset: tuple, radius: float, relative: bool = False
) -> float:
    """P(‖point − O‖ < R) with the point at `offset` in the eigenbasis of Σ = diag(variances)."""
    return _quadrature(variances, offset, radius, outside=False, relative=relative)


@cache
def reference_avoid(
    variances: tuple, offset: tuple, radius: float, relative: bool = False
) -> float:
    """P(‖point − O‖ ≥ R), integrated directly (not as 1 − the collision probability)."""
    return _quadrature(variances, offset, radius, outside=True, relative=relative)


# --------------------------------------------------------------------------------------
# Test obstacles: rotated covariances and points placed in their eigenbasis
# --------------------------------------------------------------------------------------
def _rotation(n: int, seed: int) -> np.ndarray:
    """A fixed random rotation (orthogonal, det +1)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(n, n)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _variances(n: int, ratio: float, sigma_max: float = SIGMA_MAX) -> np.ndarray:
    """Eigenvalues σ_max²·(1, ratio^{-1/2}, ratio^{-1}) (n = 3) or σ_max²·(1, 1/ratio)."""
    exponents = np.linspace(0.0, 1.0, n)
    return sigma_max**2 * ratio ** (-exponents)


def _obstacle(n: int, ratio: float, seed: int, sigma_max: float = SIGMA_MAX) -> tuple:
    """(variances, axes, mean, covariance) of a rotated obstacle."""
    variances = _variances(n, ratio, sigma_max)
    axes = _rotation(n, seed)
    mean = np.random.default_rng(seed + 100).normal(size=n)
    covariance = axes @ np.diag(variances) @ axes.T
    return variances, axes, mean, 0.5 * (covariance + covariance.T)


def _grid_offsets(variances: np.ndarray) -> np.ndarray:
    """Points in the eigenbasis from inside the ball to far away: collision probabilities
    from ~1 down to ~1e-12 (k σ beyond the ball along the widest and the narrowest axis)
    and ~1e-70 (far)."""
    n = variances.size
    sigma = np.sqrt(variances)
    wide = np.eye(n)[0]
    narrow = np.eye(n)[-1]
    diagonal = np.ones(n) / np.sqrt(n)
    rows = [
        np.zeros(n),
        0.5 * RADIUS * diagonal,
        (RADIUS + 0.5 * sigma[0]) * wide,
        (RADIUS + 3.0 * sigma[0]) * wide,
        (RADIUS + 7.0 * sigma[0]) * wide,
        (RADIUS + 1.0 * sigma[-1]) * narrow,
        (RADIUS + 7.0 * sigma[-1]) * narrow,
        (RADIUS + 4.0 * sigma[0]) * diagonal,
        10.0 * RADIUS * diagonal,
    ]
    return np.array(rows)


# --------------------------------------------------------------------------------------
# Isotropic covariance: the noncentral chi-square law
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 3])
def test_isotropic_matches_ncx2(n):
    worst = 0.0
    for variance in [0.01, 0.3, 4.0]:
        covariance = variance * np.eye(n)
        mean = np.linspace(-0.5, 0.5, n)
        for distance in [0.0, 0.3, 1.0, 2.5, 6.0]:
            point = mean + distance * np.eye(n)[0]
            nc = distance**2 / variance
            for radius in [0.2, 1.0, 3.0]:
                x = radius**2 / variance
                law = ncx2(n, nc) if nc > 0 else chi2(n)
                collision = collision_probability(point, mean, covariance, radius)
                avoid = avoid_probability(point, mean, covariance, radius)
                worst = max(worst, abs(collision - law.cdf(x)), abs(avoid - law.sf(x)))
    assert worst <= ATOL


@pytest.mark.parametrize("n", [2, 3])
def test_isotropic_quantile_matches_ncx2_ppf(n):
    r_o = 0.3
    for variance in [0.01, 0.3, 4.0]:
        covariance = variance * np.eye(n)
        mean = np.zeros(n)
        for distance in [0.0, 0.5, 3.0]:
            point = distance * np.ones(n) / np.sqrt(n)
            nc = distance**2 / variance
            law = ncx2(n, nc) if nc > 0 else chi2(n)
            for eps in [1e-4, 0.01, 0.1, 0.5, 0.9]:
                expected = np.sqrt(variance * law.ppf(1.0 - eps)) - r_o
                d_hat = quantile_distance(point, mean, covariance, r_o, eps)
                assert d_hat == pytest.approx(expected, rel=1e-10, abs=1e-10 * np.sqrt(variance))
            # Deep tail: the ε-quantile through isf (1 − ε would round at ε = 1e-9).
            expected = np.sqrt(variance * law.isf(1e-9)) - r_o
            d_hat = quantile_distance(point, mean, covariance, r_o, 1e-9)
            assert d_hat == pytest.approx(expected, rel=1e-10)


# --------------------------------------------------------------------------------------
# Anisotropic: against the iterated quadrature
# --------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("ratio", RATIOS)
@pytest.mark.parametrize("n", [2, 3])
def test_probabilities_match_quadrature(n, ratio):
    variances, axes, mean, covariance = _obstacle(n, ratio, seed=n)
    offsets = _grid_offsets(variances)
    points = mean + offsets @ axes.T
    reference = np.array(
        [reference_collision(tuple(variances), tuple(row), RADIUS) for row in offsets]
    )
    collision = collision_probability(points, mean, covariance, RADIUS)
    avoid = avoid_probability(points, mean, covariance, RADIUS)
    assert np.max(np.abs(collision - reference)) <= ATOL
    assert np.max(np.abs(avoid - (1.0 - reference))) <= ATOL
    # The grid covers the range the specification names: from above 0.4 to ~1e-12.
    assert reference.max() > 0.4 and np.any((reference > 1e-13) & (reference < 1e-10))


@pytest.mark.slow
@pytest.mark.parametrize(("n", "ratio"), [(2, 1e2), (3, 1e4), (3, 10.0)])
def test_small_tails_have_relative_accuracy(n, ratio):
    """Collision probabilities ~1e-12 and avoidance probabilities ~1e-12 (a point deep inside
    a narrow obstacle) are computed directly, not as 1 minus the other: relative error 1e-8."""
    variances, axes, mean, covariance = _obstacle(n, ratio, seed=7 + n)
    sigma = np.sqrt(variances)
    outside = (RADIUS + 7.0 * sigma[0]) * np.eye(n)[0]
    point = mean + axes @ outside
    expected = reference_collision(tuple(variances), tuple(outside), RADIUS, relative=True)
    assert 1e-14 < expected < 1e-9
    assert collision_probability(point, mean, covariance, RADIUS) == pytest.approx(
        expected, rel=1e-8
    )
    # Narrow obstacle (σ_max = R/8) centred near the point: avoidance ~1e-15.
    narrow, axes, mean, covariance = _obstacle(n, ratio, seed=7 + n, sigma_max=RADIUS / 8.0)
    inside = 0.05 * RADIUS * np.ones(n)
    expected = reference_avoid(tuple(narrow), tuple(inside), RADIUS, relative=True)
    assert 1e-18 < expected < 1e-9
    point = mean + axes @ inside
    assert avoid_probability(point, mean, covariance, RADIUS) == pytest.approx(expected, rel=1e-8)


def test_rotation_and_translation_invariance():
    _, axes, mean, covariance = _obstacle(3, 1e2, seed=3)
    offset = np.array([0.4, -0.9, 0.2])
    base = collision_probability(mean + axes @ offset, mean, covariance, RADIUS)
    turn = _rotation(3, seed=99)
    shift = np.array([5.0, -2.0, 1.0])
    moved = collision_probability(
        turn @ (mean + axes @ offset) + shift, turn @ mean + shift, turn @ covariance @ turn.T, 1.0
    )
    assert moved == pytest.approx(base, abs=1e-14)


# --------------------------------------------------------------------------------------
# Monte Carlo
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("n", "ratio", "offset"),
    [(2, 1e2, [0.9, 0.3]), (3, 1e4, [0.5, 0.2, 0.99]), (3, 10.0, [1.2, 0.0, 0.4])],
)
def test_monte_carlo(n, ratio, offset):
    _, axes, mean, covariance = _obstacle(n, ratio, seed=20 + n)
    point = mean + axes @ np.asarray(offset)
    rng = np.random.default_rng(1234 + n)
    samples = mean + rng.multivariate_normal(np.zeros(n), covariance, size=MC_SAMPLES)
    hits = np.linalg.norm(samples - point, axis=1) < RADIUS
    estimate = hits.mean()
    computed = collision_probability(point, mean, covariance, RADIUS)
    standard_error = np.sqrt(computed * (1.0 - computed) / MC_SAMPLES)
    assert 0.01 < computed < 0.99  # informative: the band is not degenerate
    assert abs(estimate - computed) <= MC_SIGMAS * standard_error


# --------------------------------------------------------------------------------------
# Quantile distance
# --------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(("n", "ratio"), [(2, 1e4), (3, 1e2), (3, 1.0)])
def test_quantile_hits_epsilon(n, ratio):
    """P(‖c − O‖ ≥ r_o + d̂) = ε to 1e-10, the probability from the independent quadrature."""
    variances, axes, mean, covariance = _obstacle(n, ratio, seed=40 + n)
    r_o = 0.25
    for offset in [0.7 * np.eye(n)[0], 1.5 * np.ones(n) / np.sqrt(n)]:
        point = mean + axes @ offset
        for eps in [1e-9, 1e-3, 0.5, 0.8]:
            d_hat = quantile_distance(point, mean, covariance, r_o, eps)
            probability = reference_avoid(tuple(variances), tuple(offset), r_o + d_hat)
            assert abs(probability - eps) <= ATOL


def test_quantile_is_monotone():
    variances, axes, mean, covariance = _obstacle(3, 1e3, seed=5)
    direction = axes @ np.array([0.6, 0.64, 0.48])
    eps_values = np.array([1e-9, 1e-6, 1e-3, 0.01, 0.1, 0.3, 0.6, 0.9])
    point = mean + 0.4 * direction
    by_eps = [quantile_distance(point, mean, covariance, 0.2, e) for e in eps_values]
    assert np.all(np.diff(by_eps) < 0.0)  # a larger ε allows a smaller margin
    # Along a ray from the mean the distance grows (Anderson's inequality).
    points = mean + np.linspace(0.0, 3.0, 13)[:, None] * direction
    along = quantile_distance(points, mean, covariance, 0.2, 0.01)
    assert np.all(np.diff(along) > 0.0)
    # d̂ may be negative: at the mean with a large obstacle radius.
    d_hat = quantile_distance(mean, mean, covariance, 2.0, 0.01)
    assert d_hat < 0.0
    expected = reference_avoid(tuple(variances), (0.0, 0.0, 0.0), 2.0 + d_hat)
    assert abs(expected - 0.01) <= ATOL


# --------------------------------------------------------------------------------------
# Gradient
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(("n", "ratio"), [(2, 1.0), (2, 1e2), (3, 10.0), (3, 1e4)])
def test_gradient_matches_finite_differences(n, ratio):
    """Five-point central differences, step h = 1e-3·σ_min. Their error is at most the
    truncation h⁴ max|q⁽⁵⁾|/30 with |q⁽⁵⁾| ≤ 10/σ_min⁵ (the normal density's fourth
    derivative is below 1.2/σ⁵; two boundary terms, generously rounded up), plus the
    rounding 1.5·η/h with η = 3e-15 the scatter of q between nearby points (measured:
    ~1e-15). With σ_min = 0.005 that is ~1e-9; the tolerance is three times the bound."""
    variances, axes, mean, covariance = _obstacle(n, ratio, seed=60 + n)
    sigma_min = np.sqrt(variances[-1])
    h = 1e-3 * sigma_min
    tolerance = 3.0 * (h**4 * 10.0 / sigma_min**5 / 30.0 + 1.5 * 3e-15 / h)
    offsets = np.array([0.3 * np.ones(n), 0.9 * np.eye(n)[0], 0.95 * np.eye(n)[-1]])
    for offset in offsets:
        point = mean + axes @ offset
        gradient = avoid_probability_gradient(point, mean, covariance, RADIUS)
        steps = h * np.eye(n)
        q = [
            [avoid_probability(point + k * step, mean, covariance, RADIUS) for k in (-2, -1, 1, 2)]
            for step in steps
        ]
        numeric = np.array([(a - 8.0 * b + 8.0 * c - d) / (12.0 * h) for a, b, c, d in q])
        assert np.max(np.abs(gradient - numeric)) <= tolerance
        assert np.max(np.abs(gradient)) > 1e-3  # not a trivially flat case


def test_gradient_vectorised_shape():
    _, _, mean, covariance = _obstacle(3, 10.0, seed=1)
    points = mean + np.array([[0.5, 0.0, 0.0], [0.0, 1.0, 0.3]])
    gradients = avoid_probability_gradient(points, mean, covariance, RADIUS)
    assert gradients.shape == (2, 3)
    single = avoid_probability_gradient(points[1], mean, covariance, RADIUS)
    np.testing.assert_allclose(gradients[1], single, rtol=0, atol=1e-15)


# --------------------------------------------------------------------------------------
# Compiled kernels and numpy reference path
# --------------------------------------------------------------------------------------
def test_compiled_matches_numpy_path():
    rng = np.random.default_rng(8)
    for n in (2, 3):
        for ratio in RATIOS:
            variances = _variances(n, ratio) * rng.uniform(0.2, 5.0)
            offsets = np.vstack([_grid_offsets(variances), rng.normal(size=(6, n))])
            compiled = (
                anisotropic.ball_probabilities(variances, offsets, RADIUS),
                anisotropic.avoid_gradient(variances, offsets, RADIUS)[1],
                [anisotropic.quantile_radius(variances, offsets, e) for e in (1e-9, 0.01, 0.7)],
            )
            with backend.pure_numpy():
                reference = (
                    anisotropic.ball_probabilities(variances, offsets, RADIUS),
                    anisotropic.avoid_gradient(variances, offsets, RADIUS)[1],
                    [anisotropic.quantile_radius(variances, offsets, e) for e in (1e-9, 0.01, 0.7)],
                )
            np.testing.assert_allclose(compiled[0], reference[0], rtol=0, atol=PATHS_ATOL)
            scale = np.max(np.abs(reference[1]))
            np.testing.assert_allclose(compiled[1], reference[1], rtol=0, atol=1e-12 * scale)
            np.testing.assert_allclose(compiled[2], reference[2], rtol=1e-12)


def test_kernel_edge_inputs():
    variances = np.array([0.5, 0.01])
    assert kernels.ball_probabilities(variances, np.array([0.3, 0.2]), 0.0) == (0.0, 1.0)
    assert np.isnan(kernels.ball_probabilities(variances, np.array([np.nan, 0.2]), 1.0)[0])
    assert kernels.quantile_radius(variances, np.array([0.3, 0.2]), 1.0) == 0.0
    # Far beyond underflow: exactly 0 collision probability, avoidance 1.
    assert kernels.ball_probabilities(variances, np.array([100.0, 0.0]), 1.0) == (0.0, 1.0)


# --------------------------------------------------------------------------------------
# Input validation
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("covariance", "rule"),
    [
        ([[1.0, 0.5], [0.4, 1.0]], "symmetric"),
        ([[1.0, 2.0], [2.0, 1.0]], "positive definite"),
        ([[0.0, 0.0], [0.0, 0.0]], "positive definite"),
        ([[1.0, 0.0], [0.0, 1e-14]], "numerically singular"),
        ([[1.0, np.nan], [np.nan, 1.0]], "finite"),
        ([[1.0, 0.0], [0.0, np.inf]], "finite"),
        ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], "2x2 or 3x3"),
        (np.eye(4), "2x2 or 3x3"),
        ([1.0, 1.0], "2x2 or 3x3"),
    ],
)
def test_bad_covariance_raises(covariance, rule):
    n = np.asarray(covariance).shape[-1] if np.asarray(covariance).ndim == 2 else 2
    with pytest.raises(ValueError, match=rule):
        collision_probability(np.zeros(min(n, 3)), np.zeros(min(n, 3)), covariance, 1.0)


@pytest.mark.parametrize(
    ("call", "rule"),
    [
        (lambda: collision_probability([0.0, 0.0], [0.0, 0.0], np.eye(2), 0.0), "radius"),
        (lambda: avoid_probability([0.0, 0.0], [0.0, 0.0], np.eye(2), -1.0), "radius"),
        (lambda: avoid_probability([0.0, 0.0], [0.0, 0.0], np.eye(2), np.nan), "radius"),
        (lambda: collision_probability([0.0, 0.0], [0.0, 0.0, 0.0], np.eye(2), 1.0), "mean"),
        (lambda: collision_probability([0.0, 0.0, 0.0], [0.0, 0.0], np.eye(2), 1.0), "point"),
        (lambda: collision_probability([np.nan, 0.0], [0.0, 0.0], np.eye(2), 1.0), "point"),
        (lambda: quantile_distance([0.0, 0.0], [0.0, 0.0], np.eye(2), 0.1, 0.0), "epsilon"),
        (lambda: quantile_distance([0.0, 0.0], [0.0, 0.0], np.eye(2), 0.1, 1.0), "epsilon"),
        (lambda: quantile_distance([0.0, 0.0], [0.0, 0.0], np.eye(2), -0.1, 0.1), "obstacle"),
    ],
)
def test_bad_arguments_raise(call, rule):
    with pytest.raises(ValueError, match=rule):
        call()


# --------------------------------------------------------------------------------------
# Quantile iteration internals: density derivatives, saddle stopping, one-evaluation steps
# --------------------------------------------------------------------------------------
def _ncx2_density_derivatives(u: float, n: int, lam: float, orders: int) -> np.ndarray:
    """d^j/du^j (j = 0..orders) of the ncx2(n, λ) density at u: its Poisson mixture of χ²_m
    densities, each differentiated term by term (Leibniz on u^a e^{−u/2})."""
    total = np.zeros(orders + 1)
    for k in range(400):
        weight = (
            np.exp(-lam / 2.0 + k * np.log(lam / 2.0) - special.gammaln(k + 1)) if lam else k == 0
        )
        m = n + 2 * k
        a = m / 2.0 - 1.0
        norm = np.exp(-(m / 2.0) * np.log(2.0) - special.gammaln(m / 2.0))
        term = np.zeros(orders + 1)
        for j in range(orders + 1):
            falling = [np.prod([a - r for r in range(i)]) for i in range(j + 1)]
            term[j] = sum(
                special.comb(j, i) * falling[i] * u ** (a - i) * (-0.5) ** (j - i)
                for i in range(j + 1)
            )
        total += weight * norm * np.exp(-u / 2.0) * term
        if k > lam / 2.0 + 10.0 and np.all(np.abs(weight * term) <= 1e-18 * np.abs(total)):
            break
    return total


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize(("sigma", "distance"), [(0.3, 0.0), (0.5, 0.2), (0.4, 1.0), (1.0, 2.0)])
def test_density_derivatives_match_ncx2(n, sigma, distance):
    """The contour's density f of Y/R² at 1 and f′..f⁗ (used by the quantile's fifth-order
    step) against the noncentral chi-square density's derivatives (isotropic Σ = σ²I, R = 1:
    Y/σ² ~ ncx2(n, d²/σ²)). Each is compared on its natural scale f·(2σ²)^{−j}: f, f′ to
    1e-12, f″ to 1e-10 and f‴, f⁗ to 1e-6: they enter the step only in its h⁴ and h⁵
    terms, which are below 1e-8 of the step where it is accepted."""
    offset = np.zeros(n)
    offset[0] = distance
    kappa = np.full(n, sigma**2)
    nu = offset**2
    computed = np.array(
        kernels._tail_at(kappa, nu, np.empty(0), kernels.saddle_log_t(kappa, nu))[2:]
    )
    orders = np.arange(5)
    reference = _ncx2_density_derivatives(1.0 / sigma**2, n, (distance / sigma) ** 2, 4)
    reference = reference / sigma ** (2.0 * (orders + 1))
    scale = reference[0] * (2.0 * sigma**2) ** (-orders.astype(float))
    error = np.abs(computed - reference) / scale
    assert np.all(error <= np.array([1e-12, 1e-12, 1e-10, 1e-6, 1e-6])), error


def test_saddle_stops_at_rounding_level():
    """A point whose Newton steps on log K′ cycled between two neighbouring x at rounding
    level (it ran to SADDLE_MAX_ITERATIONS): the saddle equation K′(ŝ) = 1 holds to 1e-15."""
    variances = np.array([0.19734618, 0.05914675, 0.01772691])
    offset = np.array([-0.01063378, -0.1575825, 1.45702618])
    threshold = 1.4450661931**2
    kappa, nu = variances / threshold, offset**2 / threshold
    x = kernels.saddle_log_t(kappa, nu)
    t = 1.0 + kappa / kappa.max() * np.expm1(x)
    assert abs(np.sum(kappa / t + nu / t**2) - 1.0) <= 2e-15


def test_compiled_start_is_the_reference_start_to_its_newton_stop():
    """The compiled Lugannani–Rice start solves its equation only until a Newton step is
    below 1e-3·(1 + |x|) (error ~1e-6: quadratic convergence), the numpy path's to 1e-12:
    over both tails, n = 2, 3 and eigenvalue ratios up to 1000, the two starting R² agree
    to 1e-5 (relative), against the ~1e-3 by which either misses the quantile."""
    rng = np.random.default_rng(31)
    for trial in range(400):
        n = 2 + trial % 2
        variances = 10.0 ** rng.uniform(-3.0, 0.0, n)
        offset = rng.normal(size=n) * rng.uniform(0.0, 3.0)
        eps = rng.uniform(0.5, 0.9999) if trial % 3 else 10.0 ** rng.uniform(-9.0, -0.3)
        start = kernels.saddlepoint_start(variances, offset, eps)
        expected = _saddlepoint_start(variances, offset[None], eps)[0]
        assert start == pytest.approx(expected, rel=1e-5, abs=0.0), (variances, offset, eps)


def test_quantile_hits_epsilon_tube_field():
    """Points as the tube meets them (ε ∈ [0.7, 0.99], eigenvalue ratios up to 100, the point
    from inside the covariance to a few σ away), where the fifth-order step usually returns
    after one contour evaluation: P(‖c − O‖ ≥ r) = ε to 1e-12 by the independent quadrature,
    and the compiled quantile within 1e-12 (relative) of the numpy path's Halley iteration."""
    rng = np.random.default_rng(77)
    for trial in range(12):
        n = 2 + trial % 2
        variances = rng.uniform(0.05, 0.5) ** 2 * np.geomspace(10.0 ** -rng.uniform(0, 2), 1, n)
        offset = rng.normal(size=n) * rng.uniform(0.0, 1.5)
        eps = rng.uniform(0.7, 0.99)
        radius = kernels.quantile_radius(variances, offset, eps)
        probability = reference_avoid(tuple(variances), tuple(offset), radius)
        assert abs(probability - eps) <= 1e-12
        with backend.pure_numpy():
            expected = anisotropic.quantile_radius(variances, offset[None], eps)[0]
        assert radius == pytest.approx(expected, rel=1e-12, abs=0.0)
