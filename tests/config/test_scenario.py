"""Bad-input and expansion tests of the scenario loader (stt_drake.config).

Every bad file is built from one small valid base scenario (a dict dumped to YAML) by
changing one field, and must be rejected with a ScenarioError whose message names the full
field path of the offending value and a word of the rule it breaks. Expected values (belief
means, sigma schedules, the derived ν, the clearance of random obstacles) are computed here
independently from the formulas in the design, not read back from the code under test.
"""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from stt_drake.assembly import load_scenario, parse_scenario
from stt_drake.config import ScenarioError
from stt_drake.core.belief import obstacle_belief
from stt_drake.core.motion import Oscillation
from stt_drake.core.probability import avoid_probability

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"
EXPECTED_DIAGRAMS = [
    "omni_hardware_case1.yaml",
    "omni_hardware_case2.yaml",
    "omni_hardware_case3.yaml",
    "omni_cluttered_50.yaml",
    "omni_anisotropic.yaml",
    "uav_anisotropic.yaml",
]


# --------------------------------------------------------------------------- helpers


class Tagged:
    """A mapping written with Drake's variant tag, ``!Tag {...}``."""

    def __init__(self, tag: str, fields: dict) -> None:
        self.tag = tag
        self.fields = fields


class _TagDumper(yaml.SafeDumper):
    """yaml.safe_dump that also writes :class:`Tagged` mappings."""


_TagDumper.add_representer(
    Tagged, lambda dumper, item: dumper.represent_mapping("!" + item.tag, item.fields)
)


def dump(data: dict) -> str:
    return yaml.dump(data, Dumper=_TagDumper, sort_keys=False)


BASE = {
    "name": "base",
    "start": [0.5, 0.5],
    "initial_set_radius": 0.5,
    "target": [4.5, 4.5],
    "target_set_radius": 0.5,
    "duration": 10.0,
    "tube": {"r_min": 0.1, "r_max": 0.3, "k1": 0.5, "k2": 0.4, "k3": 0.4},
    "controller": {"kappa": [2.0]},
    "plant": {"disturbance_amplitude": [0.0, 0.0]},  # OmniRobot, the only (untagged) plant
    "obstacles": [
        {
            "motion": Tagged("ConstantVelocity", {"start": [2.5, 2.5], "velocity": [0.0, 0.0]}),
            "radius": 0.2,
            "sigma": 0.1,
            "epsilon": 0.9,
            "p_d": 0.9999,
        }
    ],
}


def _fields(node: object) -> dict | list:
    return node.fields if isinstance(node, Tagged) else node


def scenario_dict(changes: dict | None = None, base: dict = BASE) -> dict:
    """A deep copy of `base` with `changes` ({key path tuple: value}) applied."""
    data = copy.deepcopy(base)
    for path, value in (changes or {}).items():
        node = data
        for key in path[:-1]:
            node = _fields(node)[key]
        _fields(node)[path[-1]] = copy.deepcopy(value)
    return data


def scenario_text(changes: dict | None = None, base: dict = BASE) -> str:
    return dump(scenario_dict(changes, base))


def rule_text(message: str) -> str:
    """The message without its trailing "(got <value>)", so a rule word cannot come from
    the echoed value."""
    return message.rsplit(" (got ", 1)[0]


def assert_names(message: str, path: str, word: str) -> None:
    """`message` names exactly `path` (not a longer path it prefixes) and the rule `word`."""
    assert re.search(re.escape(path) + r"(?![\w.\[])", message), (
        f"expected field path {path!r} in: {message}"
    )
    assert word in rule_text(message), f"expected rule word {word!r} in: {message}"


def assert_rejected(text: str, path: str, word: str) -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text)
    message = str(info.value)
    assert_names(message, path, word)
    return message


def cv(start: list, velocity: list) -> Tagged:
    return Tagged("ConstantVelocity", {"start": start, "velocity": velocity})


def oscillation(**fields: object) -> Tagged:
    return Tagged("Oscillation", fields)


def waypoints(times: list, positions: list) -> Tagged:
    return Tagged("Waypoints", {"times": times, "positions": positions})


MOTION = ("obstacles", 0, "motion")
OBSTACLE0 = "scenario.obstacles[0]"


# --------------------------------------------------------------------------- the base


def test_base_scenario_loads():
    scenario = parse_scenario(scenario_text())
    assert scenario.name == "base"
    assert scenario.start == [0.5, 0.5]
    assert scenario.target == [4.5, 4.5]
    assert len(scenario.obstacles) == 1
    assert scenario.obstacles[0].motion.start == [2.5, 2.5]
    assert scenario.obstacles[0].p_d == 0.9999
    assert scenario.tube.r_min == 0.1
    assert scenario.controller.kappa == [2.0]


def test_scenario_error_is_a_value_error():
    assert issubclass(ScenarioError, ValueError)


def test_load_scenario_reads_a_file_and_names_it_after_the_file(tmp_path):
    data = scenario_dict()
    del data["name"]
    path = tmp_path / "my_experiment.yaml"
    path.write_text(dump(data))
    scenario = load_scenario(path)
    assert scenario.name == "my_experiment"
    assert scenario.start == [0.5, 0.5]
    assert load_scenario(str(path)).name == "my_experiment"


# --------------------------------------------------------------------------- field rules

