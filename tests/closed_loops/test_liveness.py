"""Arriving, measured: the liveness scenarios, `--no-guide` on run and campaign, and
`stt-drake compare` over randomised draws with the guided tube as a row of its own."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stt_drake.assembly import load_scenario
from stt_drake.cli.main import main

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"
POCKET = Path(__file__).resolve().parents[1] / "scenarios" / "omni_pocket_u.yaml"

#: The keys of every row of a draws comparison (written out, not imported from the code).
DRAW_ROW_KEYS = {
    "controller",
    "draws",
    "success_rate",
    "stall_rate",
    "timeout_rate",
    "unsafe_rate",
    "t_output_in_target_p50_s",
    "t_output_in_target_p90_s",
    "path_length_mean_m",
    "min_clearance_m",
    "step_us_median",
    "collision_rate",
    "min_distance_m",
    "min_distance_worst_m",
    "comfort_violation_s",
    "obstacle_collision_frequency",
    "collision_within_allowed",
}

#: Three obstacles in a U around the line (omni_pocket_u), drawn at random around their
#: places: the reactive tube stalls in most draws, the guided one arrives.
POCKET_FIELD = """\
name: pocket_field
start: [0.0, 0.0]
initial_set_radius: 0.4
target: [8.0, 0.0]
target_set_radius: 0.4
duration: 25.0
tube: {r_min: 0.1, r_max: 0.3, k1: 0.7, k2: 0.4, k3: 0.4, max_center_speed: 1.0}
controller: {kappa: [8.0]}
plant: {disturbance_amplitude: [0.05, 0.05], disturbance_frequency_hz: 0.3}
obstacles:
  - motion: !ConstantVelocity {start: [4.0, 0.0], velocity: [0.0, 0.0]}
    radius: 0.6
    sigma: 0.1
    epsilon: 0.9
    p_d: 0.99
  - motion: !ConstantVelocity {start: [3.2, 1.0], velocity: [0.0, 0.0]}
    radius: 0.6
    sigma: 0.1
    epsilon: 0.9
    p_d: 0.99
  - motion: !ConstantVelocity {start: [3.2, -1.0], velocity: [0.0, 0.0]}
    radius: 0.6
    sigma: 0.1
    epsilon: 0.9
    p_d: 0.99
random_obstacles:
  count: 1
  seed: 3
  region_min: [10.0, 6.0]
  region_max: [12.0, 8.0]
  radius: 0.2
  sigma_range: [0.05, 0.1]
  epsilon_range: [0.8, 0.9]
  p_d: 0.99
  amplitude_range: [0.0, 0.1]
  frequency_range_hz: [0.02, 0.05]
guide: {rate_hz: 10}
"""


@pytest.mark.parametrize("name", ["liveness_clutter_2d", "liveness_clutter_3d"])
def test_liveness_scenarios_load_with_a_guide_and_a_random_field(name):
    scenario = load_scenario(DIAGRAMS / f"{name}.yaml", seed=5)
    assert scenario.guide is not None
    assert 3 <= len(scenario.obstacles) <= 10


@pytest.mark.slow
def test_run_without_the_guide_is_the_reactive_tube(tmp_path, capsys):
    """`--no-guide` drops the guide: the pocket with a guide section stalls without it."""
    guided = tmp_path / "pocket.yaml"
    guided.write_text(POCKET.read_text() + "guide: {rate_hz: 10}\n")
    assert main(["run", str(guided), "--out", str(tmp_path / "g"), "--no-figures"]) == 0
    metrics = json.loads((tmp_path / "g" / "metrics.json").read_text())
    assert metrics["reached"]
    code = main(["run", str(guided), "--out", str(tmp_path / "u"), "--no-figures", "--no-guide"])
    assert code == 1
    metrics = json.loads((tmp_path / "u" / "metrics.json").read_text())
    assert metrics["stop_reason"].startswith("stall") and metrics["holds"]
    assert "STALLED" in capsys.readouterr().out


@pytest.mark.slow
def test_campaign_without_the_guide_is_another_campaign(tmp_path):
    """--no-guide is part of the campaign's spec: recorded, and a resume must match it."""
    scenario = tmp_path / "field.yaml"
    scenario.write_text(POCKET_FIELD)
    out = tmp_path / "campaign"
    common = ["campaign", str(scenario), "--kind", "randomisation", "--runs", "2"]
    common += ["--workers", "1", "--no-progress", "--no-figures", "--out", str(out)]
    assert main([*common, "--no-guide"]) == 1  # the reactive tube stalls: draws fail
    summary = json.loads((out / "campaign.json").read_text())
    assert summary["guide"] is False
    assert summary["stall_rate"] == 1.0 and summary["reach_rate"] == 0.0
    failing = sorted((out / "failures").glob("*.yaml"))
    assert failing and "--no-guide" in failing[0].read_text().splitlines()[0]
    assert main([*common, "--resume"]) == 2  # the guided campaign is another spec


