"""Both halves in one process over memq://: the controller's run (tube, controller,
monitor on the received state) matches `stt-drake run`'s, every guarantee holds, and the
link's timing record is in the metrics; split at the detections, the tracker gets every
sample as in process and an interactive crowd in the station sees the station's robot;
the scenario's `lcm:` section and its errors."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from stt_drake.assembly import load_scenario
from stt_drake.assembly.perception import add_obstacle_sensing
from stt_drake.config import ScenarioError
from stt_drake.config.lcm import LcmConfig
from stt_drake.config.validate_lcm import validate_lcm
from stt_drake.core.motion import MotionTable
from stt_drake.robot.remote import remote_scenario
from stt_drake.robot.session import simulate_split
from stt_drake.run import simulate

ROOT = Path(__file__).resolve().parents[2]


def short_scenario(name: str, duration: float):
    return dataclasses.replace(load_scenario(ROOT / "diagrams" / f"{name}.yaml"), duration=duration)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "duration", "tolerance"),
    [
        ("omni_hardware_case1", 3.0, 0.02),
        ("uav_paper", 3.0, 0.02),
        ("franka_pick_place_case1", 2.0, 0.01),
    ],
)
def test_split_over_memq_tracks_the_in_process_run(name, duration, tolerance):
    """The split run's output y stays within `tolerance` m of the in-process run's (the
    command is held for one 10 ms control period, the in-process loop's is continuous),
    every guarantee holds, and every status of the run crossed the link in order."""
    alone = simulate(short_scenario(name, duration))
    split = simulate_split(short_scenario(name, duration))
    assert split.metrics.stop_reason is None and split.metrics.holds
    assert set(split.metrics.invariants) == set(alone.metrics.invariants)
    np.testing.assert_array_equal(split.log.t, alone.log.t)
    assert np.max(np.abs(split.log.output - alone.log.output)) < tolerance
    link = split.metrics["lcm"]
    assert link["accepted"] == round(duration / link["control_period_s"])  # ticks in [0, T)
    assert link["duplicates_dropped"] == link["out_of_order_dropped"] == 0
    assert link["age_s"]["max"] == pytest.approx(0.0, abs=1e-9)  # one Simulator: no delay
    assert 0.0 < link["tick_s"]["p50"] <= link["tick_s"]["p99"] <= link["tick_s"]["max"]


def test_lcm_section_loads_and_bad_values_name_their_field(tmp_path):
    text = (ROOT / "diagrams" / "omni_hardware_case1.yaml").read_text()
    path = tmp_path / "with_lcm.yaml"
    path.write_text(
        text + "lcm: {lcm_url: 'memq://', channel_suffix: _A, control_rate_hz: 50.0,"
        " stale_timeout: 0.5}\n"
    )
    scenario = load_scenario(path)
    assert scenario.lcm == LcmConfig(
        lcm_url="memq://", channel_suffix="_A", control_rate_hz=50.0, stale_timeout=0.5
    )
    assert remote_scenario(scenario).lcm.period == pytest.approx(0.02)
    for field, value, words in (
        ("lcm_url", "tcp://x", "scenario.lcm.lcm_url: must be empty"),
        ("status_channel", "A B", "scenario.lcm.status_channel: must be a channel name"),
        ("control_rate_hz", 0.0, "scenario.lcm.control_rate_hz: must lie in"),
        ("stale_timeout", 0.005, "scenario.lcm.stale_timeout: must be longer than one"),
    ):
        with pytest.raises(ScenarioError, match=words):
            validate_lcm(dataclasses.replace(LcmConfig(), **{field: value}))


def sensor_samples(scenario, samples: int) -> np.ndarray:
    """The first `samples` detections vectors of the scenario's sensor (the in-process
    run's: the same seeded truth and sensor draws), the robot held at the start (the range
    is infinite, so where the robot is does not matter)."""
    builder = DiagramBuilder()
    robot = builder.AddSystem(ConstantVectorSource(np.asarray(scenario.start, dtype=float)))
    _, sensor = add_obstacle_sensing(builder, scenario, robot.get_output_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    sensor_context = sensor.GetMyContextFromRoot(context)
    rows = []
    for k in range(samples):  # at latency 0, sample k is delivered at k·period
        context.SetTime(k * scenario.perception.sensor_period)
        rows.append(sensor.GetOutputPort("detections").Eval(sensor_context).copy())
    return np.array(rows)


@pytest.mark.slow
def test_tracked_split_delivers_every_detection_and_the_same_belief():
    """omni_tracked split at the detections: the station's sensor publishes each sample at
    its delivery time and the controller's subscriber drains at the tracker's update times
    (both every sensor period, offset the latency 0), so the tracker reads sample k at
    t_k = k·0.1 s, as in process: no delay. The detections and the tracker are functions
    of the seeded truth and sensor draws and of time only (infinite sensing range: the
    robot's slightly different path under the held command does not enter), so the belief
    log is bit-identical, not just close."""
    scenario = short_scenario("omni_tracked", 3.0)
    assert not scenario.perception.sensing_range and scenario.perception.latency == 0.0
    alone = simulate(scenario)
    split = simulate_split(scenario)
    assert split.metrics.stop_reason is None and split.metrics.holds and alone.metrics.holds
    assert set(split.metrics.invariants) == set(alone.metrics.invariants)
    period, samples = scenario.perception.sensor_period, 30  # t_k = 0, 0.1, ..., 2.9 s
    expected = sensor_samples(scenario, samples)
    received = split.log.rows("detections")
    for k in range(samples):  # the sample the tracker held until the next update
        held = np.flatnonzero(split.log.t < (k + 1) * period - 1e-9)[-1]
        np.testing.assert_array_equal(received[held], expected[k])
    for name in ("belief", "belief_updates", "tracker_consistency", "true_obstacle_position"):
        np.testing.assert_array_equal(split.log.rows(name), alone.log.rows(name), err_msg=name)
    record = split.metrics["lcm"]["detections"]
    assert (record["channel"], record["accepted"]) == ("STT_DETECTIONS", samples)
    assert record["duplicates_dropped"] == record["out_of_order_dropped"] == 0
    assert record["silences"] == 0
    assert record["age_s"]["max"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.slow
def test_the_interactive_crowd_reacts_to_the_station_robot(tmp_path):
    """crowd_crossing_interactive split for 8 s: the pedestrians are simulated in the
    station, around its robot (the only robot of the split diagram). Until the robot comes
    near them (about 5.7 s) they walk exactly as the same crowd without a robot (the
    scenario with `interactive: false`, drawn from the same seeds); after, they deviate
    from it: they react to the station's robot. Every guarantee holds on the controller's
    side, its tracker fed by the station's detections."""
    path = ROOT / "diagrams" / "crowd_crossing_interactive.yaml"
    duration = 8.0
    split = simulate_split(dataclasses.replace(load_scenario(path), duration=duration))
    assert split.metrics.stop_reason is None and split.metrics.holds
    assert split.metrics["lcm"]["detections"]["accepted"] == round(duration / 0.1)
    robotless = tmp_path / "robotless.yaml"
    robotless.write_text(path.read_text().replace("interactive: true", "interactive: false"))
    reference = dataclasses.replace(load_scenario(robotless), duration=duration)
    motions = MotionTable([o.motion for o in reference.obstacles], reference.dimension)
    alone = np.array([motions.positions(t).ravel() for t in split.log.t])
    deviation = np.nanmax(np.abs(split.log.rows("true_obstacle_position") - alone), axis=1)
    early = split.log.t < 5.0
    assert np.all(deviation[early] < 1e-9)
    assert deviation.max() > 0.02  # m (3.5 cm here; 0.66 m by 10 s)


def test_the_split_accepts_a_tracked_scenario():
    assert remote_scenario(short_scenario("omni_tracked", 1.0)).lcm == LcmConfig()
