"""Compiled (numba) kernel of the invariant monitor's probabilities for beliefs with full
covariances (:func:`stt_drake.core.invariants.evaluate_invariants`): per obstacle, Σ_j
checked and decomposed once, then the three avoid probabilities of the guarantees at the
tube centre and at the output, by the contour integral of :mod:`stt_drake.core._anisotropic`
(not the tube's kernel: the monitor does not share the tube's code path).

Arrays, for m obstacles in dimension n (2 or 3): ``mean`` (m, n) and ``covariance``
(m, n, n) of each centre (m, m²), ``obstacle_radius`` (m,) r_o (m).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from stt_drake.core._anisotropic import ball_probabilities
from stt_drake.core._kernels import _distance, _nan_min, active_covariances
from stt_drake.core.backend import jit_options
from stt_drake.core.constants import HIT_NEGLIGIBLE_SIGMAS

_JIT = jit_options()


@njit(**_JIT)
def _half_sum(matrix: np.ndarray, half: np.ndarray, symmetry_rtol: float) -> bool:
    """`half` ← (Σ + Σᵀ)/2; whether Σ is finite and symmetric within `symmetry_rtol` ·
    max|Σ| (the rules of :func:`stt_drake.core.anisotropic.eigen_decomposition`)."""
    n = matrix.shape[0]
    size = 0.0
    for i in range(n):
        for k in range(n):
            if not math.isfinite(matrix[i, k]):
                return False
            size = max(size, abs(matrix[i, k]))
    for i in range(n):
        for k in range(n):
            if abs(matrix[i, k] - matrix[k, i]) > symmetry_rtol * size:
                return False
            half[i, k] = 0.5 * (matrix[i, k] + matrix[k, i])
    return True


@njit(**_JIT)
def anisotropic_invariants(
    output: np.ndarray,
    center: np.ndarray,
    radius: float,
    mean: np.ndarray,
    covariance: np.ndarray,
    obstacle_radius: np.ndarray,
    r_min: float,
    symmetry_rtol: float,
    max_condition: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(q (m, 3), valid (m,)): per obstacle j the avoid probabilities
    [q_j(c) with r_o + r_min, q_j(c) with r_o + max(r, 0), q_j(y) with r_o] for a tube of
    centre `center` and radius `radius` and the output `output`; `valid` is False (and the
    row NaN) where Σ_j breaks a rule of
    :func:`stt_drake.core.anisotropic.eigen_decomposition` (finite, symmetric, positive
    definite, eigenvalue ratio ≤ `max_condition`)."""
    count, n = mean.shape
    q = np.full((count, 3), np.nan)
    valid = np.zeros(count, dtype=np.bool_)
    radii = np.empty(3)
    half = np.empty((n, n))
    for j in range(count):
        if not _half_sum(covariance[j], half, symmetry_rtol):
            continue
        variances, axes = np.linalg.eigh(half)
        if not (variances[0] > 0.0 and variances[-1] <= max_condition * variances[0]):
            continue
        radii[0] = obstacle_radius[j] + r_min
        radii[1] = obstacle_radius[j] + max(radius, 0.0)
        radii[2] = obstacle_radius[j]
        negligible = HIT_NEGLIGIBLE_SIGMAS * math.sqrt(variances[-1])
        for k in range(3):
            point = output if k == 2 else center
            # ‖point − μ_j‖; rotated into Σ_j's frame only where integrated
            if _distance(point, mean, j) > radii[k] + negligible:
                q[j, k] = 1.0  # a hit below half an ulp of 1 (HIT_NEGLIGIBLE_SIGMAS)
            else:
                q[j, k] = ball_probabilities(variances, (point - mean[j]) @ axes, radii[k])[1]
        valid[j] = True
    return q, valid


@njit(**_JIT)
def anisotropic_invariants_packed(
    output: np.ndarray,
    tube: np.ndarray,
    belief: np.ndarray,
    task: np.ndarray,
    r_min: float,
    symmetry_rtol: float,
    max_condition: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """The margins of :func:`stt_drake.core.invariants.evaluate_tube_invariants` with full
    covariances, on port vectors: tube = [c, r], the belief port vector and the task rows
    ([r_o, ε, p_d, …] per slot); the active slots only (the inactive ones: probability 1).

    Returns:
        (margins (5,), P(‖y − O_j‖ ≥ r_o_j) per slot, P(‖c − O_j‖ ≥ r_o_j + r) per slot,
        valid): `valid` is False where some active Σ_j breaks a rule of
        :func:`anisotropic_invariants` (the caller names it; the margins are then NaN).
    """
    n = output.shape[0]
    slots, mean, covariance, rows = active_covariances(belief, task, n)
    radius = tube[n]
    q, valid = anisotropic_invariants(
        output, tube[:n], radius, mean, covariance, rows[:, 0], r_min, symmetry_rtol, max_condition
    )
    margins = np.empty(5)
    offset = 0.0
    for i in range(n):
        offset += (output[i] - tube[i]) ** 2
    margins[0] = radius - math.sqrt(offset)
    worst = np.ones(3)  # with no obstacle a probability margin is vacuous: 1 > every 1 − ε
    output_q = np.ones(task.shape[0])
    tube_q = np.ones(task.shape[0])
    for k in range(slots.shape[0]):
        for column in range(3):
            worst[column] = _nan_min(worst[column], q[k, column] - rows[k, 1])
        tube_q[slots[k]] = q[k, 1]
        output_q[slots[k]] = q[k, 2]
    margins[1] = worst[0]
    margins[2] = worst[1]
    margins[3] = worst[2]
    margins[4] = radius
    return margins, output_q, tube_q, bool(np.all(valid))
