"""Scenario files: the schema (dataclasses), reading YAML into it, the rules checked
without building anything, and random obstacle fields. The complete loader, which adds the
checks that need the built laws, is :func:`stt_drake.assembly.load_scenario`."""

from stt_drake.config.load import (
    ScenarioText,
    complete_scenario,
    parse_schema,
    read_scenario,
    read_scenario_text,
)
from stt_drake.config.random_field import (
    draws_obstacles,
    expand_random_obstacles,
    has_random_field,
)
from stt_drake.config.schema import (
    PLANT_DIMENSION,
    PLANT_FUNNEL_DIMENSION,
    PLANT_STAGES,
    ArmJerk,
    AssumptionError,
    ControllerConfig,
    FrankaArm,
    FunnelConfig,
    GuideConfig,
    Obstacle,
    OmniRobot,
    Perception,
    Quadrotor,
    RandomObstacles,
    Scenario,
    ScenarioError,
    TubeConfig,
)
from stt_drake.config.source import read_scenario_file
from stt_drake.config.validate import validate

__all__ = [
    "PLANT_DIMENSION",
    "PLANT_FUNNEL_DIMENSION",
    "PLANT_STAGES",
    "ArmJerk",
    "AssumptionError",
    "ControllerConfig",
    "FrankaArm",
    "FunnelConfig",
    "GuideConfig",
    "Obstacle",
    "OmniRobot",
    "Perception",
    "Quadrotor",
    "RandomObstacles",
    "Scenario",
    "ScenarioError",
    "ScenarioText",
    "TubeConfig",
    "complete_scenario",
    "draws_obstacles",
    "expand_random_obstacles",
    "has_random_field",
    "parse_schema",
    "read_scenario",
    "read_scenario_file",
    "read_scenario_text",
    "validate",
]
