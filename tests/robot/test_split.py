"""Both halves in one process over memq://: the controller's run (tube, controller,
monitor on the received state) matches `stt-drake run`'s, every guarantee holds, and the
link's timing record is in the metrics; the scenario's `lcm:` section and its errors."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario
from stt_drake.config import ScenarioError
from stt_drake.config.lcm import LcmConfig, validate_lcm
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


def test_the_split_refuses_a_tracked_scenario_by_name():
    scenario = load_scenario(ROOT / "diagrams" / "omni_tracked.yaml")
    with pytest.raises(ScenarioError, match=r"^scenario.perception: the station/controller"):
        remote_scenario(scenario)
