"""The spatiotemporal tube law (paper Sec. 3): centre velocity, radius and diagnostics.

One call of :meth:`TubeLaw.evaluate` gives, for the tube centre c and the belief of all
obstacles, the centre velocity ċ of Eq. (4), the radius r of Eq. (14) and
per-obstacle diagnostics (q_j, d̂_j, θ_j).

Fixes to the printed paper (README, "Design decisions"):
* the attraction term is the signed cube root per component, k1·sign(η − c)|η − c|^{1/3};
* the radius is the log-sum-exp soft-min r = −(1/ν) ln(e^{−ν r_max} + Σ_j e^{−ν d̂_j}),
  which is always ≤ min(r_max, min_j d̂_j); it stays > 0 only if ν > ln(n_o + 1)/r_min.

Bounded centre, boundary layer and recovery
-------------------------------------------
|ċ| ≤ v_c = ``max_center_speed`` always: the law's ċ is scaled down to v_c when faster.
In the paper's law the term k2·θ_j·m_j only dominates very close to q_j = ε_j (with the
authors' k2 = 0.03 and θ_j ≈ 0.05 it outweighs a 1 m/s attraction only below q_j − ε_j ≈
2e-3), so the centre rides a stiff 1/(q_j − ε_j) field a hair above the level set, and
two level sets closing on it (a *pinch*: the escape from one drives it into the other,
Theorem 3.2 (ii) treats one unbounded term at a time) pushed it across (the authors' 3D
field with k1 = 0.31: −3e-6 at 8.78 s), after which law and recovery alternated at the
boundary and the integrator chattered to a stop. So the law has a *boundary layer*
of width δ_j = BOUNDARY_LAYER·(p_d_j − ε_j) above each ε level set, with weight
w_j = clip(1 − (q_j − ε_j)/δ_j, 0, 1) (:func:`boundary_layer_weights`):

    ċ = (1 − w)·sat_{v_c}(ċ_law) + w·v_c·u/‖u‖,  w = max_j w_j,  u = Σ_j w_j (c − μ_j)/‖c − μ_j‖,

ċ_law being Eq. (4) over the obstacles with q_j > ε_j. Outside every layer (w = 0) this is
the paper's law. At and below an ε level set (w_j = 1) it is the *recovery*: v_c along u,
the direction in which the violated q_j increase fastest (∇_c q_j is along c − μ_j for
isotropic beliefs), turned away from the obstacles whose layer the centre is in, until
every q_j > ε_j again. ċ is continuous in c and in the beliefs (w and u are; at w = 1 the
law's share is 0) except where u = 0 (then the goal direction is used), so no mode
switch can chatter, and nothing is floored: the centre never
jumps, and the invariant monitor reports violated margins honestly.

Why the guarantee survives: on the ε level set of obstacle j (w_j = 1),
∇_c q_j·ċ ∝ ‖u‖⁻¹(1 + Σ_{k≠j} w_k cos∠(c − μ_j, c − μ_k)) v_c, so the centre leaves
the level set at speed v_c·(that) — the paper's single-obstacle argument (the saturated
ċ along c − μ_j) is the case of no other layer. Theorem 3.2 (ii) then holds while
the level set approaches slower than that speed; two level sets meeting head on (cos = −1)
cannot be escaped by any law that only moves the centre, and the run reports it.

The 3D null-space direction v_j follows a circulation axis per obstacle
(:mod:`stt_drake.core.circulation`). The fixed-rate (real-time) tube and its discrete-time
guarantee are derived in :mod:`stt_drake.core.fixed_rate`; :meth:`TubeLaw.advance` is the
update it describes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from functools import cached_property

import numpy as np

from stt_drake.core import backend
from stt_drake.core.anisotropic_tube import obstacle_terms
from stt_drake.core.belief import GaussianBelief, ObstacleBelief, ObstacleTask, record_size
from stt_drake.core.circulation import null_space_direction
from stt_drake.core.fixed_rate import BeliefRateBounds, FixedRateUpdate, end_radius_bound
from stt_drake.core.probability import (
    PRUNE_HEADROOM_NU,
    avoid_probability,
    period_avoid_probability,
    quantile_distance,
    segment_avoid_lower_bound,
    segment_quantile_lower_bound,
)
from stt_drake.core.rules import check_tube_law, checked_by, minimum_nu


def default_nu(obstacle_count: int, r_min: float) -> float:
    """Twice :func:`minimum_nu`: guarantees r ≥ r_min/2 whenever every q_j > ε_j.

    Without obstacles the soft-min has the one argument r_max (r = r_max whatever ν) and
    :func:`minimum_nu` is 0; ν is then derived as for one obstacle, 2 ln 2/r_min, so it
    stays a positive, finite number for everything that divides by it (the pruning
    headroom 40/ν, the level-set speeds)."""
    return 2.0 * minimum_nu(max(obstacle_count, 1), r_min)


#: Width of the boundary layer above each ε level set, as a share of p_d − ε (see the
#: module docstring, "Bounded centre, boundary layer and recovery").
BOUNDARY_LAYER = 0.1
#: Largest change of any boundary-layer weight w_j in one sub-step of the fixed-rate
#: update (:meth:`TubeLaw.advance`): the explicit sub-steps resolve the layer.
LAYER_STEP = 0.25
#: Pruning headroom (× 1/ν) of the quantiles of beliefs with full covariances
#: (:attr:`TubeLaw.anisotropic_prune_above`): e^{−25} ≈ 1.4e-11, the quantile method's own
#: accuracy is ~1e-13; the isotropic law keeps PRUNE_HEADROOM_NU = 40.
ANISOTROPIC_PRUNE_HEADROOM_NU = 25.0


def boundary_layer_weights(
    avoid_probability: np.ndarray, epsilon: np.ndarray, p_d: np.ndarray
) -> np.ndarray:
    """w_j = clip(1 − (q_j − ε_j)/δ_j, 0, 1) with δ_j = BOUNDARY_LAYER·(p_d_j − ε_j): 1 at and
    below the ε level set, 0 from δ_j above it, linear in between."""
    width = BOUNDARY_LAYER * (p_d - epsilon)
    return np.clip(1.0 - (avoid_probability - epsilon) / width, 0.0, 1.0)


def signed_cube_root_attraction(
    error: np.ndarray, k1: float, linear_zone: float = 0.0
) -> np.ndarray:
    """k1·sign(e)|e|^{1/3} per component: the finite-time attraction of Eq. (4).

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
    """Exact change of c over `duration` under ċ = k1·cbrt(η − c) alone (Eq. (13)).

    Per component, |e|^{2/3} decreases linearly at rate 2k1/3 until it reaches 0, so the
    flow never overshoots η, whatever the step.
    """
    remaining = np.maximum(np.abs(error) ** (2.0 / 3.0) - (2.0 / 3.0) * k1 * duration, 0.0)
    return error - np.sign(error) * remaining**1.5