OBSTACLE_CASES = [
    # epsilon ∈ (0, 1]
    pytest.param({("obstacles", 0, "epsilon"): 0.0}, f"{OBSTACLE0}.epsilon", "(0, 1]", id="eps-0"),
    pytest.param(
        {("obstacles", 0, "epsilon"): -0.3}, f"{OBSTACLE0}.epsilon", "(0, 1]", id="eps-negative"
    ),
    pytest.param(
        {("obstacles", 0, "epsilon"): 1.2}, f"{OBSTACLE0}.epsilon", "(0, 1]", id="eps-1.2"
    ),
    # p_d ∈ (epsilon, 1]
    pytest.param(
        {("obstacles", 0, "epsilon"): 0.9, ("obstacles", 0, "p_d"): 0.9},
        f"{OBSTACLE0}.p_d",
        "epsilon",
        id="p_d-equal-eps",
    ),
    pytest.param(
        {("obstacles", 0, "epsilon"): 0.9, ("obstacles", 0, "p_d"): 0.5},
        f"{OBSTACLE0}.p_d",
        "epsilon",
        id="p_d-below-eps",
    ),
    pytest.param({("obstacles", 0, "p_d"): 1.01}, f"{OBSTACLE0}.p_d", "1]", id="p_d-above-1"),
    # sigma > 0
    pytest.param({("obstacles", 0, "sigma"): 0.0}, f"{OBSTACLE0}.sigma", "> 0", id="sigma-0"),
    pytest.param({("obstacles", 0, "sigma"): -0.1}, f"{OBSTACLE0}.sigma", "> 0", id="sigma-neg"),
    # sigma schedule
    pytest.param(
        {("obstacles", 0, "sigma_schedule"): {"times": [0.0, 5.0], "values": [0.1, 0.0]}},
        f"{OBSTACLE0}.sigma_schedule.values",
        "> 0",
        id="schedule-value-0",
    ),
    pytest.param(
        {("obstacles", 0, "sigma_schedule"): {"times": [0.0, 5.0], "values": [-0.1, 0.2]}},
        f"{OBSTACLE0}.sigma_schedule.values",
        "> 0",
        id="schedule-value-negative",
    ),
    pytest.param(
        {("obstacles", 0, "sigma_schedule"): {"times": [0.0, 5.0, 5.0, 5.0], "values": [0.1] * 4}},
        f"{OBSTACLE0}.sigma_schedule.times",
        "repeated once",
        id="schedule-time-thrice",
    ),
    pytest.param(
        {("obstacles", 0, "sigma_schedule"): {"times": [0.0, 5.0, 2.0], "values": [0.1] * 3}},
        f"{OBSTACLE0}.sigma_schedule.times",
        "increase",
        id="schedule-times-decreasing",
    ),
    pytest.param(
        {("obstacles", 0, "sigma_schedule"): {"times": [0.0, 5.0, 8.0], "values": [0.1, 0.2]}},
        f"{OBSTACLE0}.sigma_schedule",
        "values",
        id="schedule-length-mismatch",
    ),
    # radius > 0
    pytest.param({("obstacles", 0, "radius"): 0.0}, f"{OBSTACLE0}.radius", "> 0", id="radius-0"),
    pytest.param(
        {("obstacles", 0, "radius"): -0.2}, f"{OBSTACLE0}.radius", "> 0", id="radius-negative"
    ),
]

TUBE_CASES = [
    pytest.param(
        {("tube", "r_min"): 0.3, ("tube", "r_max"): 0.3},
        "scenario.tube.r_max",
        "r_min",
        id="r_min-equal-r_max",
    ),
    pytest.param(
        {("tube", "r_min"): 0.4, ("tube", "r_max"): 0.3},
        "scenario.tube.r_max",
        "r_min",
        id="r_min-above-r_max",
    ),
    pytest.param({("tube", "r_min"): 0.0}, "scenario.tube.r_min", "> 0", id="r_min-0"),
    pytest.param({("tube", "r_min"): -0.1}, "scenario.tube.r_min", "> 0", id="r_min-negative"),
    pytest.param(
        {("tube", "r_max"): 0.6, ("target_set_radius",): 1.0},
        "scenario.tube.r_max",
        "initial_set_radius",
        id="r_max-above-initial-set",
    ),
    pytest.param(
        {("tube", "r_max"): 0.3, ("target_set_radius",): 0.25},
        "scenario.tube.r_max",
        "target_set_radius",
        id="r_max-above-target-set",
    ),
    pytest.param({("tube", "k1"): 0.0}, "scenario.tube.k1", "> 0", id="k1-0"),
    pytest.param({("tube", "k1"): -0.5}, "scenario.tube.k1", "> 0", id="k1-negative"),
    pytest.param({("tube", "k2"): 0.0}, "scenario.tube.k2", "> 0", id="k2-0"),
    pytest.param({("tube", "k2"): -0.4}, "scenario.tube.k2", "> 0", id="k2-negative"),
    pytest.param({("tube", "k3"): -0.1}, "scenario.tube.k3", "≥ 0", id="k3-negative"),
    pytest.param(
        {("tube", "update_rate_hz"): -10.0},
        "scenario.tube.update_rate_hz",
        "≥ 0",
        id="update-rate-negative",
    ),
]

