"""The fixed-rate (real-time) tube: belief rate bounds, the period's radius bound and the
update's result. :meth:`stt_drake.core.tube.TubeLaw.advance` is the update.

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

The update (:meth:`stt_drake.core.tube.TubeLaw.advance`) at t_k, from the centre c_k reached at t_k:

* it integrates the law with the look-ahead lower bound Q^{2h} in place of q_j, in
  sub-steps that keep every positive gap Q^{2h}_j − ε_j at least half of what it was
  (fraction to the boundary) and change no boundary-layer weight by more than
  :data:`stt_drake.core.tube.LAYER_STEP` (explicit steps across the layer's steep field
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

from dataclasses import dataclass

import numpy as np


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
