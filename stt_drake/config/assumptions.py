"""Assumption 3 of the paper at the target, on the scenario before a run.

Assumption 3: after some time t_1, P(‖c(t) − O_j(t)‖ ≥ r_o_j + r_min) ≥ p_d_j for every
obstacle j and t ≥ t_1 — the obstacles eventually leave the tube's centre, in particular
the target η, alone. :func:`target_separation` evaluates q_j(η, t) over the run.

An assumption of the theorem is not an input error: a scenario that breaks it runs, and
:mod:`stt_drake.story` records every obstacle still within p_d of the target at the end
(metrics.json `assumptions`, with the claim it voids: claim (i) of Theorem 3.2, reaching
the target set in finite time; claims (ii) and (iii), avoidance and a positive radius, do
not use it). Only a strict scenario (`strict: true`, ``stt-drake run --strict``) is refused
when an obstacle covers the target for the whole run (:func:`check_target_separation`).
What can never hold is refused always: p_d = 1 (a Gaussian centre has unbounded support,
so q_j < 1 everywhere; :mod:`stt_drake.config.validate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stt_drake.config.schema import AssumptionError, Scenario
from stt_drake.core import anisotropic
from stt_drake.core.belief import has_full_covariance, obstacle_covariance
from stt_drake.core.motion import MotionTable
from stt_drake.core.probability import avoid_probability

#: How many evenly spaced times over [0, duration] the target separation is checked at.
SEPARATION_CHECKPOINTS = 200


@dataclass(frozen=True)
class TargetSeparation:
    """q_j(η, t) = P(‖η − O_j(t)‖ ≥ r_o_j + r_min) at `times` (k, j), and each p_d_j."""

    times: np.ndarray
    q: np.ndarray
    p_d: np.ndarray

    def below(self) -> np.ndarray:
        """(k, j): the obstacle is within p_d of the target at that time."""
        return self.q < self.p_d[None, :]


def target_separation(
    scenario: Scenario, checkpoints: int = SEPARATION_CHECKPOINTS
) -> TargetSeparation:
    """q_j(η, t) at `checkpoints` times evenly over [0, duration], η the final target: the
    means of all obstacles at all times in one call
    (:meth:`stt_drake.core.motion.MotionTable.positions_at`), the isotropic probabilities
    in one call. An obstacle that does not exist at a time (a recorded track outside its
    span, :meth:`stt_drake.core.motion.MotionTable.active_at`) reads q = 1 there.

    An obstacle with a full covariance Σ_j(t) gets the exact anisotropic probability
    (:func:`stt_drake.core.anisotropic.avoid_probability`): P(‖η − O_j‖ ≥ R) with
    O_j ~ N(μ_j, Σ_j) is P(‖(η − μ_j) − Z‖ ≥ R) with Z ~ N(0, Σ_j), so a constant Σ_j takes
    one call for all times."""
    obstacles = scenario.obstacles
    n = scenario.dimension
    times = np.linspace(0.0, scenario.duration, max(int(checkpoints), 2))
    target = np.asarray(scenario.target, dtype=float)
    table = MotionTable([o.motion for o in obstacles], n)
    radius = np.array([o.radius for o in obstacles], dtype=float) + scenario.tube.r_min
    sigma = np.tile(np.array([o.sigma for o in obstacles], dtype=float), (times.size, 1))
    full = [j for j, o in enumerate(obstacles) if has_full_covariance(o)]
    for j, obstacle in enumerate(obstacles):
        schedule = obstacle.sigma_schedule
        if schedule is not None and j not in full:  # obstacle_sigma's σ(t), for all times
            sigma[:, j] = np.interp(times, schedule.times, schedule.values)
    means = table.positions_at(times)
    if full:  # the isotropic law does not apply to these: any σ > 0 for the one call
        sigma[:, full] = 1.0
    q = avoid_probability(target, means, sigma, radius) if obstacles else sigma
    for j in full:
        offsets = target - means[:, j]
        if obstacles[j].covariance_schedule is None:
            covariance = obstacle_covariance(obstacles[j], 0.0, n)
            q[:, j] = anisotropic.avoid_probability(offsets, np.zeros(n), covariance, radius[j])
        else:
            for k, time in enumerate(times):
                covariance = obstacle_covariance(obstacles[j], float(time), n)
                q[k, j] = anisotropic.avoid_probability(
                    offsets[k], np.zeros(n), covariance, radius[j]
                )
    q = np.where(table.active_at(times), q, 1.0)
    p_d = np.array([o.p_d for o in obstacles], dtype=float)
    return TargetSeparation(times, q, p_d)


#: The claim of Theorem 3.2 that Assumption 3 serves, as metrics.json names it.
VOIDED_CLAIM = "(i)"

#: What a broken Assumption 3 means for the guarantees, as the records' messages say it.
VOIDED_CLAIM_TEXT = (
    "claim (i) of Theorem 3.2 (reaching the target set in finite time, and staying) is void; "
    "claims (ii) and (iii) (avoidance, a positive radius) do not use it"
)


def check_target_separation(scenario: Scenario, strict: bool | None = None) -> None:
    """In a strict scenario (`strict`, default the scenario's own), refuse
    (AssumptionError) an obstacle within p_d of the target at every checkpoint of the run:
    it sits on the target for good, so Assumption 3 cannot hold and the tube, which must
    stay clear of it with probability ≥ ε, can never settle in the target set. Otherwise
    such a scenario runs and the breach is recorded (module docstring)."""
    strict = scenario.strict if strict is None else strict
    if not (strict and scenario.obstacles):
        return
    separation = target_separation(scenario)
    for j in np.flatnonzero(np.all(separation.below(), axis=0)):
        raise AssumptionError(
            f"scenario.obstacles[{j}]: Assumption 3 (separation at the target) is broken: the "
            f"obstacle covers the target for the whole run — P(‖η − O_{j}(t)‖ ≥ r_o + r_min) "
            f"stays below p_d = {separation.p_d[j]:g} from t = 0 to {scenario.duration:g} s "
            f"(at most {float(np.max(separation.q[:, j])):.6g}), so the tube could never "
            f"settle in the target set ({VOIDED_CLAIM_TEXT}); refused because the run is "
            "strict (strict: true or --strict); without it the scenario runs and "
            "metrics.json records the breach; or move the obstacle or the target"
        )
