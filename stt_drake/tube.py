"""The spatiotemporal tube law (paper Sec. 3): centre velocity, radius and diagnostics.

One call of :meth:`TubeLaw.evaluate` gives, for the tube centre c and the belief of all
obstacles, the centre velocity ċ of eq. (cen_dynamic), the radius r of eq. (rad_sol) and
per-obstacle diagnostics (q_j, d̂_j, θ_j).

Fixes to the printed paper (see DESIGN.md):
* the attraction term is the signed cube root per component, k1·sign(η − c)|η − c|^{1/3};
* the radius is the log-sum-exp soft-min r = −(1/ν) ln(e^{−ν r_max} + Σ_j e^{−ν d̂_j}),
  which is always ≤ min(r_max, min_j d̂_j); it stays > 0 only if ν > ln(n_o + 1)/r_min.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from stt_drake import backend
from stt_drake.belief import ObstacleBelief, record_size
from stt_drake.probability import (
    COMPILED_DIMENSIONS,
    PRUNE_HEADROOM_NU,
    avoid_probability,
    quantile_distance,
)


def minimum_nu(obstacle_count: int, r_min: float) -> float:
    """Smallest ν for which the soft-min radius is provably positive (claim iii).

    Every d̂_j > r_min while q_j > ε_j, so r ≥ r_min − ln(n_o + 1)/ν.
    """
    return float(np.log(obstacle_count + 1) / r_min)


def default_nu(obstacle_count: int, r_min: float) -> float:
    """Twice :func:`minimum_nu`: guarantees r ≥ r_min/2 whenever every q_j > ε_j."""
    return 2.0 * minimum_nu(obstacle_count, r_min)


def signed_cube_root_attraction(
    error: np.ndarray, k1: float, linear_zone: float = 0.0
) -> np.ndarray:
    """k1·sign(e)|e|^{1/3} per component: the finite-time attraction of eq. (cen_dynamic).

    The cube root is not Lipschitz at e = 0: an error-controlled integrator chatters
    around η with ever smaller steps (measured: 3100 steps/s once c reached η). Within
    |e_i| < `linear_zone` the term is k1·e_i·δ^{-2/3} instead (continuous at δ), i.e. an
    exponential settle with time constant δ^{2/3}/k1. With δ = (k1·h)^{3/2}, h the largest
    integrator step, that time constant is h and δ is the overshoot a step of h would have
    anyway. Finite-time reach then holds to within δ, after which c → η exponentially.
    """
    if linear_zone <= 0.0:
        return k1 * np.cbrt(error)
    linear = error * linear_zone ** (-2.0 / 3.0)
    return k1 * np.where(np.abs(error) < linear_zone, linear, np.cbrt(error))


def linear_zone_for_step(k1: float, max_step: float) -> float:
    """δ = (k1·h)^{3/2}: the attraction's linear zone for an integrator step of at most h."""
    return float((k1 * max_step) ** 1.5)


def attraction_flow(error: np.ndarray, k1: float, duration: float) -> np.ndarray:
    """Exact change of c over `duration` under ċ = k1·cbrt(η − c) alone (eq. cen_simplified).

    Per component, |e|^{2/3} decreases linearly at rate 2k1/3 until it reaches 0, so the
    flow never overshoots η, whatever the step.
    """
    remaining = np.maximum(np.abs(error) ** (2.0 / 3.0) - (2.0 / 3.0) * k1 * duration, 0.0)
    return error - np.sign(error) * remaining**1.5


def attraction_reach_time(error: np.ndarray, k1: float) -> float:
    """Time for the attraction alone to bring c to η: max_i 3|e_i|^{2/3}/(2 k1)."""
    return float(np.max(3.0 * np.abs(error) ** (2.0 / 3.0) / (2.0 * k1)))


def null_space_direction(m: np.ndarray, goal_direction: np.ndarray) -> np.ndarray:
    """v_j ⟂ m_j with |v_j| = |m_j|, varying continuously with m_j (rows are obstacles).

    n = 2: m rotated by +90°. n ≥ 3: the part of the goal direction orthogonal to m,
    falling back to a fixed axis (e_z, then e_x) where the goal direction is parallel to m.
    n = 1: zero (R¹ has no orthogonal direction).
    """
    count, dimension = m.shape
    if dimension == 1:
        return np.zeros_like(m)
    if dimension == 2:
        return np.column_stack([-m[:, 1], m[:, 0]])
    norm_m = np.linalg.norm(m, axis=1, keepdims=True)
    unit_m = m / np.where(norm_m > 0.0, norm_m, 1.0)
    direction = np.empty_like(m)
    candidates = [np.broadcast_to(goal_direction, m.shape)]
    for axis in (dimension - 1, 0):
        candidates.append(np.broadcast_to(np.eye(dimension)[axis], m.shape))
    chosen = np.zeros(count, dtype=bool)
    for candidate in candidates:
        orthogonal = candidate - np.sum(candidate * unit_m, axis=1, keepdims=True) * unit_m
        length = np.linalg.norm(orthogonal, axis=1)
        usable = ~chosen & (length > 1e-6 * np.maximum(np.linalg.norm(candidate, axis=1), 1e-300))
        direction[usable] = orthogonal[usable] / length[usable, None]
        chosen |= usable
    return direction * norm_m


