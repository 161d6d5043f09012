"""Tests of the Drake perception chain in stt_drake.systems.perception: TrueObstacles →
ObstacleSensor → ObstacleTracker, in a real Diagram advanced by a Simulator.

The tracker's belief is checked against the truth it never sees: with a matched model
(truth deviations of the tracker's own process density, velocities drawn from its own
velocity prior, its own measurement noise) the normalised estimation error squared
eᵀ Σ⁻¹ e of each active slot is χ²_n distributed, so its average is n.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, VectorLogSink

from stt_drake.core.belief import GaussianBelief
from stt_drake.core.motion import ConstantVelocity
from stt_drake.core.perception import Detections, SensorModel, draw_truth_deviation
from stt_drake.core.tracking import KalmanTracker
from stt_drake.systems.perception import ObstacleSensor, ObstacleTracker, TrueObstacles

PERIOD = 0.05
DENSITY = 0.2
VELOCITY_SIGMA = 0.5


@dataclass
class Chain:
    diagram: Diagram
    truth: TrueObstacles
    tracker: ObstacleTracker
    belief_log: VectorLogSink
    truth_log: VectorLogSink


def noise_covariance(n: int) -> np.ndarray:
    return np.diag([0.02, 0.01, 0.015][:n]) + 0.004 * (1 - np.eye(n))


def build_chain(
    starts: np.ndarray,
    seed: int,
    *,
    horizon: float = 3.0,
    sensing_range: float = np.inf,
    dropout: float = 0.3,
    log_period: float = 0.5,
) -> Chain:
    """truth → sensor → tracker, robot fixed at the origin, a matched tracker model."""
    count, n = starts.shape
    rng = np.random.default_rng(seed)
    motions = [
        ConstantVelocity(start=list(start), velocity=list(VELOCITY_SIGMA * rng.standard_normal(n)))
        for start in starts
    ]
    noise = noise_covariance(n)
    builder = DiagramBuilder()
    truth = builder.AddSystem(
        TrueObstacles(motions, n, draw_truth_deviation(count, n, DENSITY, PERIOD, horizon, rng))
    )
    sensor = builder.AddSystem(
        ObstacleSensor(SensorModel(count, n, PERIOD, horizon, noise, dropout, sensing_range, rng))
    )
    law = KalmanTracker(n, DENSITY, noise, VELOCITY_SIGMA, track_timeout=0.5)
    tracker = builder.AddSystem(ObstacleTracker(law, count, PERIOD))
    robot = builder.AddSystem(ConstantVectorSource(np.zeros(n)))
    builder.Connect(robot.get_output_port(), sensor.GetInputPort("robot_position"))
    builder.Connect(
        truth.GetOutputPort("true_obstacle_position"),
        sensor.GetInputPort("true_obstacle_position"),
    )
    builder.Connect(sensor.GetOutputPort("detections"), tracker.GetInputPort("detections"))
    belief_log = LogVectorOutput(tracker.GetOutputPort("obstacle_belief"), builder, log_period)
    truth_log = LogVectorOutput(truth.GetOutputPort("true_obstacle_position"), builder, log_period)
    return Chain(builder.Build(), truth, tracker, belief_log, truth_log)


def simulate(chain: Chain, end: float) -> Simulator:
    simulator = Simulator(chain.diagram)
    simulator.AdvanceTo(end)
    return simulator


@pytest.mark.parametrize("n", [2, 3])
def test_belief_error_is_consistent_with_the_covariance(n):
    count = 400
    starts = np.random.default_rng(100 + n).uniform(-5.0, 5.0, (count, n))
    chain = build_chain(starts, seed=n)
    simulator = simulate(chain, 3.0)
    beliefs = chain.belief_log.FindLog(simulator.get_context())
    truths = chain.truth_log.FindLog(simulator.get_context())
    nees = []
    for belief_vector, truth_vector in zip(beliefs.data().T[1:], truths.data().T[1:], strict=True):
        belief = GaussianBelief.from_vector(belief_vector, n)
        assert belief.active.all()  # everything in range, dropouts shorter than the timeout
        error = truth_vector.reshape(count, n) - belief.mean
        nees.append(np.einsum("mi,mij,mj->m", error, np.linalg.inv(belief.covariance), error))
    # Per log time the 400 slots are independent: the mean of χ²_n over them has standard
    # deviation √(2n/400) ≤ 0.13; averaging over the (correlated) times cannot widen it.
    # The tolerance is 3.5 of those.
    assert abs(np.mean(nees) - n) < 3.5 * np.sqrt(2 * n / count)


def test_slots_out_of_range_stay_inactive():
    starts = np.array([[1.0, 0.0], [0.0, -2.0], [40.0, 0.0], [0.0, -60.0]])
    chain = build_chain(starts, seed=1, sensing_range=5.0, dropout=0.0)
    simulator = simulate(chain, 1.0)
    context = chain.tracker.GetMyContextFromRoot(simulator.get_context())
    belief = GaussianBelief.from_vector(
        chain.tracker.GetOutputPort("obstacle_belief").Eval(context), 2
    )
    np.testing.assert_array_equal(belief.active, [True, True, False, False])
    np.testing.assert_array_equal(belief.mean[2:], 0.0)
    np.testing.assert_array_equal(belief.covariance[2:], np.broadcast_to(np.eye(2), (2, 2, 2)))
    assert np.all(np.isfinite(belief.mean)) and np.all(np.isfinite(belief.covariance))


def final_belief(seed: int, log_period: float) -> np.ndarray:
    starts = np.random.default_rng(0).uniform(-3.0, 3.0, (6, 2))
    chain = build_chain(starts, seed=seed, horizon=2.0, log_period=log_period)
    simulator = simulate(chain, 2.0)
    context = chain.tracker.GetMyContextFromRoot(simulator.get_context())
    return chain.tracker.GetOutputPort("obstacle_belief").Eval(context).copy()


def test_same_seed_gives_identical_beliefs():
    # A different logging rate evaluates the ports at other times and another number of
    # times: the pre-drawn sensor tables make that irrelevant.
    first = final_belief(seed=11, log_period=0.5)
    np.testing.assert_array_equal(first, final_belief(seed=11, log_period=0.5))
    np.testing.assert_array_equal(first, final_belief(seed=11, log_period=0.01))
    assert not np.array_equal(first, final_belief(seed=12, log_period=0.5))


def test_true_obstacles_is_motion_plus_deviation():
    motions = [ConstantVelocity(start=[1.0, 2.0], velocity=[0.5, -0.25])]
    path = draw_truth_deviation(1, 2, 0.5, 0.1, 2.0, np.random.default_rng(2))
    system = TrueObstacles(motions, 2, path)
    context = system.CreateDefaultContext()
    context.SetTime(1.23)
    expected = np.array([1.0 + 0.5 * 1.23, 2.0 - 0.25 * 1.23]) + path.deviation(1.23)[0]
    np.testing.assert_allclose(
        system.GetOutputPort("true_obstacle_position").Eval(context), expected, atol=1e-15
    )


@pytest.mark.parametrize("latency", [0.0, 0.1, 0.12])
def test_sensor_delivers_after_the_latency_with_the_measurement_stamp(latency):
    model = SensorModel(
        2, 2, PERIOD, 1.0, noise_covariance(2), 0.0, np.inf, np.random.default_rng(3)
    )
    sensor = ObstacleSensor(model, latency)
    context = sensor.CreateDefaultContext()
    sensor.GetInputPort("robot_position").FixValue(context, np.zeros(2))
    sensor.GetInputPort("true_obstacle_position").FixValue(context, np.zeros(4))
    first = Detections.from_vector(sensor.GetOutputPort("detections").Eval(context), 2)
    if latency == 0.0:
        # Sample 0 is delivered at t = 0 itself (issue 26: a latency L delivers the sample
        # stamped t at t + L, L = 0 included); before, nothing was until the next period.
        assert first.detected.all() and np.all(first.stamp == 0.0)
    else:
        assert not first.detected.any() and np.all(first.stamp == -np.inf)
    simulator = Simulator(sensor, context)
    simulator.AdvanceTo(0.33)
    sample = Detections.from_vector(sensor.GetOutputPort("detections").Eval(context), 2)
    # The last sample whose delivery time k·period + latency is at or before 0.33 s.
    stamp = np.floor((0.33 - latency) / PERIOD + 1e-9) * PERIOD
    np.testing.assert_allclose(sample.stamp, stamp, rtol=0, atol=1e-12)
    assert sample.detected.all()
    np.testing.assert_array_equal(
        sample.position,
        model.measure(round(stamp / PERIOD), np.zeros((2, 2)), np.zeros(2)).position,
    )
