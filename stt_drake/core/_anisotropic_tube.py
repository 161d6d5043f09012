"""Per-obstacle terms of the compiled tube law for obstacles with a full covariance,
O_j ~ N(μ_j, Σ_j) (n = 2, 3): q_j, d̂_j and the direction ∇̂q_j, with the pruning bounds.

The law, its reduction to the paper's and the pruning bounds are documented in
:mod:`stt_drake.core.anisotropic_tube` (with the numpy reference of the per-obstacle
terms); the driver that runs these terms for every obstacle (the same as for isotropic
beliefs) is :func:`stt_drake.core._tube.tube_step`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from stt_drake.core._anisotropic import avoid_gradient, quantile_radius
from stt_drake.core._kernels import chi_isf, chi_sf, ndtr, ndtri
from stt_drake.core.backend import jit_options
from stt_drake.core.constants import ISOTROPIC_RTOL

_JIT = jit_options()
#: The pruning bounds are inlined into the driver's loop (numba IR inlining: no call per
#: obstacle).
_INLINE = {**_JIT, "inline": "always"}

#: Jacobi sweeps stop when every off-diagonal entry is below this fraction of the largest
#: diagonal one: the eigenvalues are then exact to a few ulps of λ_max.
_JACOBI_TOLERANCE = 1e-17
_JACOBI_SWEEPS = 12


@njit(**_JIT)
def symmetric_eigen(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(variances (n,), axes (n, n), eigenvectors as columns) of a symmetric n×n matrix by
    cyclic Jacobi rotations (n ≤ 3: a few sweeps, no LAPACK call); Σ = axes·diag·axesᵀ."""
    n = matrix.shape[0]
    a = matrix.copy()
    axes = np.eye(n)
    for _sweep in range(_JACOBI_SWEEPS):
        largest = 0.0
        off = 0.0
        for i in range(n):
            largest = max(largest, abs(a[i, i]))
            for k in range(i + 1, n):
                off = max(off, abs(a[i, k]))
        if off <= _JACOBI_TOLERANCE * largest:
            break
        for p in range(n - 1):
            for r in range(p + 1, n):
                if a[p, r] == 0.0:
                    continue
                tau = (a[r, r] - a[p, p]) / (2.0 * a[p, r])
                t = math.copysign(1.0, tau) / (abs(tau) + math.sqrt(1.0 + tau * tau))
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = t * c
                for k in range(n):  # columns p, r of a·J
                    akp, akr = a[k, p], a[k, r]
                    a[k, p] = c * akp - s * akr
                    a[k, r] = s * akp + c * akr
                for k in range(n):  # rows p, r of Jᵀ·(a·J)
                    apk, ark = a[p, k], a[r, k]
                    a[p, k] = c * apk - s * ark
                    a[r, k] = s * apk + c * ark
                for k in range(n):
                    vkp, vkr = axes[k, p], axes[k, r]
                    axes[k, p] = c * vkp - s * vkr
                    axes[k, r] = s * vkp + c * vkr
    variances = np.empty(n)
    for i in range(n):
        variances[i] = a[i, i]
    return variances, axes


@njit(**_JIT)
def projected_sigma(offset: np.ndarray, covariances: np.ndarray, j: int, distance: float) -> float:
    """s = √(uᵀΣ_ju) for u = offset/distance (u = e_0 at distance 0), Σ_j = covariances[j]:
    the standard deviation of obstacle j's centre along the line to the point (the pruning
    bounds' σ). Σ_j is read in place: a view per obstacle would be reference counted."""
    n = offset.shape[0]
    if distance == 0.0:
        return math.sqrt(covariances[j, 0, 0])
    total = 0.0
    for i in range(n):
        for k in range(n):
            total += offset[i] * covariances[j, i, k] * offset[k]
    return math.sqrt(max(total, 0.0)) / distance


@njit(**_INLINE)
def anisotropic_bounds(
    distance: float,
    sigma: float,
    radius: float,
    epsilon: float,
    normal_quantile: float,
    r_min: float,
    prune_above: float,
) -> tuple[float, float]:
    """The pruning lower bounds of obstacle j (full covariance) at distance ‖c − μ_j‖, with
    s = `sigma` = :func:`projected_sigma`: q_j ≥ Φ((‖c − μ_j‖ − r_o − r_min)/s) and
    d̂_j ≥ max(‖c − μ_j‖ − s Φ⁻¹(ε), 0) − r_o (NaN where prune_above = −∞: d̂ not wanted;
    `normal_quantile` is Φ⁻¹(ε) where the caller has it, else NaN and computed here).
    Where q's bound exceeds p_d_j and d̂'s exceeds `prune_above`, they are the obstacle's
    terms (:func:`anisotropic_obstacle` is not needed). Scalars only: a call costs no
    reference counting."""
    q_lower = ndtr((distance - (radius + r_min)) / sigma)
    if prune_above == -math.inf:
        return q_lower, math.nan
    if math.isnan(normal_quantile):
        normal_quantile = ndtri(epsilon)
    return q_lower, max(distance - sigma * normal_quantile, 0.0) - radius