DIMENSION_CASES = [
    pytest.param({("start",): [0.5, 0.5, 0.0]}, "scenario.start", "entries", id="start-3d"),
    pytest.param({("start",): [0.5]}, "scenario.start", "entries", id="start-1d"),
    pytest.param({("target",): [4.5, 4.5, 0.0]}, "scenario.target", "entries", id="target-3d"),
    pytest.param({("target",): [4.5]}, "scenario.target", "entries", id="target-1d"),
    pytest.param(
        {MOTION: cv([2.5, 2.5, 0.0], [0.0, 0.0])},
        f"{OBSTACLE0}.motion.start",
        "entries",
        id="cv-start",
    ),
    pytest.param(
        {MOTION: cv([2.5, 2.5], [0.1])}, f"{OBSTACLE0}.motion.velocity", "entries", id="cv-velocity"
    ),
    pytest.param(
        {MOTION: oscillation(center=[2.5], amplitude=[0.1, 0.1])},
        f"{OBSTACLE0}.motion.center",
        "entries",
        id="oscillation-center",
    ),
    pytest.param(
        {MOTION: oscillation(center=[2.5, 2.5], amplitude=[0.1, 0.1, 0.1])},
        f"{OBSTACLE0}.motion.amplitude",
        "entries",
        id="oscillation-amplitude",
    ),
    pytest.param(
        {MOTION: oscillation(center=[2.5, 2.5], amplitude=[0.1, 0.1], phase=[0.5])},
        f"{OBSTACLE0}.motion.phase",
        "entries",
        id="oscillation-phase",
    ),
    pytest.param(
        {MOTION: waypoints([0.0, 1.0, 2.0], [[2.5, 2.5], [2.6, 2.5, 0.0], [2.7, 2.5]])},
        f"{OBSTACLE0}.motion.positions[1]",
        "entries",
        id="waypoint-position",
    ),
    pytest.param(
        {MOTION: waypoints([0.0, 2.0, 1.0], [[2.5, 2.5], [2.6, 2.5], [2.7, 2.5]])},
        f"{OBSTACLE0}.motion.times",
        "increase",
        id="waypoint-times-decreasing",
    ),
    pytest.param(
        {MOTION: waypoints([0.0, 1.0, 1.0, 1.0], [[2.5, 2.5], [2.6, 2.5], [2.7, 2.5], [2.8, 2.5]])},
        f"{OBSTACLE0}.motion.times",
        "repeated once",
        id="waypoint-time-thrice",
    ),
    pytest.param(
        {MOTION: waypoints([0.0, 1.0, 2.0], [[2.5, 2.5], [2.6, 2.5]])},
        f"{OBSTACLE0}.motion.positions",
        "time",
        id="waypoint-count-mismatch",
    ),
    pytest.param(
        {("plant", "disturbance_amplitude"): [0.1]},
        "scenario.plant.disturbance_amplitude",
        "entries",
        id="disturbance-amplitude",
    ),
    pytest.param(
        {("plant", "initial_position"): [0.5, 0.5, 0.0]},
        "scenario.plant.initial_position",
        "entries",
        id="initial-position",
    ),
]

CONTROLLER_CASES = [
    pytest.param(
        {("controller", "kappa"): [2.0, 2.0]}, "scenario.controller.kappa", "stage", id="kappa-2"
    ),
    pytest.param({("controller", "kappa"): []}, "scenario.controller.kappa", "stage", id="kappa-0"),
    pytest.param(
        {("controller", "kappa"): [0.0]}, "scenario.controller.kappa", "> 0", id="kappa-zero"
    ),
    pytest.param(
        {("controller", "kappa"): [-1.0]}, "scenario.controller.kappa", "> 0", id="kappa-neg"
    ),
    pytest.param(
        {("controller", "funnels"): [{"start": [1.0, 1.0], "end": [0.5, 0.5], "rate": [1.0, 1.0]}]},
        "scenario.controller.funnels",
        "funnel",
        id="funnels-for-one-stage",
    ),
]

RANDOM_BASE = {
    "count": 3,
    "seed": 1,
    "region_min": [1.0, 1.0],
    "region_max": [4.0, 4.0],
    "radius": 0.2,
    "sigma_range": [0.05, 0.2],
    "epsilon_range": [0.7, 0.95],
    "p_d": 0.9999,
    "amplitude_range": [0.0, 0.4],
    "frequency_range_hz": [0.01, 0.05],
}
RANDOM = ("random_obstacles",)
RO = "scenario.random_obstacles"


def _random(**changes: object) -> dict:
    return {RANDOM: {**RANDOM_BASE, **changes}}


RANDOM_CASES = [
    pytest.param(
        _random(sigma_range=[0.2, 0.05]), f"{RO}.sigma_range", "[low, high]", id="sigma-low>high"
    ),
    pytest.param(
        _random(sigma_range=[0.0, 0.2]), f"{RO}.sigma_range", "lie in", id="sigma-low-zero"
    ),
    pytest.param(
        _random(epsilon_range=[0.95, 0.7]),
        f"{RO}.epsilon_range",
        "[low, high]",
        id="eps-low>high",
    ),
    pytest.param(
        _random(epsilon_range=[0.7, 1.2]), f"{RO}.epsilon_range", "lie in", id="eps-high>1"
    ),
    pytest.param(
        _random(epsilon_range=[0.95, 0.99], p_d=0.98),
        f"{RO}.p_d",
        "epsilon_range",
        id="p_d-below-eps-high",
    ),
    pytest.param(
        _random(epsilon_range=[0.7, 0.95], p_d=0.95),
        f"{RO}.p_d",
        "epsilon_range",
        id="p_d-equal-eps-high",
    ),
    pytest.param(_random(p_d=1.5), f"{RO}.p_d", "1]", id="p_d-above-1"),
    pytest.param(_random(count=-2), f"{RO}.count", "≥ 0", id="count-negative"),
    pytest.param(_random(region_min=[1.0]), f"{RO}.region_min", "entries", id="region-min-1d"),
    pytest.param(
        _random(region_max=[4.0, 4.0, 4.0]), f"{RO}.region_max", "entries", id="region-max-3d"
    ),
]


@pytest.mark.parametrize(
    ("changes", "path", "word"),
    OBSTACLE_CASES + TUBE_CASES + DIMENSION_CASES + CONTROLLER_CASES + RANDOM_CASES,
)
def test_bad_field_is_rejected_with_its_path_and_rule(changes, path, word):
    # The unchanged base must load, so the rejection comes from the change alone.
    parse_scenario(scenario_text())
    assert_rejected(scenario_text(changes), path, word)


def test_epsilon_one_leaves_no_room_for_p_d():
    changes = {("obstacles", 0, "epsilon"): 1.0, ("obstacles", 0, "p_d"): 1.0}
    assert_rejected(scenario_text(changes), f"{OBSTACLE0}.p_d", "epsilon")


def test_boundary_values_that_are_allowed():
    """The closed ends are accepted: k3 = 0, update_rate_hz = 0, and r_max equal to both
    set radii (p_d = 1 is not: :func:`test_p_d_one_can_never_hold_and_is_refused`)."""
    scenario = parse_scenario(
        scenario_text(
            {
                ("obstacles", 0, "p_d"): 0.999999,
                ("tube", "k3"): 0.0,
                ("tube", "update_rate_hz"): 0.0,
                ("tube", "r_max"): 0.5,
                ("initial_set_radius",): 0.5,
                ("target_set_radius",): 0.5,
            }
        )
    )
    assert scenario.obstacles[0].p_d == 0.999999
    assert scenario.tube.k3 == 0.0
    assert scenario.tube.r_max == 0.5


