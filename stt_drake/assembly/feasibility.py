"""What a scenario asks of the plant and of the fixed-rate tube, checked before a run.

Pure numpy (the arm's lever arms come from its model, loaded only for arm scenarios).

*Following speed.* The controller saturates its normalised error at 1 − 1e-9
(:data:`stt_drake.core.control.ERROR_SATURATION`), so ρ₁ ≤ ρ_max ≈ 21.4: at the tube boundary
stage 1 pulls the output back at no more than κ₁·ρ_max·r. With r ≥ r_low = r_min −
ln(n_o + 1)/ν (Theorem 3.2 (iii), while every q_j > ε_j), the output can close on the centre at

    available = g·κ₁·ρ_max·r_low − (what the plant adds on its own)

with g ≤ 1 the plant's worst gain on the command (the omni base's wheel-radius ratio) and
the second term its disturbance bound (omni: ‖disturbance_amplitude‖) or the inner
funnel's tracking band (UAV: ‖q₂‖, the velocity funnel's final box; arm: Σ_i ℓ_i q₂,i, the
joint-velocity funnel's final box through lever arms ℓ_i ≥ ‖∂y/∂q_i‖). The final box, not
the initial one: during the inner funnel's transient (about 1/μ₂ s from the start) the band
is wider, up to p₂, which this check does not cover — with the arm's p₂ the worst-case
band alone would exceed the saturated stage-1 pull.

*Tube demand.* The boundary of Γ moves towards the output at |ċ| + |ṙ|. |ċ| ≤ v_c
(max_center_speed). d̂_j is 1-Lipschitz in c and in μ_j (a quantile of ‖c − O_j‖), and in σ
|∂(d̂_j + r_o)/∂σ| ≤ (d̂_j + r_o + ‖c − μ_j‖)/σ ≤ (2(d̂_j + r_o) + σ z_ε)/σ (the scale coupling
of :mod:`stt_drake.core.fixed_rate`, with ‖c − μ‖ ≤ d̂ + r_o + σ z_ε, z_ε the ε-quantile of a central
χ_n); the soft-min radius moves no faster than its fastest argument, and only arguments up
to r_max + 40/ν matter. So the demand is 2·v_c + max_j w_j with the level-set speed
w_j = v̄_j + s̄_j (2(r_max + 40/ν + r_o_j) + σ_max,j z_ε)/σ_min,j. Theorem 4.1 under the
saturated controller needs demand < available; otherwise the run warns (it does not
refuse: the bound is worst case).

*Update period.* The fixed-rate tube looks ahead two periods (module
:mod:`stt_drake.core.fixed_rate`). A period h is admissible when, for every obstacle, the look-ahead
growth stays within the obstacle's own size — 2 v̄_j h ≤ r_o_j + r_min (the mean moves at
most one safety radius) and 2 s̄_j h ≤ σ_min,j/2 (σ at most halves) — and the start is
certified for the first period, Q^h_j(s) > ε_j at t = 0.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from stt_drake.config import (
    FrankaArm,
    OmniRobot,
    Quadrotor,
    Scenario,
    ScenarioError,
)
from stt_drake.config.source import short_repr
from stt_drake.core.belief import obstacle_rate_bounds, obstacle_sigma_bounds
from stt_drake.core.control import ERROR_SATURATION, transformed_error
from stt_drake.core.fixed_rate import BeliefRateBounds
from stt_drake.core.probability import PRUNE_HEADROOM_NU, period_avoid_probability
from stt_drake.core.tube import default_nu
from stt_drake.systems.plants.franka import fr3_lever_arm_bounds

#: ρ₁ at the saturated error: the largest pull-back gain of stage 1 (≈ 21.4).
RHO_MAX = float(transformed_error(np.array(ERROR_SATURATION)))

#: The derived max_center_speed leaves the output this share of its spare following speed.
_DERIVED_SPEED_SHARE = 1.0 / 3.0


def radius_lower_bound(scenario: Scenario) -> float:
    """r_low = r_min − ln(n_o + 1)/ν: the radius while every q_j > ε_j (Theorem 3.2 (iii)); r_max
    without obstacles."""
    count = len(scenario.obstacles)
    if count == 0:
        return scenario.tube.r_max
    return scenario.tube.r_min - math.log(count + 1) / scenario.nu


def following_terms(scenario: Scenario, nu: float | None = None) -> tuple[float, float, str]:
    """(pull, loss, what the loss is): the saturated stage-1 pull-back at the tube boundary,
    g·κ₁·ρ_max·r_low (m/s; r_low with `nu` in place of the scenario's ν when given), and
    what the plant adds on its own (m/s; module docstring)."""
    if nu is None:
        r_low = radius_lower_bound(scenario)
    else:
        count = len(scenario.obstacles)
        r_low = (
            scenario.tube.r_max if count == 0 else scenario.tube.r_min - math.log(count + 1) / nu
        )
    stage_one = scenario.controller.kappa[0] * RHO_MAX * max(r_low, 0.0)
    plant = scenario.plant
    if isinstance(plant, OmniRobot):
        gain = min(1.0, plant.wheel_radius / plant.nominal_wheel_radius)
        loss = float(np.linalg.norm(plant.disturbance_amplitude))
        return gain * stage_one, loss, "‖disturbance_amplitude‖"
    band = np.asarray(scenario.controller.funnels[0].end, dtype=float)
    if isinstance(plant, Quadrotor):
        return stage_one, float(np.linalg.norm(band)), "the velocity funnel's final band"
    if isinstance(plant, FrankaArm):
        loss = float(fr3_lever_arm_bounds() @ band)
        return stage_one, loss, "the joint-velocity funnel's final band through the lever arms"
    raise TypeError(f"no following speed for plant {type(plant).__name__}")


def following_speed(scenario: Scenario) -> float:
    """The speed (m/s) at which the saturated controller can bring the output back towards
    the centre at the tube boundary, after what the plant adds (module docstring); ≤ 0 when
    the plant's own drift can outrun the pull-back (refused at load when max_center_speed
    is derived, :func:`validate_real_time`)."""
    pull, loss, _what = following_terms(scenario)
    return pull - loss


def level_set_speeds(scenario: Scenario) -> np.ndarray:
    """w_j (m/s): how fast obstacle j's quantile distance d̂_j can change with its belief."""
    mean_speed, sigma_rate = obstacle_rate_bounds(scenario.obstacles)
    n = scenario.dimension
    speeds = mean_speed.copy()
    reach = scenario.tube.r_max + PRUNE_HEADROOM_NU / scenario.nu
    for j, obstacle in enumerate(scenario.obstacles):
        if sigma_rate[j] == 0.0:
            continue
        low, high = obstacle_sigma_bounds(obstacle)
        z = math.sqrt(stats.chi2.ppf(obstacle.epsilon, n))
        scale = 2.0 * (reach + obstacle.radius) + high * z
        speeds[j] += sigma_rate[j] * scale / low
    return speeds


