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
3, one native call per point) and a numpy reference here, vectorised over points, which is
the same algorithm in array form (used with ``STT_DRAKE_PURE_NUMPY=1``).
"""

from __future__ import annotations

import numpy as np
from scipy import special

from stt_drake.core import backend

#: Dimensions supported.
DIMENSIONS = (2, 3)
#: A covariance whose eigenvalue ratio λ_max/λ_min exceeds this is numerically singular:
#: eigh determines λ_min only to ~1e-16·λ_max.
MAX_CONDITION = 1e12
#: Relative asymmetry max|Σ − Σᵀ|/max|Σ| accepted (and removed by symmetrising).
SYMMETRY_RTOL = 1e-12

# The contour and iteration constants of :mod:`stt_drake.core._anisotropic` (repeated: that
# module imports nothing of the package, and numba's cache freezes its globals; a test checks
# they agree).
PATH_STEP = 0.175
PATH_STRETCH = 0.03
PATH_END = 30.0
PATH_BEND = 0.6
PATH_BEND_SCALE = 1.0
STEP_ACCEPT = 2e-4
NEWTON_MAX_ITERATIONS = 60
SADDLE_MAX_ITERATIONS = 200
QUANTILE_RTOL = 1e-5
QUANTILE_MAX_ITERATIONS = 60
_SERIES_BELOW = 0.1
_SERIES_TERMS = 24  # Σ_{k=2}^{25} (k − 1) z^k / k: the next term is < 1e-24 z² for |z| < 0.1
_UNDERFLOW = -745.0


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
    return _numpy_ball_probabilities(variances, offsets, radius)


def avoid_gradient(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """(avoid (k,), ∂avoid/∂offset (k, n)) for points in the eigenbasis (rotate the gradient
    with the axes: ∇_point = gradient @ axesᵀ)."""
    kernel = backend.compiled("avoid_gradient_array", len(variances))
    if kernel is not None:
        return kernel(*_contiguous(variances, offsets), float(radius))
    return _numpy_avoid_gradient(variances, offsets, radius)


def quantile_radius(variances: np.ndarray, offsets: np.ndarray, epsilon: float) -> np.ndarray:
    """(k,) radii r with P(‖point − O‖ ≥ r) = epsilon, for points in the eigenbasis."""
    kernel = backend.compiled("quantile_radius_array", len(variances))
    if kernel is not None:
        return kernel(*_contiguous(variances, offsets), float(epsilon))
    return _numpy_quantile_radius(variances, offsets, epsilon)


def _contiguous(variances: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C-contiguous float copies for the kernels (one signature, one compilation)."""
    return (
        np.ascontiguousarray(variances, dtype=float),
        np.ascontiguousarray(np.atleast_2d(offsets), dtype=float),
    )


# --------------------------------------------------------------------------- numpy reference
def path_table() -> np.ndarray:
    """The contour at its nodes (same definition as
    :func:`stt_drake.core._anisotropic.path_table`): rows [T², dT²/du, d²T²/du², d³T²/du³, T,
    dT/du, e^{−T²}] at u_k = (k − ½)h while τ(u_k)² ≤ :data:`PATH_END`, τ = u + γu³,
    T² = τ² + iβτ² tanh(τ/τ_c)."""
    count = 1
    while ((count + 0.5) * PATH_STEP + PATH_STRETCH * ((count + 0.5) * PATH_STEP) ** 3) ** 2 <= (
        PATH_END
    ):
        count += 1
    u = (np.arange(1, count + 1) - 0.5) * PATH_STEP
    tau = u + PATH_STRETCH * u**3
    tau1 = 1.0 + 3.0 * PATH_STRETCH * u * u
    tau2 = 6.0 * PATH_STRETCH * u
    tau3 = 6.0 * PATH_STRETCH
    c = PATH_BEND_SCALE
    th = np.tanh(tau / c)
    se = 1.0 - th * th
    bend = 1j * PATH_BEND
    g0 = tau * tau + bend * tau * tau * th
    g1 = 2.0 * tau + bend * (2.0 * tau * th + tau * tau * se / c)
    g2 = 2.0 + bend * (2.0 * th + 4.0 * tau * se / c - 2.0 * tau * tau * th * se / c**2)
    g3 = bend * (
        6.0 * se / c
        - 12.0 * tau * th * se / c**2
        + (4.0 * tau * tau * th * th * se - 2.0 * tau * tau * se * se) / c**3
    )
    d1 = g1 * tau1
    d2 = g2 * tau1**2 + g1 * tau2
    d3 = g3 * tau1**3 + 3.0 * g2 * tau1 * tau2 + g1 * tau3
    root = np.sqrt(g0)
    return np.array([g0, d1, d2, d3, root, d1 / (2.0 * root), np.exp(-g0)])


