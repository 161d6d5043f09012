"""The scenario rules that need the built laws or the arm model (the rest are in
:mod:`stt_drake.config.validate`): the funnels of Sec. 4 contain each stage's initial
error, the arm starts inside its joint limits with its TCP in Γ(0), and the real-time
checks of :mod:`stt_drake.assembly.feasibility`."""

from __future__ import annotations

from typing import Any

import numpy as np

from stt_drake.assembly.feasibility import validate_real_time
from stt_drake.assembly.laws import make_arm_law, make_funnel_controller, make_tube_law
from stt_drake.config import PLANT_STAGES, FrankaArm, Quadrotor, Scenario
from stt_drake.config.validate import require, require_vector
from stt_drake.core.arm import ArmLimits
from stt_drake.systems.plants.franka import FR3_JOINTS, FR3_LINKS, ArmKinematics


def check_buildable(scenario: Scenario) -> None:
    """Every rule that needs a built law or the arm model; raise ScenarioError. The
    real-time checks come first: they refuse a scenario whose derived max_center_speed
    would not be positive, before a law is made with it (TubeLaw refuses one)."""
    validate_real_time(scenario)
    if isinstance(scenario.plant, FrankaArm):
        _validate_franka(scenario)
    else:
        _validate_funnel_starts(scenario)


def _validate_franka(scenario: Scenario) -> None:
    """The arm's fields, q(0) inside the joint limits, y(0) = TCP(q(0)) within r_min of the
    start (so y(0) ∈ Γ(0)), and stage 2's funnel around the initial joint-velocity error —
    all on one parse of the arm model."""
    plant, path = scenario.plant, "scenario.plant"
    require_vector(plant.initial_configuration, FR3_JOINTS, f"{path}.initial_configuration")
    for i, waypoint in enumerate(plant.waypoints):
        require_vector(waypoint, scenario.dimension, f"{path}.waypoints[{i}]")
    require(plant.hold_time >= 0.0, f"{path}.hold_time", "must be ≥ 0 (s)", plant.hold_time)
    require(
        plant.jacobian_damping > 0.0,
        f"{path}.jacobian_damping",
        "must be > 0 (m)",
        plant.jacobian_damping,
    )
    for name in ("posture_gain", "limit_gain"):
        value = getattr(plant, name)
        require(value >= 0.0, f"{path}.{name}", "must be ≥ 0", value)
    require(
        plant.limit_margin > 0.0, f"{path}.limit_margin", "must be > 0 (rad)", plant.limit_margin
    )
    for i, jerk in enumerate(plant.jerks):
        where = f"{path}.jerks[{i}]"
        require(jerk.time >= 0.0, f"{where}.time", "must be ≥ 0 (s)", jerk.time)
        require(jerk.duration > 0.0, f"{where}.duration", "must be > 0 (s)", jerk.duration)
        require(jerk.link in FR3_LINKS, f"{where}.link", f"must be one of {FR3_LINKS}", jerk.link)
        require_vector(jerk.force, 3, f"{where}.force")
        require_vector(jerk.point, 3, f"{where}.point")
    kinematics = ArmKinematics()
    limits = ArmLimits.of(kinematics.plant)
    q0 = np.asarray(plant.initial_configuration, dtype=float)
    require(
        bool(np.all((limits.position_lower < q0) & (q0 < limits.position_upper))),
        f"{path}.initial_configuration",
        f"must lie inside the joint limits {limits.position_lower.tolist()} .. "
        f"{limits.position_upper.tolist()} (rad)",
        plant.initial_configuration,
    )
    tcp = kinematics.position(q0)
    require(
        float(np.linalg.norm(tcp - np.asarray(scenario.start))) < scenario.tube.r_min,
        "scenario.start",
        f"must lie within r_min = {scenario.tube.r_min} m of the TCP at the initial "
        f"configuration, {np.round(tcp, 6).tolist()}, so y(0) ∈ Γ(0)",
        scenario.start,
    )
    _validate_arm_funnel_start(
        scenario, make_arm_law(scenario, limits), make_tube_law(scenario), kinematics
    )


def initial_stage_states(scenario: Scenario) -> np.ndarray:
    """x(0) = [x_1(0); ...; x_N(0)] as an (N, n) array: the position y(0) and, for a
    second-order plant, the initial velocity."""
    states = [scenario.initial_output()]
    if isinstance(scenario.plant, Quadrotor):
        states.append(np.asarray(scenario.plant.initial_velocity, dtype=float))
    return np.vstack(states)


def _validate_funnel_starts(scenario: Scenario) -> None:
    """Sec. 4: each box funnel must contain its stage's initial error,
    |x_k,i(0) − r_k,i(0)| < p_k,i, with r_k(0) from the control law at t = 0 (so r_2(0) = 0
    when y(0) = s, and p_2 must exceed |v(0)| per axis)."""
    if PLANT_STAGES[type(scenario.plant)] < 2:
        return
    start = np.asarray(scenario.start, dtype=float)
    radius = make_tube_law(scenario).evaluate(start, scenario.belief_at(0.0)).radius
    states = initial_stage_states(scenario)
    evaluation = make_funnel_controller(scenario).evaluate(0.0, states, start, radius)
    for k, error in enumerate(evaluation.normalized_errors[1:]):
        funnel = scenario.controller.funnels[k]
        initial_error = np.abs(error) * np.asarray(funnel.start, dtype=float)
        require(
            bool(np.all(np.abs(error) < 1.0)),
            f"scenario.controller.funnels[{k}].start",
            f"must exceed the initial error |x_{k + 2}(0) − r_{k + 2}(0)| = "
            f"{np.round(initial_error, 6).tolist()} on every axis (Sec. 4)",
            funnel.start,
        )


def _validate_arm_funnel_start(
    scenario: Scenario, law: Any, tube_law: Any, kinematics: Any
) -> None:
    """The arm starts at rest: stage 2's funnel must contain |0 − q̇_ref(0)| per joint,
    with q̇_ref(0) from the law at t = 0 (the null-space posture term when q(0) is not the
    home posture)."""
    q0 = np.asarray(scenario.plant.initial_configuration, dtype=float)
    start = np.asarray(scenario.start, dtype=float)
    radius = tube_law.evaluate(start, scenario.belief_at(0.0)).radius
    evaluation = law.evaluate(
        0.0, kinematics.position(q0), q0, np.zeros_like(q0), kinematics.jacobian(q0), start, radius
    )
    require(
        bool(np.all(np.abs(evaluation.normalized_errors[1:]) < 1.0)),
        "scenario.controller.funnels[0].start",
        "must exceed the initial joint-velocity error |q̇(0) − q̇_ref(0)| = "
        f"{np.round(np.abs(evaluation.joint_velocity), 6).tolist()} rad/s on every joint (Sec. 4)",
        scenario.controller.funnels[0].start,
    )
