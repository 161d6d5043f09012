"""A scenario's `lcm:` section is checked when the scenario loads: a bad value fails at
load with ScenarioError naming ``scenario.lcm.<field>``."""

from __future__ import annotations

from pathlib import Path

import pytest

from stt_drake.assembly import load_scenario
from stt_drake.config import ScenarioError

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("section", "words"),
    [
        ("{lcm_url: 'tcp://robot:7667'}", "scenario.lcm.lcm_url: must be empty"),
        ("{detections_channel: 'A B'}", "scenario.lcm.detections_channel: must be a channel"),
        ("{control_rate_hz: 100.0, stale_timeout: 0.001}", "scenario.lcm.stale_timeout:"),
    ],
)
def test_a_bad_lcm_value_fails_at_load_naming_its_field(tmp_path, section, words):
    text = (ROOT / "diagrams" / "omni_hardware_case1.yaml").read_text()
    path = tmp_path / "bad_lcm.yaml"
    path.write_text(text + f"lcm: {section}\n")
    with pytest.raises(ScenarioError, match=words):
        load_scenario(path)
