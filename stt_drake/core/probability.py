"""Avoidance probabilities and quantile distances for Gaussian obstacles (paper Sec. 3).

All functions are vectorised over obstacles j. With Z = (x − O_j)/sigma_j ~ N(a e, I_n),
a = ‖x − mean_j‖/sigma_j, the squared norm ‖Z‖² is noncentral chi-square with n degrees of
freedom and noncentrality λ = a² (Proposition 3.1). So

* the avoidance probability of a point, P(‖x − O_j‖ ≥ R) (Eqs. (6) and (9)), is the
  *survival function* of χ'²_n(λ) at (R/sigma)² — computed directly, never as 1 − CDF;
* the quantile distance d̂_j (Eq. (8)) is sigma·sqrt(F⁻¹(1 − ε; λ)) − r_o, the largest
  ball radius around x that the obstacle still misses with probability ≥ ε.

Two implementations (selected by :mod:`stt_drake.core.backend`):

* compiled, for n = 1, 2, 3 (the default): :mod:`stt_drake.core._kernels` — closed forms for
  n = 1, 3, a Bessel series for the n = 2 Marcum Q-function, and a bracketed Halley
  quantile; exact to ~1e-14 (see that module);
* numpy reference (any n, and the fallback with ``STT_DRAKE_PURE_NUMPY=1``): closed forms
  for n = 1 and n = 3 (normal CDF/PDF); other n use the Boost noncentral chi-square that
  ``scipy.stats.ncx2`` wraps, called as the bare ufunc to skip the ~100 µs of
  ``rv_continuous`` argument handling per call; the quantile is Boost's isf in the upper
  tail and cdflib's ``chndtrix`` (what ``ncx2.ppf`` uses) at 1 − ε in the lower one.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import special
from scipy.optimize import brentq

from stt_drake.core import backend
from stt_drake.core.constants import SF_IS_ONE_BELOW

try:  # the ufuncs behind scipy.stats.ncx2.sf / .isf (same Boost code, no wrapper overhead)
    from scipy.special._ufuncs import _ncx2_isf, _ncx2_sf
except ImportError:  # pragma: no cover - only on a SciPy that moved them
    from scipy.stats import ncx2 as _ncx2

    def _ncx2_sf(x: np.ndarray, df: float, nc: np.ndarray) -> np.ndarray:
        return _ncx2.sf(x, df, nc)

    def _ncx2_isf(p: np.ndarray, df: float, nc: np.ndarray) -> np.ndarray:
        return _ncx2.isf(p, df, nc)


_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)

#: An obstacle whose quantile distance provably exceeds `prune_above` gets this many
#: 1/nu of headroom: its soft-min weight e^{-nu d̂} is then below e^{-40} ≈ 4e-18 of the
#: r_max term, under double rounding.
PRUNE_HEADROOM_NU = 40.0


#: Offset a from which the numpy reference uses the large-offset forms instead of Boost and
#: cdflib, whose noncentral χ² series stop converging from a ≈ 2e5 (λ = a² ≈ 4e10; near
#: b ≈ a they return NaN or wrong values — what made σ = 1e-6 "a non-finite value").
#: There ‖Z‖ = a + X + R²/(2a) + O(1/a²), X ~ N(0, 1), R² ~ χ²_{n−1}, so
#: sf(b) = Φ(a − b) + φ(b − a)(n − 1)/(2b) + O(1/b²) and the quantile is
#: a + Φ⁻¹(1 − ε) + (n − 1)/(2a) + O(1/a²); the reference returns its lower bound
#: a − Φ⁻¹(ε) (conservative: d̂ low by at most σ(n − 1)/(2a), ≤ 1e-5 σ).
LARGE_OFFSET = 1e5


def _normal_pdf(x: np.ndarray) -> np.ndarray:
    return _INV_SQRT_2PI * np.exp(-0.5 * x * x)


def noncentral_chi_sf(threshold: np.ndarray, offset: np.ndarray, dimension: int) -> np.ndarray:
    """P(‖Z‖ ≥ threshold) for Z ~ N(offset·e, I_dimension) (arrays broadcast together).

    This is the survival function of the noncentral chi distribution, i.e. of χ'²_n at
    threshold² with noncentrality offset².
    """
    kernel = backend.compiled("chi_sf_array", dimension)
    if kernel is None:
        return _numpy_chi_sf(threshold, offset, dimension)
    return _elementwise(kernel, threshold, offset, dimension)


def _elementwise(
    kernel: Callable[..., np.ndarray], first: np.ndarray, second: np.ndarray, dimension: int
) -> np.ndarray:
    """Apply a compiled (1D, 1D, n) → 1D kernel to two arrays broadcast together."""
    x, y = np.broadcast_arrays(np.asarray(first, dtype=float), np.asarray(second, dtype=float))
    flat = kernel(np.array(x, dtype=float).ravel(), np.array(y, dtype=float).ravel(), dimension)
    return flat.reshape(x.shape)[()]


def _numpy_chi_sf(threshold: np.ndarray, offset: np.ndarray, dimension: int) -> np.ndarray:
    """Reference path of :func:`noncentral_chi_sf` (numpy closed forms and Boost)."""
    b = np.asarray(threshold, dtype=float)
    a = np.asarray(offset, dtype=float)
    if dimension == 1:
        return special.ndtr(a - b) + special.ndtr(-a - b)
    if dimension == 3:
        # sf = Φ(a−b) + Φ(−a−b) + [φ(b−a) − φ(b+a)]/a, with φ(b+a) = φ(b−a)e^{−2ab}:
        # the bracket is φ(b−a)(−expm1(−2ab))/a, whose limit at a → 0 is 2bφ(b).
        safe_a = np.where(a > 0.0, a, 1.0)
        shell = np.where(
            a > 0.0,
            _normal_pdf(b - a) * -np.expm1(-2.0 * b * a) / safe_a,
            2.0 * b * _normal_pdf(b),
        )
        return special.ndtr(a - b) + special.ndtr(-a - b) + shell
    # Where the answer is 1 to double precision, return it without calling Boost: its sf
    # returns −0.0 at x = 0 when nc > 0, and raises OverflowError (tgamma) for x ≲ 2.5e-8
    # once nc ≳ 400. Since ‖Z‖ ≥ Z·e, 1 − sf ≤ Φ(b − a) ≤ 2⁻⁵⁴ when b − a ≤ SF_IS_ONE_BELOW,
    # and 1 − 2⁻⁵⁴ rounds to 1. (Written so that NaN inputs still reach Boost and give NaN.)
    b, a = np.broadcast_arrays(b, a)
    x, nc = b * b, a * a
    compute = ~((x <= 0.0) | (b - a <= SF_IS_ONE_BELOW))
    large = compute & (a >= LARGE_OFFSET)
    series = compute & ~large
    result = np.ones(x.shape)
    result[series] = _ncx2_sf(x[series], dimension, nc[series])
    bl, al = b[large], a[large]
    result[large] = np.minimum(
        special.ndtr(al - bl) + _normal_pdf(bl - al) * (dimension - 1) / (2.0 * bl), 1.0
    )
    return result[()]


def noncentral_chi_isf(probability: np.ndarray, offset: np.ndarray, dimension: int) -> np.ndarray:
    """The s ≥ 0 with P(‖Z‖ ≥ s) = probability, for Z ~ N(offset·e, I_dimension)."""
    kernel = backend.compiled("chi_isf_array", dimension)
    if kernel is None:
        return _numpy_chi_isf(probability, offset, dimension)
    return _elementwise(kernel, probability, offset, dimension)


def _numpy_chi_isf(probability: np.ndarray, offset: np.ndarray, dimension: int) -> np.ndarray:
    """Reference path of :func:`noncentral_chi_isf`: Boost's isf for p ≤ 1/2, cdflib's
    inverse CDF at 1 − p above (1 − p is exact there; an isf near p = 1 is conditioned by
    the absolute rounding of sf and loses ~1e-16/(n(1 − p)) relative); from
    :data:`LARGE_OFFSET` on, the lower bound a − Φ⁻¹(p)."""
    p, a = np.broadcast_arrays(
        np.asarray(probability, dtype=float), np.asarray(offset, dtype=float)
    )
    p, offset = p.ravel(), a.ravel()
    nc = offset * offset
    large = offset >= LARGE_OFFSET
    lower_tail = (p > 0.5) & ~large
    upper_tail = ~((p > 0.5) | large)
    x = np.empty(p.shape)
    x[lower_tail] = special.chndtrix(1.0 - p[lower_tail], dimension, nc[lower_tail])
    x[upper_tail] = _ncx2_isf(p[upper_tail], dimension, nc[upper_tail])
    s = np.sqrt(x)
    s[large] = np.maximum(offset[large] - special.ndtri(p[large]), 0.0)
    return s.reshape(a.shape)[()]


def avoid_probability(
    point: np.ndarray, mean: np.ndarray, sigma: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """P(‖point − O_j‖ ≥ radius_j) for O_j ~ N(mean_j, sigma_j² I) (Proposition 3.1, Eq. (6)).

    With radius = r_o + r_min this is q_j of Eq. (5); with radius = r_o it is q̂_j of
    Eq. (9); with radius = r_o + r it is the avoidance probability of the ball B(point, r).

    Args:
        point: (n,) one point, or (m, n) one point per obstacle.
        mean: (m, n) obstacle means.
        sigma: (m,) standard deviations (> 0).
        radius: (m,) or scalar, the distance that counts as a collision.

    Returns:
        (m,) probabilities in [0, 1].
    """
    mean = np.asarray(mean, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    distance = np.linalg.norm(np.asarray(point, dtype=float) - mean, axis=-1)
    return noncentral_chi_sf(np.asarray(radius) / sigma, distance / sigma, mean.shape[-1])


def ball_avoid_probability(
    center: np.ndarray,
    ball_radius: float,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
) -> np.ndarray:
    """Avoidance probability of the ball B(center, ball_radius).

    P(‖center − O_j‖ ≥ radius_j + ball_radius): the ball misses obstacle j.

    This is the tube's avoidance probability of Definition 2.5, Eq. (3d).
    """
    return avoid_probability(center, mean, sigma, np.asarray(radius) + ball_radius)


def quantile_distance(
    point: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    prune_above: float | None = None,
) -> np.ndarray:
    """d̂_j = sigma_j·sqrt(F⁻¹_{χ'²_n}(1 − ε_j; λ_j)) − r_o_j (Eq. (8)).

    The largest r with P(‖point − O_j‖ ≥ r_o_j + r) ≥ ε_j. The (1 − ε) quantile of the CDF
    is computed as the ε upper quantile (isf), so no 1 − ε subtraction happens.

    Pruning (exact for the tube's outputs): ‖Z‖ ≥ Z·e, so F(s) ≤ Φ(s − a) and the quantile
    is at least a + Φ⁻¹(1 − ε). When that lower bound already puts d̂_j above
    `prune_above`, the expensive quantile is skipped and the bound is returned instead
    (it is a true lower bound of d̂_j, and still above `prune_above`).

    Returns:
        (m,) distances in metres; may be negative where the point is already too close.
    """
    mean = np.asarray(mean, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    radius = np.asarray(radius, dtype=float)
    epsilon = np.broadcast_to(np.asarray(epsilon, dtype=float), sigma.shape)
    offset = np.linalg.norm(np.asarray(point, dtype=float) - mean, axis=-1) / sigma
    lower = sigma * np.maximum(offset - special.ndtri(epsilon), 0.0) - radius
    exact = np.ones(sigma.shape, dtype=bool) if prune_above is None else lower <= prune_above
    result = lower.copy()
    if np.any(exact):
        quantile = noncentral_chi_isf(epsilon[exact], offset[exact], mean.shape[-1])
        result[exact] = sigma[exact] * quantile - radius[exact]
    return result


def period_avoid_probability(
    point: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    reach: np.ndarray,
    spread: np.ndarray,
) -> np.ndarray:
    """A lower bound of P(‖point − O_j(t)‖ ≥ radius_j) over every belief reachable within a
    horizon τ from N(mean_j, sigma_j² I): means within `reach` Δ_j = v̄_j τ of mean_j and
    standard deviations in [σ_j − s̄_j τ, σ_j + s̄_j τ], with spread γ_j = σ_j/(σ_j − s̄_j τ) − 1
    (derivation: :mod:`stt_drake.core.fixed_rate`, "Discrete-time guarantee").

    With a = ‖point − mean_j‖ it is the survival function at the offset max(a − Δ_j, 0) and
    the radius radius_j + γ_j (a + Δ_j + radius_j); Δ = γ = 0 gives :func:`avoid_probability`.
    """
    mean = np.asarray(mean, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    radius = np.asarray(radius, dtype=float)
    distance = np.linalg.norm(np.asarray(point, dtype=float) - mean, axis=-1)
    grown = radius + spread * (distance + reach + radius)
    return noncentral_chi_sf(
        grown / sigma, np.maximum(distance - reach, 0.0) / sigma, mean.shape[-1]
    )


def segment_distances(
    start: np.ndarray, end: np.ndarray, mean: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per obstacle j, the smallest and the largest distance from mean_j to a point of the
    segment [start, end] (the closest point's, and an endpoint's)."""
    mean = np.asarray(mean, dtype=float)
    start = np.asarray(start, dtype=float)
    chord = np.asarray(end, dtype=float) - start
    length2 = float(chord @ chord)
    along = (mean - start) @ chord / length2 if length2 > 0.0 else np.zeros(len(mean))
    closest = start + np.clip(along, 0.0, 1.0)[:, None] * chord
    nearest = np.linalg.norm(closest - mean, axis=-1)
    farthest = np.maximum(
        np.linalg.norm(start - mean, axis=-1), np.linalg.norm(start + chord - mean, axis=-1)
    )
    return nearest, farthest


def segment_avoid_lower_bound(
    start: np.ndarray,
    end: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    reach: np.ndarray,
    spread: np.ndarray,
) -> np.ndarray:
    """A lower bound of :func:`period_avoid_probability` at every point of the segment
    [start, end]: the survival function falls with the radius and rises with the offset, so
    take the offset at the segment's closest point to mean_j and the radius at its farthest
    (an endpoint)."""
    mean = np.asarray(mean, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    nearest, farthest = segment_distances(start, end, mean)
    grown = radius + spread * (farthest + reach + radius)
    return noncentral_chi_sf(
        grown / sigma, np.maximum(nearest - reach, 0.0) / sigma, mean.shape[-1]
    )


def segment_quantile_lower_bound(
    start: np.ndarray,
    end: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    reach: np.ndarray,
    spread: np.ndarray,
) -> np.ndarray:
    """A lower bound of d̂_j (Eq. (8)) at every point of the segment [start, end] and for
    every belief reachable within the horizon of (reach, spread): the largest r with
    P(‖x − O_j(t)‖ ≥ r_o_j + r) ≥ ε_j for all those x and beliefs.

    By the coupling of :mod:`stt_drake.core.fixed_rate` the collision event at radius R is
    inside the event at radius R(1 + γ) + γ(a_max + Δ) + Δ-shifted offset, so any R with
    R(1 + γ) + γ(a_max + Δ) ≤ σ·s_ε(max(a_min − Δ, 0)/σ) is safe, s_ε the noncentral-χ upper
    ε quantile: D_j = (σ s_ε − γ(a_max + Δ))/(1 + γ) − r_o_j. It exceeds r_min exactly when
    :func:`segment_avoid_lower_bound` (with r_o + r_min) exceeds ε_j."""
    mean = np.asarray(mean, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    nearest, farthest = segment_distances(start, end, mean)
    epsilon = np.broadcast_to(np.asarray(epsilon, dtype=float), sigma.shape)
    offset = np.maximum(nearest - reach, 0.0) / sigma
    quantile = sigma * noncentral_chi_isf(epsilon, offset, mean.shape[-1])
    return (quantile - spread * (farthest + reach)) / (1.0 + spread) - np.asarray(radius)


def level_set_radius(level: float, sigma: float, radius: float, dimension: int) -> float:
    """Distance d from the mean at which q̂(x) = P(‖x − O‖ ≥ radius) equals `level`.

    q̂ depends on x only through d = ‖x − mean‖ and grows with it, so {q̂ ≤ level} is the
    closed disc (ball) of radius d around the mean.

    Args:
        level: probability in (0, 1].
        sigma: standard deviation of the obstacle centre per axis (> 0), metres.
        radius: obstacle radius r_o (≥ 0), metres.
        dimension: n.

    Returns:
        d in metres: 0 if even the mean has q̂ ≥ level (the set is empty or a point);
        ``inf`` if q̂ < level everywhere (the set is the whole space).
    """
    threshold = radius / sigma

    def gap(offset: float) -> float:
        return float(noncentral_chi_sf(threshold, offset, dimension)) - level

    if gap(0.0) >= 0.0:
        return 0.0
    upper = threshold + np.sqrt(dimension) + 10.0
    for _ in range(60):
        if gap(upper) >= 0.0:
            break
        upper *= 2.0
    else:
        return float("inf")
    return sigma * brentq(gap, 0.0, upper, xtol=1e-13, rtol=8.0 * np.finfo(float).eps)
