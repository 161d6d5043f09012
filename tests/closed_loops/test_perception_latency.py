"""The sensor's latency contract (issue 26, item 4), in a real Diagram advanced by a
Simulator: latency L delivers the detection taken at t (stamped t) to the tracker at
t + L, so the tracker's belief at τ holds every detection stamped ≤ τ − L and none later
— L = 0 included (the tracker sees the sample taken at its own update instant).

Drake's convention at an event instant: a discrete update at τ takes effect at τ⁺ (the
state read back after ``AdvanceTo(τ)`` is the one before that instant's updates, as a
logger at τ sees it). The contract is therefore checked just before and just after every
delivery and at times between them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from stt_drake.core.motion import ConstantVelocity
from stt_drake.core.perception import Detections, SensorModel, draw_truth_deviation
from stt_drake.core.tracking import KalmanTracker, TrackTable
from stt_drake.systems.perception import ObstacleSensor, ObstacleTracker, TrueObstacles

PERIOD = 0.1
HORIZON = 2.0
START = np.array([1.0, 2.0])
VELOCITY = np.array([0.3, -0.2])
#: Just before / after an instant (s): far below the period, far above rounding.
NUDGE = 1e-7


@dataclass
class Chain:
    diagram: Diagram
    sensor: ObstacleSensor
    tracker: ObstacleTracker


def build_chain(latency: float, noise: float = 0.0, dropout: float = 0.0) -> Chain:
    """One constant-velocity obstacle with exactly its scripted motion (no process noise),
    the robot at the origin, a sensor with noise σ = `noise` (0: deterministic) and
    `dropout`, and a tracker updating at the delivery times (offset = latency)."""
    builder = DiagramBuilder()
    motion = ConstantVelocity(start=list(START), velocity=list(VELOCITY))
    path = draw_truth_deviation(1, 2, 0.0, PERIOD, HORIZON + latency + PERIOD, None)
    truth = builder.AddSystem(TrueObstacles([motion], 2, path))
    model = SensorModel(
        1,
        2,
        PERIOD,
        HORIZON + latency + PERIOD,
        noise**2 * np.eye(2),
        dropout,
        np.inf,
        np.random.default_rng(5),
    )
    sensor = builder.AddSystem(ObstacleSensor(model, latency))
    # The tracker's own noise model must be positive (a zero R makes S singular).
    law = KalmanTracker(2, 0.01, 0.05**2 * np.eye(2), 0.5, track_timeout=1.0)
    tracker = builder.AddSystem(ObstacleTracker(law, 1, PERIOD, offset=latency))
    robot = builder.AddSystem(ConstantVectorSource(np.zeros(2)))
    builder.Connect(robot.get_output_port(), sensor.GetInputPort("robot_position"))
    builder.Connect(truth.get_output_port(), sensor.GetInputPort("true_obstacle_position"))
    builder.Connect(sensor.GetOutputPort("detections"), tracker.GetInputPort("detections"))
    return Chain(builder.Build(), sensor, tracker)


def tracks_at(chain: Chain, times) -> list[TrackTable]:
    """The tracker's table after advancing to each of `times` (increasing)."""
    simulator = Simulator(chain.diagram)
    context = chain.tracker.GetMyContextFromRoot(simulator.get_context())
    tables = []
    for t in times:
        simulator.AdvanceTo(t)
        # A copy: the table's arrays view the context's state, which moves on.
        tables.append(TrackTable.from_vector(chain.tracker.tracks(context).to_vector(), 2))
    return tables


def last_stamp(tau: float, latency: float) -> float:
    """The contract: the largest k·T ≤ τ − L (−inf before the first delivery)."""
    k = np.floor((tau - latency) / PERIOD + 1e-9)
    return k * PERIOD if k >= 0 else -np.inf


LATENCIES = [0.0, PERIOD / 2, 1.5 * PERIOD]


@pytest.mark.parametrize("latency", LATENCIES)
def test_first_track_is_born_at_the_latency_from_the_sample_stamped_zero(latency):
    times = ([latency - NUDGE] if latency > 0.0 else []) + [latency + NUDGE]
    tables = tracks_at(build_chain(latency), times)
    if latency > 0.0:
        assert not tables[0].active.any()
        assert tables[0].detection_time[0] == -np.inf
    born = tables[-1]
    assert born.active[0]
    assert born.detection_time[0] == 0.0
    # A deterministic sensor: the birth's mean is the true centre at the stamp, t = 0.
    np.testing.assert_array_equal(born.state[0, :2], START)


