"""Is a Kalman track consistent with its own noise model? The normalised innovation squared
(NIS) test, adaptive process noise and the belief's calibration against the truth.

NIS (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, ch. 5.4): at each correction of a track in R^n the innovation y = z − p̂⁻ and
its predicted covariance S = P⁻_pp + R give ν = yᵀ S⁻¹ y, which is χ²_n distributed and
independent over time when the filter's model is the truth's. The **window test** sums the
last k = min(updates, W) values (W = ``window``): Σν ~ χ²_{k·n}, inside the two-sided
interval [χ²_{k·n}((1 − c)/2), χ²_{k·n}((1 + c)/2)] with probability c (``confidence``).
Above it the track is *overconfident* (its covariance is too small for the errors it
makes: a manoeuvre the constant-velocity model does not have, or too little process
noise); below it, underconfident (conservative). The bounds are χ² quantiles taken once,
at construction (scipy), for k = 1..W.

Adaptive process noise (``adaptive``): the white-acceleration density of track j is
q_j = q_base·s_j with a scale s_j ∈ [1, s_max] adapted at each correction by a bounded
multiplicative covariance-matching rule (a stochastic approximation on E[ν] = n):

    u = min(ν/n − 1, c_step),   s ← clip(s · exp(β · (u if u > 0 else ρ·u)), 1, s_max),

with β = ``gain``, c_step = ``step_cap`` and ρ = ``relax`` < 1, and the prediction of that
same correction is topped up with the extra noise (q_base·(s_new − s_old)·Q₁(Δt)), so a
large innovation widens the covariance at once, before the correction. When the track is
consistent again, ν/n averages below 1 at the raised s and the scale relaxes
geometrically, ρ times slower than it rose; it never goes below 1 (the model's own q).
With ρ < 1 the scale settles where E[ν] ≈ 0.8·n (for n = 2, ρ = 0.7), not at n: a
deliberately conservative filter (a consistent model's scale hovers a few times above 1),
which buys calibration on manoeuvring obstacles (measured: docs/guide/perception.md, "A
tracker that checks itself"). q_base is the model's density, or ``density_floor`` if that
is larger (a model with q = 0 has nothing to scale), and s_max = ``density_ceiling``/q_base.

With ``adaptive`` off the test still runs (the NIS is reported) and the filter is exactly
the constant-velocity filter of :mod:`stt_drake.core.tracking`.

Calibration (:func:`calibration_counts`): the fraction of times at which the true centre
O lies in the belief's 95 % ellipsoid, (O − μ)ᵀ Σ⁻¹ (O − μ) ≤ χ²_n(0.95).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

#: The belief's ellipsoid whose coverage of the true centre is the calibration.
CALIBRATION_LEVEL = 0.95
#: Calibration below this (with confidence: :func:`calibration_upper_bound`) is reported as
#: a warning by a run.
CALIBRATION_WARNING = 0.90
#: z of the one-sided 99 % bound on one run's calibration.
CALIBRATION_Z = 2.326
#: A track overconfident (window test above its interval) for more than this share of its
#: tracked time is reported as inconsistent by a run (a consistent one: about (1 − c)/2).
OVERCONFIDENT_SHARE = 0.2
#: β of the scale rule (per correction) and the cap on ν/n − 1 in one step.
DEFAULT_GAIN = 0.5
DEFAULT_STEP_CAP = 5.0
#: The down-steps' share of β: the scale rises at once and relaxes more slowly.
DEFAULT_RELAX = 0.7


@dataclass(frozen=True)
class Adaptation:
    """The NIS window test and the adaptive process noise (module docstring).

    Attributes:
        dimension: n.
        window: W, updates in the window test (≥ 1).
        confidence: c in (0, 1), the two-sided χ² interval's probability.
        adaptive: whether the process noise adapts (else the test only reports).
        density_floor: the smallest q_base (m²/s³), used when the model's q is smaller.
        density_ceiling: the largest adapted density q_base·s (m²/s³).
        gain: β of the scale rule.
        step_cap: the cap c_step on ν/n − 1 in one step.
        relax: ρ, the factor on the steps down (ν < n).
    """

    dimension: int
    window: int = 10
    confidence: float = 0.95
    adaptive: bool = True
    density_floor: float = 0.0
    density_ceiling: float = math.inf
    gain: float = DEFAULT_GAIN
    step_cap: float = DEFAULT_STEP_CAP
    relax: float = DEFAULT_RELAX
    lower: np.ndarray = field(init=False, repr=False, compare=False)
    upper: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.window < 1 or not 0.0 < self.confidence < 1.0:
            raise ValueError(
                f"Adaptation: window must be ≥ 1 and confidence in (0, 1), got "
                f"{self.window}, {self.confidence}"
            )
        if not 0.0 <= self.density_floor <= self.density_ceiling:
            raise ValueError(
                "Adaptation: need 0 ≤ density_floor ≤ density_ceiling, got "
                f"{self.density_floor}, {self.density_ceiling}"
            )
        dof = self.dimension * np.arange(1, self.window + 1)
        tail = 0.5 * (1.0 - self.confidence)
        object.__setattr__(self, "lower", chi2.ppf(tail, dof))
        object.__setattr__(self, "upper", chi2.isf(tail, dof))

    def base_density(self, density: float) -> float:
        """q_base for a model density q (m²/s³): q, raised to the floor when adaptive."""
        return max(density, self.density_floor) if self.adaptive else density

    def max_scale(self, density: float) -> float:
        """s_max = density_ceiling / q_base (≥ 1; 1 when not adaptive)."""
        base = self.base_density(density)
        if not self.adaptive or base <= 0.0:
            return 1.0
        return max(1.0, self.density_ceiling / base)

    @property
    def step_gain(self) -> float:
        """β in force: 0 when not adaptive."""
        return self.gain if self.adaptive else 0.0


def mahalanobis_squared(truth: np.ndarray, mean: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(O − μ)ᵀ Σ⁻¹ (O − μ) over leading axes: truth, mean (..., n), covariance (..., n, n)."""
    error = truth - mean
    return np.einsum("...a,...a->...", error, np.linalg.solve(covariance, error[..., None])[..., 0])