@pytest.mark.slow
def test_compare_over_draws_puts_the_guided_tube_ahead(tmp_path, capsys):
    """Every controller on the same draws: the guided tube arrives where the reactive one
    stalls, neither breaks the task (unsafe rate 0)."""
    scenario = tmp_path / "field.yaml"
    scenario.write_text(POCKET_FIELD)
    out = tmp_path / "compare"
    code = main(
        ["compare", str(scenario), "--controllers", "stt", "stt-guided", "--draws", "2",
         "--workers", "2", "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    document = json.loads((out / "comparison.json").read_text())
    assert document["mode"] == "draws" and document["draws"] == 2
    rows = {row["controller"]: row for row in document["rows"]}
    assert all(set(row) == DRAW_ROW_KEYS for row in rows.values())
    assert rows["stt"]["stall_rate"] == 1.0 and rows["stt"]["success_rate"] == 0.0
    assert rows["stt-guided"]["success_rate"] == 1.0
    assert rows["stt"]["unsafe_rate"] == 0.0 and rows["stt-guided"]["unsafe_rate"] == 0.0
    records = (out / "draws.jsonl").read_text().splitlines()
    assert len(records) == 4
    assert "stt-guided" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("words", "message"),
    [
        (["--draws", "0"], "--draws: must be ≥ 1"),
        (["--draws", "2", "--controllers", "stt", "bogus"], "--controllers"),
        (["--runs", "5", "--controllers", "stt", "stt-guided", "--draws", "1", "--model-error"],
         "--draws runs on local processes"),
    ],
)  # fmt: skip
def test_compare_over_draws_refuses_bad_input(tmp_path, capsys, words, message):
    scenario = tmp_path / "field.yaml"
    scenario.write_text(POCKET_FIELD)
    if "--controllers" not in words:
        words = [*words, "--controllers", "stt"]
    code = main(["compare", str(scenario), *words, "--out", str(tmp_path / "o")])
    assert code == 2
    assert message in capsys.readouterr().err


def test_compare_over_draws_needs_a_random_field(tmp_path, capsys):
    code = main(
        ["compare", str(POCKET), "--controllers", "stt", "--draws", "2", "--out",
         str(tmp_path / "o")]
    )  # fmt: skip
    assert code == 2
    assert "random_obstacles" in capsys.readouterr().err


@pytest.mark.slow
def test_compare_has_a_guided_row_on_one_scenario(tmp_path):
    """On the pocket: the reactive `stt` row fails to arrive, `stt-guided` arrives; both
    are checked against true obstacles like every row."""
    out = tmp_path / "compare"
    code = main(
        ["compare", str(POCKET), "--controllers", "stt", "stt-guided", "--runs", "200",
         "--workers", "1", "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    rows = {r["controller"]: r for r in json.loads((out / "comparison.json").read_text())["rows"]}
    assert rows["stt"]["success_rate"] == 0.0 and rows["stt"]["t_output_in_target_s"] is None
    assert rows["stt-guided"]["success_rate"] == 1.0
    assert rows["stt-guided"]["worst_collision_frequency"] <= 0.1  # ε = 0.9