@pytest.mark.parametrize("latency", LATENCIES)
def test_the_last_consumed_stamp_is_the_latest_sample_delivered(latency):
    deliveries = latency + PERIOD * np.arange(12)
    between = np.arange(0.013, 1.2, 0.037)
    # Not at a delivery instant itself (Drake shows the state before its update there).
    off = np.abs((between - latency) / PERIOD - np.round((between - latency) / PERIOD)) > 1e-6
    times = np.sort(np.concatenate([deliveries - NUDGE, deliveries + NUDGE, between[off]]))
    times = times[times > 0.0]
    tables = tracks_at(build_chain(latency), times)
    consumed = np.array([table.detection_time[0] for table in tables])
    expected = np.array([last_stamp(t, latency) for t in times])
    np.testing.assert_allclose(consumed, expected, rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("latency", [PERIOD / 2, 0.09, 1.5 * PERIOD])
def test_a_latency_delays_the_tracks_and_nothing_else(latency):
    """The same detections, consumed L later: the track table at τ + L with latency L is
    the table at τ with latency 0, bit for bit (noise and dropouts drawn)."""
    times = np.arange(0.05, 1.5, 0.1)
    prompt = tracks_at(build_chain(0.0, noise=0.05, dropout=0.2), times)
    late = tracks_at(build_chain(latency, noise=0.05, dropout=0.2), times + latency)
    for now, then in zip(prompt, late, strict=True):
        np.testing.assert_array_equal(then.to_vector(), now.to_vector())


def test_latency_below_one_period_changes_the_belief():
    """The bug of issue 26: latency 0 and 0.09 s (period 0.1 s) gave bit-identical beliefs
    (every sample reached the tracker one period late)."""
    beliefs = []
    for latency in (0.0, 0.09):
        chain = build_chain(latency, noise=0.05, dropout=0.2)
        simulator = Simulator(chain.diagram)
        simulator.AdvanceTo(1.55)
        context = chain.tracker.GetMyContextFromRoot(simulator.get_context())
        beliefs.append(chain.tracker.GetOutputPort("obstacle_belief").Eval(context).copy())
        stamp = chain.tracker.tracks(context).detection_time[0]
        assert stamp == pytest.approx(1.5 if latency == 0.0 else 1.4, abs=1e-12)
    assert not np.array_equal(beliefs[0], beliefs[1])


@pytest.mark.parametrize("latency", [0.0, 0.05, 0.1, 0.12, 0.3, 0.35, 1.0])
def test_sensor_output_is_the_latest_delivered_sample_at_every_time(latency):
    """Between events, just before and just after them (integer multiples of the period
    included, whose quotient rounds below the integer): the output is sample
    ⌊(τ − L)/T⌋, exactly as measured, and the ring never misses it."""
    model = SensorModel(2, 2, PERIOD, 3.0, 0.01 * np.eye(2), 0.3, np.inf, np.random.default_rng(8))
    sensor = ObstacleSensor(model, latency)
    assert sensor.depth == int(np.ceil(round(latency / PERIOD, 9))) + 1
    context = sensor.CreateDefaultContext()
    sensor.GetInputPort("robot_position").FixValue(context, np.zeros(2))
    sensor.GetInputPort("true_obstacle_position").FixValue(context, np.zeros(4))
    simulator = Simulator(sensor, context)
    instants = np.concatenate([PERIOD * np.arange(25), latency + PERIOD * np.arange(25)])
    times = np.sort(np.concatenate([instants - NUDGE, instants + NUDGE, instants + 0.031]))
    for t in times[(times > 0.0) & (times < 2.4)]:
        simulator.AdvanceTo(t)
        sample = Detections.from_vector(sensor.GetOutputPort("detections").Eval(context), 2)
        stamp = last_stamp(t, latency)
        np.testing.assert_array_equal(sample.stamp, stamp)
        if stamp >= 0.0:
            expected = model.measure(round(stamp / PERIOD), np.zeros((2, 2)), np.zeros(2))
            np.testing.assert_array_equal(sample.detected, expected.detected)
            np.testing.assert_array_equal(sample.position, expected.position)


def test_at_latency_zero_the_sample_of_the_instant_is_read_before_it_is_stored():
    """Another system's update at a sample instant reads the state before the sensor's
    measuring event: the output then measures from the inputs, the value the event stores."""
    model = SensorModel(1, 2, PERIOD, 1.0, 0.01 * np.eye(2), 0.0, np.inf, np.random.default_rng(9))
    sensor = ObstacleSensor(model)
    context = sensor.CreateDefaultContext()
    sensor.GetInputPort("robot_position").FixValue(context, np.zeros(2))
    sensor.GetInputPort("true_obstacle_position").FixValue(context, np.array([1.0, 1.0]))
    before = sensor.GetOutputPort("detections").Eval(context).copy()  # nothing stored yet
    assert Detections.from_vector(before, 2).stamp[0] == 0.0
    simulator = Simulator(sensor, context)
    simulator.AdvanceTo(0.5 * PERIOD)  # the event at 0 has stored sample 0
    np.testing.assert_array_equal(sensor.GetOutputPort("detections").Eval(context), before)


@pytest.mark.parametrize("bad", [-0.1, np.inf, np.nan])
def test_bad_latency_and_offset_are_refused(bad):
    model = SensorModel(1, 2, PERIOD, 1.0, np.eye(2), 0.0, np.inf, np.random.default_rng(0))
    with pytest.raises(ValueError, match="latency must be finite and >= 0"):
        ObstacleSensor(model, bad)
    law = KalmanTracker(2, 0.01, np.eye(2), 0.5, track_timeout=1.0)
    with pytest.raises(ValueError, match="offset must be finite and >= 0"):
        ObstacleTracker(law, 1, PERIOD, offset=bad)


def test_the_loader_allows_any_latency_below_the_duration():
    """The first detection is tracked at t = latency (no period lost on the way): a latency
    just below the run's duration loads, one equal to it is refused naming the field; the
    track timeout need only exceed sensor_period + latency."""
    from stt_drake.assembly import parse_scenario
    from stt_drake.config import ScenarioError

    text = (Path(__file__).resolve().parents[2] / "diagrams" / "omni_tracked.yaml").read_text()
    text = re.sub(r"track_timeout: 1\.0[^\n]*", "track_timeout: 13.0", text)
    base = re.sub(r"  sensor_period: 0\.1[^\n]*", "  sensor_period: 0.1\n  latency: LATENCY", text)
    assert parse_scenario(base.replace("LATENCY", "11.95")).perception.latency == 11.95
    with pytest.raises(ScenarioError, match=r"scenario\.perception\.latency: must let"):
        parse_scenario(base.replace("LATENCY", "12.0"))
    tight = text.replace("track_timeout: 13.0", "track_timeout: 0.1")
    with pytest.raises(ScenarioError, match=r"track_timeout: must exceed sensor_period"):
        parse_scenario(tight)
    assert parse_scenario(text.replace("track_timeout: 13.0", "track_timeout: 0.11"))
