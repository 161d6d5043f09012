"""Avoidance probabilities and quantile distances for a Gaussian obstacle with a full
covariance, O ~ N(μ, Σ), Σ symmetric positive definite, n = 2 or 3.

For a point c, Y = ‖c − O‖² is a positive definite noncentral quadratic form (a generalized
chi-square): in the eigenbasis Σ = V diag(λ) Vᵀ, with offset = Vᵀ(c − μ),

    Y = Σ_i (offset_i + √λ_i z_i)² = Σ_i λ_i (z_i + b_i)²,   z ~ N(0, I), b_i = offset_i/√λ_i.

This module gives q(c) = P(‖c − O‖ ≥ R) (Eq. (5), R = r_o + r_min), the collision probability
1 − q, ∇_c q, and the quantile distance d̂(c) = √Q_Y(1 − ε) − r_o (Eq. (8)).

Method: saddle-point contour integration of the Laplace inversion integral
--------------------------------------------------------------------------
Y has the cumulant generating function K(s) = Σ_i [−½ log(1 − 2λ_i s) + λ_i b_i² s/(1 − 2λ_i s)]
(s < 1/(2λ_max)), and with Φ(s) = K(s) − sy (Gil-Pelaez; Imhof 1961, in Laplace form)

    P(Y ≥ y) = (1/2πi) ∫_{c−i∞}^{c+i∞} e^{Φ(s)} ds/s   (0 < c < 1/(2λ_max)),
    P(Y < y) = −(same integral)                           (c < 0).

The line is moved through the saddle point ŝ, K′(ŝ) = y; ŝ > 0 exactly when y > E[Y], so
the sign of ŝ picks the *smaller* tail, which is computed directly (the other is 1 minus
it). From ŝ the contour follows Φ(ŝ + δ) = Φ̂ − T², T² = τ² + iβτ² tanh(τ) (Φ̂ = Φ(ŝ)):
with β = 0 this is the path of steepest descent (Rice 1980, "Distribution of quadratic forms
in normal random variables — evaluation by numerical integration", SIAM J. Sci. Stat.
Comput. 1, 438–448), on which the integrand is e^{Φ̂}·e^{−τ²}, a Gaussian weight with no
oscillation and no cancellation; the bend β = 0.6 keeps the path away from the singular
points 1/(2λ_i) that a steepest-descent path hugs when eigenvalues differ (there its
integrand has features of width ~0.2 in τ; bent, ~1). The pole of 1/s is subtracted in
closed form: its share is ½erfc(w), w = √(−Φ̂) — the leading Lugannani–Rice term — so the
rest is smooth at every ŝ, including ŝ → 0 where the pole crosses the path. The remaining
integral is a trapezoid rule in a parameter u, τ = u + 0.03u³, step 0.175, 22 nodes (to
τ² = 30): exponentially convergent for an integrand analytic in a strip (Trefethen &
Weideman 2014, "The exponentially convergent trapezoidal rule", SIAM Review 56, 385–458).
Each node's δ is solved by a Newton-type iteration from a Taylor step along the path.

Why this method: it is one-dimensional for every n (a direct quadrature of the Gaussian over
the ball is two-dimensional for n = 3, and sharp when λ_max/λ_min = 1e4); its cost does not
depend on the eigenvalue ratio; the integrand carries the factor e^{Φ̂} (the Chernoff bound)
so both tails keep relative accuracy (a collision probability of 1e-12 is computed as such,
not as 1 − (1 − 1e-12)); it is deterministic (fixed nodes, no adaptivity); and the density
and the gradient are integrals of the same kind on the same nodes. Imhof's real integral
decays like u^{−1−n/2} and oscillates (~1e6 nodes for 1e-12); Ruben's (1962) chi-square
series needs ~(λ_max/λ_min)·ln(1/tol) terms; Davies's (1980) algorithm (a trapezoid rule on
the characteristic function with truncation bounds) works but its step count grows with the
required accuracy. Accuracy: the trapezoid error is O(e^{−2πd/h}) for an integrand analytic
in a strip of half-width d, but d depends on the problem, so the bound is not a priori: the
step, bend and stretch were chosen, and the result checked, against independent iterated
``scipy.integrate.quad`` over ~1000 random cases (λ_max/λ_min in [1, 1e4], λ/R² in
[1e-6, 1e8], probabilities from 1e-15 to ½): the largest absolute error was 1.5e-13 and the
largest relative error of a small tail 7e-13. Cost (compiled,
:mod:`stt_drake.core._anisotropic`, one call in a loop): ~5–7 µs per probability or
gradient, ~13–19 µs per quantile (two contour evaluations and the start).

Isotropic case: with λ_1 = … = λ_n = σ², K(s) = −(n/2) log(1 − 2σ²s) + ‖b‖²σ²s/(1 − 2σ²s) is
the cumulant generating function of σ²·χ′²_n(‖b‖²), so the same integral is the noncentral
chi-square law of :mod:`stt_drake.core.probability` (Proposition 3.1): q = P(χ′²_n(‖b‖²) ≥
R²/σ²). (The saddle point is then the root of a quadratic in 1 − 2σ²s.)

Gradient: ∂K/∂(offset_i²) = s/(1 − 2λ_i s), so ∂P(Y < R²)/∂offset_i = −2 offset_i D_i with
D_i = (1/2πi)∫ e^{Φ(s)}/(1 − 2λ_i s) ds, the density at R² of Y + λ_i χ²₂ — an integral of the
same kind without the pole, on the same nodes. Hence ∇_c q = 2 V (offset ⊙ D).

Quantile: Halley's iteration on log P(Y ≥ y) − log ε in y = (r_o + d̂)², started from the
Lugannani–Rice approximation and kept in a bracket valid from the start (see
:func:`stt_drake.core._anisotropic.quantile_radius`); the density and its slope come from the
same contour, so two contour evaluations usually suffice.

Two implementations, selected by :mod:`stt_drake.core.backend`: the compiled kernels (n = 2,
3, one native call per point) and a numpy reference vectorised over points, which is
the same algorithm in array form (used with ``STT_DRAKE_PURE_NUMPY=1``), in
:mod:`stt_drake.core.anisotropic_contour` with the contour's constants.
"""

