"""The fixed-rate (real-time) tube: belief rate bounds, the period's radius bound and the
update's result, and the update itself (:func:`advance`, which
:meth:`stt_drake.core.tube.TubeLaw.advance` calls).

Discrete-time guarantee (the fixed-rate tube)
---------------------------------------------
A real-time tube updates every h seconds with the belief sampled at the update t_k, and
the obstacles keep moving in between. Suppose each belief moves at bounded rates,
‖μ̇_j‖ ≤ v̄_j and |σ̇_j| ≤ s̄_j (from the motion model, a tracker's velocity estimate or a
declared bound). Over a horizon τ every belief N(μ_j(t), σ_j(t)²I), t ∈ [t_k, t_k + τ], has
‖μ_j(t) − μ_j(t_k)‖ ≤ Δ_j = v̄_j τ and σ_j(t) ≥ σ_lo = σ_j(t_k) − s̄_j τ. Couple O(t) =
μ(t) + σ(t)Z with O_k = μ_k + σ_k Z (same Z, σ_k = σ_j(t_k)). For a point x, radius R and
d = x − μ(t):

1. Scale: ‖d − σ(t)Z‖ < R implies ‖d − σ_k Z‖ < R + γ(‖d‖ + R) with γ = σ_k/σ_lo − 1 (in
   units of σ the collision ball B(d/σ, R/σ) is contained in B(d/σ_k, (R + γ(‖d‖ + R))/σ_k)
   both when σ(t) < σ_k and when σ(t) ≥ σ_k, since 1 − σ_k/σ(t) ≤ γ).
2. Translate: ‖d‖ ≤ a + Δ with a = ‖x − μ_k‖, and the survival function of ‖x − μ_k − σ_kZ‖
   only falls when the centre offset falls, so shifting the mean by at most Δ costs at most
   Δ of offset.

Hence q_j(x, t) ≥ Q_j^τ(x) := P(‖Z'‖ ≥ (R + γ(a + Δ + R))/σ_k), Z' ~ N(max(a − Δ, 0)/σ_k·e, I),
for every t in the horizon (:func:`stt_drake.core.probability.period_avoid_probability`; a
Monte Carlo test samples beliefs inside the bounds). On a segment, take the offset at the
closest point and the radius at the farthest (:func:`stt_drake.core.probability.
segment_avoid_lower_bound`).

The update (:func:`advance`) at t_k, from the centre c_k reached at t_k:

* it integrates the law with the look-ahead lower bound Q^{2h} in place of q_j, in
  sub-steps that keep every positive gap Q^{2h}_j − ε_j at least half of what it was
  (fraction to the boundary) and change no boundary-layer weight by more than
  :data:`stt_drake.core.constants.LAYER_STEP` (explicit steps across the layer's steep field
  would bounce in and out of it, period after period), at |ċ| ≤ v_c, giving c_{k+1};
* it certifies the straight segment [c_k, c_{k+1}] with Q^h: every obstacle whose
  Q^h_j(c_k) > ε_j must keep the segment's lower bound > ε_j, else c_{k+1} is pulled back
  to the earlier sub-steps' ends (a path that slid along a level set has a chord that
  cuts into it; a shorter chord cuts less) and then towards c_k (c_k itself passes);
* the tube output moves linearly from c_k to c_{k+1} over [t_k, t_k + h] (continuous,
  |ċ| ≤ v_c), so q_j(c(t), t) > ε_j at every instant of the period for every certified j.

Induction: Q^{2h} from the belief at t_k bounds every belief up to t_k + 2h, which contains
the horizon h after t_{k+1}, so Q^{2h}_{k}(c_{k+1}) > ε_j implies Q^h_{k+1}(c_{k+1}) > ε_j
for a translating belief (the composition of the two shifts is exact; with σ changing it
holds to first order in s̄h/σ, and any shortfall is flagged as a recovery, never hidden).
So without belief jumps every period is certified. An obstacle whose Q^h_j(c_k) ≤ ε_j
(its belief jumped, or moved faster than its bound) is *recovering* for that period: the
update escapes along the recovery direction at v_c, and the run records it.

The radius over a period. The same coupling bounds the quantile distance d̂_j from below
over the period: D0_j at c_k and D_j over the whole segment
(:func:`stt_drake.core.probability.segment_quantile_lower_bound`). The radius moves linearly
from r_k ≤ min_j D0_j to r_{k+1}, and d̂_j is 1-Lipschitz in the point, so at the fraction
s of the period d̂_j ≥ max(D0_j − sℓ, D_j) with ℓ = ‖c_{k+1} − c_k‖. A linear r(s) stays
below that bound for the largest r_{k+1} of :func:`end_radius_bound`; r_{k+1} is the
soft-min of those per-obstacle limits and of the look-ahead bound at c_{k+1}, and c_{k+1}
is also pulled back until every certified obstacle's limit is ≥ r_min (so r > 0 by the
choice of ν, Theorem 3.2 (iii)). Hence r(t) ≤ d̂_j(c(t), t) at every instant (the ball is
certified, Theorem 3.2 (ii)), and the radius can fall as fast as the centre approaches an obstacle
(the first version required D_j ≥ r_k, which let r fall only by the soft-min slack per
period and stalled the centre in front of thin barriers at 10-20 Hz).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from stt_drake.core import backend
from stt_drake.core.belief import ObstacleBelief, ObstacleTask
from stt_drake.core.constants import LAYER_STEP
from stt_drake.core.probability import (
    period_avoid_probability,
    segment_avoid_lower_bound,
    segment_quantile_lower_bound,
)
from stt_drake.core.tube_terms import (
    LawConstants,
    TubeEvaluation,
    attraction_flow,
    boundary_layer_weights,
    kernel_extras,
)


@dataclass(frozen=True)
class BeliefRateBounds:
    """How fast each obstacle's belief may change: sup ‖μ̇_j‖ and sup |σ̇_j| (m/s).

    Steps (belief jumps) are outside these bounds by definition: the tube recovers from them.
    """

    mean_speed: np.ndarray
    sigma_rate: np.ndarray

    @classmethod
    def still(cls, count: int) -> BeliefRateBounds:
        """Bounds of a belief that does not move (every rate 0)."""
        return cls(np.zeros(count), np.zeros(count))

    def inflation(self, sigma: np.ndarray, horizon: float) -> tuple[np.ndarray, np.ndarray]:
        """(Δ_j, γ_j) over `horizon` seconds from standard deviations `sigma`: the reach
        v̄_j·τ of the mean and the spread σ_j/(σ_j − s̄_j τ) − 1 (infinite once σ could
        reach 0); see the module docstring, "Discrete-time guarantee"."""
        sigma = np.asarray(sigma, dtype=float)
        low = sigma - self.sigma_rate * horizon
        positive = low > 0.0
        spread = np.full(sigma.shape, np.inf)
        spread[positive] = sigma[positive] / low[positive] - 1.0
        return self.mean_speed * horizon, spread


def end_radius_bound(
    start_radius: float, at_start: np.ndarray, on_segment: np.ndarray, length: float
) -> np.ndarray:
    """Per obstacle, the largest end radius r_{k+1} for which the linearly interpolated
    radius r(s) = r_k + s(r_{k+1} − r_k), s ∈ [0, 1], stays below the quantile distance
    d̂_j along the period (module docstring, "The radius over a period").

    With D0 = `at_start` (the bound at c_k over the period, ≥ r_k), D = `on_segment` (over
    the whole segment) and ℓ = `length` = ‖c_{k+1} − c_k‖, d̂_j at the point s is at least
    max(D0 − sℓ, D) (d̂_j is 1-Lipschitz in the point). A linear r(s) from r_k ≤ D0 stays
    below that: up to D0 − ℓ when D0 − ℓ ≥ D; up to D when r_k ≤ D; otherwise only if it
    has fallen to D where the two lines cross, s* = (D0 − D)/ℓ, i.e. up to
    r_k − (r_k − D)·ℓ/(D0 − D).
    """
    at_start = np.asarray(at_start, dtype=float)
    on_segment = np.asarray(on_segment, dtype=float)
    lipschitz = at_start - length
    with np.errstate(divide="ignore", invalid="ignore"):
        falling = start_radius - (start_radius - on_segment) * length / (at_start - on_segment)
    return np.where(
        lipschitz >= on_segment,
        lipschitz,
        np.where(start_radius <= on_segment, on_segment, falling),
    )


@dataclass(frozen=True)
class FixedRateUpdate:
    """One fixed-rate update: where the centre goes, and what is certified.

    Attributes:
        center: (n,) c_{k+1}, reached at the end of the period (the output moves linearly).
        certified: (m,) True where q_j(c(t), t) > ε_j is proven over the whole period;
            False where obstacle j is recovering (its belief left its rate bounds).
        substeps: accepted sub-steps of the law.
        start_radius: r at the start of the period: the given radius, unless the belief
            left its bounds (or this is the first update), when it drops to what the period
            certifies.
        end_radius: r at the end of the period (linear in between).
        theta: (m,) θ_j at `center` with the belief of the update (what decides which
            obstacles are active there, e.g. for the 3D circulation axes).
    """

    center: np.ndarray
    certified: np.ndarray
    substeps: int
    start_radius: float
    end_radius: float
    theta: np.ndarray


class _Law(LawConstants, Protocol):
    """What :func:`advance` reads of a :class:`stt_drake.core.tube.TubeLaw`."""

    @property
    def prune_above(self) -> float: ...

    def evaluate(
        self, center: np.ndarray, belief: ObstacleBelief, **options: Any
    ) -> TubeEvaluation: ...

    def switching_gains(self, center: np.ndarray, belief: ObstacleBelief) -> np.ndarray: ...

    def kernel_arguments(
        self, count: int, mode: str
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def advance(
    law: _Law,
    center: np.ndarray,
    belief: ObstacleBelief,
    duration: float,
    bounds: BeliefRateBounds | None = None,
    circulation: np.ndarray | None = None,
    radius: float = math.nan,
    max_attempts: int = 200,
) -> FixedRateUpdate:
    """Fixed-rate (real-time) update over one period h = `duration` with the belief
    sampled at its start (:mod:`stt_drake.core.fixed_rate`, "Discrete-time guarantee").

    The law runs with the look-ahead bound Q^{2h} (from `bounds`; None = a belief that
    does not move) in sub-steps at |ċ| ≤ v_c: the attraction's exact flow when no
    obstacle acts, else an explicit step of the law (its linear zone keeps that step
    from overshooting η). A sub-step is accepted only if every positive gap
    Q^{2h}_j − ε_j stays at least half of what it was and every boundary-layer weight
    changes by at most :data:`LAYER_STEP` (the explicit sub-steps resolve the layer
    instead of bouncing across it), else it is halved; after an
    accepted one the next may double. Then the segment from `center` to the result is
    certified with Q^h and pulled back until it is (to the earlier sub-steps' ends, whose
    chords cut less into a level set the path slid along, then halved towards
    `center`), and until the end radius it allows
    (:func:`end_radius_bound`, from `radius`, the tube radius at the start of the
    period; NaN: none yet) is at least r_min for every certified obstacle. The radius
    moves linearly over the period from its start value to the soft-min of those limits
    and the look-ahead's distance bounds at the new centre, so the whole ball is
    certified too (:mod:`stt_drake.core.fixed_rate`, "The radius over a period").

    One call of the compiled :func:`stt_drake.core._tube.tube_advance` for n ≤ 3 (unless
    the numpy path is selected; a belief from a port with every slot active goes to
    :func:`advance_port`, whose :func:`stt_drake.core._tube.tube_advance_packed` reads the
    port vector itself);
    the steps below are its reference: :func:`_integrate`,
    :func:`_start_radius`, :func:`_pull_back`, then the end radius and θ_j at the end.
    `belief`: the obstacles (all of them: a fixed-rate tube needs every slot active).

    Returns:
        the :class:`FixedRateUpdate`; never raises for lack of progress (a period the
        sub-steps cannot cover is held where they got to, which stays certified).
    """
    center = np.array(center, dtype=float)
    if belief.packed is not None and belief.all_active:  # an isotropic belief from a port
        task = belief.slot_task
        bounds = bounds if bounds is not None else BeliefRateBounds.still(task.count)
        return advance_port(
            law, center, belief.vector, task, duration, bounds, circulation, radius, max_attempts
        )
    belief = belief.obstacles()
    bounds = bounds if bounds is not None else BeliefRateBounds.still(belief.count)
    kernel = backend.compiled("tube_advance", belief.dimension)
    if kernel is not None:
        return _compiled_advance(
            kernel,
            law,
            center,
            belief.mean.shape,
            belief.arrays(),
            duration,
            bounds,
            circulation,
            radius,
            max_attempts,
        )
    look_ahead = bounds.inflation(belief.sigma, 2.0 * duration)
    path = _integrate(law, center, belief, duration, look_ahead, circulation, max_attempts)
    period = bounds.inflation(belief.sigma, duration)
    at_start = _distance_bound(belief, center, center, period)
    start_radius = _start_radius(law, radius, at_start)
    position, certified, allowed = _pull_back(law, belief, path, period, at_start, start_radius)
    ahead = _distance_bound(belief, position, position, look_ahead)
    end_radius = law.radius(np.minimum(allowed, ahead))
    theta = law.switching_gains(position, belief)
    return FixedRateUpdate(position, certified, len(path) - 1, start_radius, end_radius, theta)


def advance_port(
    law: _Law,
    center: np.ndarray,
    vector: np.ndarray,
    task: ObstacleTask,
    duration: float,
    bounds: BeliefRateBounds,
    circulation: np.ndarray | None = None,
    radius: float = math.nan,
    max_attempts: int = 200,
) -> FixedRateUpdate:
    """:func:`advance` of ``ObstacleBelief.from_port(vector, n, task)`` for `center` (n,),
    float64, and a port `vector` of ``task.count`` slots, every one active (the caller
    checks): a fixed-rate system's hot path. Where the compiled kernel runs it reads the
    vector itself (:func:`stt_drake.core._tube.tube_advance_packed`) and no belief is made."""
    n = len(center)
    kernel = backend.compiled("tube_advance_packed", n)
    if kernel is None:  # the obstacles' arrays (a belief from the port would come back here)
        belief = ObstacleBelief.from_port(vector, n, task).obstacles()
        return advance(law, center, belief, duration, bounds, circulation, radius, max_attempts)
    return _compiled_advance(
        kernel,
        law,
        center,
        (task.count, n),
        (vector, task.table()),
        duration,
        bounds,
        circulation,
        radius,
        max_attempts,
    )


def _compiled_advance(
    kernel: Callable[..., tuple],
    law: _Law,
    center: np.ndarray,
    shape: tuple[int, int],
    obstacles: tuple[np.ndarray, ...],
    duration: float,
    bounds: BeliefRateBounds,
    circulation: np.ndarray | None,
    radius: float,
    max_attempts: int,
) -> FixedRateUpdate:
    """:func:`advance` in one call of the compiled :func:`stt_drake.core._tube.tube_advance`
    (`obstacles` = μ, σ, r_o, ε, p_d) or :func:`stt_drake.core._tube.tube_advance_packed`
    (`obstacles` = the port vector and the task rows), for `shape` = (obstacles, n)."""
    k2, k3, constants = law.kernel_arguments(shape[0], "rate")
    _reach, _spread, axes = kernel_extras(shape, circulation, None)
    position, certified, accepted, start_radius, end_radius, theta = kernel(
        center,
        *obstacles,
        k2,
        k3,
        np.asarray(bounds.mean_speed, dtype=float),
        np.asarray(bounds.sigma_rate, dtype=float),
        axes,
        constants,
        law.prune_above,
        float(duration),
        float(radius),
        max_attempts,
    )
    return FixedRateUpdate(position, certified, accepted, start_radius, end_radius, theta)


def _integrate(
    law: _Law,
    center: np.ndarray,
    belief: ObstacleBelief,
    duration: float,
    look_ahead: tuple[np.ndarray, np.ndarray],
    circulation: np.ndarray | None,
    max_attempts: int,
) -> list[np.ndarray]:
    """The law's sub-steps over the period with the look-ahead bound Q^{2h}
    (:func:`_sub_step_accepted` decides each): `center` and the end of every accepted
    sub-step, in order."""

    def evaluate(point: np.ndarray) -> TubeEvaluation:
        return law.evaluate(
            point, belief, circulation=circulation, inflation=look_ahead, quantiles=False
        )

    position, evaluation = center, evaluate(center)
    remaining, step = duration, duration
    path = [center]
    for _attempt in range(max_attempts):
        if remaining <= 1e-12 * duration or step < duration * 2.0**-30:
            break
        step = min(step, remaining)
        candidate = position + _displacement(law, position, evaluation, step)
        candidate_evaluation = evaluate(candidate)
        if _sub_step_accepted(law, belief, evaluation, candidate_evaluation):
            position, evaluation = candidate, candidate_evaluation
            remaining -= step
            path.append(position)
            step *= 2.0
        else:
            step *= 0.5
    return path


def _displacement(
    law: _Law, center: np.ndarray, evaluation: TubeEvaluation, step: float
) -> np.ndarray:
    """One sub-step's move: the exact attraction flow when no obstacle acts (θ = 0 for
    all), else step·ċ; never longer than v_c·step."""
    if np.any(evaluation.theta > 0.0):
        return step * evaluation.center_rate
    move = attraction_flow(law.target - center, law.k1, step)
    length = float(np.linalg.norm(move))
    limit = law.max_center_speed * step
    return move * (limit / length) if length > limit else move


def _sub_step_accepted(
    law: _Law, belief: ObstacleBelief, before: TubeEvaluation, after: TubeEvaluation
) -> bool:
    """Every positive gap Q^{2h}_j − ε_j keeps at least half of itself, and (with a finite
    v_c) no boundary-layer weight changes by more than :data:`LAYER_STEP`."""
    gap = before.avoid_probability - belief.epsilon
    new_gap = after.avoid_probability - belief.epsilon
    resolved = True
    if math.isfinite(law.max_center_speed):
        layer_change = boundary_layer_weights(
            after.avoid_probability, belief.epsilon, belief.p_d
        ) - boundary_layer_weights(before.avoid_probability, belief.epsilon, belief.p_d)
        resolved = bool(np.all(np.abs(layer_change) <= LAYER_STEP))
    return resolved and bool(np.all((gap <= 0.0) | (new_gap >= 0.5 * gap)))


def _distance_bound(
    belief: ObstacleBelief,
    start: np.ndarray,
    end: np.ndarray,
    inflation: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """Per obstacle, a lower bound of d̂_j over the segment [start, end] for every belief
    within `inflation` (Δ, γ) of the sampled one."""
    return segment_quantile_lower_bound(
        start, end, belief.mean, belief.sigma, belief.radius, belief.epsilon, *inflation
    )


def _start_radius(law: _Law, radius: float, at_start: np.ndarray) -> float:
    """r at the start of the period: `radius` (where the last period ended) while the
    period's distance bounds at c_k allow it, else it drops now (the first update, or a
    belief that left its bounds) to the soft-min of those bounds."""
    if np.isfinite(radius) and radius <= np.min(at_start, initial=np.inf):
        return float(radius)
    return law.radius(at_start)


def _pull_back(
    law: _Law,
    belief: ObstacleBelief,
    path: list[np.ndarray],
    period: tuple[np.ndarray, np.ndarray],
    at_start: np.ndarray,
    start_radius: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Certify the segment from c_k = ``path[0]`` to the sub-steps' end with Q^h, pulling
    the end back (to the earlier sub-steps' ends, whose chords cut less into a level set
    the path slid along, then halving towards c_k) until every obstacle with Q^h_j(c_k) > ε_j
    keeps the segment's lower bound above ε_j and allows an end radius ≥ r_min.

    Returns:
        (c_{k+1}, certified (m,), the end-radius limits :func:`end_radius_bound` (m,)).
    """
    center, position = path[0], path[-1]
    safety_radius = belief.radius + law.r_min
    start_gap = (
        period_avoid_probability(center, belief.mean, belief.sigma, safety_radius, *period)
        - belief.epsilon
    )
    must_hold = start_gap > 0.0
    back = len(path) - 1  # the segment ends at path[back] until that is the first sub-step
    for _pull in range(len(path) + 59):
        lower = segment_avoid_lower_bound(
            center, position, belief.mean, belief.sigma, safety_radius, *period
        )
        certified = lower - belief.epsilon > 0.0
        allowed = end_radius_bound(
            start_radius,
            at_start,
            _distance_bound(belief, center, position, period),
            float(np.linalg.norm(position - center)),
        )
        if np.all(certified[must_hold]) and np.all(allowed[must_hold] >= law.r_min):
            return position, certified, allowed
        if back > 1:
            back -= 1
            position = path[back]
        else:
            position = center + 0.5 * (position - center)
    return center, must_hold, at_start
