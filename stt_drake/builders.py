"""Scenario → Drake Diagram, with handles to every system and logger a caller needs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem, OutputPort
from pydrake.systems.primitives import LogVectorOutput, Sine, VectorLogSink

from stt_drake.control import BoxFunnel, FunnelController
from stt_drake.scenario import OmniRobot as OmniRobotConfig
from stt_drake.scenario import Scenario, initial_output
from stt_drake.systems.belief_source import ObstacleBeliefSource
from stt_drake.systems.controller import STTController
from stt_drake.systems.monitor import InvariantMonitor
from stt_drake.systems.omni import OmniDriveInterface, OmniRobot
from stt_drake.systems.tube import SpatiotemporalTube
from stt_drake.tube import TubeLaw, linear_zone_for_step


@dataclass
class PlantHandles:
    """What a plant builder adds: its main system, where the control goes in, and the
    ports the loop reads (y for the monitor, the stacked stage states for the controller)."""

    plant: LeafSystem
    control_input: object  # an InputPort
    output: OutputPort
    plant_state: OutputPort


@dataclass
class SttDiagram:
    """A built scenario: the Diagram and handles to its systems and loggers."""

    diagram: Diagram
    belief_source: ObstacleBeliefSource
    tube: SpatiotemporalTube
    controller: STTController
    monitor: InvariantMonitor
    plant: LeafSystem
    loggers: dict[str, VectorLogSink] = field(default_factory=dict)


def make_tube_law(scenario: Scenario) -> TubeLaw:
    """The tube law with the scenario's constants (ν derived when not given).

    In continuous time the attraction gets the linear zone that the simulator's largest
    step cannot resolve anyway (see :func:`stt_drake.tube.signed_cube_root_attraction`);
    the fixed-rate update integrates the attraction's exact flow and needs none.
    """
    config = scenario.tube
    continuous = config.update_rate_hz == 0.0
    return TubeLaw(
        target=np.asarray(scenario.target, dtype=float),
        k1=config.k1,
        k2=config.k2,
        k3=config.k3,
        r_min=config.r_min,
        r_max=config.r_max,
        nu=scenario.nu,
        linear_zone=linear_zone_for_step(config.k1, scenario.simulator.max_step_size)
        if continuous
        else 0.0,
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
    angular_frequency = 2.0 * np.pi * config.disturbance_frequency_hz
    disturbance = builder.AddNamedSystem(
        "disturbance",
        Sine(
            amplitudes=np.asarray(config.disturbance_amplitude, dtype=float),
            frequencies=np.full(2, angular_frequency),
            phases=np.array([0.0, np.pi / 2.0]),
        ),
    )
    builder.Connect(drive.GetOutputPort("wheel_speeds"), robot.GetInputPort("wheel_speeds"))
    builder.Connect(robot.GetOutputPort("pose"), drive.GetInputPort("pose"))
    builder.Connect(disturbance.get_output_port(0), robot.GetInputPort("disturbance"))
    return PlantHandles(
        plant=robot,
        control_input=drive.GetInputPort("velocity_command"),
        output=robot.GetOutputPort("output"),
        plant_state=robot.GetOutputPort("plant_state"),
    )


#: Plant builders by the scenario's plant config type; a case study registers its own.
PLANT_BUILDERS: dict[type, Callable[[DiagramBuilder, Scenario], PlantHandles]] = {
    OmniRobotConfig: add_omni_robot,
}


def build_diagram(scenario: Scenario) -> SttDiagram:
    """Wire belief source → tube → controller → plant, the monitor, and loggers on the
    plant output, tube, belief, diagnostics, control and margins (DESIGN.md diagram)."""
    builder = DiagramBuilder()
    n, count = scenario.dimension, len(scenario.obstacles)
    belief_source = builder.AddSystem(ObstacleBeliefSource(scenario.obstacles, n))
    rate = scenario.tube.update_rate_hz
    tube = builder.AddSystem(
        SpatiotemporalTube(
            make_tube_law(scenario),
            np.asarray(scenario.start, dtype=float),
            count,
            update_period=1.0 / rate if rate > 0.0 else None,
        )
    )
    controller = builder.AddSystem(STTController(make_funnel_controller(scenario), n))
    monitor = builder.AddSystem(InvariantMonitor(n, count, scenario.tube.r_min))
    plant = PLANT_BUILDERS[type(scenario.plant)](builder, scenario)

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
        "control": controller.GetOutputPort("control"),
        "margins": monitor.GetOutputPort("margins"),
        "output_avoid_probability": monitor.GetOutputPort("output_avoid_probability"),
        "tube_avoid_probability": monitor.GetOutputPort("tube_avoid_probability"),
    }
    loggers = {}
    for name, port in logged.items():
        loggers[name] = LogVectorOutput(port, builder, scenario.log_period)
        loggers[name].set_name(f"{name}_logger")
    diagram = builder.Build()
    diagram.set_name(scenario.name)
    return SttDiagram(diagram, belief_source, tube, controller, monitor, plant.plant, loggers)