def center_speed(scenario: Scenario) -> float:
    """v_c: `tube.max_center_speed`, or when 0 a third of the following speed left after
    the fastest level set, so that the demand 2 v_c + w stays below what the plant can
    follow.

    The arithmetic: with F = :func:`following_speed` and w = the fastest level set,
    v_c = (F − w)/3 when F > w (then 2 v_c + w = (2F + w)/3 < F), else F/3 (no v_c keeps
    the demand below F; the run warns). Both are > 0 exactly when F > 0. F ≤ 0 — the
    plant's drift at least the saturated pull-back κ₁·ρ_max·r_low, e.g. a given ν just
    above ln(n_o + 1)/r_min makes r_low tiny — has no positive v_c at all (the output can
    leave the tube whatever the centre does), and such a scenario is refused at load
    (:func:`validate_real_time`), so a validated scenario's v_c is positive."""
    if scenario.tube.max_center_speed > 0.0:
        return scenario.tube.max_center_speed
    spare = following_speed(scenario) - float(np.max(level_set_speeds(scenario), initial=0.0))
    return _DERIVED_SPEED_SHARE * (spare if spare > 0.0 else following_speed(scenario))


def rate_bounds(scenario: Scenario) -> BeliefRateBounds:
    """The belief rate bounds of the scenario's obstacles (motion models, σ schedules)."""
    return BeliefRateBounds(*obstacle_rate_bounds(scenario.obstacles))


def admissible_period(scenario: Scenario) -> tuple[float, str]:
    """The longest admissible update period (s) and the rule that sets it (module
    docstring, "Update period"); (inf, "") when nothing limits it."""
    mean_speed, sigma_rate = obstacle_rate_bounds(scenario.obstacles)
    best, reason = math.inf, ""
    r_min = scenario.tube.r_min
    for j, obstacle in enumerate(scenario.obstacles):
        if mean_speed[j] > 0.0:
            limit = (obstacle.radius + r_min) / (2.0 * mean_speed[j])
            if limit < best:
                best, reason = (
                    limit,
                    (
                        f"obstacle {j} moves up to {mean_speed[j]:.4g} m/s and may not move more "
                        f"than its safety radius r_o + r_min = {obstacle.radius + r_min:.4g} m "
                        "within the look-ahead of two periods"
                    ),
                )
        if sigma_rate[j] > 0.0:
            limit = obstacle_sigma_bounds(obstacle)[0] / (4.0 * sigma_rate[j])
            if limit < best:
                best, reason = (
                    limit,
                    (
                        f"obstacle {j}'s σ changes at up to {sigma_rate[j]:.4g} m/s and may "
                        "at most "
                        "halve within the look-ahead of two periods"
                    ),
                )
    start_limit = _start_certified_period(scenario, best)
    if start_limit < best:
        best, reason = (
            start_limit,
            ("the start must stay certified clear of every obstacle for the first period"),
        )
    return best, reason