def test_p_d_one_can_never_hold_and_is_refused():
    """p_d = 1 asks P(‖c − O_j‖ ≥ r_o + r_min) = 1 of a Gaussian centre, which has
    unbounded support: Assumption 3 can never hold, so it stays a refusal (strict or
    not), for an obstacle and for a random field."""
    message = assert_rejected(
        scenario_text({("obstacles", 0, "p_d"): 1.0}), f"{OBSTACLE0}.p_d", "Gaussian"
    )
    assert "unbounded support" in message
    assert_rejected(scenario_text(_random(p_d=1.0)), f"{RO}.p_d", "can never hold")


# --------------------------------------------------------------------------- ν (soft-min)


def _far_obstacles(count: int) -> list[dict]:
    """`count` obstacles far away from the start and the target."""
    return [
        {
            "motion": cv([20.0 + 2.0 * i, 20.0], [0.0, 0.0]),
            "radius": 0.2,
            "sigma": 0.1,
            "epsilon": 0.9,
            "p_d": 0.9999,
        }
        for i in range(count)
    ]


def test_nu_too_small_for_the_obstacle_count_is_rejected():
    # ln(51)/0.1 ≈ 39.3 > 20: the log-sum-exp can undershoot the true minimum by more
    # than r_min, so the "soft-min radius" could go negative.
    assert math.log(50 + 1) / 0.1 > 20.0
    text = scenario_text(
        {("obstacles",): _far_obstacles(50), ("tube", "r_min"): 0.1, ("tube", "nu"): 20.0}
    )
    assert_rejected(text, "scenario.tube.nu", "r_min")


def test_nu_exactly_at_the_bound_is_rejected():
    bound = math.log(50 + 1) / 0.1
    text = scenario_text(
        {("obstacles",): _far_obstacles(50), ("tube", "r_min"): 0.1, ("tube", "nu"): bound}
    )
    assert_rejected(text, "scenario.tube.nu", "r_min")


def test_nu_above_the_bound_is_kept():
    nu = 1.01 * math.log(50 + 1) / 0.1
    scenario = parse_scenario(
        scenario_text(
            {("obstacles",): _far_obstacles(50), ("tube", "r_min"): 0.1, ("tube", "nu"): nu}
        )
    )
    assert scenario.nu == nu


@pytest.mark.parametrize("count", [0, 1, 50])
def test_nu_zero_is_derived_from_the_obstacle_count(count):
    scenario = parse_scenario(
        scenario_text(
            {("obstacles",): _far_obstacles(count), ("tube", "r_min"): 0.1, ("tube", "nu"): 0.0}
        )
    )
    assert len(scenario.obstacles) == count
    # Without obstacles ν does not matter (r = r_max): it is derived as for one obstacle.
    expected = 2.0 * math.log(max(count, 1) + 1) / 0.1
    assert scenario.nu == pytest.approx(expected, rel=1e-12)


# --------------------------------------------------------------------------- unknown keys


@pytest.mark.parametrize(
    ("changes", "path"),
    [
        pytest.param({("colour",): "red"}, "scenario.colour", id="top-level"),
        pytest.param({("tube", "r_mn"): 0.1}, "scenario.tube.r_mn", id="nested"),
        pytest.param({("obstacles", 0, "colour"): "red"}, f"{OBSTACLE0}.colour", id="list-item"),
        pytest.param(
            {MOTION: oscillation(center=[2.5, 2.5], amplitude=[0.1, 0.1], centre=[2.5, 2.5])},
            f"{OBSTACLE0}.motion.centre",
            id="tagged-motion",
        ),
        pytest.param(
            {("obstacles", 0, "sigma_schedule"): {"times": [0.0], "value": [0.1]}},
            f"{OBSTACLE0}.sigma_schedule.value",
            id="optional-schedule",
        ),
        pytest.param(
            {("plant", "wheel_radus"): 0.05},
            "scenario.plant.wheel_radus",
            id="plant",
        ),
        pytest.param(
            {("controller", "funnels"): [{"strat": [1.0, 1.0]}]},
            "scenario.controller.funnels[0].strat",
            id="funnel-item",
        ),
        pytest.param(_random(cont=3), f"{RO}.cont", id="random-obstacles"),
        pytest.param(
            {("simulator",): {"integration_schem": "runge_kutta3"}},
            "scenario.simulator.integration_schem",
            id="simulator-config",
        ),
    ],
)
def test_unknown_key_is_rejected_with_its_full_path(changes, path):
    assert_rejected(scenario_text(changes), path, "unknown")


def test_unknown_key_inside_a_tagged_motion_written_as_text():
    text = dump({k: v for k, v in scenario_dict().items() if k != "obstacles"}) + (
        "obstacles:\n"
        "  - motion: !Oscillation {centre: [3, 3], amplitude: [0.1, 0.1]}\n"
        "    sigma: 0.1\n"
    )
    assert_rejected(text, f"{OBSTACLE0}.motion.centre", "unknown")


def test_unknown_motion_tag_is_rejected():
    text = dump({k: v for k, v in scenario_dict().items() if k != "obstacles"}) + (
        "obstacles:\n  - motion: !Teleport {start: [3, 3], velocity: [0, 0]}\n"
    )
    message = assert_rejected(text, f"{OBSTACLE0}.motion", "unknown")
    assert "Teleport" in message


def test_unknown_plant_tag_is_rejected():
    text = dump({k: v for k, v in scenario_dict().items() if k != "plant"}) + (
        "plant: !Submarine {depth: 3}\n"
    )
    message = assert_rejected(text, "scenario.plant", "unknown")
    assert "Submarine" in message


