"""Scenario → Drake Diagram, with handles to every system and logger a caller needs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem, OutputPort
from pydrake.systems.primitives import LogVectorOutput, MatrixGain, Sine, VectorLogSink

from stt_drake.core.control import BoxFunnel, FunnelController
from stt_drake.build.feasibility import center_speed, rate_bounds
from stt_drake.core.arm import (
    ArmFunnelLaw,
    ArmLimits,
    JerkWindow,
    JointSpaceMapping,
    arm_metrics,
)
from stt_drake.config import FrankaArm as FrankaArmConfig
from stt_drake.config import OmniRobot as OmniRobotConfig
from stt_drake.config import Quadrotor as QuadrotorConfig
from stt_drake.config import Scenario, initial_output, task_targets
from stt_drake.systems.belief_source import ObstacleBeliefSource
from stt_drake.systems.controller import STTController
from stt_drake.systems.plants.franka import (
    FR3_HOME,
    ArmKinematics,
    ArmMeasurement,
    ArmRobotInterface,
    ArmSTTController,
    ExternalJerks,
    Jerk,
    add_fr3,
    make_fr3_plant,
)
from stt_drake.systems.monitor import InvariantMonitor
from stt_drake.systems.plants.omni import OmniDriveInterface, OmniRobot
from stt_drake.systems.plants.quadrotor import Quadrotor
from stt_drake.systems.sequencer import TargetSequencer
from stt_drake.systems.tube import SpatiotemporalTube
from stt_drake.core.tube import TubeLaw, linear_zone_for_step


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
    metrics.json)."""

    plant: LeafSystem
    control_input: object  # an InputPort
    output: OutputPort
    plant_state: OutputPort
    controller: LeafSystem | None = None
    sequencer: LeafSystem | None = None
    logged: dict[str, OutputPort] = field(default_factory=dict)
    log_constants: dict[str, np.ndarray] = field(default_factory=dict)
    report: Callable[[dict[str, np.ndarray]], dict[str, Any]] | None = None


@dataclass
class SttDiagram:
    """A built scenario: the Diagram and handles to its systems and loggers."""

    diagram: Diagram
    belief_source: ObstacleBeliefSource
    tube: SpatiotemporalTube
    controller: LeafSystem
    monitor: InvariantMonitor
    plant: LeafSystem
    loggers: dict[str, VectorLogSink] = field(default_factory=dict)
    sequencer: LeafSystem | None = None
    extra_logs: tuple[str, ...] = ()
    log_constants: dict[str, np.ndarray] = field(default_factory=dict)
    plant_report: Callable[[dict[str, np.ndarray]], dict[str, Any]] | None = None


def make_tube_law(scenario: Scenario) -> TubeLaw:
    """The tube law with the scenario's constants (ν and max_center_speed derived when not
    given, :func:`stt_drake.build.feasibility.center_speed`).

    The attraction gets the linear zone δ = (k1·h)^{3/2} of the longest step h that
    integrates it — the simulator's max step in continuous time, the update period at a
    fixed rate — so no step of h overshoots η (see
    :func:`stt_drake.core.tube.signed_cube_root_attraction`).
    """
    config = scenario.tube
    rate = config.update_rate_hz
    step = 1.0 / rate if rate > 0.0 else scenario.simulator.max_step_size
    return TubeLaw(
        target=np.asarray(scenario.target, dtype=float),
        k1=config.k1,
        k2=config.k2,
        k3=config.k3,
        r_min=config.r_min,
        r_max=config.r_max,
        nu=scenario.nu,
        linear_zone=linear_zone_for_step(config.k1, step),
        max_center_speed=center_speed(scenario),
    )


def make_funnel_controller(scenario: Scenario) -> FunnelController:
    """The funnel controller with the scenario's gains and box funnels."""
    config = scenario.controller
    return FunnelController(
        kappa=list(config.kappa),
        funnels=[
            BoxFunnel(start=np.array(f.start), end=np.array(f.end), rate=np.array(f.rate))
            for f in config.funnels
        ],
    )