def attraction_reach_time(error: np.ndarray, k1: float) -> float:
    """Time for the attraction alone to bring c to η: max_i 3|e_i|^{2/3}/(2 k1)."""
    return float(np.max(3.0 * np.abs(error) ** (2.0 / 3.0) / (2.0 * k1)))


@dataclass(frozen=True)
class TubeEvaluation:
    """Everything the tube law gives at one instant.

    Attributes:
        center_rate: (n,) ċ of Eq. (4) saturated at max_center_speed and blended with
            the escape velocity in the boundary layer (the recovery velocity at and below
            an ε level set), m/s.
        radius: r of Eq. (14), metres.
        avoid_probability: (m,) q_j(c, t) of Eq. (5) (its period lower bound when the
            law was evaluated with a horizon).
        quantile_distance: (m,) d̂_j of Eq. (8), metres (a lower bound where pruned).
        theta: (m,) switching gains θ_j (at their largest in-law value 1/ε_j − 1/p_d_j
            where q_j ≤ ε_j: the recovery velocity does not use them).
    """

    center_rate: np.ndarray
    radius: float
    avoid_probability: np.ndarray
    quantile_distance: np.ndarray
    theta: np.ndarray

    def in_slots(self, belief: GaussianBelief) -> TubeEvaluation:
        """This evaluation of the active slots of `belief` spread over all its slots; the
        inactive ones read q = 1, d̂ = +∞, θ = 0 (no obstacle there)."""
        if belief.active.all():
            return self
        return replace(
            self,
            avoid_probability=belief.per_slot(self.avoid_probability, 1.0),
            quantile_distance=belief.per_slot(self.quantile_distance, np.inf),
            theta=belief.per_slot(self.theta, 0.0),
        )