def test_unknown_plant_tag_without_fields_is_rejected():
    text = dump({k: v for k, v in scenario_dict().items() if k != "plant"}) + (
        "plant: !Submarine {}\n"
    )
    message = assert_rejected(text, "scenario.plant", "unknown")
    assert "Submarine" in message


def test_plant_written_with_its_own_tag_loads_or_names_the_plant_field():
    """OmniRobot is the only plant type: its tag is either accepted, or refused with a
    message that names scenario.plant and the tag (never Drake's path-less message)."""
    text = dump({k: v for k, v in scenario_dict().items() if k != "plant"}) + (
        "plant: !OmniRobot {wheel_radius: 0.061}\n"
    )
    try:
        scenario = parse_scenario(text)
    except ScenarioError as error:
        assert_names(str(error), "scenario.plant", "tag")
    else:
        assert scenario.plant.wheel_radius == 0.061


def test_start_of_the_wrong_dimension_is_named_before_random_obstacles_are_drawn():
    changes = {("start",): [0.5, 0.5, 0.0], **_random(count=2)}
    assert_rejected(scenario_text(changes), "scenario.start", "entries")


def test_tagged_motion_written_as_text_loads():
    text = dump({k: v for k, v in scenario_dict().items() if k != "obstacles"}) + (
        "obstacles:\n  - motion: !ConstantVelocity {start: [3, 3], velocity: [0, 0]}\n"
        "    sigma: 0.1\n    epsilon: 0.9\n    p_d: 0.9999\n"
    )
    scenario = parse_scenario(text)
    assert scenario.obstacles[0].motion.start == [3.0, 3.0]
    assert scenario.obstacles[0].motion.velocity == [0.0, 0.0]


# --------------------------------------------------------------------------- initial condition


def test_start_inside_an_obstacle_fails_the_initial_avoidance_condition():
    obstacles = [
        *_far_obstacles(1),
        {
            "motion": cv([0.5, 0.5], [0.0, 0.0]),
            "radius": 0.2,
            "sigma": 0.1,
            "epsilon": 0.9,
            "p_d": 0.9999,
        },
    ]
    message = assert_rejected(
        scenario_text({("obstacles",): obstacles}), "scenario.start", "initial"
    )
    assert re.search(r"obstacle(s\[| )1\b", message), message


def test_start_on_the_buffered_boundary_fails_the_initial_avoidance_condition():
    # Mean exactly r_o + r_min away from the start: q_0(s, 0) is then near 1/2, below ε.
    radius, r_min, sigma, epsilon = 0.2, 0.1, 0.05, 0.9
    mean = [0.5 + radius + r_min, 0.5]
    q = avoid_probability(np.array([0.5, 0.5]), np.array([mean]), np.array([sigma]), radius + r_min)
    assert q[0] <= epsilon
    changes = {
        ("obstacles",): [
            {
                "motion": cv(mean, [0.0, 0.0]),
                "radius": radius,
                "sigma": sigma,
                "epsilon": epsilon,
                "p_d": 0.9999,
            }
        ],
        ("tube", "r_min"): r_min,
    }
    message = assert_rejected(scenario_text(changes), "scenario.start", "initial")
    assert re.search(r"obstacle(s\[| )0\b", message), message


def test_initial_position_farther_than_r_min_from_start_is_rejected():
    changes = {("plant", "initial_position"): [0.5, 0.5 + 0.15], ("tube", "r_min"): 0.1}
    assert_rejected(scenario_text(changes), "scenario.plant.initial_position", "r_min")


def test_initial_position_within_r_min_of_start_is_accepted():
    changes = {("plant", "initial_position"): [0.5, 0.5 + 0.05], ("tube", "r_min"): 0.1}
    scenario = parse_scenario(scenario_text(changes))
    assert scenario.plant.initial_position == [0.5, 0.55]


# --------------------------------------------------------------------------- random obstacles


def test_impossible_random_obstacle_count_is_rejected():
    # The whole region lies within 0.1 m of the start: no draw can clear it.
    changes = {
        ("obstacles",): [],
        **_random(count=1, region_min=[0.45, 0.45], region_max=[0.55, 0.55]),
    }
    assert_rejected(scenario_text(changes), f"{RO}.count", "clear")


def _random_scenario(seed: int, count: int = 4, **spec: object):
    changes = {("obstacles",): [], **_random(seed=seed, count=count, **spec)}
    return parse_scenario(scenario_text(changes))


def test_random_obstacles_are_deterministic_for_a_seed():
    first, again, other = _random_scenario(3), _random_scenario(3), _random_scenario(4)
    assert first.obstacles == again.obstacles
    assert first.obstacles != other.obstacles
    centers = [tuple(o.motion.center) for o in first.obstacles]
    assert len(set(centers)) == len(centers)


def test_random_obstacles_are_added_to_the_listed_ones():
    changes = _random(seed=5, count=2)
    scenario = parse_scenario(scenario_text(changes))
    assert len(scenario.obstacles) == 1 + 2
    assert scenario.obstacles[0].motion.start == [2.5, 2.5]
    assert scenario.nu == pytest.approx(2.0 * math.log(3 + 1) / BASE["tube"]["r_min"], rel=1e-12)


# Regions that crowd the start (0.5, 0.5), the target (4.5, 4.5), or neither: in the first
# two many draws must be refused, so a missing check against either anchor shows up.
REGIONS = {
    "middle": ([1.0, 1.0], [4.0, 4.0]),
    "near-start": ([0.0, 0.0], [2.0, 2.0]),
    "near-target": ([3.0, 3.0], [5.0, 5.0]),
}