@dataclass(frozen=True)
class TubeEvaluation:
    """Everything the tube law gives at one instant.

    Attributes:
        center_rate: (n,) ċ of eq. (cen_dynamic), m/s.
        radius: r of eq. (rad_sol), metres.
        avoid_probability: (m,) q_j(c, t) of eq. (prob_q).
        quantile_distance: (m,) d̂_j of eq. (m_crv), metres (a lower bound where pruned).
        theta: (m,) switching gains θ_j.
    """

    center_rate: np.ndarray
    radius: float
    avoid_probability: np.ndarray
    quantile_distance: np.ndarray
    theta: np.ndarray


@dataclass(frozen=True)
class TubeLaw:
    """Centre and radius law of the STT (eqs. cen_dynamic, prob_q, m_crv, rad_sol).

    Attributes:
        target: (n,) η, the point the centre is pulled to.
        k1: attraction gain (> 0).
        k2: avoidance gain along m_j (> 0), scalar or one per obstacle.
        k3: gain along v_j ⟂ m_j (≥ 0), scalar or one per obstacle.
        r_min: buffer added to each obstacle radius in q_j (> 0).
        r_max: largest tube radius (> r_min).
        nu: soft-min sharpness; must exceed ln(n_o + 1)/r_min for claim (iii).
        linear_zone: δ of :func:`signed_cube_root_attraction` (metres; 0 = exact cube root).
    """

    target: np.ndarray
    k1: float
    k2: np.ndarray | float
    k3: np.ndarray | float
    r_min: float
    r_max: float
    nu: float
    linear_zone: float = 0.0

    def radius(self, quantile_distance: np.ndarray) -> float:
        """Soft-min radius r = −(1/ν) ln(e^{−ν r_max} + Σ e^{−ν d̂_j}) (eq. rad_sol).

        Shifted by the hard minimum before exponentiating, so nothing under/overflows.
        """
        values = np.append(quantile_distance, self.r_max)
        smallest = np.min(values)
        return float(smallest - np.log(np.sum(np.exp(-self.nu * (values - smallest)))) / self.nu)

    @property
    def prune_above(self) -> float:
        """d̂_j provably above r_max + PRUNE_HEADROOM_NU/ν is not computed exactly: its
        soft-min weight e^{−ν d̂_j} is below e^{−40} of the r_max term, so r moves by less
        than n_o·e^{−40}/ν (≈ 4e-18·n_o/ν m), and ċ, q_j, θ_j do not depend on d̂_j at all."""
        return self.r_max + PRUNE_HEADROOM_NU / self.nu

    @cached_property
    def _kernel_constants(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(k2, k3, constants, constants without pruning) as float arrays for the compiled
        kernel (layout: :data:`stt_drake.kernels.TUBE_CONSTANTS`, then η); once per law."""
        head = [self.k1, self.r_min, self.r_max, self.nu, self.linear_zone]
        target = np.asarray(self.target, dtype=float).ravel()
        return (
            np.atleast_1d(np.array(self.k2, dtype=float)).ravel(),
            np.atleast_1d(np.array(self.k3, dtype=float)).ravel(),
            np.array([*head, self.prune_above, *target], dtype=float),
            np.array([*head, np.inf, *target], dtype=float),
        )

    def _gains_for(self, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        constants = self._kernel_constants
        if constants[0].size not in (1, count) or constants[1].size not in (1, count):
            raise ValueError(
                f"k2/k3: need one gain or one per obstacle ({count}), "
                f"got {constants[0].size} and {constants[1].size}"
            )
        return constants

    def evaluate(
        self, center: np.ndarray, belief: ObstacleBelief, prune: bool = True
    ) -> TubeEvaluation:
        """Evaluate ċ, r and the diagnostics at the centre `center` (n,).

        One call of the compiled :func:`stt_drake.kernels.tube_step` for n ≤ 3 (unless the
        numpy path is selected, see :mod:`stt_drake.backend`), else the numpy reference
        below. `prune=False` computes every d̂_j exactly (see :attr:`prune_above`).
        """
        kernels = backend.kernels()
        if kernels is None or belief.mean.shape[-1] not in COMPILED_DIMENSIONS:
            return self._evaluate_numpy(center, belief, prune)
        k2, k3, pruned, unpruned = self._gains_for(belief.mean.shape[0])
        return TubeEvaluation(
            *kernels.tube_step(
                np.asarray(center, dtype=float),
                belief.mean,
                belief.sigma,
                belief.radius,
                belief.epsilon,
                belief.p_d,
                k2,
                k3,
                pruned if prune else unpruned,
            )
        )

    def evaluate_packed(
        self, center: np.ndarray, belief_vector: np.ndarray, prune: bool = True
    ) -> TubeEvaluation:
        """:meth:`evaluate` on a belief port vector (layout of :mod:`stt_drake.belief`),
        without building the :class:`ObstacleBelief` (the Drake system's hot path)."""
        kernels = backend.kernels()
        dimension = len(center)
        if (
            kernels is None
            or dimension not in COMPILED_DIMENSIONS
            or len(belief_vector) % record_size(dimension)  # from_vector names the problem
        ):
            belief = ObstacleBelief.from_vector(belief_vector, dimension)
            return self._evaluate_numpy(center, belief, prune)
        k2, k3, pruned, unpruned = self._gains_for(len(belief_vector) // record_size(dimension))
        return TubeEvaluation(
            *kernels.tube_step_packed(
                np.asarray(center, dtype=float),
                np.asarray(belief_vector, dtype=float),
                k2,
                k3,
                pruned if prune else unpruned,
            )
        )

    def _evaluate_numpy(
        self, center: np.ndarray, belief: ObstacleBelief, prune: bool = True
    ) -> TubeEvaluation:
        """The numpy reference of :meth:`evaluate` (any n)."""
        q = avoid_probability(center, belief.mean, belief.sigma, belief.radius + self.r_min)
        d_hat = quantile_distance(
            center,
            belief.mean,
            belief.sigma,
            belief.radius,
            belief.epsilon,
            prune_above=self.prune_above if prune else None,
        )
        active = q <= belief.p_d
        theta = np.zeros_like(q)
        theta[active] = 1.0 / q[active] - 1.0 / belief.p_d[active]
        goal_direction = self.target - center
        rate = signed_cube_root_attraction(goal_direction, self.k1, self.linear_zone)
        if np.any(active):
            # The centre must never reach q = ε; if a crossing ever happens the monitor
            # reports it, and the floor keeps m pointing away from the obstacle meanwhile.
            gap = np.maximum(q[active] - belief.epsilon[active], 1e-12)
            m = (center - belief.mean[active]) / gap[:, None]
            v = null_space_direction(m, goal_direction)
            k2 = np.broadcast_to(self.k2, q.shape)[active]
            k3 = np.broadcast_to(self.k3, q.shape)[active]
            rate = rate + np.sum((k2[:, None] * m + k3[:, None] * v) * theta[active, None], axis=0)
        return TubeEvaluation(
            center_rate=rate,
            radius=self.radius(d_hat),
            avoid_probability=q,
            quantile_distance=d_hat,
            theta=theta,
        )

    def advance(
        self,
        center: np.ndarray,
        belief: ObstacleBelief,
        duration: float,
        max_substeps: int = 10_000,
    ) -> tuple[np.ndarray, int]:
        """Fixed-rate (real-time) update: move c over one period with the belief held.

        Splitting: the attraction uses its exact flow (:func:`attraction_flow`, never
        overshoots η); the avoidance term an explicit Euler step. A sub-step is accepted only
        if every gap q_j − ε_j that was positive stays at least half of what it was
        (a fraction-to-boundary rule), else it is halved; after an accepted sub-step the
        next one may double. So no q_j can cross ε_j within a period, however thin the
        barrier layer.

        Returns:
            the centre after `duration`, and the number of accepted sub-steps.

        Raises:
            RuntimeError: if `max_substeps` attempts cannot cover the period.
        """
        center = np.array(center, dtype=float)
        remaining, step, accepted = duration, duration, 0
        evaluation = self.evaluate(center, belief)
        for _attempt in range(max_substeps):
            if remaining <= 0.0:
                return center, accepted
            step = min(step, remaining)
            attraction = signed_cube_root_attraction(
                self.target - center, self.k1, self.linear_zone
            )
            avoidance = evaluation.center_rate - attraction
            candidate = (
                center + attraction_flow(self.target - center, self.k1, step) + step * avoidance
            )
            candidate_evaluation = self.evaluate(candidate, belief)
            gap = evaluation.avoid_probability - belief.epsilon
            new_gap = candidate_evaluation.avoid_probability - belief.epsilon
            if np.all((gap <= 0.0) | (new_gap >= 0.5 * gap)):
                center, evaluation = candidate, candidate_evaluation
                remaining -= step
                accepted += 1
                step *= 2.0
                if remaining <= 0.0:  # covered by this attempt, even if it was the last one
                    return center, accepted
            else:
                step *= 0.5
        raise RuntimeError(
            f"tube fixed-rate update: {max_substeps} sub-steps did not cover {duration} s "
            f"(last step {step:.3g} s)"
        )