@dataclass(frozen=True)
class TubeLaw:
    """Centre and radius law of the STT (Eqs. (4), (5), (8) and (14)).

    Attributes:
        target: (n,) η, the point the centre is pulled to.
        k1: attraction gain (> 0).
        k2: avoidance gain along m_j (> 0), scalar or one per obstacle.
        k3: gain along v_j ⟂ m_j (≥ 0), scalar or one per obstacle.
        r_min: buffer added to each obstacle radius in q_j (> 0).
        r_max: largest tube radius (> r_min).
        nu: soft-min sharpness; must exceed ln(n_o + 1)/r_min for Theorem 3.2 (iii).
        linear_zone: δ of :func:`signed_cube_root_attraction` (metres; 0 = exact cube root).
        max_center_speed: v_c, the bound on |ċ| and the recovery speed (m/s). Infinite
            means unbounded: no boundary layer (the paper's law above every ε level set),
            and a recovery has no finite speed, so its ċ is not finite (the Drake system
            stops the run and says so).

    Checked when made (:func:`stt_drake.core.rules.check_tube_law`, a scenario file's rules);
    ν against the obstacle count where that is known (SpatiotemporalTube, AddStt).
    """

    target: np.ndarray
    k1: float
    k2: np.ndarray | float
    k3: np.ndarray | float
    r_min: float
    r_max: float
    nu: float
    linear_zone: float = 0.0
    max_center_speed: float = math.inf

    def __post_init__(self) -> None:
        with checked_by("TubeLaw"):
            check_tube_law(*(getattr(self, f.name) for f in fields(TubeLaw)))  # in order

    def radius(self, quantile_distance: np.ndarray) -> float:
        """Soft-min radius r = −(1/ν) ln(e^{−ν r_max} + Σ e^{−ν d̂_j}) (Eq. (14)).

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

    @property
    def anisotropic_prune_above(self) -> float:
        """:attr:`prune_above` for beliefs with full covariances, whose quantile costs a
        contour integral (~15 µs) instead of ~0.1 µs: r_max + ANISOTROPIC_PRUNE_HEADROOM_NU/ν.
        A pruned d̂_j enters the soft-min as its lower bound (≤ d̂_j: r only gets smaller, so
        r ≤ min_j d̂_j still holds), which moves r by less than n_o·e^{−25}/ν
        (≈ 1.4e-11·n_o/ν m) from the all-exact law."""
        return self.r_max + ANISOTROPIC_PRUNE_HEADROOM_NU / self.nu

    @cached_property
    def _kernel_constants(self) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """(k2, k3, constants by pruning mode) as float arrays for the compiled kernel
        (layout: :data:`stt_drake.core._kernels.TUBE_CONSTANTS`, then η); once per law. Modes:
        "pruned", "exact" (every quantile) and "rate" (ċ, q, θ only; the compiled kernel
        then returns NaN for d̂ and r)."""
        target = np.asarray(self.target, dtype=float).ravel()

        def constants(prune_above: float) -> np.ndarray:
            head = [self.k1, self.r_min, self.r_max, self.nu, self.linear_zone]
            return np.array([*head, prune_above, self.max_center_speed, *target], dtype=float)

        return (
            np.atleast_1d(np.array(self.k2, dtype=float)).ravel(),
            np.atleast_1d(np.array(self.k3, dtype=float)).ravel(),
            {
                "pruned": constants(self.prune_above),
                "pruned_anisotropic": constants(self.anisotropic_prune_above),
                "exact": constants(np.inf),
                "rate": constants(-np.inf),
            },
        )

    def with_target(self, target: np.ndarray) -> TubeLaw:
        """This law attracted to `target` (n,), its kernel constants reused with only η
        replaced: a guide or a task sequencer moves η as often as every step."""
        target = np.array(target, dtype=float).ravel()
        k2, k3, constants = self._kernel_constants
        n = target.size
        moved = {}
        for mode, values in constants.items():
            moved[mode] = values.copy()
            moved[mode][-n:] = target
        # A field-for-field copy (dataclasses.replace re-runs __init__: 5× slower); the
        # constants go where cached_property keeps them.
        law = object.__new__(TubeLaw)
        law.__dict__.update(self.__dict__)
        law.__dict__["target"] = target
        law.__dict__["_kernel_constants"] = (k2, k3, moved)
        return law

    def _gains_for(self, count: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        constants = self._kernel_constants
        if constants[0].size not in (1, count) or constants[1].size not in (1, count):
            raise ValueError(
                f"k2/k3: need one gain or one per obstacle ({count}), "
                f"got {constants[0].size} and {constants[1].size}"
            )
        return constants

    def evaluate(
        self,
        center: np.ndarray,
        belief: ObstacleBelief,
        prune: bool = True,
        circulation: np.ndarray | None = None,
        inflation: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> TubeEvaluation:
        """Evaluate ċ, r and the diagnostics at the centre `center` (n,).

        One call of the compiled :func:`stt_drake.core._kernels.tube_step` for n ≤ 3 (unless the
        numpy path is selected, see :mod:`stt_drake.core.backend`), else the numpy reference
        below. `prune=False` computes every d̂_j exactly (see :attr:`prune_above`).
        `circulation`: (m, 3) axes ω_j of :func:`carry_circulation` (3D). `inflation`:
        (Δ, γ) of :meth:`BeliefRateBounds.inflation`; q_j, θ_j and ċ then use the period
        lower bound of q_j (d̂_j and r stay at the belief itself).
        """
        return self._evaluate(
            center, belief, "pruned" if prune else "exact", circulation, inflation
        )

    def switching_gains(self, center: np.ndarray, belief: ObstacleBelief) -> np.ndarray:
        """θ_j at `center` (no quantile is computed)."""
        return self._evaluate(center, belief, "rate", None, None).theta

    def _evaluate(
        self,
        center: np.ndarray,
        belief: ObstacleBelief,
        mode: str,
        circulation: np.ndarray | None,
        inflation: tuple[np.ndarray, np.ndarray] | None,
    ) -> TubeEvaluation:
        if belief.covariance is not None:
            return self._evaluate_anisotropic(center, belief, mode, circulation, inflation)
        kernel = backend.compiled("tube_step", belief.mean.shape[-1])
        if kernel is None:
            return self._evaluate_numpy(center, belief, mode, circulation, inflation)
        k2, k3, constants = self._gains_for(belief.mean.shape[0])
        reach, spread, axes = _kernel_extras(belief.mean.shape, circulation, inflation)
        return TubeEvaluation(
            *kernel(
                np.asarray(center, dtype=float),
                belief.mean,
                belief.sigma,
                belief.radius,
                belief.epsilon,
                belief.p_d,
                k2,
                k3,
                reach,
                spread,
                axes,
                constants[mode],
            )
        )

    def _evaluate_anisotropic(
        self,
        center: np.ndarray,
        belief: ObstacleBelief,
        mode: str,
        circulation: np.ndarray | None,
        inflation: tuple[np.ndarray, np.ndarray] | None,
    ) -> TubeEvaluation:
        """:meth:`_evaluate` with the belief's full covariances
        (:mod:`stt_drake.core.anisotropic_tube`): one call of the compiled
        :func:`stt_drake.core._anisotropic_tube.anisotropic_tube_step` for n = 2, 3."""
        if inflation is not None:
            raise ValueError(
                "covariance: the fixed-rate tube's period bounds are for isotropic beliefs "
                "(sigma) only; run a belief with full covariances in continuous time"
            )
        count, n = belief.mean.shape
        kernel = backend.compiled("anisotropic_tube_step", n)
        if kernel is None:
            return self._evaluate_numpy(center, belief, mode, circulation, None)
        k2, k3, constants = self._gains_for(count)
        _reach, _spread, axes = _kernel_extras((count, n), circulation, None)
        mode = "pruned_anisotropic" if mode == "pruned" else mode
        return TubeEvaluation(
            *kernel(
                np.asarray(center, dtype=float),
                np.ascontiguousarray(belief.mean, dtype=float),
                np.ascontiguousarray(belief.covariance, dtype=float).reshape(count, n, n),
                np.asarray(belief.radius, dtype=float),
                np.asarray(belief.epsilon, dtype=float),
                np.asarray(belief.p_d, dtype=float),
                k2,
                k3,
                axes,
                constants[mode],
            )
        )

    def evaluate_packed(
        self,
        center: np.ndarray,
        belief_vector: np.ndarray,
        task_table: np.ndarray,
        prune: bool = True,
        circulation: np.ndarray | None = None,
    ) -> TubeEvaluation:
        """:meth:`evaluate` on a belief port vector (layout of :mod:`stt_drake.core.belief`)
        and the task rows (:meth:`ObstacleTask.table`), with σ_j = √λ_max(Σ_j), in one
        compiled call (the Drake system's hot path). The outputs are per slot; an inactive
        slot never reaches ċ or r and reads q = 1, d̂ = +∞, θ = 0."""
        dimension = len(center)
        mode = "pruned" if prune else "exact"
        kernel = backend.compiled("tube_step_packed", dimension)
        # A malformed belief vector takes the numpy path: from_vector names the problem.
        if kernel is None or len(belief_vector) % record_size(dimension):
            task = ObstacleTask(*np.asarray(task_table, dtype=float).T)
            belief = GaussianBelief.from_vector(belief_vector, dimension)
            return self.evaluate_slots(center, belief, task, False, prune, circulation)
        count = len(task_table)
        k2, k3, constants = self._gains_for(count)
        _reach, _spread, axes = _kernel_extras((count, dimension), circulation, None)
        return TubeEvaluation(
            *kernel(
                np.asarray(center, dtype=float),
                np.asarray(belief_vector, dtype=float),
                task_table,
                k2,
                k3,
                axes,
                constants[mode],
            )
        )

    def evaluate_slots(
        self,
        center: np.ndarray,
        belief: GaussianBelief,
        task: ObstacleTask,
        full_covariance: bool,
        prune: bool = True,
        circulation: np.ndarray | None = None,
    ) -> TubeEvaluation:
        """:meth:`evaluate` on the active slots of `belief` (:meth:`ObstacleBelief.of`;
        Σ_j exactly when `full_covariance`), outputs per slot as in
        :meth:`evaluate_packed`."""
        law_belief = ObstacleBelief.of(belief, task, full_covariance)
        if circulation is not None:
            circulation = np.asarray(circulation).reshape(belief.count, -1)[belief.active]
        evaluation = self.evaluate(center, law_belief, prune, circulation)
        return evaluation.in_slots(belief)

    def _evaluate_numpy(
        self,
        center: np.ndarray,
        belief: ObstacleBelief,
        mode: str = "pruned",
        circulation: np.ndarray | None = None,
        inflation: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> TubeEvaluation:
        """The numpy reference of :meth:`evaluate` (any n)."""
        safety_radius = belief.radius + self.r_min
        prune_above = {"pruned": self.prune_above, "exact": None, "rate": -np.inf}[mode]
        if belief.covariance is not None and mode == "pruned":
            prune_above = self.anisotropic_prune_above
        offset = center - belief.mean
        distance = np.linalg.norm(offset, axis=1)
        if belief.covariance is not None:  # q_j, d̂_j and ∇̂q_j with Σ_j (pruned alike)
            if inflation is not None:
                raise ValueError(
                    "covariance: the fixed-rate tube's period bounds are for isotropic "
                    "beliefs (sigma) only; run a belief with full covariances in continuous time"
                )
            q, d_hat, unit = obstacle_terms(
                center,
                belief.mean,
                np.asarray(belief.covariance).reshape(belief.count, belief.dimension, -1),
                belief.radius,
                belief.epsilon,
                belief.p_d,
                self.r_min,
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
        theta[active] = (
            1.0 / np.maximum(q[active], belief.epsilon[active]) - 1.0 / belief.p_d[active]
        )
        goal_direction = self.target - center
        rate = signed_cube_root_attraction(goal_direction, self.k1, self.linear_zone)
        law_terms = active & ~violated
        if np.any(law_terms):
            gap = q[law_terms] - belief.epsilon[law_terms]
            # m_j = ‖c − μ_j‖·∇̂q_j/(q_j − ε_j): the paper's (c − μ_j)/(q_j − ε_j) for Σ = σ²I
            m = (distance[law_terms] / gap)[:, None] * unit[law_terms]
            axes = None if circulation is None else np.asarray(circulation)[law_terms]
            v = null_space_direction(m, goal_direction, axes)
            k2 = np.broadcast_to(self.k2, q.shape)[law_terms]
            k3 = np.broadcast_to(self.k3, q.shape)[law_terms]
            weights = theta[law_terms, None]
            rate = rate + np.sum((k2[:, None] * m + k3[:, None] * v) * weights, axis=0)
        speed = float(np.linalg.norm(rate))
        if speed > self.max_center_speed:
            rate = rate * (self.max_center_speed / speed)
        if math.isfinite(self.max_center_speed):
            layer = boundary_layer_weights(q, belief.epsilon, belief.p_d)
        else:  # unbounded: no layer, only the recovery
            layer = violated * 1.0
        share = float(np.max(layer, initial=0.0))
        if share > 0.0:
            escape = self._recovery_velocity(unit[layer > 0.0], goal_direction, layer[layer > 0.0])
            rate = escape if share == 1.0 else (1.0 - share) * rate + share * escape
        return TubeEvaluation(
            center_rate=rate,
            radius=self.radius(d_hat),
            avoid_probability=q,
            quantile_distance=d_hat,
            theta=theta,
        )

    def _recovery_velocity(
        self, unit: np.ndarray, goal_direction: np.ndarray, weights: np.ndarray
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
                    return self.max_center_speed * direction / size
        rate = np.zeros_like(goal_direction, dtype=float)
        rate[0] = self.max_center_speed
        return rate

    def advance(
        self,
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

        One call of the compiled :func:`stt_drake.core._kernels.tube_advance` for n ≤ 3 (unless
        the numpy path is selected); the code below is its reference.

        Returns:
            the :class:`FixedRateUpdate`; never raises for lack of progress (a period the
            sub-steps cannot cover is held where they got to, which stays certified).
        """
        center = np.array(center, dtype=float)
        count = belief.count
        bounds = bounds if bounds is not None else BeliefRateBounds.still(count)
        kernel = backend.compiled("tube_advance", belief.dimension)
        if kernel is not None:
            k2, k3, constants = self._gains_for(count)
            _reach, _spread, axes = _kernel_extras(belief.mean.shape, circulation, None)
            position, certified, accepted, start_radius, end_radius, theta = kernel(
                center,
                belief.mean,
                belief.sigma,
                belief.radius,
                belief.epsilon,
                belief.p_d,
                k2,
                k3,
                np.asarray(bounds.mean_speed, dtype=float),
                np.asarray(bounds.sigma_rate, dtype=float),
                axes,
                constants["rate"],
                self.prune_above,
                float(duration),
                float(radius),
                max_attempts,
            )
            return FixedRateUpdate(position, certified, accepted, start_radius, end_radius, theta)
        look_ahead = bounds.inflation(belief.sigma, 2.0 * duration)
        position, evaluation = (
            center,
            self._evaluate(center, belief, "rate", circulation, look_ahead),
        )
        remaining, step, accepted = duration, duration, 0
        path = [center]  # the accepted sub-steps' ends
        for _attempt in range(max_attempts):
            if remaining <= 1e-12 * duration or step < duration * 2.0**-30:
                break
            step = min(step, remaining)
            candidate = position + self._displacement(position, evaluation, belief, step)
            candidate_evaluation = self._evaluate(
                candidate, belief, "rate", circulation, look_ahead
            )
            gap = evaluation.avoid_probability - belief.epsilon
            new_gap = candidate_evaluation.avoid_probability - belief.epsilon
            resolved = True
            if math.isfinite(self.max_center_speed):
                layer_change = boundary_layer_weights(
                    candidate_evaluation.avoid_probability, belief.epsilon, belief.p_d
                ) - boundary_layer_weights(evaluation.avoid_probability, belief.epsilon, belief.p_d)
                resolved = bool(np.all(np.abs(layer_change) <= LAYER_STEP))
            if resolved and np.all((gap <= 0.0) | (new_gap >= 0.5 * gap)):
                position, evaluation = candidate, candidate_evaluation
                remaining -= step
                accepted += 1
                path.append(position)
                step *= 2.0
            else:
                step *= 0.5
        period = bounds.inflation(belief.sigma, duration)
        safety_radius = belief.radius + self.r_min
        start_gap = (
            period_avoid_probability(center, belief.mean, belief.sigma, safety_radius, *period)
            - belief.epsilon
        )
        must_hold = start_gap > 0.0

        def distance_bound(
            start: np.ndarray, end: np.ndarray, inflation: tuple[np.ndarray, np.ndarray]
        ) -> np.ndarray:
            return segment_quantile_lower_bound(
                start, end, belief.mean, belief.sigma, belief.radius, belief.epsilon, *inflation
            )

        at_start = distance_bound(center, center, period)
        if np.isfinite(radius) and radius <= np.min(at_start, initial=np.inf):
            start_radius = float(radius)  # continuous: the period starts where the last ended
        else:  # the first update, or a belief that left its bounds: the radius drops now
            start_radius = self.radius(at_start)
        back = accepted  # the segment ends at path[back] until that is the first sub-step
        for _pull in range(accepted + 60):
            lower = segment_avoid_lower_bound(
                center, position, belief.mean, belief.sigma, safety_radius, *period
            )
            certified = lower - belief.epsilon > 0.0
            allowed = end_radius_bound(
                start_radius,
                at_start,
                distance_bound(center, position, period),
                float(np.linalg.norm(position - center)),
            )
            if np.all(certified[must_hold]) and np.all(allowed[must_hold] >= self.r_min):
                break
            if back > 1:  # an earlier sub-step's end: the path's chords cut less inward
                back -= 1
                position = path[back]
            else:
                position = center + 0.5 * (position - center)
        else:
            position = center
            certified = must_hold
            allowed = at_start
        ahead = distance_bound(position, position, look_ahead)
        end_radius = self.radius(np.minimum(allowed, ahead))
        theta = self.switching_gains(position, belief)
        return FixedRateUpdate(position, certified, accepted, start_radius, end_radius, theta)

    def _displacement(
        self, center: np.ndarray, evaluation: TubeEvaluation, belief: ObstacleBelief, step: float
    ) -> np.ndarray:
        """One sub-step's move: the exact attraction flow when no obstacle acts (θ = 0 for
        all), else step·ċ; never longer than v_c·step."""
        if np.any(evaluation.theta > 0.0):
            return step * evaluation.center_rate
        move = attraction_flow(self.target - center, self.k1, step)
        length = float(np.linalg.norm(move))
        limit = self.max_center_speed * step
        return move * (limit / length) if length > limit else move


def _kernel_extras(
    shape: tuple[int, int],
    circulation: np.ndarray | None,
    inflation: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(reach, spread, circulation) arrays for the compiled kernel: empty where not used."""
    count, dimension = shape
    empty = np.empty(0)
    reach, spread = (empty, empty) if inflation is None else inflation
    axes = (
        np.empty((0, dimension))
        if circulation is None
        else np.ascontiguousarray(circulation, dtype=float).reshape(count, dimension)
    )
    return np.asarray(reach, dtype=float), np.asarray(spread, dtype=float), axes