def _start_certified_period(scenario: Scenario, upper: float) -> float:
    """The longest h ≤ upper (bisection) with Q^h_j(s, 0) > ε_j for every obstacle."""
    if not scenario.obstacles:
        return math.inf
    belief = scenario.belief_at(0.0)
    bounds = rate_bounds(scenario)
    start = np.asarray(scenario.start, dtype=float)
    radius = belief.radius + scenario.tube.r_min

    def certified(h: float) -> bool:
        reach, spread = bounds.inflation(belief.sigma, h)
        q = period_avoid_probability(start, belief.mean, belief.sigma, radius, reach, spread)
        return bool(np.all(q > belief.epsilon))

    high = upper if math.isfinite(upper) else 3600.0
    if certified(high):
        return math.inf if not math.isfinite(upper) else upper
    low = 0.0
    for _ in range(50):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if certified(middle) else (low, middle)
    return low


def validate_real_time(scenario: Scenario) -> None:
    """Refuse a max_center_speed the plant cannot follow and an update period that is too
    long for the obstacles (ScenarioError naming the field, the rule and the limit)."""
    tube = scenario.tube  # finite and ≥ 0 already (stt_drake.core.rules.check_center_speed)
    available = following_speed(scenario)
    if tube.max_center_speed == 0.0 and available <= 0.0:
        raise ScenarioError(_unfollowable(scenario, available))
    if tube.max_center_speed > 0.0 and tube.max_center_speed >= available:
        raise ScenarioError(
            "scenario.tube.max_center_speed: must be below the speed the plant can follow "
            f"under the controller's saturation, {available:.4g} m/s (κ₁·ρ_max·r_low less the "
            f"plant's own disturbance or tracking error) (got {tube.max_center_speed!r})"
        )
    if tube.update_rate_hz > 0.0:
        period = 1.0 / tube.update_rate_hz
        longest, reason = admissible_period(scenario)
        if period > longest:
            raise ScenarioError(
                f"scenario.tube.update_rate_hz: the period 1/{tube.update_rate_hz:g} Hz = "
                f"{period:.4g} s is too long: {reason}; the largest admissible period is "
                f"{longest:.4g} s (update_rate_hz ≥ {1.0 / longest:.4g})"
            )


def _unfollowable(scenario: Scenario, available: float) -> str:
    """The refusal of a scenario whose following speed is ≤ 0 with a derived
    max_center_speed: the numbers, and the field to change (tube.nu when a given ν is why,
    i.e. the derived ν = 2 ln(n_o + 1)/r_min would leave a positive speed)."""
    tube = scenario.tube
    pull, loss, what = following_terms(scenario)
    derived_nu = default_nu(len(scenario.obstacles), tube.r_min)
    derived_pull, _, _ = following_terms(scenario, derived_nu)
    given_nu = tube.nu > 0.0 and derived_pull > loss
    path = "scenario.tube.nu" if given_nu else "scenario.tube.max_center_speed"
    fix = (
        f"raise nu (0 derives {derived_nu:.4g}, r_low = r_min/2, which leaves "
        f"{derived_pull - loss:.4g} m/s)"
        if given_nu
        else "raise controller.kappa or tube.r_min, or lower the plant's disturbance"
    )
    return (
        f"{path}: no max_center_speed can be derived: the plant can follow at "
        f"{available:.4g} m/s ≤ 0 — the saturated controller pulls back at most "
        f"κ₁·ρ_max·r_low = {pull:.4g} m/s (κ₁ = {scenario.controller.kappa[0]:g}, "
        f"ρ_max = {RHO_MAX:.3g}, r_low = r_min − ln(n_o + 1)/ν = "
        f"{radius_lower_bound(scenario):.4g} m with ν = {scenario.nu:.6g}), and "
        f"{what} adds {loss:.4g} m/s — so the output can leave the tube whatever the centre "
        f"does (max_center_speed would be {available / 3.0:.3g} m/s: the centre could not "
        f"move); {fix} (got {short_repr(tube.nu if given_nu else tube.max_center_speed)})"
    )


def scenario_warnings(scenario: Scenario) -> list[str]:
    """Validation warnings: what the scenario allows but the guarantees cannot cover."""
    warnings = []
    speed = center_speed(scenario)
    levels = level_set_speeds(scenario)
    available = following_speed(scenario)
    demand = 2.0 * speed + float(np.max(levels, initial=0.0))
    if demand >= available:
        warnings.append(
            "Theorem 4.1 cannot be guaranteed: the tube boundary may move towards the output "
            f"at up to {demand:.4g} m/s (2·max_center_speed + the fastest level set), but the "
            f"saturated controller can follow at {available:.4g} m/s "
            f"(κ₁·ρ_max·r_low with ρ_max = {RHO_MAX:.3g})"
        )
    for j in np.flatnonzero(levels >= speed):
        warnings.append(
            f"claim (ii) cannot be guaranteed for obstacle {j}: its level set may move at "
            f"{levels[j]:.4g} m/s, not slower than max_center_speed = {speed:.4g} m/s, the "
            "speed at which the centre leaves an ε level set (the law's boundary layer), so "
            "it can overtake the centre"
        )
    return warnings