def add_omni_robot(builder: DiagramBuilder, scenario: Scenario) -> PlantHandles:
    """Omni base + its nominal-kinematics drive interface + a sinusoidal disturbance."""
    config: OmniRobotConfig = scenario.plant
    robot = builder.AddSystem(
        OmniRobot(
            config.wheel_radius,
            config.base_radius,
            initial_output(scenario),
            config.initial_heading,
        )
    )
    drive = builder.AddSystem(
        OmniDriveInterface(
            config.nominal_wheel_radius,
            config.nominal_base_radius,
            config.heading_gain,
            config.initial_heading,
        )
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
    uav = builder.AddSystem(
        Quadrotor(
            config.mass,
            config.drag,
            config.gravity,
            initial_output(scenario),
            np.asarray(config.initial_velocity, dtype=float),
        )
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


def make_arm_law(scenario: Scenario, limits: ArmLimits | None = None) -> ArmFunnelLaw:
    """The arm's two-space funnel law: the scenario's κ and joint-velocity funnel, and the
    task → joint mapping (posture: the FR3 home configuration; limits: the model's)."""
    config: FrankaArmConfig = scenario.plant
    limits = limits if limits is not None else ArmLimits.of(make_fr3_plant())
    return ArmFunnelLaw(
        controller=make_funnel_controller(scenario),
        mapping=JointSpaceMapping(
            damping=config.jacobian_damping,
            posture=FR3_HOME,
            posture_gain=config.posture_gain,
            position_lower=limits.position_lower,
            position_upper=limits.position_upper,
            limit_margin=config.limit_margin,
            limit_gain=config.limit_gain,
        ),
    )


def add_franka(builder: DiagramBuilder, scenario: Scenario) -> PlantHandles:
    """FR3 arm: continuous-time MultibodyPlant + SceneGraph (torque actuation), the robot's
    torque interface (gravity compensation from its own model, saturation), the TCP
    measurement, the arm's STT controller, the external jerks and the pick-and-place task
    sequencer."""
    config: FrankaArmConfig = scenario.plant
    plant, _scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    add_fr3(plant)
    plant.Finalize()
    plant.SetDefaultPositions(np.asarray(config.initial_configuration, dtype=float))
    limits = ArmLimits.of(plant)
    interface = builder.AddSystem(ArmRobotInterface(make_fr3_plant(), config.gravity_compensation))
    measurement = builder.AddSystem(ArmMeasurement(plant))
    law = make_arm_law(scenario, limits)
    controller = builder.AddSystem(ArmSTTController(law, ArmKinematics()))
    state = plant.get_state_output_port()
    builder.Connect(state, interface.GetInputPort("state"))
    builder.Connect(state, measurement.GetInputPort("state"))
    builder.Connect(plant.get_body_poses_output_port(), measurement.GetInputPort("body_poses"))
    builder.Connect(interface.GetOutputPort("actuation"), plant.get_actuation_input_port())
    logged = {
        "joint_state": state,
        "requested_torque": interface.GetOutputPort("requested_torque"),
        "applied_torque": interface.GetOutputPort("actuation"),
        "funnel_errors": controller.GetOutputPort("funnel_errors"),
        "joint_velocity_reference": controller.GetOutputPort("joint_velocity_reference"),
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
        pushes = builder.AddSystem(ExternalJerks(jerks))
        builder.Connect(
            pushes.GetOutputPort("spatial_forces"), plant.get_applied_spatial_force_input_port()
        )
        logged["external_force"] = pushes.GetOutputPort("force")
    targets = task_targets(scenario)
    sequencer = None
    if len(targets) > 1:
        sequencer = builder.AddSystem(
            TargetSequencer(targets, scenario.target_set_radius, config.hold_time, SEQUENCER_PERIOD)
        )
    return PlantHandles(
        plant=plant,
        control_input=interface.GetInputPort("torque_command"),
        output=measurement.GetOutputPort("output"),
        plant_state=measurement.GetOutputPort("plant_state"),
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
            jerks=[JerkWindow(j.start, j.start + j.duration) for j in jerks],
            settle=JERK_SETTLE_TIME,
            targets=targets,
            target_set_radius=scenario.target_set_radius,
        ),
    )


#: Plant builders by the scenario's plant config type; a case study registers its own.
PLANT_BUILDERS: dict[type, Callable[[DiagramBuilder, Scenario], PlantHandles]] = {
    OmniRobotConfig: add_omni_robot,
    QuadrotorConfig: add_quadrotor,
    FrankaArmConfig: add_franka,
}


def build_diagram(scenario: Scenario) -> SttDiagram:
    """Wire belief source → tube → controller → plant, the monitor, and loggers on the
    plant output, tube, belief, diagnostics, control and margins (DESIGN.md diagram)."""
    builder = DiagramBuilder()
    n, count = scenario.dimension, len(scenario.obstacles)
    belief_source = builder.AddSystem(ObstacleBeliefSource(scenario.obstacles, n))
    plant = PLANT_BUILDERS[type(scenario.plant)](builder, scenario)
    rate = scenario.tube.update_rate_hz
    tube = builder.AddSystem(
        SpatiotemporalTube(
            make_tube_law(scenario),
            np.asarray(scenario.start, dtype=float),
            count,
            update_period=1.0 / rate if rate > 0.0 else None,
            target_input=plant.sequencer is not None,
            rate_bounds=rate_bounds(scenario),
        )
    )
    controller = plant.controller
    if controller is None:
        controller = builder.AddSystem(STTController(make_funnel_controller(scenario), n))
    monitor = builder.AddSystem(InvariantMonitor(n, count, scenario.tube.r_min))

    belief = belief_source.GetOutputPort("obstacle_belief")
    builder.Connect(belief, tube.GetInputPort("obstacle_belief"))
    builder.Connect(tube.GetOutputPort("tube"), controller.GetInputPort("tube"))
    builder.Connect(plant.plant_state, controller.GetInputPort("plant_state"))
    builder.Connect(controller.GetOutputPort("control"), plant.control_input)
    builder.Connect(tube.GetOutputPort("tube"), monitor.GetInputPort("tube"))
    builder.Connect(belief, monitor.GetInputPort("obstacle_belief"))
    builder.Connect(plant.output, monitor.GetInputPort("output"))

    logged = {
        "output": plant.output,
        "tube": tube.GetOutputPort("tube"),
        "belief": belief,
        "diagnostics": tube.GetOutputPort("diagnostics"),
        "recovery": tube.GetOutputPort("recovery"),
        "control": controller.GetOutputPort("control"),
        "margins": monitor.GetOutputPort("margins"),
        "output_avoid_probability": monitor.GetOutputPort("output_avoid_probability"),
        "tube_avoid_probability": monitor.GetOutputPort("tube_avoid_probability"),
    }
    extra = dict(plant.logged)
    if plant.sequencer is not None:
        builder.Connect(tube.GetOutputPort("tube"), plant.sequencer.GetInputPort("tube"))
        builder.Connect(plant.sequencer.GetOutputPort("target"), tube.GetInputPort("target"))
        extra["task_target"] = plant.sequencer.GetOutputPort("target")
    logged.update(extra)
    loggers = {}
    for name, port in logged.items():
        loggers[name] = LogVectorOutput(port, builder, scenario.log_period)
        loggers[name].set_name(f"{name}_logger")
    diagram = builder.Build()
    diagram.set_name(scenario.name)
    return SttDiagram(
        diagram,
        belief_source,
        tube,
        controller,
        monitor,
        plant.plant,
        loggers,
        sequencer=plant.sequencer,
        extra_logs=tuple(extra),
        log_constants=dict(plant.log_constants),
        plant_report=plant.report,
    )
