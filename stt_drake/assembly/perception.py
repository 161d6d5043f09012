"""The perception half of a scenario's diagram: the true obstacles (scripted motion plus a
drawn deviation, or the interactive crowd), the sensor ranging from the robot, and the
Kalman tracker whose `obstacle_belief` the tube reads; or the tracker alone, fed with
detections from elsewhere (the LCM link of :mod:`stt_drake.robot`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import DiagramBuilder, OutputPort

from stt_drake.assembly.load import crowd_setup
from stt_drake.config import Scenario
from stt_drake.core.perception import SensorModel, draw_truth_deviation
from stt_drake.core.tracking import KalmanTracker
from stt_drake.systems.crowd import CrowdSimulator
from stt_drake.systems.perception import ObstacleSensor, ObstacleTracker, TrueObstacles


@dataclass
class PerceptionHandles:
    """The perception chain :func:`add_perception` added (no truth or sensor: the
    detections came from elsewhere)."""

    truth: TrueObstacles | CrowdSimulator | None
    sensor: ObstacleSensor | None
    tracker: ObstacleTracker


#: Independent random streams of one scenario seed (numpy SeedSequence spawn keys).
TRUTH_STREAM, SENSOR_STREAM = 1, 2


def add_crowd(
    builder: DiagramBuilder, scenario: Scenario, robot_output: OutputPort
) -> CrowdSimulator:
    """The interactive crowd of `scenario.crowd` (:class:`CrowdSimulator`, named "crowd"),
    the robot's position (`robot_output`) connected to it; its slots are the scenario's
    obstacles (:func:`stt_drake.assembly.load.crowd_obstacles`, the same draw)."""
    config = scenario.crowd
    crowd = builder.AddNamedSystem(
        "crowd", CrowdSimulator(crowd_setup(scenario), config.robot_radius, config.period)
    )
    builder.Connect(robot_output, crowd.GetInputPort("robot_position"))
    return crowd


def add_obstacle_sensing(
    builder: DiagramBuilder, scenario: Scenario, robot_output: OutputPort
) -> tuple[TrueObstacles | CrowdSimulator, ObstacleSensor]:
    """The world side of `scenario.perception`: the true obstacles (drawn from the seed; the
    interactive crowd, which sees the robot at `robot_output`, if there is one) and the
    sensor ranging them from `robot_output`."""
    config = scenario.perception
    n, count = scenario.dimension, len(scenario.obstacles)
    horizon = scenario.duration + config.latency + config.sensor_period
    if scenario.crowd is not None and scenario.crowd.interactive:  # the pedestrians, who
        # see the robot, are the truth
        truth = add_crowd(builder, scenario, robot_output)
    else:
        truth_draws = np.random.default_rng([scenario.seed, TRUTH_STREAM])
        path = draw_truth_deviation(
            count, n, config.process_noise_density, config.truth_period, horizon, truth_draws
        )
        truth = builder.AddNamedSystem(
            "true_obstacles", TrueObstacles([o.motion for o in scenario.obstacles], n, path)
        )
    model = SensorModel(
        count,
        n,
        config.sensor_period,
        horizon,
        config.noise(n),
        config.dropout_probability,
        config.sensing_range or np.inf,
        np.random.default_rng([scenario.seed, SENSOR_STREAM]),
    )
    crowd = isinstance(truth, CrowdSimulator)
    sensor = builder.AddNamedSystem(
        "obstacle_sensor", ObstacleSensor(model, config.latency, presence=crowd)
    )
    if crowd:  # a pedestrian out of the scene is not detected
        builder.Connect(
            truth.GetOutputPort("pedestrian_active"), sensor.GetInputPort("obstacle_present")
        )
    builder.Connect(
        truth.GetOutputPort("true_obstacle_position"),
        sensor.GetInputPort("true_obstacle_position"),
    )
    builder.Connect(robot_output, sensor.GetInputPort("robot_position"))
    return truth, sensor


def add_perception(
    builder: DiagramBuilder,
    scenario: Scenario,
    robot_output: OutputPort,
    detections: OutputPort | None = None,
) -> PerceptionHandles:
    """True obstacles → sensor (:func:`add_obstacle_sensing`, ranging from `robot_output`)
    → Kalman tracker (`scenario.perception`). Given `detections` (a sensor's port, e.g.
    received from a station), only the tracker is added, reading them."""
    config = scenario.perception
    n, count = scenario.dimension, len(scenario.obstacles)
    truth = sensor = None
    if detections is None:
        truth, sensor = add_obstacle_sensing(builder, scenario, robot_output)
        detections = sensor.GetOutputPort("detections")
    tracker = KalmanTracker(
        n,
        config.tracker_density(),
        config.tracker_noise(n),
        config.initial_velocity_sigma,
        config.track_timeout,
        config.adaptation(n),
    )
    tracking = builder.AddNamedSystem(
        "obstacle_tracker",
        ObstacleTracker(
            tracker, count, config.sensor_period, config.blend_time, offset=config.latency
        ),
    )
    builder.Connect(detections, tracking.GetInputPort("detections"))
    return PerceptionHandles(truth, sensor, tracking)