@pytest.mark.parametrize("region", sorted(REGIONS))
@pytest.mark.parametrize("seed", [0, 11])
def test_random_obstacles_respect_their_ranges_and_promised_clearance(seed, region):
    count = 4
    region_min, region_max = REGIONS[region]
    scenario = _random_scenario(seed, count, region_min=region_min, region_max=region_max)
    spec = {**RANDOM_BASE, "region_min": region_min, "region_max": region_max}
    assert len(scenario.obstacles) == count
    assert scenario.nu == pytest.approx(2.0 * math.log(count + 1) / scenario.tube.r_min)
    start, target = np.array(scenario.start), np.array(scenario.target)
    duration = scenario.duration
    times = [0.0, 0.13 * duration, 0.5 * duration, 0.77 * duration, duration]
    for obstacle in scenario.obstacles:
        assert spec["sigma_range"][0] <= obstacle.sigma <= spec["sigma_range"][1]
        assert spec["epsilon_range"][0] <= obstacle.epsilon <= spec["epsilon_range"][1]
        assert obstacle.radius == spec["radius"]
        assert obstacle.p_d == spec["p_d"]
        motion = obstacle.motion
        assert isinstance(motion, Oscillation)
        for axis in range(2):
            assert spec["region_min"][axis] <= motion.center[axis] <= spec["region_max"][axis]
            low, high = spec["amplitude_range"]
            assert low <= motion.amplitude[axis] <= high
        low, high = spec["frequency_range_hz"]
        assert low <= motion.frequency_hz <= high
        for t in times:
            # μ(t) = center + amplitude·sin(2π f t + phase), written out independently.
            mean = np.array(
                [
                    motion.center[axis]
                    + motion.amplitude[axis]
                    * math.sin(2.0 * math.pi * motion.frequency_hz * t + motion.phase[axis])
                    for axis in range(2)
                ]
            )
            for anchor in (start, target):
                q = avoid_probability(
                    anchor,
                    mean[None, :],
                    np.array([obstacle.sigma]),
                    obstacle.radius + scenario.tube.r_min,
                )
                assert q[0] >= spec["p_d"], (seed, t, anchor, q)


# --------------------------------------------------------------------------- beliefs

BELIEF_TEXT = """\
start: [0.5, 0.5]
target: [4.5, 4.5]
obstacles:
  - motion: !ConstantVelocity {start: [3.0, 1.0], velocity: [0.1, -0.2]}
    radius: 0.15
    sigma: 0.05
    epsilon: 0.9
    p_d: 0.999
  - motion: !Oscillation {center: [2.0, 4.0], amplitude: [0.5, 0.25], frequency_hz: 0.1,
                          phase: [0.3, 1.2]}
    radius: 0.25
    sigma_schedule: {times: [1.0, 3.0, 7.0], values: [0.1, 0.3, 0.2]}
    epsilon: 0.8
    p_d: 0.99
  - motion: !Waypoints {times: [2.0, 4.0, 8.0], positions: [[3.0, 3.0], [4.0, 2.0], [1.0, 4.0]]}
    radius: 0.1
    sigma: 0.07
    epsilon: 0.95
    p_d: 0.9999
  - motion: !Oscillation {center: [4.0, 1.0], amplitude: [0.2, 0.0], frequency_hz: 0.25}
    radius: 0.2
    sigma: 0.12
    epsilon: 0.7
    p_d: 0.9
"""

# Waypoint means and scheduled sigmas, worked out by hand from the text above:
# waypoints held at [3, 3] before t = 2 and at [1, 4] after t = 8; the schedule held at 0.1
# before t = 1 and at 0.2 after t = 7.
HAND_WAYPOINTS = {
    0.0: [3.0, 3.0],
    1.0: [3.0, 3.0],
    2.0: [3.0, 3.0],
    3.0: [3.5, 2.5],
    4.0: [4.0, 2.0],
    5.0: [3.25, 2.5],
    8.0: [1.0, 4.0],
    12.0: [1.0, 4.0],
}
HAND_SCHEDULE = {
    0.0: 0.1,
    1.0: 0.1,
    2.0: 0.2,
    3.0: 0.3,
    4.0: 0.275,
    5.0: 0.25,
    8.0: 0.2,
    12.0: 0.2,
}


@pytest.mark.parametrize("t", sorted(HAND_WAYPOINTS))
def test_belief_means_and_sigmas_follow_the_motion_models(t):
    scenario = parse_scenario(BELIEF_TEXT)
    belief = scenario.belief_at(t)
    direct = obstacle_belief(scenario.obstacles, 2, t)
    expected_mean = np.array(
        [
            [3.0 + 0.1 * t, 1.0 - 0.2 * t],
            [
                2.0 + 0.5 * math.sin(2.0 * math.pi * 0.1 * t + 0.3),
                4.0 + 0.25 * math.sin(2.0 * math.pi * 0.1 * t + 1.2),
            ],
            HAND_WAYPOINTS[t],
            [4.0 + 0.2 * math.sin(2.0 * math.pi * 0.25 * t), 1.0],
        ]
    )
    for b in (belief, direct):
        assert b.mean.shape == (4, 2)
        np.testing.assert_allclose(b.mean, expected_mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            b.sigma, [0.05, HAND_SCHEDULE[t], 0.07, 0.12], rtol=0, atol=1e-12
        )
        np.testing.assert_array_equal(b.radius, [0.15, 0.25, 0.1, 0.2])
        np.testing.assert_array_equal(b.epsilon, [0.9, 0.8, 0.95, 0.7])
        np.testing.assert_array_equal(b.p_d, [0.999, 0.99, 0.9999, 0.9])


def test_belief_with_no_obstacles_is_empty():
    scenario = parse_scenario(scenario_text({("obstacles",): []}))
    belief = scenario.belief_at(1.0)
    assert belief.mean.shape == (0, 2)
    assert belief.sigma.shape == (0,)


# --------------------------------------------------------------------------- malformed files


@pytest.mark.parametrize(
    ("text", "path", "word"),
    [
        pytest.param("start: [0.5, 0.5\ntarget: [1, 1]\n", "scenario", "YAML", id="not-yaml"),
        pytest.param("- start\n- target\n", "scenario", "mapping", id="list"),
        pytest.param("just some words\n", "scenario", "mapping", id="scalar"),
        pytest.param("", "scenario", "mapping", id="empty"),
    ],
)
def test_malformed_text_is_rejected(text, path, word):
    assert_rejected(text, path, word)


