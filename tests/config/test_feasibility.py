"""What a scenario may ask of the plant and of the fixed-rate tube (stt_drake.assembly.feasibility):
the admissible update period, the speed the saturated controller can follow, the derived
max_center_speed and the validation warnings. Expected values are the closed forms of the
module docstring, computed here from the scenario's numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import ncx2

from stt_drake.assembly import feasibility, parse_scenario
from stt_drake.config import ScenarioError

RHO_MAX = 2.0 * math.atanh(1.0 - 1e-9)  # ρ₁ at the controller's saturated error

OMNI = """
name: feasibility
start: [0.0, 0.0]
target: [6.0, 0.0]
duration: 5.0
tube: {{r_min: 0.1, r_max: 0.3, k1: 0.7, k2: 0.4, k3: 0.4, update_rate_hz: {rate},
        max_center_speed: {speed}}}
controller: {{kappa: [{kappa}]}}
plant:
  wheel_radius: 0.048
  nominal_wheel_radius: 0.05
  disturbance_amplitude: [0.03, 0.04]
obstacles:
  - motion: !ConstantVelocity {{start: [3.0, 2.0], velocity: [0.0, -{obstacle_speed}]}}
    radius: 0.3
    sigma: 0.1
{schedule}    epsilon: 0.9
    p_d: 0.9999
