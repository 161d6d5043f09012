"""The scenario's `guide:` section (stt_drake.config.validate_guide): a valid section parses
and validates with the tube, plant and perception it may come with; every broken rule is
refused with a ScenarioError naming ``scenario.guide.<field>`` and the rule. The corpus
tests/bad_scenarios/guide_*.yaml covers one defect per file through `stt-drake run`; this
file covers the other rules, the boundaries that are allowed and the grid-size formula.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from stt_drake.assembly import parse_scenario
from stt_drake.config import GuideConfig, ScenarioError
from stt_drake.config.validate_guide import MAX_GRID_CELLS, guide_grid_cells

ROOT = Path(__file__).resolve().parents[2]
DIAGRAMS = ROOT / "diagrams"
BASES = ROOT / "tests" / "bad_scenarios" / "base"
CASE1 = (DIAGRAMS / "omni_hardware_case1.yaml").read_text()


def with_guide(guide: str, text: str = CASE1) -> str:
    """`text` (a scenario without a guide) with the section ``guide: <guide>`` appended."""
    assert not re.search(r"^guide:", text, re.MULTILINE)
    return text.rstrip("\n") + f"\nguide: {guide}\n"


def refused(guide: str, text: str = CASE1) -> str:
    with pytest.raises(ScenarioError) as error:
        parse_scenario(with_guide(guide, text), "bad")
    message = str(error.value)
    assert "\n" not in message
    return message


def assert_names(message: str, field: str, word: str) -> None:
    """`message` names exactly ``scenario.guide.<field>`` and the rule `word` (outside the
    echoed value)."""
    assert re.search(rf"scenario\.guide\.{field}(?![\w.\[])", message), message
    assert word in message.rsplit(" (got ", 1)[0], message


# --------------------------------------------------------------------------- valid


def test_a_valid_guide_section_parses_and_validates():
    scenario = parse_scenario(with_guide("{rate_hz: 5, horizon: 10}"), "guided")
    assert scenario.guide == GuideConfig(rate_hz=5.0, horizon=10.0)
    assert scenario.guide.clearance is None  # the tube's r_max − r_min, derived later
    assert scenario.guide.planner == "grid"


def test_a_scenario_without_guide_has_none():
    assert parse_scenario(CASE1, "plain").guide is None
    assert parse_scenario(with_guide("null"), "plain").guide is None


def test_every_guide_field_written_out_loads():
    guide = (
        "{planner: grid, rate_hz: 20.0, replan_period: 0.5, horizon: 15.0, time_step: 0.1, "
        "resolution: 0.05, avoid_level: 0.995, clearance: 0.0, speed: 0.4, max_wait: 3.0, "
        "lookahead: 0.8, stall_time: 2.0, stall_progress: 0.05}"
    )
    assert parse_scenario(with_guide(guide), "all").guide == GuideConfig(
        planner="grid",
        rate_hz=20.0,
        replan_period=0.5,
        horizon=15.0,
        time_step=0.1,
        resolution=0.05,
        avoid_level=0.995,
        clearance=0.0,
        speed=0.4,
        max_wait=3.0,
        lookahead=0.8,
        stall_time=2.0,
        stall_progress=0.05,
    )


@pytest.mark.parametrize(
    "guide",
    [
        "{rate_hz: 3.0, replan_period: 0.3333333333333333}",  # exactly one tick
        "{rate_hz: 1000.0, replan_period: 0.001}",  # the fastest rate
        "{horizon: 5.0, time_step: 5.0}",  # one knot step
        "{horizon: 100.0, time_step: 0.01}",  # exactly 10000 knots
        "{horizon: 10000.0, time_step: 1.0, replan_period: 10000.0}",  # the longest times
        "{horizon: 5.0, max_wait: 5.0}",  # a wait as long as the predictions
        "{avoid_level: 0.99}",  # exactly the largest epsilon (obstacle 0)
        "{resolution: 0.005}",  # 2000 × 2000 cells: exactly the bound
        "{clearance: 0.0, speed: 0.0, lookahead: 0.0, stall_progress: 0.0}",
        "{stall_time: 10000.0}",  # longer than the run: never fires, allowed
    ],
)
def test_boundary_values_are_allowed(guide):
    assert parse_scenario(with_guide(guide), "edge").guide is not None


def test_the_guide_is_allowed_with_the_fixed_rate_tube():
    text = (DIAGRAMS / "omni_authors_field_50hz.yaml").read_text()
    scenario = parse_scenario(with_guide("{rate_hz: 5}", text), "fixed")
    assert scenario.tube.update_rate_hz > 0.0 and scenario.guide.rate_hz == 5.0


def test_the_guide_is_allowed_with_perception():
    text = (DIAGRAMS / "omni_tracked.yaml").read_text()
    scenario = parse_scenario(with_guide("{horizon: 8}", text), "tracked")
    assert scenario.perception is not None and scenario.guide.horizon == 8.0


@pytest.mark.parametrize("base, resolution", [("arm", 0.05), ("uav", 0.1)])
def test_the_guide_is_allowed_on_the_arm_and_the_uav(base, resolution):
    text = (BASES / f"{base}.yaml").read_text()
    scenario = parse_scenario(with_guide(f"{{resolution: {resolution}}}", text), base)
    assert scenario.dimension == 3 and scenario.guide.resolution == resolution


def test_a_3d_grid_counts_every_axis():
    # The UAV base: start (1, 1, 1), target (8, 8, 8): 13 m sides, 260³ cells at 5 cm.
    text = (BASES / "uav.yaml").read_text()
    assert_names(refused("{resolution: 0.05}", text), "resolution", "17576000 cells")


# --------------------------------------------------------------------------- refused


def test_nan_in_guide_horizon_is_refused_naming_the_field():
    assert_names(refused("{horizon: .nan}"), "horizon", "finite")


@pytest.mark.parametrize(
    "guide, field, word",
    [
        ("{planner: ''}", "planner", "one of: grid"),
        ("{planner: Grid}", "planner", "one of: grid"),
        ("{rate_hz: -1.0}", "rate_hz", "> 0"),
        ("{rate_hz: .inf}", "rate_hz", "finite"),
        ("{rate_hz: 1000.5, replan_period: 1.0}", "rate_hz", "≤ 1000"),
        ("{replan_period: 0.0}", "replan_period", "> 0"),
        ("{replan_period: 20000.0}", "replan_period", "≤ 10000"),
        ("{replan_period: .nan}", "replan_period", "finite"),
        ("{rate_hz: 4.0, replan_period: 0.2}", "replan_period", "1/rate_hz = 0.25 s"),
        ("{horizon: 0.0}", "horizon", "> 0"),
        ("{horizon: 20000.0}", "horizon", "≤ 10000"),
        ("{time_step: 0.0}", "time_step", "> 0"),
        ("{time_step: -0.1}", "time_step", "> 0"),
        ("{horizon: 100.0, time_step: 0.0099}", "time_step", "at most 10000 prediction knots"),
        ("{resolution: -0.1}", "resolution", "≥ 0"),
        ("{resolution: 0.0049}", "resolution", "at most 4000000 cells"),
        ("{resolution: 1.0e-300}", "resolution", "at most 4000000 cells"),
        ("{avoid_level: 1.0}", "avoid_level", "(0, 1)"),
        ("{avoid_level: -0.5}", "avoid_level", "(0, 1)"),
        ("{avoid_level: 0.98}", "avoid_level", "epsilon = 0.99 of obstacle 0"),
        ("{clearance: .inf}", "clearance", "finite"),
        ("{clearance: -0.01}", "clearance", "≥ 0"),
        ("{speed: -1.0}", "speed", "≥ 0"),
        ("{max_wait: -1.0}", "max_wait", "≥ 0"),
        ("{horizon: 5.0, max_wait: 5.5}", "max_wait", "≤ horizon = 5 s"),
        ("{lookahead: -0.5}", "lookahead", "≥ 0"),
        ("{stall_time: -1.0}", "stall_time", "> 0"),
        ("{stall_time: 20000.0}", "stall_time", "≤ 10000"),
        ("{stall_progress: -0.01}", "stall_progress", "≥ 0"),
        ("{replan_rate: 1.0}", "replan_rate", "unknown field"),
        ("{rate_hz: fast}", "rate_hz", "must be a number"),
    ],
)
def test_bad_guide_field_is_refused_with_its_path_and_rule(guide, field, word):
    assert_names(refused(guide), field, word)


def test_avoid_level_below_an_epsilon_names_the_first_such_obstacle():
    # case 1: epsilon 0.99, 0.9, 0.8, 0.95: at 0.85 obstacles 0, 1 and 3 are stricter.
    message = refused("{avoid_level: 0.85}")
    assert_names(message, "avoid_level", "of obstacle 0")
    assert "obstacle 1" not in message


def test_avoid_level_is_held_to_a_random_fields_highest_epsilon():
    text = (BASES / "omni_random.yaml").read_text()  # epsilon_range [0.7, 0.95]
    message = refused("{avoid_level: 0.9}", text)
    assert_names(message, "avoid_level", "random field's highest epsilon = 0.95")
    assert "scenario.random_obstacles.epsilon_range" in message
    assert parse_scenario(with_guide("{avoid_level: 0.95}", text), "r").guide.avoid_level == 0.95


# --------------------------------------------------------------------------- grid size


def test_grid_cells_cover_start_and_target_grown_by_three_metres():
    # 2D: sides 4 + 6 = 10 m at 0.5 m: 20 × 20.
    assert guide_grid_cells([0.5, 0.5], [4.5, 4.5], 0.5) == 400
    # 3D: sides 7, 8, 9 m at 1 m; a side not a multiple of the resolution rounds up.
    assert guide_grid_cells([0.0, 0.0, 0.0], [1.0, -2.0, 3.0], 1.0) == 7 * 8 * 9
    assert guide_grid_cells([0.0, 0.0], [0.5, 0.0], 2.0) == 4 * 3
    # Values written at the bound are not pushed over it by rounding (10/0.005).
    assert guide_grid_cells([0.5, 0.5], [4.5, 4.5], 0.005) == MAX_GRID_CELLS


def test_grid_cells_of_a_vanishing_resolution_is_a_float_not_a_huge_integer():
    cells = guide_grid_cells([0.0, 0.0], [1.0, 1.0], 5e-324)
    assert math.isinf(cells)
