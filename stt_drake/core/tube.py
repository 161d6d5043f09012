"""The spatiotemporal tube law (paper Sec. 3): centre velocity, radius and diagnostics.

One call of :meth:`TubeLaw.evaluate` gives, for the tube centre c and the belief of all
obstacles, the centre velocity ċ of eq. (cen_dynamic), the radius r of eq. (rad_sol) and
per-obstacle diagnostics (q_j, d̂_j, θ_j).

Fixes to the printed paper (see DESIGN.md):
* the attraction term is the signed cube root per component, k1·sign(η − c)|η − c|^{1/3};
* the radius is the log-sum-exp soft-min r = −(1/ν) ln(e^{−ν r_max} + Σ_j e^{−ν d̂_j}),
  which is always ≤ min(r_max, min_j d̂_j); it stays > 0 only if ν > ln(n_o + 1)/r_min.

Bounded centre, and recovery
----------------------------
|ċ| ≤ v_c = ``max_center_speed`` always: the law's ċ is scaled down to v_c when faster.
Near q_j = ε_j the term k2·θ_j·m_j dominates and points along c − μ_j, so the saturated
ċ leaves the ε level set at speed v_c: claim (ii) part 1 holds as long as that level set
does not approach faster than v_c (for a translating obstacle, its speed). When some
q_j ≤ ε_j already (a belief that jumped, a new obstacle, an obstacle faster than v_c) the
law is in *recovery*: ċ = v_c·u/‖u‖ with u = Σ_{j: q_j ≤ ε_j} (c − μ_j)/‖c − μ_j‖, the
direction in which those q_j increase fastest (∇_c q_j is along c − μ_j for isotropic
beliefs), until every q_j > ε_j again. Nothing is floored, so the centre never jumps; the
invariant monitor reports the violated margins honestly.

In 3D, v_j ⟂ m_j cannot be a continuous function of m_j alone on the whole sphere (the
hairy-ball theorem), which is why the goal-based choice flipped across the
obstacle–target line. The law therefore takes a circulation axis ω_j per obstacle, chosen
once when obstacle j activates (ω = m̂ × (η − c), so v_j starts along the goal) and carried
along while it stays active (:func:`carry_circulation`): v_j = |m_j|·(ω_j × m̂_j)/|ω_j × m̂_j|.

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

The update (:meth:`TubeLaw.advance`) at t_k, from the centre c_k reached at t_k:

* it integrates the law with the look-ahead lower bound Q^{2h} in place of q_j, in
  sub-steps that keep every positive gap Q^{2h}_j − ε_j at least half of what it was
  (fraction to the boundary), at |ċ| ≤ v_c, giving c_{k+1};
* it certifies the straight segment [c_k, c_{k+1}] with Q^h: every obstacle whose
  Q^h_j(c_k) > ε_j must keep the segment's lower bound > ε_j, else c_{k+1} is pulled back
  towards c_k (c_k itself passes);
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
choice of ν, claim iii). Hence r(t) ≤ d̂_j(c(t), t) at every instant (the ball is
certified, claim ii), and the radius can fall as fast as the centre approaches an obstacle
(the first version required D_j ≥ r_k, which let r fall only by the soft-min slack per
period and stalled the centre in front of thin barriers at 10-20 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from stt_drake.core import backend
from stt_drake.core.belief import ObstacleBelief, record_size
from stt_drake.core.probability import (
    COMPILED_DIMENSIONS,
    PRUNE_HEADROOM_NU,
    avoid_probability,
    period_avoid_probability,
    quantile_distance,
    segment_avoid_lower_bound,
    segment_quantile_lower_bound,
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


def null_space_direction(
    m: np.ndarray, goal_direction: np.ndarray, circulation: np.ndarray | None = None
) -> np.ndarray:
    """v_j ⟂ m_j with |v_j| = |m_j| (rows are obstacles).

    n = 2: m rotated by +90°. n = 3 with a circulation axis ω_j (row of `circulation`, zero
    = none chosen): along ω_j × m_j. Otherwise (n ≥ 3): the part of the goal direction
    orthogonal to m, falling back to a fixed axis (e_z, then e_x) where the goal direction
    is parallel to m. n = 1: zero (R¹ has no orthogonal direction).
    """
    count, dimension = m.shape
    if dimension == 1:
        return np.zeros_like(m)
    if dimension == 2:
        return np.column_stack([-m[:, 1], m[:, 0]])
    norm_m = np.linalg.norm(m, axis=1, keepdims=True)
    unit_m = m / np.where(norm_m > 0.0, norm_m, 1.0)
    direction = np.empty_like(m)
    chosen = np.zeros(count, dtype=bool)
    if dimension == 3 and circulation is not None and len(circulation) == count:
        turned = np.cross(circulation, unit_m)
        length = np.linalg.norm(turned, axis=1)
        chosen = length > CIRCULATION_MIN_SINE
        direction[chosen] = turned[chosen] / length[chosen, None]
    candidates = [np.broadcast_to(goal_direction, m.shape)]
    for axis in (dimension - 1, 0):
        candidates.append(np.broadcast_to(np.eye(dimension)[axis], m.shape))
    for candidate in candidates:
        orthogonal = candidate - np.sum(candidate * unit_m, axis=1, keepdims=True) * unit_m
        length = np.linalg.norm(orthogonal, axis=1)
        usable = ~chosen & (length > 1e-6 * np.maximum(np.linalg.norm(candidate, axis=1), 1e-300))
        direction[usable] = orthogonal[usable] / length[usable, None]
        chosen |= usable
    return direction * norm_m


#: A circulation axis ω is used while |ω × m̂| exceeds this (same as the compiled kernel).
CIRCULATION_MIN_SINE = 1e-3


def carry_circulation(
    axes: np.ndarray, center: np.ndarray, mean: np.ndarray, active: np.ndarray, goal: np.ndarray
) -> np.ndarray:
    """The circulation axes ω_j (rows, 3D) after one step: zero where obstacle j is not
    active (θ_j = 0); chosen as m̂_j × (η − c) where it has just activated (falling back to
    m̂ × e_z, then m̂ × e_x, when the goal lies along m̂); otherwise carried along, i.e. made
    orthogonal to the current m̂_j again and renormalised (re-chosen if that degenerates).
    m̂_j = (c − μ_j)/‖c − μ_j‖ has the direction of m_j (q_j > ε_j while it is active).

    One call of the compiled :func:`stt_drake.core._kernels.carry_circulation` unless the numpy
    path is selected (the code below is its reference)."""
    kernels = backend.kernels()
    if kernels is not None:
        return kernels.carry_circulation(
            np.asarray(axes, dtype=float),
            np.asarray(center, dtype=float),
            np.asarray(mean, dtype=float),
            np.asarray(active, dtype=bool),
            np.asarray(goal, dtype=float),
        )
    offset = np.asarray(center, dtype=float) - np.asarray(mean, dtype=float)
    unit_m = offset / np.maximum(np.linalg.norm(offset, axis=1, keepdims=True), 1e-300)
    carried = axes - np.sum(axes * unit_m, axis=1, keepdims=True) * unit_m
    length = np.linalg.norm(carried, axis=1)
    result = np.zeros_like(axes)
    keep = active & (length > 1e-6)
    result[keep] = carried[keep] / length[keep, None]
    fresh = active & ~keep
    for candidate in (goal, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])):
        axis = np.cross(unit_m, np.broadcast_to(candidate, unit_m.shape))
        length = np.linalg.norm(axis, axis=1)
        usable = fresh & (length > 1e-6 * max(float(np.linalg.norm(candidate)), 1e-300))
        result[usable] = axis[usable] / length[usable, None]
        fresh &= ~usable
    return result


@dataclass(frozen=True)
class TubeEvaluation:
    """Everything the tube law gives at one instant.

    Attributes:
        center_rate: (n,) ċ of eq. (cen_dynamic) saturated at max_center_speed, or the
            recovery velocity, m/s.
        radius: r of eq. (rad_sol), metres.
        avoid_probability: (m,) q_j(c, t) of eq. (prob_q) (its period lower bound when the
            law was evaluated with a horizon).
        quantile_distance: (m,) d̂_j of eq. (m_crv), metres (a lower bound where pruned).
        theta: (m,) switching gains θ_j (at their largest in-law value 1/ε_j − 1/p_d_j
            where q_j ≤ ε_j: the recovery velocity does not use them).
    """

    center_rate: np.ndarray
    radius: float
    avoid_probability: np.ndarray
    quantile_distance: np.ndarray
    theta: np.ndarray


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
    """

    center: np.ndarray
    certified: np.ndarray
    substeps: int
    start_radius: float
    end_radius: float


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
        max_center_speed: v_c, the bound on |ċ| and the recovery speed (m/s). Infinite
            means unbounded: a recovery then has no finite speed and its ċ is not finite
            (the Drake system stops the run and says so).
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
                "exact": constants(np.inf),
                "rate": constants(-np.inf),
            },
        )

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
        kernels = backend.kernels()
        if kernels is None or belief.mean.shape[-1] not in COMPILED_DIMENSIONS:
            return self._evaluate_numpy(center, belief, mode, circulation, inflation)
        k2, k3, constants = self._gains_for(belief.mean.shape[0])
        reach, spread, axes = _kernel_extras(belief.mean.shape, circulation, inflation)
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
                reach,
                spread,
                axes,
                constants[mode],
            )
        )

    def evaluate_packed(
        self,
        center: np.ndarray,
        belief_vector: np.ndarray,
        prune: bool = True,
        circulation: np.ndarray | None = None,
    ) -> TubeEvaluation:
        """:meth:`evaluate` on a belief port vector (layout of :mod:`stt_drake.core.belief`),
        without building the :class:`ObstacleBelief` (the Drake system's hot path)."""
        kernels = backend.kernels()
        dimension = len(center)
        mode = "pruned" if prune else "exact"
        if (
            kernels is None
            or dimension not in COMPILED_DIMENSIONS
            or len(belief_vector) % record_size(dimension)  # from_vector names the problem
        ):
            belief = ObstacleBelief.from_vector(belief_vector, dimension)
            return self._evaluate_numpy(center, belief, mode, circulation, None)
        count = len(belief_vector) // record_size(dimension)
        k2, k3, constants = self._gains_for(count)
        reach, spread, axes = _kernel_extras((count, dimension), circulation, None)
        return TubeEvaluation(
            *kernels.tube_step_packed(
                np.asarray(center, dtype=float),
                np.asarray(belief_vector, dtype=float),
                k2,
                k3,
                reach,
                spread,
                axes,
                constants[mode],
            )
        )

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
        if inflation is None:
            q = avoid_probability(center, belief.mean, belief.sigma, safety_radius)
        else:
            q = period_avoid_probability(
                center, belief.mean, belief.sigma, safety_radius, *inflation
            )
        prune_above = {"pruned": self.prune_above, "exact": None, "rate": -np.inf}[mode]
        d_hat = quantile_distance(
            center, belief.mean, belief.sigma, belief.radius, belief.epsilon, prune_above
        )
        active = q <= belief.p_d
        violated = q <= belief.epsilon
        theta = np.zeros_like(q)
        # In recovery θ_j is unused; it is reported at its largest in-law value 1/ε − 1/p_d.
        theta[active] = (
            1.0 / np.maximum(q[active], belief.epsilon[active]) - 1.0 / belief.p_d[active]
        )
        goal_direction = self.target - center
        rate = signed_cube_root_attraction(goal_direction, self.k1, self.linear_zone)
        if np.any(violated):
            rate = self._recovery_velocity(center, belief.mean[violated], goal_direction)
        else:
            if np.any(active):
                gap = q[active] - belief.epsilon[active]
                m = (center - belief.mean[active]) / gap[:, None]
                axes = None if circulation is None else np.asarray(circulation)[active]
                v = null_space_direction(m, goal_direction, axes)
                k2 = np.broadcast_to(self.k2, q.shape)[active]
                k3 = np.broadcast_to(self.k3, q.shape)[active]
                weights = theta[active, None]
                rate = rate + np.sum((k2[:, None] * m + k3[:, None] * v) * weights, axis=0)
            speed = float(np.linalg.norm(rate))
            if speed > self.max_center_speed:
                rate = rate * (self.max_center_speed / speed)
        return TubeEvaluation(
            center_rate=rate,
            radius=self.radius(d_hat),
            avoid_probability=q,
            quantile_distance=d_hat,
            theta=theta,
        )

    def _recovery_velocity(
        self, center: np.ndarray, means: np.ndarray, goal_direction: np.ndarray
    ) -> np.ndarray:
        """v_c along Σ (c − μ_j)/‖c − μ_j‖ over the violated obstacles (the goal direction,
        else e_0, when those cancel)."""
        offset = center - means
        distance = np.linalg.norm(offset, axis=1, keepdims=True)
        escape = np.sum(
            np.where(distance > 0.0, offset / np.where(distance > 0.0, distance, 1.0), 0.0), axis=0
        )
        for direction in (escape, goal_direction):
            size = float(np.linalg.norm(direction))
            if size > 1e-9:
                return self.max_center_speed * direction / size
        rate = np.zeros_like(center, dtype=float)
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
        sampled at its start (module docstring, "Discrete-time guarantee").

        The law runs with the look-ahead bound Q^{2h} (from `bounds`; None = a belief that
        does not move) in sub-steps at |ċ| ≤ v_c: the attraction's exact flow when no
        obstacle acts, else an explicit step of the law (its linear zone keeps that step
        from overshooting η). A sub-step is accepted only if every positive gap
        Q^{2h}_j − ε_j stays at least half of what it was, else it is halved; after an
        accepted one the next may double. Then the segment from `center` to the result is
        certified with Q^h and pulled back until it is, and until the end radius it allows
        (:func:`end_radius_bound`, from `radius`, the tube radius at the start of the
        period; NaN: none yet) is at least r_min for every certified obstacle. The radius
        moves linearly over the period from its start value to the soft-min of those limits
        and the look-ahead's distance bounds at the new centre, so the whole ball is
        certified too (module docstring, "The radius over a period").

        One call of the compiled :func:`stt_drake.core._kernels.tube_advance` for n ≤ 3 (unless
        the numpy path is selected); the code below is its reference.

        Returns:
            the :class:`FixedRateUpdate`; never raises for lack of progress (a period the
            sub-steps cannot cover is held where they got to, which stays certified).
        """
        center = np.array(center, dtype=float)
        count = belief.count
        bounds = bounds if bounds is not None else BeliefRateBounds.still(count)
        kernels = backend.kernels()
        if kernels is not None and belief.dimension in COMPILED_DIMENSIONS:
            k2, k3, constants = self._gains_for(count)
            _reach, _spread, axes = _kernel_extras(belief.mean.shape, circulation, None)
            position, certified, accepted, start_radius, end_radius = kernels.tube_advance(
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
            return FixedRateUpdate(position, certified, accepted, start_radius, end_radius)
        look_ahead = bounds.inflation(belief.sigma, 2.0 * duration)
        position, evaluation = (
            center,
            self._evaluate(center, belief, "rate", circulation, look_ahead),
        )
        remaining, step, accepted = duration, duration, 0
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
            if np.all((gap <= 0.0) | (new_gap >= 0.5 * gap)):
                position, evaluation = candidate, candidate_evaluation
                remaining -= step
                accepted += 1
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
        for _halving in range(60):
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
            position = center + 0.5 * (position - center)
        else:
            position = center
            certified = must_hold
            allowed = at_start
        ahead = distance_bound(position, position, look_ahead)
        end_radius = self.radius(np.minimum(allowed, ahead))
        return FixedRateUpdate(position, certified, accepted, start_radius, end_radius)

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