@pytest.mark.parametrize(
    ("changes", "path", "word"),
    [
        pytest.param({("duration",): "abc"}, "scenario.duration", "number", id="duration-abc"),
        pytest.param({("tube", "r_min"): "small"}, "scenario.tube.r_min", "number", id="r_min"),
        pytest.param(
            {("obstacles", 0, "sigma"): "wide"}, f"{OBSTACLE0}.sigma", "number", id="sigma"
        ),
        pytest.param(
            {("controller", "kappa"): ["a"]}, "scenario.controller.kappa[0]", "number", id="kappa"
        ),
        pytest.param({("start",): "home"}, "scenario.start", "list", id="start-not-list"),
        pytest.param({("obstacles",): 3}, "scenario.obstacles", "list", id="obstacles-not-list"),
        pytest.param({("tube",): 3}, "scenario.tube", "mapping", id="tube-not-mapping"),
        pytest.param({("tube",): [1, 2]}, "scenario.tube", "mapping", id="tube-list"),
        pytest.param({("seed",): 1.5}, "scenario.seed", "integer", id="seed-float"),
        pytest.param({("strict",): "maybe"}, "scenario.strict", "true or false", id="strict"),
    ],
)
def test_wrong_type_is_rejected_with_its_path(changes, path, word):
    assert_rejected(scenario_text(changes), path, word)


def test_missing_file_is_rejected(tmp_path):
    missing = tmp_path / "no_such_scenario.yaml"
    with pytest.raises(ScenarioError) as info:
        load_scenario(missing)
    assert str(missing) in str(info.value)
    assert "no such" in str(info.value)


# --------------------------------------------------------------------------- shipped files


def test_expected_diagrams_exist():
    missing = [name for name in EXPECTED_DIAGRAMS if not (DIAGRAMS / name).is_file()]
    assert not missing, f"missing scenario files in {DIAGRAMS}: {missing}"


# The glob runs at collection; the expected names are always included, so the list is
# never empty (no skipped test) and a missing expected file fails here too.
_SHIPPED = sorted({p.name for p in DIAGRAMS.glob("*.yaml")} | set(EXPECTED_DIAGRAMS))


@pytest.mark.parametrize("name", _SHIPPED)
def test_shipped_diagram_loads(name):
    scenario = load_scenario(DIAGRAMS / name)
    assert scenario.name
    assert scenario.dimension == len(scenario.start) == len(scenario.target)
    assert scenario.duration > 0.0


def test_infinite_duration_is_rejected():
    assert_rejected(scenario_text({("duration",): float("inf")}), "scenario.duration", "finite")


def test_reversed_random_region_is_rejected():
    text = scenario_text(_random(region_min=[3.0, 3.0], region_max=[1.0, 4.0]))
    assert_rejected(text, "scenario.random_obstacles.region_max", "region_min")


def test_count_range_draws_the_number_of_obstacles_per_seed():
    counts = {
        seed: len(_random_scenario(seed, count=0, count_range=[1, 4]).obstacles)
        for seed in range(12)
    }
    assert all(1 <= c <= 4 for c in counts.values())
    assert len(set(counts.values())) > 1  # the count really varies with the seed
    again = _random_scenario(5, count=0, count_range=[1, 4])
    assert len(again.obstacles) == counts[5]


def test_count_and_count_range_together_are_rejected():
    text = scenario_text(_random(count=2, count_range=[1, 3]))
    assert_rejected(text, "scenario.random_obstacles.count", "not both")


def test_reversed_count_range_is_rejected():
    text = scenario_text(_random(count=0, count_range=[3, 1]))
    assert_rejected(text, "scenario.random_obstacles.count_range", "[low, high]")


# --------------------------------------------------------------------------- issue 12 rules
# (the bad-file corpus is tests/bad_scenarios/, run by tests/test_bad_scenarios.py)


@pytest.mark.parametrize(
    ("changes", "path", "word"),
    [
        pytest.param({("tube", "k1"): math.inf}, "scenario.tube.k1", "finite", id="k1-inf"),
        pytest.param({("tube", "nu"): math.nan}, "scenario.tube.nu", "finite", id="nu-nan"),
        pytest.param({("start",): [1e308, 1e308]}, "scenario.start[0]", "magnitude", id="start"),
        pytest.param(
            {MOTION: cv([2.5, 2.5], [0.0, math.inf])},
            f"{OBSTACLE0}.motion.velocity[1]",
            "finite",
            id="velocity-inf",
        ),
        pytest.param(
            _random(amplitude_range=[0.0, math.inf]),
            f"{RO}.amplitude_range[1]",
            "finite",
            id="amplitude-range-inf",
        ),
        pytest.param(
            {("simulator",): {"integration_scheme": "bogus"}},
            "scenario.simulator.integration_scheme",
            "runge_kutta3",
            id="scheme-lists-the-known-ones",
        ),
        pytest.param({("seed",): -1}, "scenario.seed", "[0, 2^63", id="seed-negative"),
        pytest.param({("name",): "../x"}, "scenario.name", "not a path", id="name-parent"),
        pytest.param(
            {("obstacles", 0, "sigma"): 5e-4}, f"{OBSTACLE0}.sigma", "≥ 0.001", id="sigma-tiny"
        ),
        pytest.param(
            {("log_period",): 20.0}, "scenario.log_period", "≤ duration", id="log-period-long"
        ),
    ],
)
def test_numbers_seeds_names_and_the_simulator_are_checked(changes, path, word):
    assert_rejected(scenario_text(changes), path, word)


def _float_slots(value: object, path: str):
    """(field path, owner, key) of every float in the schema dataclasses under `value`,
    list entries included (key: an attribute name or a list index)."""
    from dataclasses import fields, is_dataclass

    items = []
    if is_dataclass(value):
        items = [(f"{path}.{f.name}", f.name, getattr(value, f.name)) for f in fields(value)]
    elif isinstance(value, list):
        items = [(f"{path}[{i}]", i, item) for i, item in enumerate(value)]
    for where, key, child in items:
        if isinstance(child, float):
            yield where, value, key
        else:
            yield from _float_slots(child, where)


