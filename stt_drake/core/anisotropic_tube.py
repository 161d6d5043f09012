"""The tube law of Sec. 3 for obstacles with a full covariance, O_j ~ N(μ_j, Σ_j).

The paper restricts Σ_j to σ_j²I. With a full Σ_j (n = 2, 3) the law keeps its structure
(Eq. (4), (14)); only the per-obstacle quantities change:

* q_j(c) = P(‖c − O_j‖ ≥ r_o_j + r_min) (Eq. (5)) is a generalized chi-square tail,
  computed exactly by :mod:`stt_drake.core.anisotropic`; θ_j = 1/q_j − 1/p_d_j as before.
* m_j = ‖c − μ_j‖ · ∇_c q_j/‖∇_c q_j‖ / (q_j − ε_j): along the gradient of q_j, scaled by
  1/(q_j − ε_j). For Σ_j = σ_j²I, q_j depends on c only through ‖c − μ_j‖ and increases
  with it, so ∇_c q_j = q_j′(‖c − μ_j‖)·(c − μ_j)/‖c − μ_j‖ with q_j′ > 0 and m_j is exactly
  the paper's (c − μ_j)/(q_j − ε_j) (the factor ‖c − μ_j‖ keeps the gains k2, k3 of the
  isotropic scenarios meaning the same; tests/core/test_anisotropic_tube.py checks the
  reduction against the isotropic kernel).
* v_j ⟂ m_j as in the isotropic law (:func:`stt_drake.core.circulation.null_space_direction`).
* d̂_j(c) = √Q_Y(1 − ε_j) − r_o_j (Eq. (8)) with Y = ‖c − O_j‖², the generalized chi-square
  quantile; r(t) is the soft-min of Eq. (14), unchanged.
* The boundary layer and the recovery (:mod:`stt_drake.core.tube`) escape along
  Σ_k w_k ∇̂q_k, the direction in which each q_k increases fastest (for Σ = σ²I, the
  paper's (c − μ_k)/‖c − μ_k‖).

Why claims (ii) and (iii) of Theorem 3.2 still hold. The proof of (ii) uses only that, as
q_j ↓ ε_j, the term k2·θ_j·m_j grows without bound along a direction that increases q_j
(dq_j/dt = ∇q_j·ċ, and ∇q_j·m_j = ‖c − μ_j‖‖∇q_j‖/(q_j − ε_j) → +∞ while the attraction,
the other obstacles' bounded terms and v_j (⟂ m_j, so ⟂ ∇q_j: it does not change q_j to
first order) stay bounded); with the boundary layer the centre leaves a level set at
v_c·∇̂q_j, where dq_j/dt = v_c‖∇q_j‖ > 0. Claim (iii), r ≤ d̂_j, uses only the quantile's
definition: P(‖c − O_j‖ ≥ r_o_j + d̂_j) = ε_j, so the whole ball B(c, r) with r ≤ d̂_j is
avoided with probability ≥ ε_j — true for any distribution of O_j. ∇q_j = 0 only where q_j
is stationary (at c = μ_j for an ellipsoidal Gaussian, deep inside the obstacle), where the
law falls back to (c − μ_j)/‖c − μ_j‖ and then to the goal direction as the isotropic one.

Pruning (what makes 50 obstacles cost microseconds). For any unit u, ‖c − O‖ ≥ |u·(c − O)|,
and u·(c − O) ~ N(u·(c − μ), s²) with s² = uᵀΣu. With u = (c − μ)/‖c − μ‖:

    q_j ≥ Φ((‖c − μ_j‖ − R_j)/s_j)                      (R_j = r_o_j + r_min),
    d̂_j ≥ max(‖c − μ_j‖ − s_j Φ⁻¹(ε_j), 0) − r_o_j       (P(‖c − O‖ ≥ ‖c−μ‖ − sΦ⁻¹(ε)) ≥ ε).

(Both are the isotropic kernel's bounds with σ → s_j; both are exact in 1D.) Where the first
exceeds p_d_j the obstacle cannot act (θ_j = 0, no boundary-layer weight), and q_j is not
computed: the returned q_j is then that lower bound (> p_d_j). Where the second exceeds the
law's :attr:`~stt_drake.core.tube.TubeLaw.anisotropic_prune_above` = r_max + 25/ν the
quantile is not computed and the bound is used and returned: its soft-min weight is below
e^{−25} of the r_max term, and a lower bound in the soft-min only lowers r (so r ≤ d̂_j
still holds), by less than n_o·e^{−25}/ν. (The isotropic law prunes at r_max + 40/ν; here a
quantile costs a contour integral, and in the 3D bench field the headroom 25 computes 2
quantiles where 40 computes 6.)
Everything else is exact: the eigen-decomposition, q_j and ∇q_j (one contour integral), d̂_j
(Halley on the same contour).

A Σ_j that is σ_j²I to rounding (every entry of Σ_j − σ_j²I within
:data:`~stt_drake.core.constants.ISOTROPIC_RTOL` of its largest diagonal entry, σ_j² = tr Σ_j/n)
takes the noncentral χ law of :mod:`stt_drake.core.probability` instead of the contour
integral: the same law (the isotropic case of :mod:`stt_drake.core.anisotropic`), its
probabilities moved by less than 5e-12, at about a tenth of the cost. A tracker's covariance
is often exactly that: a Kalman filter with isotropic noises keeps it σ²I to ~1e-15.

This module is the numpy reference (:func:`obstacle_terms`); the compiled kernel is
:func:`stt_drake.core._tube.exact_tube_step`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr, ndtri

from stt_drake.core import anisotropic, probability
from stt_drake.core.constants import ISOTROPIC_RTOL


def pruning_bounds(
    center: np.ndarray,
    mean: np.ndarray,
    covariance: np.ndarray,
    radius: float,
    epsilon: float,
    r_min: float,
) -> tuple[float, float, float]:
    """(‖c − μ‖, lower bound of q, lower bound of d̂) for one obstacle (module docstring)."""
    offset = np.asarray(center, dtype=float) - mean
    distance = float(np.linalg.norm(offset))
    unit = offset / distance if distance > 0.0 else np.eye(len(offset))[0]
    spread = float(np.sqrt(max(unit @ covariance @ unit, 0.0)))
    q_lower = float(ndtr((distance - (radius + r_min)) / spread))
    d_lower = max(distance - spread * float(ndtri(epsilon)), 0.0) - radius
    return distance, q_lower, d_lower


def isotropic_variance(covariance: np.ndarray) -> float | None:
    """σ² = tr Σ/n where Σ is σ²I to rounding (every entry of Σ − σ²I within
    :data:`~stt_drake.core.constants.ISOTROPIC_RTOL` of Σ's largest diagonal entry, σ² > 0),
    else None: there the law's terms are the noncentral χ law's (Proposition 3.1)."""
    diagonal = np.diag(covariance)
    variance = float(np.mean(diagonal))
    deviation = np.abs(covariance - variance * np.eye(len(diagonal)))
    if variance > 0.0 and np.all(deviation <= ISOTROPIC_RTOL * np.max(diagonal)):
        return variance
    return None


def obstacle_terms(
    center: np.ndarray,
    mean: np.ndarray,
    covariance: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    p_d: np.ndarray,
    r_min: float,
    prune_above: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per obstacle: q_j, d̂_j and the unit direction ∇̂q_j of m_j (zero where it is not
    needed, i.e. where q_j > p_d_j), with the pruning of the module docstring
    (`prune_above` None: every d̂_j exact; −∞: d̂_j not wanted, NaN). A Σ_j that is σ_j²I to
    rounding (:func:`isotropic_variance`) takes the noncentral χ law of
    :mod:`stt_drake.core.probability` (the same law; the contour integral costs ~10× more)."""
    count, n = mean.shape
    q = np.empty(count)
    d_hat = np.full(count, np.nan)
    direction = np.zeros((count, n))
    for j in range(count):
        distance, q_lower, d_lower = pruning_bounds(
            center, mean[j], covariance[j], radius[j], epsilon[j], r_min
        )
        variance = isotropic_variance(covariance[j])
        # Σ_j = σ_j²I: σ_j as the isotropic law's (1,) array, obstacle j as its (1,) slices
        sigma = None if variance is None else np.sqrt([variance])
        one = slice(j, j + 1)
        if prune_above is None or (prune_above != -np.inf and d_lower <= prune_above):
            if sigma is None:
                d_hat[j] = anisotropic.quantile_distance(
                    center, mean[j], covariance[j], radius[j], epsilon[j]
                )
            else:
                d_hat[j] = probability.quantile_distance(
                    center, mean[one], sigma, radius[one], epsilon[one]
                )[0]
        elif prune_above != -np.inf:
            d_hat[j] = d_lower
        if q_lower > p_d[j]:
            q[j] = q_lower
            continue
        reach = radius[j] + r_min
        if sigma is not None:
            q[j] = probability.avoid_probability(center, mean[one], sigma, reach)[0]
            if q[j] <= p_d[j] and distance > 0.0:
                direction[j] = (center - mean[j]) / distance
            continue
        q[j] = anisotropic.avoid_probability(center, mean[j], covariance[j], reach)
        if q[j] > p_d[j]:
            continue
        gradient = anisotropic.avoid_probability_gradient(center, mean[j], covariance[j], reach)
        size = float(np.linalg.norm(gradient))
        if size > 0.0:
            direction[j] = gradient / size
        elif distance > 0.0:
            direction[j] = (center - mean[j]) / distance
    return q, d_hat, direction
