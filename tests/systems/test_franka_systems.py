"""The arm's control law, its Drake systems and its scenario rules, one piece at a time.

References: textbook formulas written out here (the damped least-squares inverse
Jᵀ(JJᵀ + λ²I)⁻¹, the funnel stages of Sec. 4), the published DH kinematics (from
test_franka_model) and the physics of the simulated plant.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from stt_drake.assembly import parse_scenario
from stt_drake.config import ScenarioError
from stt_drake.core.arm import (
    ArmFunnelLaw,
    ArmLimits,
    JerkWindow,
    JointSpaceMapping,
    jerk_report,
    limit_report,
    segment_report,
)
from stt_drake.core.control import BoxFunnel, FunnelController
from stt_drake.systems.plants.franka import (
    FR3_HOME,
    ArmMeasurement,
    ArmRobotInterface,
    ExternalJerks,
    Jerk,
    add_fr3,
    make_fr3_plant,
)
from stt_drake.systems.sequencer import TargetSequencer
from tests.systems.test_franka_model import (
    EFFORT,
    POSITION_LOWER,
    POSITION_UPPER,
    VELOCITY,
    dh_frames,
)

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"
LIMITS = ArmLimits(
    position_lower=np.array(POSITION_LOWER),
    position_upper=np.array(POSITION_UPPER),
    velocity=np.array(VELOCITY),
    effort=np.array(EFFORT, dtype=float),
)


def make_mapping(damping: float = 0.02, posture_gain: float = 1.0) -> JointSpaceMapping:
    return JointSpaceMapping(
        damping=damping,
        posture=FR3_HOME,
        posture_gain=posture_gain,
        position_lower=LIMITS.position_lower,
        position_upper=LIMITS.position_upper,
        limit_margin=0.25,
        limit_gain=1.0,
    )


def random_jacobians(count: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield rng.normal(size=(3, 7)), rng.normal(size=3), rng.uniform(-1.0, 1.0, size=7)


# --------------------------------------------------------------------------- the law


def test_mapping_task_part_is_the_textbook_damped_least_squares_inverse():
    mapping = make_mapping(damping=0.05, posture_gain=0.0)
    for jacobian, velocity, _ in random_jacobians(20):
        q = FR3_HOME  # posture term zero, limits far: only the task part remains
        expected = jacobian.T @ np.linalg.solve(
            jacobian @ jacobian.T + 0.05**2 * np.eye(3), velocity
        )
        np.testing.assert_allclose(mapping.reference(jacobian, velocity, q), expected, atol=1e-12)


def test_null_space_term_never_moves_the_end_effector():
    mapping = make_mapping(posture_gain=2.0)
    for jacobian, _, offset in random_jacobians(20, seed=1):
        q = FR3_HOME + offset
        assert np.linalg.norm(mapping.null_space_velocity(q)) > 0.1
        np.testing.assert_allclose(
            jacobian @ mapping.reference(jacobian, np.zeros(3), q), 0, atol=1e-12
        )


def test_task_space_gain_is_symmetric_positive_definite():
    """ẏ = J q̇_ref = G v_ref with G = J Jᵀ (J Jᵀ + λ² I)⁻¹ ≻ 0: progress along v_ref."""
    mapping = make_mapping()
    for jacobian, _, offset in random_jacobians(20, seed=2):
        gain = np.column_stack(
            [jacobian @ mapping.reference(jacobian, e, FR3_HOME + offset) for e in np.eye(3)]
        )
        np.testing.assert_allclose(gain, gain.T, atol=1e-12)
        singular = np.linalg.svd(jacobian, compute_uv=False)
        np.testing.assert_allclose(
            np.linalg.eigvalsh(gain), np.sort(singular**2 / (singular**2 + 0.02**2)), atol=1e-12
        )


def test_null_space_velocity_pulls_home_and_pushes_off_limits():
    mapping = make_mapping(posture_gain=1.0)
    np.testing.assert_allclose(mapping.null_space_velocity(FR3_HOME), 0.0)
    away = FR3_HOME + 0.3
    np.testing.assert_allclose(mapping.null_space_velocity(away), -0.3, atol=1e-12)
    near_upper = FR3_HOME.copy()
    near_upper[0] = POSITION_UPPER[0] - 0.05  # 0.2 of the 0.25 band: repulsion 0.8 rad/s
    expected = -(near_upper[0] - FR3_HOME[0]) - 1.0 * (0.25 - 0.05) / 0.25
    assert mapping.null_space_velocity(near_upper)[0] == pytest.approx(expected)


def test_arm_law_stages_match_the_paper_formulas():
    kappa, funnel = (5.0, 1.5), BoxFunnel(start=np.full(7, 1.2), end=np.full(7, 0.4), rate=0.8)
    law = ArmFunnelLaw(FunnelController(kappa=kappa, funnels=[funnel]), make_mapping())
    rng = np.random.default_rng(4)
    for _ in range(20):
        jacobian, t = rng.normal(size=(3, 7)), rng.uniform(0.0, 5.0)
        center, radius = rng.normal(size=3), 0.05
        position = center + rng.uniform(0.0, 0.045) * _unit(rng.normal(size=3))
        q = FR3_HOME + rng.uniform(-0.5, 0.5, 7)
        e1 = np.linalg.norm(position - center) / radius
        task = -kappa[0] * np.log((1 + e1) / (1 - e1)) * (position - center)
        reference = make_mapping().reference(jacobian, task, q)
        gamma = (1.2 - 0.4) * np.exp(-0.8 * t) + 0.4
        v = reference + gamma * rng.uniform(-0.95, 0.95, 7)  # inside the stage-2 funnel
        out = law.evaluate(t, position, q, v, jacobian, center, radius)
        np.testing.assert_allclose(out.task_velocity, task, atol=1e-12)
        e2 = (v - reference) / gamma
        torque = -kappa[1] * 4.0 / (gamma * (1 - e2**2)) * np.log((1 + e2) / (1 - e2))
        np.testing.assert_allclose(out.torque, torque, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(out.normalized_errors, [e1, *e2], atol=1e-12)
        assert np.all(out.torque * (v - reference) <= 0.0)  # it opposes the velocity error


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


# --------------------------------------------------------------------------- post-run checks


def test_limit_report_finds_the_worst_joint_and_time():
    t = np.linspace(0.0, 1.0, 5)
    q = np.tile(FR3_HOME, (5, 1))
    q[3, 3] = POSITION_UPPER[3] + 0.01  # joint 4 beyond its upper limit at t = 0.75
    v = np.zeros((5, 7))
    v[1, 4] = 5.0  # joint 5 at 5 of 5.26 rad/s
    torque = np.zeros((5, 7))
    torque[2, 6] = -11.5  # joint 7 at 11.5 of 12 N·m
    report = limit_report(t, q, v, torque, LIMITS)
    assert report["joint_position"] == {
        "holds": False, "worst_margin": pytest.approx(-0.01), "t_worst": 0.75, "joint": 4
    }  # fmt: skip
    assert report["joint_velocity"]["joint"] == 5
    assert report["joint_velocity"]["worst_margin"] == pytest.approx(0.26)
    assert report["joint_torque"]["joint"] == 7 and report["joint_torque"]["t_worst"] == 0.5
    assert report["joint_torque"]["worst_margin"] == pytest.approx(0.5)


def test_segment_report_reconstructs_reach_times_and_flags_unfinished_tasks():
    t = np.arange(10) * 0.1
    targets = [np.zeros(3), np.ones(3), 2 * np.ones(3)]
    task_target = np.array([targets[0]] * 4 + [targets[1]] * 6)
    center = task_target.copy()
    center[0] += 0.5  # Γ ⊄ T_0 at t = 0
    center[4:7] += 0.5  # segment 1 enters T_1 at t = 0.7
    radius = np.full(10, 0.05)
    report = segment_report(t, task_target, center, radius, 0.1, targets)
    assert [s["t_tube_in_target"] for s in report] == [pytest.approx(0.1), pytest.approx(0.7), None]
    assert [s["completed"] for s in report] == [True, True, False]
    assert report[2]["t_start"] is None  # target 2 never became active


def test_jerk_report_measures_each_push_until_the_next():
    t = np.arange(0.0, 3.0, 0.01)
    errors = np.zeros((t.size, 8))
    errors[:, 0] = 0.1
    errors[(t >= 1.0) & (t < 1.3), 0] = 0.6
    errors[(t >= 1.05) & (t < 1.1), 3] = -0.7
    center = np.zeros((t.size, 3))
    output = center + errors[:, :1] * np.array([0.05, 0.0, 0.0])
    report = jerk_report(
        t, errors, output, center, [JerkWindow(1.0, 1.2), JerkWindow(2.0, 2.2)], 0.5
    )
    first, second = report
    assert first["peak_stage1_error"] == pytest.approx(0.6)
    assert first["stage1_error_before"] == pytest.approx(0.1)
    assert first["peak_stage2_error"] == pytest.approx(0.7)
    assert first["peak_offset_from_center"] == pytest.approx(0.03)
    assert second["peak_stage1_error"] == pytest.approx(0.1)


# --------------------------------------------------------------------------- Drake systems


def _arm_with_interface(gravity_compensation: bool):
    builder = DiagramBuilder()
    plant = builder.AddSystem(make_fr3_plant())
    interface = builder.AddSystem(ArmRobotInterface(make_fr3_plant(), gravity_compensation))
    builder.Connect(plant.get_state_output_port(), interface.GetInputPort("state"))
    builder.Connect(interface.GetOutputPort("actuation"), plant.get_actuation_input_port())
    builder.ExportInput(interface.GetInputPort("torque_command"), "torque_command")
    builder.ExportInput(plant.get_applied_spatial_force_input_port(), "spatial_forces")
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    plant.SetPositions(plant.GetMyMutableContextFromRoot(context), FR3_HOME)
    diagram.GetInputPort("torque_command").FixValue(context, np.zeros(7))
    return diagram, plant, interface, context


@pytest.mark.parametrize("compensation", [True, False])
def test_robot_interface_gravity_compensation_holds_the_arm(compensation):
    diagram, plant, _, context = _arm_with_interface(compensation)
    simulator = Simulator(diagram, context)
    simulator.AdvanceTo(0.5)
    moved = np.max(np.abs(plant.GetPositions(plant.GetMyContextFromRoot(context)) - FR3_HOME))
    if compensation:
        assert moved < 1e-6  # zero command: the robot holds its own weight
    else:
        assert moved > 0.05  # without it the arm falls


def test_robot_interface_saturates_at_the_effort_limits():
    diagram, plant, interface, context = _arm_with_interface(True)
    command = np.array([200.0, -200.0, 50.0, 0.0, 30.0, -30.0, 1.0])
    diagram.GetInputPort("torque_command").FixValue(context, command)
    local = interface.GetMyContextFromRoot(context)
    plant_context = plant.GetMyContextFromRoot(context)
    gravity = -plant.CalcGravityGeneralizedForces(plant_context)
    requested = interface.GetOutputPort("requested_torque").Eval(local)
    np.testing.assert_allclose(requested, command + gravity, atol=1e-9)
    np.testing.assert_allclose(
        interface.GetOutputPort("actuation").Eval(local),
        np.clip(command + gravity, -np.array(EFFORT), np.array(EFFORT)),
        atol=1e-9,
    )


def test_measurement_reports_the_tcp_of_the_dh_model():
    builder = DiagramBuilder()
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph

    plant, _ = AddMultibodyPlantSceneGraph(builder, 0.0)
    add_fr3(plant)
    plant.Finalize()
    measurement = builder.AddSystem(ArmMeasurement(plant))
    builder.Connect(plant.get_state_output_port(), measurement.GetInputPort("state"))
    builder.Connect(plant.get_body_poses_output_port(), measurement.GetInputPort("body_poses"))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    rng = np.random.default_rng(5)
    for _ in range(5):
        q, v = rng.uniform(POSITION_LOWER, POSITION_UPPER), rng.normal(size=7)
        plant.SetPositionsAndVelocities(plant.GetMyMutableContextFromRoot(context), [*q, *v])
        local = measurement.GetMyContextFromRoot(context)
        tcp = dh_frames(q)[-1][:3, 3]
        np.testing.assert_allclose(measurement.GetOutputPort("output").Eval(local), tcp, atol=1e-9)
        np.testing.assert_allclose(
            measurement.GetOutputPort("plant_state").Eval(local), [*tcp, *q, *v], atol=1e-9
        )


def test_jerk_is_a_half_sine_pulse_with_the_expected_impulse():
    jerk = Jerk(
        start=1.0, duration=0.2, body=3, force=np.array([0.0, 30.0, -40.0]), point=np.zeros(3)
    )
    times = np.linspace(0.9, 1.3, 40001)
    forces = np.array([jerk.force_at(t) for t in times])
    assert np.all(forces[(times < 1.0) | (times > 1.2)] == 0.0)
    np.testing.assert_allclose(forces.max(axis=0)[1], 30.0, rtol=1e-6)
    impulse = np.trapezoid(forces, times, axis=0)
    np.testing.assert_allclose(impulse, 2.0 / np.pi * 0.2 * jerk.force, rtol=1e-6)
    system = ExternalJerks([jerk])
    context = system.CreateDefaultContext()
    context.SetTime(1.1)
    (applied,) = system.GetOutputPort("spatial_forces").Eval(context)
    assert int(applied.body_index) == 3
    np.testing.assert_allclose(applied.F_Bq_W.translational(), jerk.force)
    context.SetTime(1.5)
    assert system.GetOutputPort("spatial_forces").Eval(context) == []


def test_a_jerk_pushes_the_compensated_arm_along_the_force():
    diagram, plant, _, context = _arm_with_interface(True)
    hand = int(plant.GetBodyByName("fr3_hand").index())
    jerks = ExternalJerks([Jerk(0.0, 0.1, hand, np.array([0.0, 40.0, 0.0]), np.zeros(3))])
    jerk_context = jerks.CreateDefaultContext()
    simulator = Simulator(diagram, context)
    plant_context = plant.GetMyContextFromRoot(context)
    before = plant.EvalBodyPoseInWorld(plant_context, plant.GetBodyByName("fr3_hand"))
    for step in range(1, 21):  # hold the pulse piecewise constant over 5 ms steps
        jerk_context.SetTime((step - 0.5) * 0.005)
        forces = jerks.GetOutputPort("spatial_forces").Eval(jerk_context)
        diagram.GetInputPort("spatial_forces").FixValue(context, forces)
        simulator.AdvanceTo(step * 0.005)
    after = plant.EvalBodyPoseInWorld(plant_context, plant.GetBodyByName("fr3_hand"))
    moved = after.translation() - before.translation()
    assert moved[1] > 0.005 and abs(moved[1]) > 3 * max(abs(moved[0]), abs(moved[2]))


def _run_sequencer(tube: np.ndarray, hold: float, duration: float) -> np.ndarray:
    targets = [np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])]
    sequencer = TargetSequencer(targets, 0.1, hold, 0.01)
    context = sequencer.CreateDefaultContext()
    sequencer.GetInputPort("tube").FixValue(context, tube)
    simulator = Simulator(sequencer, context)
    seen = []
    for t in np.arange(0.0, duration, 0.005):
        simulator.AdvanceTo(t)
        seen.append([t, sequencer.segment(context)])
    return np.array(seen)


def test_sequencer_switches_only_after_the_target_set_held():
    inside = _run_sequencer(np.array([0.02, 0.0, 0.0, 0.05]), hold=0.3, duration=1.0)
    switch = inside[np.argmax(inside[:, 1] > 0), 0]
    assert 0.3 <= switch <= 0.32 and inside[-1, 1] == 1  # the tube never enters T_1
    outside = _run_sequencer(np.array([0.06, 0.0, 0.0, 0.05]), hold=0.0, duration=0.5)
    assert np.all(outside[:, 1] == 0)  # ‖c − η‖ + r = 0.11 > 0.1: never reached


# --------------------------------------------------------------------------- scenario rules


#: A line of the case 1 file after which plant fields can be added.
HOLD = "  hold_time: 0.3"


def _case1_text(**replacements: str) -> str:
    text = (DIAGRAMS / "franka_pick_place_case1.yaml").read_text()
    for old, new in replacements.items():
        assert old in text
        text = text.replace(old, new)
    return text


def test_task_targets_are_the_waypoints_then_the_target():
    scenario = parse_scenario(_case1_text())
    targets = np.array(scenario.task_targets())
    np.testing.assert_allclose(targets[:3], scenario.plant.waypoints)
    np.testing.assert_allclose(targets[3], scenario.target)


@pytest.mark.parametrize(
    ("old", "new", "path"),
    [
        (HOLD, f"{HOLD}\n  jerks: [{{link: fr3_link9}}]", "plant.jerks[0].link"),
        (HOLD, f"{HOLD}\n  jerks: [{{duration: 0.0}}]", "jerks[0].duration"),
        (HOLD, f"{HOLD}\n  initial_configuration: [0, 0, 0, 0, 0, 0, 0]",
         "plant.initial_configuration"),
        ("    - [0.42, -0.35, 0.12]      # pick", "    - [0.42, -0.35]", "plant.waypoints[1]"),
        ("start: [0.306891, 0.0, 0.486882]", "start: [0.35, 0.0, 0.486882]", "scenario.start"),
        ("    - start: [1.2, 1.2, 1.2, 1.2, 2.0, 2.0, 2.0]", "    - start: [1.2, 1.2, 1.2]",
         "funnels[0].start"),
        ("  jacobian_damping: 0.02", "  jacobian_damping: 0.0", "plant.jacobian_damping"),
        ("kappa: [12.0, 1.5]", "kappa: [12.0]", "controller.kappa"),
    ],
)  # fmt: skip
def test_bad_arm_fields_are_reported_with_their_path(old, new, path):
    with pytest.raises(ScenarioError, match=re.escape(path)):
        parse_scenario(_case1_text(**{old: new}))


def test_funnel_must_contain_the_initial_null_space_velocity():
    """Away from the home posture the null-space term asks for q̇_ref(0) ≠ 0 at rest."""
    q0 = FR3_HOME + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.5])  # joint 7 only: same TCP
    text = _case1_text(
        **{"  hold_time: 0.3": f"  hold_time: 0.3\n  initial_configuration: {q0.tolist()}"}
    )
    text = text.replace("posture_gain: 1.0", "posture_gain: 1.5")
    with pytest.raises(ScenarioError, match=r"funnels\[0\]\.start.*initial joint-velocity error"):
        parse_scenario(text)
    parse_scenario(text.replace("posture_gain: 1.5", "posture_gain: 1.0"))  # 1.5 < p = 2.0
