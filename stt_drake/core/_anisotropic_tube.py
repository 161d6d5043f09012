"""Compiled tube law for obstacles with a full covariance, O_j ~ N(μ_j, Σ_j) (n = 2, 3).

The law, its reduction to the paper's and the pruning bounds are documented in
:mod:`stt_drake.core.anisotropic_tube` (with the numpy reference of the per-obstacle
terms); this module is the one-call kernel the Drake system runs, selected by
:mod:`stt_drake.core.backend`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Numba's cache keys each kernel on its own file only: a change to a callee in _anisotropic.py
# is not seen by the cached anisotropic_tube_step until this file changes too (or the
# __pycache__/*.nbi index is removed). Last callee change: the quantile's fifth-order step.
from stt_drake.core._anisotropic import avoid_gradient, quantile_radius
from stt_drake.core._kernels import (
    _attraction,
    _finish_rate,
    _obstacle_terms,
    ndtr,
    ndtri,
    soft_min_radius,
)

_JIT = {"cache": True, "error_model": "numpy", "nogil": True}

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
def projected_sigma(offset: np.ndarray, covariance: np.ndarray, distance: float) -> float:
    """s = √(uᵀΣu) for u = offset/distance (u = e_0 at distance 0): the standard deviation
    of the obstacle centre along the line to the point (the pruning bounds' σ)."""
    n = offset.shape[0]
    if distance == 0.0:
        return math.sqrt(covariance[0, 0])
    total = 0.0
    for i in range(n):
        for k in range(n):
            total += offset[i] * covariance[i, k] * offset[k]
    return math.sqrt(max(total, 0.0)) / distance


@njit(**_JIT)
def anisotropic_tube_step(
    center: np.ndarray,
    mean: np.ndarray,
    covariance: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    p_d: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`stt_drake.core.tube.TubeLaw.evaluate` for a belief with covariances in one
    call (the rules and bounds of :mod:`stt_drake.core.anisotropic_tube`, whose
    :func:`~stt_drake.core.anisotropic_tube.obstacle_terms` is the numpy reference of the
    per-obstacle part): `covariance` (m, n, n); `constants` laid out as
    :data:`stt_drake.core._kernels.TUBE_CONSTANTS` followed by η.

    Returns:
        (ċ, r, q, d̂, θ); q_j and d̂_j are the pruning lower bounds where those decided.
    """
    k1 = constants[0]
    r_min = constants[1]
    r_max = constants[2]
    nu = constants[3]
    linear_zone = constants[4]
    prune_above = constants[5]
    max_speed = constants[6]
    target = constants[7:]
    count, n = mean.shape
    q = np.empty(count)
    d_hat = np.empty(count)
    theta = np.zeros(count)
    goal = np.empty(n)
    rate = np.empty(n)
    escape = np.zeros(n)
    share = 0.0
    no_axis = np.empty(0)
    _attraction(center, target, k1, linear_zone, goal, rate)
    offset = np.empty(n)
    direction = np.empty(n)
    m = np.empty(n)
    variances = np.empty(n)
    axes = np.empty((n, n))
    along = np.empty(n)  # the offset in the eigenbasis, axesᵀ(c − μ_j)
    for j in range(count):
        distance = 0.0
        for i in range(n):
            offset[i] = center[i] - mean[j, i]
            distance += offset[i] * offset[i]
        distance = math.sqrt(distance)
        sigma_u = projected_sigma(offset, covariance[j], distance)
        reach = radius[j] + r_min
        eps = epsilon[j]
        q_lower = ndtr((distance - reach) / sigma_u)
        d_lower = max(distance - sigma_u * ndtri(eps), 0.0) - radius[j]
        need_q = q_lower <= p_d[j]
        need_d = prune_above != -math.inf and d_lower <= prune_above
        if need_q or need_d:
            variances, axes = symmetric_eigen(covariance[j])
            along[:] = 0.0
            for i in range(n):
                for k in range(n):
                    along[k] += axes[i, k] * offset[i]
        if prune_above == -math.inf:
            d_hat[j] = math.nan
        elif need_d:
            d_hat[j] = quantile_radius(variances, along, eps) - radius[j]
        else:
            d_hat[j] = d_lower
        if not need_q:
            q[j] = q_lower
            continue
        qj, gradient = avoid_gradient(variances, along, reach)
        q[j] = qj
        if qj > p_d[j]:
            continue
        size = 0.0  # ∇_c q_j = axes·gradient; its unit vector is the direction of m_j
        for i in range(n):
            direction[i] = 0.0
            for k in range(n):
                direction[i] += axes[i, k] * gradient[k]
            size += direction[i] * direction[i]
        size = math.sqrt(size)
        for i in range(n):
            if size > 0.0:
                direction[i] /= size
            else:  # q stationary (c = μ_j): the isotropic law's direction, or none
                direction[i] = offset[i] / distance if distance > 0.0 else 0.0
        axis = circulation[j] if circulation.shape[0] == count else no_axis
        theta[j], weight = _obstacle_terms(
            rate,
            escape,
            m,
            direction,
            distance,
            qj,
            eps,
            p_d[j],
            k2,
            k3,
            j,
            axis,
            goal,
            max_speed,
        )
        share = max(share, weight)
    _finish_rate(rate, share, escape, goal, max_speed)
    return rate, soft_min_radius(d_hat, r_max, nu), q, d_hat, theta