def calibration_inside(
    truth: np.ndarray, mean: np.ndarray, covariance: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(T, m) whether the true centre lay inside the belief's :data:`CALIBRATION_LEVEL`
    ellipsoid at each logged time (False without a track), and (T, m) whether there was a
    track; truth and mean (T, m, n), covariance (T, m, n, n), active (T, m). A true centre
    that does not exist (NaN: a recorded obstacle outside its span) is never inside."""
    n = truth.shape[-1]
    active = np.asarray(active, dtype=bool)
    safe = np.where(active[..., None, None], covariance, np.eye(n))
    distance = mahalanobis_squared(truth, mean, safe)
    return (distance <= chi2.ppf(CALIBRATION_LEVEL, n)) & active, active


def calibration_counts(
    truth: np.ndarray, mean: np.ndarray, covariance: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per slot, (times with the true centre inside the belief's :data:`CALIBRATION_LEVEL`
    ellipsoid, times with a track) (:func:`calibration_inside`)."""
    inside, active = calibration_inside(truth, mean, covariance, active)
    return inside.sum(axis=0), active.sum(axis=0)


def calibration_upper_bound(inside: np.ndarray, z: float = CALIBRATION_Z) -> tuple[float, float]:
    """(upper, effective samples): a one-sided upper confidence bound on a track's
    calibration from its inside/outside series (bool, one per tracked logged time), and
    the number of independent samples the series is worth.

    One run's errors are correlated in time (a belief that is off stays off for a while),
    so its N logged times are not N samples: the series is read as a two-state Markov
    chain with lag-1 autocorrelation ρ, whose sample mean has the variance of
    N_eff = N(1 − ρ)/(1 + ρ) independent samples (ρ clipped to [0, 0.999]). The bound is
    Wilson's score bound at z (default 2.326: one-sided 99 %) with N_eff samples. A run
    warns only when even that bound lies below :data:`CALIBRATION_WARNING`."""
    x = np.asarray(inside, dtype=float)
    count = x.size
    if count == 0:
        return 1.0, 0.0
    p = float(x.mean())
    rho = 0.0
    if count > 2 and 0.0 < p < 1.0:
        centred = x - p
        rho = float(np.dot(centred[:-1], centred[1:]) / np.dot(centred, centred))
    rho = min(max(rho, 0.0), 0.999)
    effective = max(count * (1.0 - rho) / (1.0 + rho), 1.0)
    z2 = z * z / effective
    spread = z * math.sqrt(p * (1.0 - p) / effective + z2 / (4.0 * effective))
    return min((p + z2 / 2.0 + spread) / (1.0 + z2), 1.0), effective


def run_nis_bounds(updates: int, dimension: int, confidence: float) -> tuple[float, float]:
    """The interval of the mean NIS over `updates` corrections of a consistent track,
    χ²_{N·n}((1 ∓ c)/2)/N (N = updates): outside it the whole run's test fails."""
    dof = updates * dimension
    tail = 0.5 * (1.0 - confidence)
    return float(chi2.ppf(tail, dof) / updates), float(chi2.isf(tail, dof) / updates)


#: The adapted density's range in units of r/T³ (the dimensionless tracking index
#: q·T³/r, r = λ_max(R), T the sensor period): q_base ≥ FLOOR_INDEX·r/T³ (a model with a
#: smaller q, zero included, is scaled from there) and q_base·s ≤ CEILING_INDEX·r/T³ (at
#: which the filter follows the detections alone).
FLOOR_INDEX = 1e-6
CEILING_INDEX = 1e2


def density_bounds(noise_covariance: np.ndarray, period: float) -> tuple[float, float]:
    """(density_floor, density_ceiling) in m²/s³ for measurement noise R (n×n, m²) and a
    sensor period T (s): :data:`FLOOR_INDEX` and :data:`CEILING_INDEX` times λ_max(R)/T³."""
    unit = float(np.linalg.eigvalsh(np.asarray(noise_covariance, dtype=float))[-1]) / period**3
    return FLOOR_INDEX * unit, CEILING_INDEX * unit


#: Per-slot fields of :class:`stt_drake.systems.perception.ObstacleTracker`'s `consistency` output.
CONSISTENCY_FIELDS = 7