"""


def omni(rate=0.0, speed=1.0, kappa=6.0, obstacle_speed=0.5, schedule=""):
    return OMNI.format(
        rate=rate, speed=speed, kappa=kappa, obstacle_speed=obstacle_speed, schedule=schedule
    )


def following(kappa: float) -> float:
    """g·κ₁·ρ_max·r_low − ‖d‖ for the file above: one obstacle, ν = 2 ln 2/r_min, so
    r_low = r_min/2; g = 0.048/0.05; ‖d‖ = 0.05."""
    return 0.048 / 0.05 * kappa * RHO_MAX * 0.05 - 0.05


def test_following_speed_is_the_saturated_stage_one_pull_less_the_disturbance():
    scenario = parse_scenario(omni(kappa=6.0))
    assert feasibility.following_speed(scenario) == pytest.approx(following(6.0), rel=1e-12)
    assert feasibility.radius_lower_bound(scenario) == pytest.approx(0.05, rel=1e-12)


def test_max_center_speed_the_plant_cannot_follow_is_refused():
    available = following(0.5)
    with pytest.raises(ScenarioError) as info:
        parse_scenario(omni(kappa=0.5, speed=available * 1.01))
    message = str(info.value)
    assert message.startswith("scenario.tube.max_center_speed:")
    assert f"{available:.4g} m/s" in message
    parse_scenario(omni(kappa=0.5, speed=available * 0.99))  # just below: accepted


@pytest.mark.parametrize("bad", [".nan", ".inf", "-1.0"])
def test_max_center_speed_must_be_finite_and_not_negative(bad):
    with pytest.raises(ScenarioError, match=r"scenario\.tube\.max_center_speed: must be finite"):
        parse_scenario(omni(speed=bad))


def test_derived_center_speed_leaves_the_plant_two_thirds_of_its_spare_speed():
    scenario = parse_scenario(omni(speed=0.0, obstacle_speed=0.5))
    expected = (following(6.0) - 0.5) / 3.0
    assert feasibility.center_speed(scenario) == pytest.approx(expected, rel=1e-12)
    assert feasibility.scenario_warnings(scenario) == []  # 2 v_c + w < available


def test_admissible_period_from_the_obstacle_speed():
    # 2 v̄ h ≤ r_o + r_min: h ≤ 0.4/(2·2.0) = 0.1 s; the start is far enough not to bind.
    scenario = parse_scenario(omni(obstacle_speed=2.0))
    longest, reason = feasibility.admissible_period(scenario)
    assert longest == pytest.approx(0.1, rel=1e-12)
    assert "obstacle 0 moves up to 2 m/s" in reason
    parse_scenario(omni(rate=10.0, obstacle_speed=2.0))  # h = 0.1: admissible
    with pytest.raises(ScenarioError) as info:
        parse_scenario(omni(rate=5.0, obstacle_speed=2.0))
    message = str(info.value)
    assert message.startswith("scenario.tube.update_rate_hz:")
    assert "largest admissible period is 0.1 s" in message and "update_rate_hz ≥ 10" in message


def test_admissible_period_from_a_sigma_schedule():
    # σ from 0.1 to 0.5 over 2 s: s̄ = 0.2 m/s, σ_min = 0.1; h ≤ σ_min/(4 s̄) = 0.125 s.
    schedule = "    sigma_schedule: {times: [0.0, 2.0], values: [0.1, 0.5]}\n"
    scenario = parse_scenario(omni(obstacle_speed=0.1, schedule=schedule))
    longest, reason = feasibility.admissible_period(scenario)
    assert longest == pytest.approx(0.125, rel=1e-12)
    assert "σ changes at up to 0.2 m/s" in reason


def test_a_step_in_the_schedule_does_not_limit_the_period():
    # A step (repeated time) is a belief jump, not a rate: only the ramps count.
    schedule = "    sigma_schedule: {times: [0.0, 2.0, 2.0, 5.0], values: [0.1, 0.1, 0.4, 0.4]}\n"
    scenario = parse_scenario(omni(obstacle_speed=0.1, schedule=schedule))
    assert feasibility.rate_bounds(scenario).sigma_rate[0] == 0.0
    assert feasibility.admissible_period(scenario)[0] == pytest.approx(0.4 / 0.2, rel=1e-12)


def test_admissible_period_keeps_the_start_certified():
    """An obstacle heading for the start: the longest h is where the period bound of q at
    the start, q(s; μ shifted by v̄h towards s), reaches ε (scipy), shorter than the
    speed rule (r_o + r_min)/(2 v̄) = 0.4 s."""
    text = omni(obstacle_speed=0.5).replace("start: [3.0, 2.0]", "start: [0.0, 0.6]")
    scenario = parse_scenario(text)
    longest, reason = feasibility.admissible_period(scenario)
    assert "start must stay certified" in reason
    # q(s) with the mean 0.6 − 0.5 h from s, radius r_o + r_min = 0.4, σ = 0.1, n = 2:
    distance = 0.6 - 0.5 * longest
    q = ncx2.sf((0.4 / 0.1) ** 2, 2, (distance / 0.1) ** 2)
    assert q == pytest.approx(0.9, abs=1e-9)
    assert longest < 0.4


def test_warnings_name_theorem_4_1_and_an_obstacle_faster_than_the_centre():
    # κ = 0.5: the plant follows at ~0.46 m/s; v_c = 0.3, an obstacle at 0.35 m/s.
    scenario = parse_scenario(omni(kappa=0.5, speed=0.3, obstacle_speed=0.35))
    warnings = feasibility.scenario_warnings(scenario)
    demand = 2 * 0.3 + 0.35
    assert any(
        w.startswith("Theorem 4.1 cannot be guaranteed")
        and f"{demand:.4g} m/s" in w
        and f"{following(0.5):.4g} m/s" in w
        for w in warnings
    )
    assert any(w.startswith("claim (ii) cannot be guaranteed for obstacle 0") for w in warnings)


@pytest.mark.parametrize(
    ("obstacle_speed", "k3", "warned"),
    [(0.8, 0.4, False), (0.8, 0.0, False), (1.0, 0.4, True), (1.2, 0.0, True)],
)
def test_claim_ii_warning_compares_the_level_set_speed_with_max_center_speed(
    obstacle_speed, k3, warned
):
    """In the boundary layer the centre leaves an ε level set at v_c whatever k3 (the
    escape velocity has no v_j part; before it, the saturated law split v_c between k2·m
    and k3·v and left at v_c/√2 with k2 = k3, so a 0.8 m/s obstacle was warned about)."""
    text = omni(obstacle_speed=obstacle_speed).replace("k3: 0.4", f"k3: {k3}")
    scenario = parse_scenario(text)
    assert feasibility.center_speed(scenario) == 1.0
    claims = [w for w in feasibility.scenario_warnings(scenario) if w.startswith("claim (ii)")]
    assert bool(claims) is warned
    if warned:
        assert f"move at {obstacle_speed:.4g} m/s" in claims[0]
        assert "max_center_speed = 1 m/s" in claims[0]


def test_fr3_lever_arms_bound_the_jacobian():
    """‖J(q) e‖ ≤ Σ_i ℓ_i |e_i| at random configurations and joint-velocity errors."""
    from stt_drake.systems.plants.franka import ArmKinematics, fr3_lever_arm_bounds

    lever = fr3_lever_arm_bounds()
    assert np.all(np.diff(lever) <= 1e-12)  # shorter towards the hand
    kinematics = ArmKinematics()
    rng = np.random.default_rng(4)
    for _ in range(200):
        q = rng.uniform(-2.5, 2.5, 7)
        e = rng.normal(size=7)
        jacobian = kinematics.jacobian(q)
        assert np.linalg.norm(jacobian @ e) <= lever @ np.abs(e) + 1e-12
        # and each column's norm is within its lever arm
        assert np.all(np.linalg.norm(jacobian, axis=0) <= lever + 1e-12)