def test_every_float_of_the_schema_is_checked_for_finiteness():
    """The walk covers every float of every dataclass, list entries too (and the simulator
    config): a NaN planted in each one in turn is refused naming that exact field."""
    from stt_drake.config.limits import check_numbers

    scenario = parse_scenario(scenario_text(_random(count=2)))
    paths = [path for path, _, _ in _float_slots(scenario, "scenario")]
    assert {"scenario.tube.k1", f"{OBSTACLE0}.sigma", "scenario.start[1]"} <= set(paths)
    assert f"{RO}.frequency_range_hz[1]" in paths
    for path in paths:
        broken = copy.deepcopy(scenario)
        owner, key = {p: (o, k) for p, o, k in _float_slots(broken, "scenario")}[path]
        if isinstance(key, str):
            setattr(owner, key, math.nan)
        else:
            owner[key] = math.nan
        with pytest.raises(ScenarioError, match=re.escape(path) + ": must be finite"):
            check_numbers(broken, "scenario")
    broken = copy.deepcopy(scenario)
    broken.simulator.accuracy = math.nan
    with pytest.raises(ScenarioError, match=r"scenario\.simulator\.accuracy: must be finite"):
        check_numbers(broken, "scenario")


def test_missing_safety_fields_are_required_not_defaulted():
    obstacles = copy.deepcopy(BASE["obstacles"])
    for name in ("sigma", "epsilon", "p_d"):
        obstacle = {k: v for k, v in obstacles[0].items() if k != name}
        text = scenario_text({("obstacles",): [*obstacles, *obstacles, obstacle]})
        message = assert_rejected(text, f"scenario.obstacles[2].{name}", "required")
        assert message.startswith(f"scenario.obstacles[2].{name}: required (")
    # A sigma_schedule stands in for sigma.
    scheduled = {k: v for k, v in obstacles[0].items() if k != "sigma"}
    scheduled["sigma_schedule"] = {"times": [0.0, 5.0], "values": [0.1, 0.2]}
    assert parse_scenario(scenario_text({("obstacles",): [scheduled]})).obstacles
    # A random field that draws nothing needs no ranges.
    assert parse_scenario(scenario_text({RANDOM: {"count": 0}})).random_obstacles.count == 0
    for name in ("sigma_range", "epsilon_range", "p_d"):
        spec = {k: v for k, v in RANDOM_BASE.items() if k != name}
        assert_rejected(scenario_text({RANDOM: spec}), f"{RO}.{name}", "required")


def test_duplicate_keys_are_refused_but_merges_and_aliases_are_not_duplicates():
    text = scenario_text()
    assert_rejected(text + "duration: 12.0\n", "scenario.duration", "duplicate")
    # An anchored obstacle reused, and a merge whose key is overridden explicitly.
    shared = dump({k: v for k, v in scenario_dict().items() if k != "obstacles"}) + (
        "obstacles:\n"
        "  - &o {motion: !ConstantVelocity {start: [2.5, 2.5], velocity: [0, 0]},\n"
        "        radius: 0.2, sigma: 0.1, epsilon: 0.9, p_d: 0.9999}\n"
        "  - {<<: *o, motion: !ConstantVelocity {start: [3.5, 2.0], velocity: [0, 0]}}\n"
    )
    scenario = parse_scenario(shared)
    assert [o.motion.start for o in scenario.obstacles] == [[2.5, 2.5], [3.5, 2.0]]
    assert scenario.obstacles[1].sigma == 0.1


def test_user_values_are_echoed_short():
    long_name = "x" * 5000
    message = assert_rejected(scenario_text({("name",): long_name + "/"}), "scenario.name", "path")
    assert len(message) < 400


def test_default_name_from_the_file_is_made_a_valid_name(tmp_path):
    data = scenario_dict()
    del data["name"]
    path = tmp_path / "my scenario (v2).yaml"
    path.write_text(dump(data))
    assert load_scenario(path).name == "my_scenario__v2_"


def test_a_negative_seed_override_is_refused(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(scenario_text())
    with pytest.raises(ScenarioError, match=r"^seed: must be an integer in \[0, 2\^63"):
        load_scenario(path, seed=-1)


def test_an_obstacle_that_leaves_the_target_is_accepted():
    """Assumption 3 needs the obstacles to leave the target eventually: one that starts
    on it and moves away is fine; one that never leaves it breaks an assumption of the
    theorem, not a rule of the file: it loads (the run records it, claim (i) void), and a
    strict scenario refuses it."""
    leaving = {
        "motion": waypoints([0.0, 4.0], [[4.5, 4.5], [4.5, 8.0]]),
        "radius": 0.2,
        "sigma": 0.1,
        "epsilon": 0.9,
        "p_d": 0.9999,
    }
    assert len(parse_scenario(scenario_text({("obstacles",): [leaving]})).obstacles) == 1
    staying = {**leaving, "motion": waypoints([0.0, 4.0], [[4.5, 8.0], [4.5, 4.5]])}
    staying["motion"].fields["positions"] = [[4.5, 4.5], [4.6, 4.5]]
    assert len(parse_scenario(scenario_text({("obstacles",): [staying]})).obstacles) == 1
    assert_rejected(
        scenario_text({("obstacles",): [staying], ("strict",): True}),
        "scenario.obstacles[0]",
        "Assumption 3",
    )


def test_scenario_errors_are_one_bounded_line():
    from stt_drake.config.schema import MAX_MESSAGE_LENGTH

    assert str(ScenarioError("scenario: a\n  b\n\nc")) == "scenario: a b c"
    assert len(str(ScenarioError("x" * 10 * MAX_MESSAGE_LENGTH))) == MAX_MESSAGE_LENGTH
