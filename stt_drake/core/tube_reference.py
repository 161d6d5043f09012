"""The numpy reference of the tube law's evaluation (:meth:`stt_drake.core.tube.TubeLaw.evaluate`,
Eqs. (4), (5), (8), (14) with the boundary layer and the recovery of
:mod:`stt_drake.core.tube`): any n, and the path ``STT_DRAKE_PURE_NUMPY=1`` selects. The
compiled kernels (:func:`stt_drake.core._tube.tube_step`,
:func:`stt_drake.core._tube.exact_tube_step`) compute the same.
"""

from __future__ import annotations

import math

import numpy as np

from stt_drake.core.anisotropic_tube import obstacle_terms
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.circulation import null_space_direction
from stt_drake.core.probability import (
    avoid_probability,
    period_avoid_probability,
    quantile_distance,
)
from stt_drake.core.tube_terms import (
    LawConstants,
    TubeEvaluation,
    boundary_layer_weights,
    signed_cube_root_attraction,
)


def evaluate_reference(
    law: LawConstants,
    center: np.ndarray,
    belief: ObstacleBelief,
    prune_above: float | None,
    circulation: np.ndarray | None = None,
    inflation: tuple[np.ndarray, np.ndarray] | None = None,
) -> TubeEvaluation:
    """ċ, r and the diagnostics of `law` at `center` for the obstacles of `belief` (not per
    slot: the caller spreads them). `prune_above`: d̂_j provably above it is not computed
    (None: every d̂_j exact; −∞: none wanted, d̂ and r NaN); `circulation` (m, 3) axes;
    `inflation` (Δ, γ): q_j, θ_j and ċ use the period lower bound of q_j (isotropic only)."""
    safety_radius = belief.radius + law.r_min
    offset = center - belief.mean
    distance = np.linalg.norm(offset, axis=1)
    if belief.covariance is not None:  # q_j, d̂_j and ∇̂q_j with Σ_j (pruned alike)
        q, d_hat, unit = obstacle_terms(
            center,
            belief.mean,
            np.asarray(belief.covariance).reshape(belief.count, belief.dimension, -1),
            belief.radius,
            belief.epsilon,
            belief.p_d,
            law.r_min,
            prune_above,
        )
    else:  # q_j depends on ‖c − μ_j‖ only: ∇̂q_j = (c − μ_j)/‖c − μ_j‖
        if inflation is None:
            q = avoid_probability(center, belief.mean, belief.sigma, safety_radius)
        else:
            q = period_avoid_probability(
                center, belief.mean, belief.sigma, safety_radius, *inflation
            )
        d_hat = quantile_distance(
            center, belief.mean, belief.sigma, belief.radius, belief.epsilon, prune_above
        )
        positive = distance[:, None] > 0.0
        unit = np.where(positive, offset / np.where(positive, distance[:, None], 1.0), 0.0)
    active = q <= belief.p_d
    violated = q <= belief.epsilon
    theta = np.zeros_like(q)
    # In recovery θ_j is unused; it is reported at its largest in-law value 1/ε − 1/p_d.
    theta[active] = 1.0 / np.maximum(q[active], belief.epsilon[active]) - 1.0 / belief.p_d[active]
    goal_direction = law.target - center
    rate = signed_cube_root_attraction(goal_direction, law.k1, law.linear_zone)
    law_terms = active & ~violated
    if np.any(law_terms):
        gap = q[law_terms] - belief.epsilon[law_terms]
        # m_j = ‖c − μ_j‖·∇̂q_j/(q_j − ε_j): the paper's (c − μ_j)/(q_j − ε_j) for Σ = σ²I
        m = (distance[law_terms] / gap)[:, None] * unit[law_terms]
        axes = None if circulation is None else np.asarray(circulation)[law_terms]
        v = null_space_direction(m, goal_direction, axes)
        k2 = np.broadcast_to(law.k2, q.shape)[law_terms]
        k3 = np.broadcast_to(law.k3, q.shape)[law_terms]
        weights = theta[law_terms, None]
        rate = rate + np.sum((k2[:, None] * m + k3[:, None] * v) * weights, axis=0)
    speed = float(np.linalg.norm(rate))
    if speed > law.max_center_speed:
        rate = rate * (law.max_center_speed / speed)
    if math.isfinite(law.max_center_speed):
        layer = boundary_layer_weights(q, belief.epsilon, belief.p_d)
    else:  # unbounded: no layer, only the recovery
        layer = violated * 1.0
    share = float(np.max(layer, initial=0.0))
    if share > 0.0:
        escape = _recovery_velocity(
            law.max_center_speed, unit[layer > 0.0], goal_direction, layer[layer > 0.0]
        )
        rate = escape if share == 1.0 else (1.0 - share) * rate + share * escape
    return TubeEvaluation(
        center_rate=rate,
        radius=law.radius(d_hat),
        avoid_probability=q,
        quantile_distance=d_hat,
        theta=theta,
    )


def _recovery_velocity(
    max_center_speed: float, unit: np.ndarray, goal_direction: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """v_c along Σ w_j ∇̂q_j over the obstacles in the boundary layer (∇̂q_j =
    (c − μ_j)/‖c − μ_j‖ for Σ_j = σ_j²I), the goal direction, else e_0, when those cancel."""
    escape = np.sum(weights[:, None] * unit, axis=0)
    for direction in (escape, goal_direction):
        size = float(np.linalg.norm(direction))
        if size > 1e-9:
            # An infinite v_c (unbounded) makes ċ not finite, as documented: ±inf along
            # the direction and inf·0 = NaN across it, exactly as the compiled kernel's
            # IEEE arithmetic gives; that NaN is the intended answer, not a warning.
            with np.errstate(invalid="ignore"):
                return max_center_speed * direction / size
    rate = np.zeros_like(goal_direction, dtype=float)
    rate[0] = max_center_speed
    return rate