_TABLE = path_table()
_TSQ, _DTSQ, _D2TSQ, _D3TSQ, _T, _TP, _WEIGHT = _TABLE
_POLE_WEIGHT = _WEIGHT * _TP


def _log_gap(z: np.ndarray) -> np.ndarray:
    """G(z) = log(1 − z) + z/(1 − z) for real z < 1 (series Σ (k − 1)z^k/k near 0)."""
    z = np.asarray(z, dtype=float)
    near = np.abs(z) < _SERIES_BELOW
    far = np.where(near, 0.5, z)
    result = np.log1p(-far) + far / (1.0 - far)
    series = np.zeros(z.shape)
    power = z * z
    for k in range(2, 2 + _SERIES_TERMS):
        series += power * ((k - 1.0) / k)
        power = power * z
    return np.where(near, series, result)


def _saddle_log_t(kappa: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Per row, x = log(1 − 2κ_max ŝ) at K′(ŝ) = 1 (as the kernel's ``saddle_log_t``)."""
    n = kappa.shape[1]
    kmax = kappa.max(axis=1)
    ratio = kappa / kmax[:, None]
    mean = (kappa + nu).sum(axis=1)
    tail = (nu / ratio**2).sum(axis=1)
    above = mean >= 1.0
    top = np.log(np.maximum(np.maximum(2.0 * n * kmax, np.sqrt(2.0 * tail)), 1.0))
    lo = np.where(above, 0.0, np.log(np.where(above, 1.0, kmax)))
    hi = np.where(above, top, 0.0)
    x = 0.5 * (lo + hi)
    active = np.ones(x.shape, dtype=bool)
    for _ in range(SADDLE_MAX_ITERATIONS):
        grow = np.expm1(x)[:, None]
        t = 1.0 + ratio * grow
        first = (kappa / t + nu / (t * t)).sum(axis=1)
        second = (2.0 * kappa * kappa / (t * t) + 4.0 * kappa * nu / (t * t * t)).sum(axis=1)
        g = np.log(first)
        lo = np.where(active & (g > 0.0), x, lo)
        hi = np.where(active & ~(g > 0.0), x, hi)
        new = x + g / (second / first * np.exp(x) / (2.0 * kmax))
        new = np.where((lo <= new) & (new <= hi), new, 0.5 * (lo + hi))
        tolerance = 4e-16 * (1.0 + np.abs(x))
        done = (np.abs(new - x) <= tolerance) | (hi - lo <= tolerance)
        x = np.where(active, new, x)
        active &= ~done
        if not active.any():
            break
    return x


def _sum_log(delta: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Σ_i log(1 − ρ_iδ) per row for Im δ > 0 (as the kernel: one arctangent per pair)."""
    q = 1.0 - rho * delta[:, None]
    modulus = np.prod(q.real**2 + q.imag**2, axis=1)
    angle = np.zeros(delta.shape)
    for i in range(0, rho.shape[1], 2):
        if i + 1 < rho.shape[1]:
            pair = np.angle(q[:, i] * q[:, i + 1])
            angle += np.where(pair > 0.0, pair - 2.0 * np.pi, pair)
        else:
            angle += np.angle(q[:, i])
    return 0.5 * np.log(modulus) + 1j * angle


def _psi(delta: np.ndarray, rho: np.ndarray, a: np.ndarray) -> tuple:
    """(ψ, ψ′, ψ″, ψ‴) per row at δ (see the kernel's ``_psi``)."""
    z = rho * delta[:, None]
    w = 1.0 / (1.0 - z)
    w2 = w * w
    zw = z * w
    p0 = -0.5 * _sum_log(delta, rho) + (-0.5 * z + (a / rho) * z * zw).sum(axis=1)
    p1 = (0.5 * rho * zw + a * zw * (2.0 - z) * w).sum(axis=1)
    p2 = (rho * (0.5 * rho + 2.0 * a * w) * w2).sum(axis=1)
    p3 = (rho * rho * w2 * w * (rho + 6.0 * a * w)).sum(axis=1)
    return p0, p1, p2, p3


def _solve_node(delta: np.ndarray, k: int, rho: np.ndarray, a: np.ndarray) -> tuple:
    """Per row, δ with ψ(δ) = −T_k² and (ψ′, ψ″, ψ‴) there (see the kernel's ``_solve_node``)."""
    delta = delta.copy()
    p1, p2, p3, correction = (np.zeros(delta.shape, dtype=complex) for _ in range(4))
    active = np.arange(delta.shape[0])
    for _ in range(NEWTON_MAX_ITERATIONS):
        q0, q1, q2, q3 = _psi(delta[active], rho[active], a[active])
        inverse = 1.0 / q1
        u = (q0 + _TSQ[k]) * inverse
        size = np.abs(u) ** 2
        scale = np.abs(delta[active]) ** 2
        c2 = 0.5 * q2 * inverse
        c3 = q3 * inverse / 6.0
        step = np.where(size > 1e-2 * scale, u, u * (1.0 + u * (c2 + u * (2.0 * c2 * c2 - c3))))
        delta[active] -= step
        p1[active], p2[active], p3[active], correction[active] = q1, q2, q3, step
        active = active[size > STEP_ACCEPT**2 * scale]
        if active.size == 0:
            break
    return (
        delta,
        p1 - correction * (p2 - 0.5 * correction * p3),
        p2 - correction * p3,
        p3,
    )


def _small_tail(kappa: np.ndarray, nu: np.ndarray, gradient: bool) -> tuple:
    """Per row of (κ, ν) (k, n): (tail, upper, density, slope, D (k, n) or None), as the
    kernel's ``small_tail``."""
    count, n = kappa.shape
    tail = np.zeros(count)
    density = np.zeros(count)
    slope = np.zeros(count)
    terms = np.zeros((count, n)) if gradient else None
    x = _saddle_log_t(kappa, nu)
    kmax = kappa.max(axis=1)
    grow = np.expm1(x)
    s_hat = -grow / (2.0 * kmax)
    z = -(kappa / kmax[:, None]) * grow[:, None]
    t_hat = 1.0 - z
    rho = 2.0 * kappa / t_hat
    a = nu / (t_hat * t_hat)
    k2 = (0.5 * rho * rho + 2.0 * a * rho).sum(axis=1)
    k3 = (rho**3 + 6.0 * rho * rho * a).sum(axis=1)
    phi_hat = -(0.5 * _log_gap(z) + 0.5 * nu * z * z / (kappa * t_hat * t_hat)).sum(axis=1)
    upper = s_hat > 0.0
    live = np.flatnonzero(phi_hat >= _UNDERFLOW)
    if live.size == 0:
        return tail, upper, density, slope, terms
    rho, a, t_hat, s_hat = rho[live], a[live], t_hat[live], s_hat[live]
    w = np.sqrt(-phi_hat[live])
    pole = 1j * np.where(upper[live], w, -w)
    a1 = 1j * np.sqrt(2.0 / k2[live])
    a2 = k3[live] / (3.0 * k2[live] ** 2)
    h = PATH_STEP
    delta = d1 = d2 = d3 = d4 = np.zeros(live.size, dtype=complex)
    sums = np.zeros((3, live.size))
    grad = np.zeros((live.size, n))
    for k in range(_TSQ.shape[0]):
        if k == 0:
            delta = _T[0] * (a1 + a2 * _T[0])
        else:
            delta = delta + h * (d1 + h * (0.5 * d2 + h * (d3 + 0.25 * h * d4) / 6.0))
        delta, p1, p2, p3 = _solve_node(delta, k, rho, a)
        inverse = -1.0 / p1
        d1 = _DTSQ[k] * inverse
        d2 = (_D2TSQ[k] + p2 * d1 * d1) * inverse
        previous = d3
        d3 = (_D3TSQ[k] + 3.0 * p2 * d1 * d2 + p3 * d1**3) * inverse
        d4 = (d3 - previous) / h if k > 0 else np.zeros(live.size, dtype=complex)
        s = s_hat + delta
        weighted = _WEIGHT[k] * d1
        sums[0] += (weighted / s - _POLE_WEIGHT[k] / (_T[k] - pole)).imag
        sums[1] += weighted.imag
        sums[2] -= (weighted * s).imag
        if gradient:
            grad += (weighted[:, None] / (1.0 - rho * delta[:, None])).imag / t_hat
    scale = np.exp(phi_hat[live]) * h / np.pi
    sign = np.where(upper[live], 1.0, -1.0)
    tail[live] = np.clip(0.5 * special.erfc(w) + sign * scale * sums[0], 0.0, 1.0)
    density[live] = scale * sums[1]
    slope[live] = scale * sums[2]
    if gradient:
        terms[live] = scale[:, None] * grad
    return tail, upper, density, slope, terms


def _scaled(variances: np.ndarray, offsets: np.ndarray, radius: float) -> tuple:
    """(κ, ν) = (λ/R², offset²/R²) as (k, n) arrays."""
    offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
    threshold = float(radius) ** 2
    kappa = np.broadcast_to(np.asarray(variances, dtype=float) / threshold, offsets.shape)
    return np.array(kappa), offsets * offsets / threshold


def _numpy_ball_probabilities(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Reference path of :func:`ball_probabilities`."""
    tail, upper, _, _, _ = _small_tail(*_scaled(variances, offsets, radius), False)
    collision = np.where(upper, 1.0 - tail, tail)
    return collision, np.where(upper, tail, 1.0 - tail)


def _numpy_avoid_gradient(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Reference path of :func:`avoid_gradient`: ∂avoid/∂offset_i = 2 offset_i D_i/R²."""
    offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
    tail, upper, _, _, terms = _small_tail(*_scaled(variances, offsets, radius), True)
    return np.where(upper, tail, 1.0 - tail), 2.0 * offsets * terms / float(radius) ** 2


def _gap_and_slope(ratio: np.ndarray, b2: np.ndarray, x: np.ndarray) -> tuple:
    """Per row, (J, dJ/dx) with J = ŝK′ − K at s = (1 − e^x)/(2λ_max) (as the kernel)."""
    grow = np.expm1(x)[:, None]
    z = -ratio * grow
    t = 1.0 - z
    gap = (0.5 * _log_gap(z) + 0.5 * b2 * z * z / (t * t)).sum(axis=1)
    slope = (z * ratio / (t * t) + 2.0 * z * ratio * b2 / (t * t * t)).sum(axis=1)
    return gap, -0.5 * np.exp(x) * slope


def _solve_gap(ratio: np.ndarray, b2: np.ndarray, goal: np.ndarray, direction: float) -> np.ndarray:
    """Per row, x on the side `direction` with √J(x) = goal (as the kernel's ``_solve_gap``)."""
    count = b2.shape[0]
    lo = np.zeros(count)
    hi = np.full(count, direction)
    growing = goal > 0.0
    while True:
        short = growing & (np.sqrt(_gap_and_slope(ratio, b2, hi)[0]) < goal) & (np.abs(hi) < 512)
        if not short.any():
            break
        lo = np.where(short, hi, lo)
        hi = np.where(short, 2.0 * hi, hi)
    x = np.where(growing, 0.5 * (lo + hi), 0.0)
    active = growing.copy()
    for _ in range(SADDLE_MAX_ITERATIONS):
        if not active.any():
            break
        gap, slope = _gap_and_slope(ratio, b2, x)
        root = np.sqrt(gap)
        below = root < goal
        lo = np.where(active & below, x, lo)
        hi = np.where(active & ~below, x, hi)
        safe = np.where(slope != 0.0, slope, 1.0)
        new = np.where(slope != 0.0, x - (root - goal) * 2.0 * root / safe, lo)
        inside = (np.minimum(lo, hi) <= new) & (new <= np.maximum(lo, hi))
        new = np.where(inside, new, 0.5 * (lo + hi))
        done = np.abs(new - x) <= 1e-12 * (1.0 + np.abs(x))
        x = np.where(active, new, x)
        active &= ~done
    return x


def _saddlepoint_start(variances: np.ndarray, offsets: np.ndarray, epsilon: float) -> np.ndarray:
    """Per row, the kernel's ``saddlepoint_start``: R² where the Lugannani–Rice tail is ε."""
    ratio = variances / variances.max()
    b2 = offsets * offsets / variances
    small = min(epsilon, 1.0 - epsilon)
    sign = 1.0 if epsilon < 0.5 else -1.0
    target = np.full(offsets.shape[0], small)
    x = np.zeros(offsets.shape[0])
    correcting = np.ones(offsets.shape[0], dtype=bool)
    for attempt in range(3):
        goal = special.erfcinv(2.0 * target)
        x = np.where(correcting, _solve_gap(ratio, b2, goal, -sign), x)
        gap = _gap_and_slope(ratio, b2, x)[0]
        correcting &= gap >= 1e-3
        if attempt == 2 or not correcting.any():
            break
        grow = np.expm1(x)[:, None]
        t = 1.0 + ratio * grow
        curvature = (2.0 * ratio**2 / (t * t) * (1.0 + 2.0 * b2 / t)).sum(axis=1)
        u_hat = -0.5 * grow[:, 0] * np.sqrt(curvature)
        w_hat = sign * np.sqrt(2.0 * gap)
        with np.errstate(divide="ignore", invalid="ignore"):
            correction = np.exp(-gap) / np.sqrt(2.0 * np.pi) * (1.0 / u_hat - 1.0 / w_hat)
        corrected = np.clip(small - sign * correction, 0.1 * small, 0.5)
        target = np.where(correcting, corrected, target)
    t = 1.0 + ratio * np.expm1(x)[:, None]
    return (variances / t + offsets * offsets / (t * t)).sum(axis=1)


def _numpy_quantile_radius(
    variances: np.ndarray, offsets: np.ndarray, epsilon: float
) -> np.ndarray:
    """Reference path of :func:`quantile_radius` (the kernel's iteration, row-wise)."""
    variances = np.asarray(variances, dtype=float)
    offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
    count, n = offsets.shape
    norm2 = (offsets * offsets).sum(axis=1)
    along = (variances * offsets * offsets).sum(axis=1)
    distance = np.sqrt(norm2)
    sigma_max = np.sqrt(variances.max())
    lower = np.full(count, max(-sigma_max * special.ndtri(0.5 * epsilon), 0.0))
    aligned = distance - np.sqrt(along / np.where(norm2 > 0.0, norm2, 1.0)) * special.ndtri(epsilon)
    lower = np.where(norm2 > 0.0, np.maximum(lower, aligned), lower)
    u = -np.log(epsilon)
    upper = distance + sigma_max * np.sqrt(n + 2.0 * np.sqrt(n * u) + 2.0 * u)
    y_lo, y_hi = lower * lower, upper * upper
    upper_tail = epsilon <= 0.5
    target = np.log(epsilon) if upper_tail else np.log1p(-epsilon)
    sign = -1.0 if upper_tail else 1.0
    y = np.clip(_saddlepoint_start(variances, offsets, epsilon), y_lo, y_hi)
    y = np.where(y > 0.0, y, 0.5 * (y_lo + y_hi))
    radius = np.full(count, np.nan)
    active = np.arange(count)
    for _ in range(QUANTILE_MAX_ITERATIONS):
        ya = y[active]
        tail, side, density, slope, _ = _small_tail(
            np.array(np.broadcast_to(variances, (active.size, n))) / ya[:, None],
            offsets[active] ** 2 / ya[:, None],
            False,
        )
        prob = np.where(side == upper_tail, tail, 1.0 - tail)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_prob = np.log(prob)
            above = np.where(prob > 0.0, (log_prob > target) == upper_tail, not upper_tail)
            y_lo[active] = np.where(above, ya, y_lo[active])
            y_hi[active] = np.where(above, y_hi[active], ya)
            f = density / ya
            f_slope = slope / (ya * ya)
            g = log_prob - target
            g1 = sign * f / prob
            g2 = sign * f_slope / prob - g1 * g1
            halley = ya - 2.0 * g * g1 / (2.0 * g1 * g1 - g * g2)
        lo, hi = y_lo[active], y_hi[active]
        new = np.where((prob > 0.0) & (f > 0.0), halley, 0.5 * (lo + hi))
        new = np.where((lo <= new) & (new <= hi), new, 0.5 * (lo + hi))
        converged = np.abs(new - ya) <= QUANTILE_RTOL * ya
        narrow = hi - lo <= 1e-15 * hi
        radius[active] = np.where(converged, np.sqrt(new), np.sqrt(0.5 * (lo + hi)))
        y[active] = new
        active = active[~(converged | narrow)]
        if active.size == 0:
            break
    radius[active] = np.sqrt(y[active])
    return radius