from __future__ import annotations

import numpy as np

from stt_drake.core import anisotropic_contour as contour
from stt_drake.core import backend

#: Dimensions supported.
DIMENSIONS = (2, 3)
#: A covariance whose eigenvalue ratio λ_max/λ_min exceeds this is numerically singular:
#: eigh determines λ_min only to ~1e-16·λ_max.
MAX_CONDITION = 1e12
#: Relative asymmetry max|Σ − Σᵀ|/max|Σ| accepted (and removed by symmetrising).
SYMMETRY_RTOL = 1e-12


# --------------------------------------------------------------------------- validation
def eigen_decomposition(covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate a covariance and decompose it: Σ = axes · diag(variances) · axesᵀ.

    Returns:
        (variances (n,) ascending, axes (n, n) with the eigenvectors as columns).

    Raises:
        ValueError: Σ is not a 2×2 or 3×3 array, not finite, not symmetric (beyond
            :data:`SYMMETRY_RTOL`), not positive definite, or numerically singular
            (λ_max/λ_min > :data:`MAX_CONDITION`).
    """
    matrix = np.asarray(covariance, dtype=float)
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1] or matrix.shape[0] not in DIMENSIONS:
        raise ValueError(f"covariance must be a 2x2 or 3x3 matrix, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError("covariance must be finite (it has NaN or infinite entries)")
    size = float(np.max(np.abs(matrix)))
    asymmetry = float(np.max(np.abs(matrix - matrix.T)))
    if asymmetry > SYMMETRY_RTOL * size:
        raise ValueError(
            f"covariance must be symmetric: max |Σ − Σᵀ| = {asymmetry:.3g} "
            f"(allowed {SYMMETRY_RTOL:g} × max |Σ|)"
        )
    variances, axes = np.linalg.eigh(0.5 * (matrix + matrix.T))
    if not variances[0] > 0.0:
        raise ValueError(
            f"covariance must be positive definite: smallest eigenvalue {variances[0]:.3g}"
        )
    if variances[-1] > MAX_CONDITION * variances[0]:
        raise ValueError(
            "covariance must be positive definite and well conditioned: eigenvalue ratio "
            f"{variances[-1] / variances[0]:.3g} exceeds {MAX_CONDITION:g} (numerically singular)"
        )
    return variances, axes


def _points(point: np.ndarray, n: int) -> tuple[np.ndarray, bool]:
    """(points (k, n), whether a single (n,) point was given)."""
    array = np.asarray(point, dtype=float)
    if array.shape == (n,):
        return array[None, :], True
    if array.ndim != 2 or array.shape[1] != n:
        raise ValueError(f"point must have shape ({n},) or (k, {n}), got {array.shape}")
    return array, False


def _offsets(point: np.ndarray, mean: np.ndarray, covariance: np.ndarray) -> tuple:
    """Validate (point, mean, covariance): (variances, axes, offsets (k, n), single)."""
    variances, axes = eigen_decomposition(covariance)
    n = variances.shape[0]
    centre = np.asarray(mean, dtype=float)
    if centre.shape != (n,):
        raise ValueError(f"mean must have shape ({n},), got {centre.shape}")
    if not np.all(np.isfinite(centre)):
        raise ValueError("mean must be finite")
    points, single = _points(point, n)
    if not np.all(np.isfinite(points)):
        raise ValueError("point must be finite")
    return variances, axes, (points - centre) @ axes, single


def _positive(value: float, name: str) -> float:
    """`value` as a float, checked finite and > 0."""
    number = float(value)
    if not (np.isfinite(number) and number > 0.0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return number


def _result(values: np.ndarray, single: bool) -> float | np.ndarray:
    """A float for a single point, else the array."""
    return float(values[0]) if single else values


# --------------------------------------------------------------------------- public API
def collision_probability(
    point: np.ndarray, mean: np.ndarray, covariance: np.ndarray, radius: float
) -> float | np.ndarray:
    """P(‖point − O‖ < radius) for O ~ N(mean, covariance).

    Args:
        point: (n,) or (k, n) points.
        mean: (n,) mean of the obstacle centre.
        covariance: (n, n) symmetric positive definite, n = 2 or 3.
        radius: the distance that counts as a collision (> 0).

    Returns:
        A float for one point, else (k,) probabilities.
    """
    variances, _, offsets, single = _offsets(point, mean, covariance)
    collision, _ = ball_probabilities(variances, offsets, _positive(radius, "radius"))
    return _result(collision, single)


def avoid_probability(
    point: np.ndarray, mean: np.ndarray, covariance: np.ndarray, radius: float
) -> float | np.ndarray:
    """q = P(‖point − O‖ ≥ radius) for O ~ N(mean, covariance) (Eq. (5) with radius
    r_o + r_min); arguments as :func:`collision_probability`."""
    variances, _, offsets, single = _offsets(point, mean, covariance)
    _, avoid = ball_probabilities(variances, offsets, _positive(radius, "radius"))
    return _result(avoid, single)


def avoid_probability_gradient(
    point: np.ndarray, mean: np.ndarray, covariance: np.ndarray, radius: float
) -> np.ndarray:
    """∇_point q, q = P(‖point − O‖ ≥ radius): (n,) for one point, else (k, n)."""
    variances, axes, offsets, single = _offsets(point, mean, covariance)
    _, gradient = avoid_gradient(variances, offsets, _positive(radius, "radius"))
    rotated = gradient @ axes.T
    return rotated[0] if single else rotated


def quantile_distance(
    point: np.ndarray,
    mean: np.ndarray,
    covariance: np.ndarray,
    obstacle_radius: float,
    epsilon: float,
) -> float | np.ndarray:
    """d̂ with P(‖point − O‖ ≥ obstacle_radius + d̂) = epsilon (Eq. (8)): √Q_Y(1 − ε) − r_o.

    May be negative (the point is already closer than that). Returns a float for one point,
    else (k,) distances.
    """
    variances, _, offsets, single = _offsets(point, mean, covariance)
    r_o = float(obstacle_radius)
    if not (np.isfinite(r_o) and r_o >= 0.0):
        raise ValueError(f"obstacle_radius must be finite and >= 0, got {obstacle_radius!r}")
    eps = float(epsilon)
    if not 0.0 < eps < 1.0:
        raise ValueError(f"epsilon must be in (0, 1), got {epsilon!r}")
    return _result(quantile_radius(variances, offsets, eps) - r_o, single)


def level_set_radii(
    directions: np.ndarray, covariance: np.ndarray, obstacle_radius: float, level: float
) -> np.ndarray:
    """Distances t_k from the mean along unit `directions` (k, n) at which
    q̂(μ + t u_k) = P(‖μ + t u_k − O‖ ≥ r_o) equals `level` ∈ (0, 1), O ~ N(μ, Σ).

    By Anderson's theorem (a centred Gaussian, the symmetric convex ball B(0, r_o)), the
    collision probability P(O − μ ∈ B(t u, r_o)) does not increase with t ≥ 0, so q̂ grows
    along every ray from μ and {q̂ ≤ level} is star-shaped about μ: each ray meets its
    boundary once. Found by bisection to 1e-9 of √λ_max; 0 where q̂(μ) ≥ level already.
    """
    variances, axes = eigen_decomposition(covariance)
    units = np.asarray(directions, dtype=float) @ axes  # in the eigenbasis
    radius = _positive(obstacle_radius, "obstacle_radius")
    scale = float(np.sqrt(variances[-1]))

    def avoid(t: np.ndarray) -> np.ndarray:
        return ball_probabilities(variances, units * t[:, None], radius)[1]

    low = np.zeros(len(units))
    high = np.full(len(units), radius + 2.0 * scale)
    for _ in range(200):  # grow the bracket until q̂ ≥ level at its top
        short = avoid(high) < level
        if not np.any(short):
            break
        high[short] *= 2.0
    inside = avoid(low) < level
    for _ in range(80):
        if np.all(high - low <= 1e-9 * scale):
            break
        middle = 0.5 * (low + high)
        below = avoid(middle) < level
        low = np.where(below, middle, low)
        high = np.where(below, high, middle)
    return np.where(inside, 0.5 * (low + high), 0.0)


# --------------------------------------------------------------------------- eigenbasis API
def ball_probabilities(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """(collision (k,), avoid (k,)) for points given in the eigenbasis.

    Args:
        variances: (n,) eigenvalues of Σ (> 0), e.g. from :func:`eigen_decomposition`.
        offsets: (k, n) rows Vᵀ(point − mean).
        radius: R > 0.
    """
    kernel = backend.compiled("ball_probabilities_array", len(variances))
    if kernel is not None:
        table = kernel(*_contiguous(variances, offsets), float(radius))
        return table[:, 0], table[:, 1]
    return contour.ball_probabilities(variances, offsets, radius)


def avoid_gradient(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """(avoid (k,), ∂avoid/∂offset (k, n)) for points in the eigenbasis (rotate the gradient
    with the axes: ∇_point = gradient @ axesᵀ)."""
    kernel = backend.compiled("avoid_gradient_array", len(variances))
    if kernel is not None:
        return kernel(*_contiguous(variances, offsets), float(radius))
    return contour.avoid_gradient(variances, offsets, radius)


def quantile_radius(variances: np.ndarray, offsets: np.ndarray, epsilon: float) -> np.ndarray:
    """(k,) radii r with P(‖point − O‖ ≥ r) = epsilon, for points in the eigenbasis."""
    kernel = backend.compiled("quantile_radius_array", len(variances))
    if kernel is not None:
        return kernel(*_contiguous(variances, offsets), float(epsilon))
    return contour.quantile_radius(variances, offsets, epsilon)


def _contiguous(variances: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C-contiguous float copies for the kernels (one signature, one compilation)."""
    return (
        np.ascontiguousarray(variances, dtype=float),
        np.ascontiguousarray(np.atleast_2d(offsets), dtype=float),
    )
