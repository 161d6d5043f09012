"""Scenario → Drake Diagram, with handles to every system and logger a caller needs."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, SceneGraph
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, MultibodyPlant
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem, OutputPort
from pydrake.systems.primitives import MatrixGain, Sine

from stt_drake.assembly.feasibility import rate_bounds
from stt_drake.assembly.guide import add_guide
from stt_drake.assembly.laws import make_arm_law, make_funnel_controller, make_tube_law
from stt_drake.assembly.loggers import LoggedSignal, add_loggers
from stt_drake.assembly.perception import add_perception
from stt_drake.assembly.stt import AddStt
from stt_drake.config import FrankaArm as FrankaArmConfig
from stt_drake.config import OmniRobot as OmniRobotConfig
from stt_drake.config import Quadrotor as QuadrotorConfig
from stt_drake.config import Scenario
from stt_drake.core.arm import ArmLimits, JerkWindow, arm_metrics, summarize_arm
from stt_drake.core.belief import ObstacleTask
from stt_drake.systems.belief_source import ObstacleBeliefSource
from stt_drake.systems.crowd import CrowdSimulator
from stt_drake.systems.monitor import InvariantMonitor
from stt_drake.systems.plants.franka import (
    ArmKinematics,
    ArmMeasurement,
    ArmRobotInterface,
    ArmSTTController,
    ExternalJerks,
    Jerk,
    add_fr3,
    make_fr3_plant,
)
from stt_drake.systems.plants.omni import OmniDriveInterface, OmniRobot
from stt_drake.systems.plants.quadrotor import Quadrotor
from stt_drake.systems.sequencer import TargetSequencer
from stt_drake.systems.tube import SpatiotemporalTube
from stt_drake.systems.visualizer import PUBLISH_PERIOD, AddTubeVisualizer, draw_task_sets


@dataclass
class PlantHandles:
    """What a plant builder adds: its main system, where the control goes in, and the
    ports the loop reads (y for the monitor, the stacked stage states for the controller).

    Optional, for plants the generic loop does not cover: `controller`, the plant's own STT
    controller system (input ports `tube` and `plant_state`, output port `control`; default:
    :class:`STTController`); `sequencer`, a system that switches the tube's target (input
    `tube`, output `target`) for a sequence of reach-avoid-stay tasks; `logged`, more
    signals to log (log name → port); `log_constants`, constants added to the run log (e.g.
    joint limits); `report`, plant-specific metrics computed from the run log (merged into
    metrics.json); `summary`, the plant's lines of the run summary from metrics.json.

    With perception, a plant whose sensor is elsewhere (a station over LCM) gives its
    `detections` (:class:`ObstacleSensor`'s layout): the loop adds only the tracker; its
    `true_obstacle_position`, where the truth is in this diagram, is logged."""

    plant: LeafSystem
    control_input: object  # an InputPort
    output: OutputPort
    plant_state: OutputPort
    controller: LeafSystem | None = None
    sequencer: LeafSystem | None = None
    logged: dict[str, OutputPort] = field(default_factory=dict)
    log_constants: dict[str, np.ndarray] = field(default_factory=dict)
    report: Callable[[Mapping[str, np.ndarray]], dict[str, Any]] | None = None
    summary: Callable[[Mapping[str, Any]], list[str]] | None = None
    scene_graph: SceneGraph | None = None
    detections: OutputPort | None = None
    true_obstacle_position: OutputPort | None = None


@dataclass
class SttDiagram:
    """A built scenario: the Diagram and handles to its systems and loggers."""

    diagram: Diagram
    belief_source: ObstacleBeliefSource | None
    tube: SpatiotemporalTube
    controller: LeafSystem
    monitor: InvariantMonitor
    plant: LeafSystem
    loggers: dict[str, LoggedSignal] = field(default_factory=dict)
    sequencer: LeafSystem | None = None
    extra_logs: tuple[str, ...] = ()
    log_constants: dict[str, np.ndarray] = field(default_factory=dict)
    plant_report: Callable[[Mapping[str, np.ndarray]], dict[str, Any]] | None = None
    plant_summary: Callable[[Mapping[str, Any]], list[str]] | None = None
    scene_graph: SceneGraph | None = None


def add_omni_robot(builder: DiagramBuilder, scenario: Scenario) -> PlantHandles:
    """Omni base + its nominal-kinematics drive interface + a sinusoidal disturbance."""
    config: OmniRobotConfig = scenario.plant
    robot = builder.AddNamedSystem(
        "omni_robot",
        OmniRobot(
            config.wheel_radius,
            config.base_radius,
            scenario.initial_output(),
            config.initial_heading,
        ),
    )
    drive = builder.AddNamedSystem(
        "omni_drive_interface",
        OmniDriveInterface(
            config.nominal_wheel_radius,
            config.nominal_base_radius,
            config.heading_gain,
            config.initial_heading,
        ),
    )
    disturbance = add_sinusoidal_disturbance(
        builder,
        config.disturbance_amplitude,
        [config.disturbance_frequency_hz],
        np.array([[0.0], [np.pi / 2.0]]),
    )
    builder.Connect(drive.GetOutputPort("wheel_speeds"), robot.GetInputPort("wheel_speeds"))
    builder.Connect(robot.GetOutputPort("pose"), drive.GetInputPort("pose"))
    builder.Connect(disturbance, robot.GetInputPort("disturbance"))
    return PlantHandles(
        plant=robot,
        control_input=drive.GetInputPort("velocity_command"),
        output=robot.GetOutputPort("output"),
        plant_state=robot.GetOutputPort("plant_state"),
    )


def add_sinusoidal_disturbance(
    builder: DiagramBuilder,
    amplitude: list[float] | np.ndarray,
    frequencies_hz: list[float] | np.ndarray,
    phases: np.ndarray,
) -> OutputPort:
    """A bounded disturbance w_i(t) = A_i/K · Σ_k sin(2π f_k t + φ_ik) from Drake primitives.

    One `Sine` with the n·K terms (named "disturbance" when K = 1); for K > 1 a `MatrixGain`
    named "disturbance" sums each axis' K terms. The weights 1/K sum to 1, so
    |w_i(t)| ≤ A_i at all times.

    Args:
        amplitude: (n,) A_i ≥ 0, the bound per axis (in the plant's unit: m/s, N, ...).
        frequencies_hz: (K,) f_k in Hz.
        phases: (n, K) φ_ik in rad.

    Returns:
        The output port of w (n).
    """
    amplitude = np.asarray(amplitude, dtype=float)
    frequencies = 2.0 * np.pi * np.asarray(frequencies_hz, dtype=float)
    n, count = amplitude.size, frequencies.size
    terms = Sine(
        amplitudes=np.repeat(amplitude / count, count),
        frequencies=np.tile(frequencies, n),
        phases=np.asarray(phases, dtype=float).reshape(n * count),
    )
    if count == 1:
        return builder.AddNamedSystem("disturbance", terms).get_output_port(0)
    builder.AddNamedSystem("disturbance_terms", terms)
    total = builder.AddNamedSystem(
        "disturbance", MatrixGain(np.kron(np.eye(n), np.ones((1, count))))
    )
    builder.Connect(terms.get_output_port(0), total.get_input_port())
    return total.get_output_port()


def add_quadrotor(builder: DiagramBuilder, scenario: Scenario) -> PlantHandles:
    """UAV point mass (true mass, drag, gravity) + its bounded wind force (phases drawn
    from the scenario seed, logged as "wind"); the STT controller's force goes straight to
    `control`."""
    config: QuadrotorConfig = scenario.plant
    uav = builder.AddNamedSystem(
        "quadrotor",
        Quadrotor(
            config.mass,
            config.drag,
            config.gravity,
            scenario.initial_output(),
            np.asarray(config.initial_velocity, dtype=float),
        ),
    )
    rng = np.random.default_rng(scenario.seed)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(3, len(config.wind_frequencies_hz)))
    wind = add_sinusoidal_disturbance(
        builder, config.wind_amplitude, config.wind_frequencies_hz, phases
    )
    builder.Connect(wind, uav.GetInputPort("disturbance"))
    return PlantHandles(
        plant=uav,
        control_input=uav.GetInputPort("control"),
        output=uav.GetOutputPort("output"),
        plant_state=uav.GetOutputPort("plant_state"),
        logged={"wind": wind},
    )


#: How often the arm's task sequencer checks whether the current target is reached (s).
SEQUENCER_PERIOD = 0.01
#: How long after a jerk its effect is measured in the report (s).
JERK_SETTLE_TIME = 1.0


@dataclass
class Fr3Robot:
    """What :func:`add_fr3_robot` added, and its signals to log."""

    plant: MultibodyPlant
    scene_graph: SceneGraph
    interface: ArmRobotInterface
    logged: dict[str, OutputPort]


def add_fr3_robot(builder: DiagramBuilder, scenario: Scenario) -> Fr3Robot:
    """The FR3 as a station simulates it: continuous-time MultibodyPlant + SceneGraph, the
    robot's torque interface (gravity compensation from its own model, saturation) and the
    scenario's external jerks; logs joint state, requested/applied torque, jerk force."""
    config: FrankaArmConfig = scenario.plant
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    add_fr3(plant)
    plant.Finalize()
    plant.SetDefaultPositions(np.asarray(config.initial_configuration, dtype=float))
    interface = builder.AddNamedSystem(
        "fr3_robot_interface", ArmRobotInterface(make_fr3_plant(), config.gravity_compensation)
    )
    state = plant.get_state_output_port()
    builder.Connect(state, interface.GetInputPort("state"))
    builder.Connect(interface.GetOutputPort("actuation"), plant.get_actuation_input_port())
    logged = {
        "joint_state": state,
        "requested_torque": interface.GetOutputPort("requested_torque"),
        "applied_torque": interface.GetOutputPort("actuation"),
    }
    jerks = [
        Jerk(
            start=jerk.time,
            duration=jerk.duration,
            body=int(plant.GetBodyByName(jerk.link).index()),
            force=np.asarray(jerk.force, dtype=float),
            point=np.asarray(jerk.point, dtype=float),
        )
        for jerk in config.jerks
    ]
    if jerks:
        pushes = builder.AddNamedSystem("external_jerks", ExternalJerks(jerks))
        builder.Connect(
            pushes.GetOutputPort("spatial_forces"), plant.get_applied_spatial_force_input_port()
        )
        logged["external_force"] = pushes.GetOutputPort("force")
    return Fr3Robot(plant, scene_graph, interface, logged)


def add_arm_controller(
    builder: DiagramBuilder,
    scenario: Scenario,
    limits: ArmLimits,
    kinematics: ArmKinematics,
    measured: PlantHandles,
) -> PlantHandles:
    """The FR3's controller side around its `measured` ports (the simulated robot's or the
    status received over LCM): the arm's STT controller, the task sequencer, the limits as
    log constants and the arm's report (:func:`stt_drake.core.arm.arm_metrics`)."""
    config: FrankaArmConfig = scenario.plant
    controller = builder.AddNamedSystem(
        "arm_stt_controller", ArmSTTController(make_arm_law(scenario, limits), kinematics)
    )
    targets = scenario.task_targets()
    sequencer = None
    if len(targets) > 1:
        sequencer = builder.AddNamedSystem(
            "target_sequencer",
            TargetSequencer(
                targets, scenario.target_set_radius, config.hold_time, SEQUENCER_PERIOD
            ),
        )
    logged = {
        **measured.logged,
        "funnel_errors": controller.GetOutputPort("funnel_errors"),
        "joint_velocity_reference": controller.GetOutputPort("joint_velocity_reference"),
    }
    return dataclasses.replace(
        measured,
        controller=controller,
        sequencer=sequencer,
        logged=logged,
        log_constants={
            "position_lower": limits.position_lower,
            "position_upper": limits.position_upper,
            "velocity_limit": limits.velocity,
            "effort_limit": limits.effort,
        },
        report=partial(
            arm_metrics,
            limits=limits,
            jerks=[JerkWindow(j.time, j.time + j.duration) for j in config.jerks],
            settle=JERK_SETTLE_TIME,
            targets=targets,
            target_set_radius=scenario.target_set_radius,
        ),
        summary=summarize_arm,
    )


def add_franka(builder: DiagramBuilder, scenario: Scenario) -> PlantHandles:
    """FR3 arm: the robot (:func:`add_fr3_robot`), its TCP measurement and the controller
    side (:func:`add_arm_controller`)."""
    robot = add_fr3_robot(builder, scenario)
    measurement = builder.AddNamedSystem("fr3_measurement", ArmMeasurement(robot.plant))
    builder.Connect(robot.plant.get_state_output_port(), measurement.GetInputPort("state"))
    builder.Connect(
        robot.plant.get_body_poses_output_port(), measurement.GetInputPort("body_poses")
    )
    measured = PlantHandles(
        plant=robot.plant,
        control_input=robot.interface.GetInputPort("torque_command"),
        output=measurement.GetOutputPort("output"),
        plant_state=measurement.GetOutputPort("plant_state"),
        logged=robot.logged,
        scene_graph=robot.scene_graph,
    )
    return add_arm_controller(
        builder, scenario, ArmLimits.of(robot.plant), ArmKinematics(), measured
    )


#: Plant builders by the scenario's plant config type; a case study registers its own.
PLANT_BUILDERS: dict[type, Callable[[DiagramBuilder, Scenario], PlantHandles]] = {
    OmniRobotConfig: add_omni_robot,
    QuadrotorConfig: add_quadrotor,
    FrankaArmConfig: add_franka,
}


def add_live_view(
    builder: DiagramBuilder,
    scenario: Scenario,
    meshcat: Meshcat,
    plant: PlantHandles,
    tube: OutputPort,
    belief: OutputPort,
    task: ObstacleTask,
    full_covariance: bool = False,
) -> None:
    """Draw the run live into `meshcat`: a :class:`~stt_drake.systems.visualizer.TubeVisualizer`
    (tube, obstacles, their ε and p_d level sets; the robot at y for a plant without a
    SceneGraph), Drake's `MeshcatVisualizer` for a plant's SceneGraph (the FR3 arm, under
    ``/stt/arm``), and the initial and target sets."""
    radius = None
    if plant.scene_graph is None:
        for name in ("body_radius", "base_radius"):
            radius = getattr(scenario.plant, name, radius)
    AddTubeVisualizer(
        builder,
        meshcat,
        tube,
        belief,
        scenario.dimension,
        task,
        output=plant.output,
        robot_radius=None if radius is None else float(radius),
        full_covariance=full_covariance,
    )
    if plant.scene_graph is not None:
        params = MeshcatVisualizerParams(publish_period=PUBLISH_PERIOD, prefix="/stt/arm")
        MeshcatVisualizer.AddToBuilder(builder, plant.scene_graph, meshcat, params)
    draw_task_sets(
        meshcat,
        np.asarray(scenario.start, dtype=float),
        scenario.initial_set_radius,
        scenario.task_targets(),
        scenario.target_set_radius,
    )


def build_diagram(scenario: Scenario, meshcat: Meshcat | None = None) -> SttDiagram:
    """The scenario's plant (from :data:`PLANT_BUILDERS`) and its STT loop (:func:`AddStt`)
    connected, and loggers on the plant output, tube, belief, diagnostics, control and
    margins (`stt-drake diagram` draws it). With a `meshcat`, the run is also drawn there live
    (:func:`add_live_view`)."""
    builder = DiagramBuilder()
    plant = PLANT_BUILDERS[type(scenario.plant)](builder, scenario)
    rate = scenario.tube.update_rate_hz
    source: dict[str, Any] = {"obstacles": scenario.obstacles}
    perceived = None
    if scenario.perception is not None:
        perceived = add_perception(builder, scenario, plant.output, plant.detections)
        source = {
            "belief": perceived.tracker.GetOutputPort("obstacle_belief"),
            "task": ObstacleTask.of(scenario.obstacles),
            "full_covariance": scenario.perception.full_covariance,
        }
    law = make_tube_law(scenario)
    stt = AddStt(
        builder,
        law,
        plant.controller or make_funnel_controller(scenario),
        scenario.start,
        **source,
        update_period=1.0 / rate if rate > 0.0 else None,
        rate_bounds=rate_bounds(scenario),
        target_input=plant.sequencer is not None or scenario.guide is not None,
    )
    builder.Connect(plant.plant_state, stt.plant_state)
    builder.Connect(stt.control, plant.control_input)
    builder.Connect(plant.output, stt.output)
    tube, controller, monitor = stt.tube_system, stt.controller, stt.monitor

    logged = {
        "output": plant.output,
        "tube": stt.tube,
        "belief": stt.belief,
        "diagnostics": tube.GetOutputPort("diagnostics"),
        "recovery": tube.GetOutputPort("recovery"),
        "control": controller.GetOutputPort("control"),
        "margins": monitor.GetOutputPort("margins"),
        "output_avoid_probability": monitor.GetOutputPort("output_avoid_probability"),
        "tube_avoid_probability": monitor.GetOutputPort("tube_avoid_probability"),
    }
    extra = dict(plant.logged)
    if perceived is not None:  # the truth the end-to-end check needs, and the corrections
        truth = plant.true_obstacle_position
        if perceived.truth is not None:
            truth = perceived.truth.GetOutputPort("true_obstacle_position")
        if truth is not None:
            extra["true_obstacle_position"] = truth
        extra["belief_updates"] = perceived.tracker.GetOutputPort("belief_updates")
        if isinstance(perceived.truth, CrowdSimulator):
            extra["pedestrian_active"] = perceived.truth.GetOutputPort("pedestrian_active")
        extra["tracker_consistency"] = perceived.tracker.GetOutputPort("consistency")
    task_target = None
    if plant.sequencer is not None:
        builder.Connect(stt.tube, plant.sequencer.GetInputPort("tube"))
        task_target = plant.sequencer.GetOutputPort("target")
        extra["task_target"] = task_target
    if scenario.guide is not None:  # the guide moves η; the task's target stays the goal
        guide = add_guide(
            builder,
            scenario,
            law,
            stt,
            tracks=None if perceived is None else perceived.tracker.GetOutputPort("tracks"),
            tracker=None if perceived is None else perceived.tracker.model,
            goal=task_target,
        )
        extra["guide_target"] = guide.GetOutputPort("target")
        extra["guide_status"] = guide.GetOutputPort("guide_status")
    elif task_target is not None:
        builder.Connect(task_target, tube.GetInputPort("target"))
    logged.update(extra)
    loggers = add_loggers(builder, logged, scenario.log_period)
    if meshcat is not None:
        add_live_view(
            builder, scenario, meshcat, plant, stt.tube, stt.belief, stt.task, stt.full_covariance
        )
    diagram = builder.Build()
    diagram.set_name(scenario.name)
    return SttDiagram(
        diagram,
        stt.belief_source,
        tube,
        controller,
        monitor,
        plant.plant,
        loggers,
        sequencer=plant.sequencer,
        extra_logs=tuple(extra),
        log_constants={**plant.log_constants, "full_covariance": np.array(stt.full_covariance)},
        plant_report=plant.report,
        plant_summary=plant.summary,
        scene_graph=plant.scene_graph,
    )