@njit(**_INLINE)
def isotropic_variance(covariance: np.ndarray) -> float:
    """σ² = tr Σ/n where Σ (n × n) is σ²I to rounding: every entry of Σ − σ²I within
    :data:`~stt_drake.core.constants.ISOTROPIC_RTOL` of the largest diagonal entry, and
    σ² > 0; NaN otherwise (also for a non-finite Σ)."""
    n = covariance.shape[0]
    variance = 0.0
    largest = 0.0
    for i in range(n):
        variance += covariance[i, i]
        largest = max(largest, covariance[i, i])
    variance /= n
    tolerance = ISOTROPIC_RTOL * largest
    for i in range(n):
        for k in range(n):
            entry = covariance[i, k] - variance if i == k else covariance[i, k]
            if not abs(entry) <= tolerance:
                return math.nan
    return variance if variance > 0.0 else math.nan


@njit(**_INLINE)
def isotropic_terms(
    offset: np.ndarray,
    distance: float,
    sigma: float,
    radius: float,
    epsilon: float,
    p_d: float,
    r_min: float,
    q_lower: float,
    d_lower: float,
    prune_above: float,
    unit: np.ndarray,
) -> tuple[float, float, bool]:
    """:func:`anisotropic_obstacle` for Σ_j = σ_j²I (`sigma` = σ_j, :func:`isotropic_variance`):
    the same terms and pruning by the noncentral χ law (Proposition 3.1: q_j of Eq. (5),
    d̂_j of Eq. (8)), with ∇̂q_j = (c − μ_j)/‖c − μ_j‖."""
    n = offset.shape[0]
    a = distance / sigma
    d_hat = d_lower
    if d_lower <= prune_above:
        d_hat = sigma * chi_isf(epsilon, a, n) - radius
    if not q_lower <= p_d:  # the bound decided q (a NaN bound too)
        return q_lower, d_hat, False
    q = chi_sf((radius + r_min) / sigma, a, n)
    if q > p_d:
        return q, d_hat, False
    for i in range(n):
        unit[i] = offset[i] / distance if distance > 0.0 else 0.0
    return q, d_hat, True


@njit(**_JIT)
def anisotropic_obstacle(
    offset: np.ndarray,
    distance: float,
    covariance: np.ndarray,
    radius: float,
    epsilon: float,
    p_d: float,
    r_min: float,
    q_lower: float,
    d_lower: float,
    prune_above: float,
    along: np.ndarray,
    unit: np.ndarray,
) -> tuple[float, float, bool]:
    """Obstacle j's terms for a full covariance Σ_j (`covariance`, n × n) at `offset`
    = c − μ_j (`distance` its norm) where a bound of :func:`anisotropic_bounds` (`q_lower`,
    `d_lower`) does not decide, the rules of :func:`stt_drake.core.anisotropic_tube.
    obstacle_terms`: the saddle-point d̂_j (Eq. (8)) where d_lower ≤ `prune_above`, the
    saddle-point q_j (Eq. (5)) where q_lower ≤ p_d_j, and there, if q_j ≤ p_d_j, `unit`
    = ∇̂q_j (its unit vector; the isotropic law's (c − μ_j)/‖c − μ_j‖ where q is
    stationary). `along` (n,) is a work buffer. A Σ_j that is σ_j²I to rounding takes
    :func:`isotropic_terms` (the contour integral would compute the same law at ~10× the cost).

    Returns:
        (q_j, d̂_j, whether obstacle j acts on ċ: q_j ≤ p_d_j); q_j and d̂_j are the bounds
        where those decided.
    """
    n = offset.shape[0]
    variance = isotropic_variance(covariance)
    if not math.isnan(variance):
        return isotropic_terms(
            offset,
            distance,
            math.sqrt(variance),
            radius,
            epsilon,
            p_d,
            r_min,
            q_lower,
            d_lower,
            prune_above,
            unit,
        )
    variances, axes = symmetric_eigen(covariance)
    along[:] = 0.0  # the offset in the eigenbasis, axesᵀ(c − μ_j)
    for i in range(n):
        for k in range(n):
            along[k] += axes[i, k] * offset[i]
    d_hat = d_lower
    if d_lower <= prune_above:
        d_hat = quantile_radius(variances, along, epsilon) - radius
    if not q_lower <= p_d:  # the bound decided q (a NaN bound too)
        return q_lower, d_hat, False
    q, gradient = avoid_gradient(variances, along, radius + r_min)
    if q > p_d:
        return q, d_hat, False
    size = 0.0  # ∇_c q_j = axes·gradient; its unit vector is the direction of m_j
    for i in range(n):
        unit[i] = 0.0
        for k in range(n):
            unit[i] += axes[i, k] * gradient[k]
        size += unit[i] * unit[i]
    size = math.sqrt(size)
    for i in range(n):
        if size > 0.0:
            unit[i] /= size
        else:  # q stationary (c = μ_j): the isotropic law's direction, or none
            unit[i] = offset[i] / distance if distance > 0.0 else 0.0
    return q, d_hat, True
