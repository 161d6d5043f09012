"""The limits every scenario is held to before anything is drawn, built or simulated:

* every number of the schema finite and at most :data:`MAX_MAGNITUDE` in magnitude (one
  walk over the dataclasses, the Drake ``SimulatorConfig`` and their lists, naming the
  field path of the first bad value);
* seeds: integers in [0, :data:`MAX_SEED`];
* the simulator: a Drake integration scheme, a step, an accuracy and a real-time pacing a
  run can work with (:func:`check_simulator`);
* a memory budget: the run's logs and obstacles are estimated (:func:`estimate_run_bytes`)
  and a scenario that would need more than the budget is refused, naming the field that
  drives the estimate, the estimate and the budget (:func:`check_memory`). The budget is
  :data:`DEFAULT_MEMORY_BUDGET_GB`; the scenario's `max_memory_gb` or the environment
  variable :data:`MEMORY_BUDGET_ENV` (in that order) replace it.

:func:`require` is how every rule of the scenario modules is checked (here so that
:mod:`stt_drake.config.validate` and the section modules it calls share it without an
import cycle; it is re-exported there).
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

from pydrake.systems.analysis import GetIntegrationSchemes, SimulatorConfig

from stt_drake.config.schema import FrankaArm, Scenario, ScenarioError
from stt_drake.config.source import short_repr
from stt_drake.core.belief import has_full_covariance

#: Largest magnitude of any number in a scenario (metres, seconds, gains, ...): a million
#: metres is far beyond any arena; larger values are typos or attacks (1e308 overflows).
MAX_MAGNITUDE = 1e6

#: Largest seed: a non-negative 64-bit integer.
MAX_SEED = 2**63 - 1

#: Slowest real-time pacing (`simulator.target_realtime_rate`) other than 0 (as fast as
#: possible): slower makes a run last over ten times its simulated duration in wall-clock
#: time (0.001 turns a 25 s scenario into 7 hours).
MIN_REALTIME_RATE = 0.1

#: Drake integration schemes that need a MultibodyPlant named "plant" in the diagram.
MULTIBODY_SCHEMES = ("cenic",)

#: The memory budget of one run (GB = 1e9 bytes) unless the scenario or the environment
#: sets another.
DEFAULT_MEMORY_BUDGET_GB = 2.0

#: Environment variable that replaces :data:`DEFAULT_MEMORY_BUDGET_GB` (a number of GB).
MEMORY_BUDGET_ENV = "STT_DRAKE_MEMORY_BUDGET_GB"

#: Logged values per sample that do not grow with the obstacles: the output, tube, control
#: and margins, the plant's own signals (the arm's joint state and torques are the most)
#: and one time stamp per logger.
FIXED_VALUES_PER_SAMPLE = 128

#: Logged values per obstacle and sample beyond the n of its mean: σ, radius, ε, p_d
#: (belief), q_j, d̂_j, θ_j (diagnostics), the recovery flag and two avoidance probabilities
#: (and the n² entries of Σ_j in a run with full covariances).
OBSTACLE_VALUES_PER_SAMPLE = 10

#: How many times the logged data is held at once: Drake's loggers grow their storage by
#: doubling (up to 2×), and the run log copies it once.
LOG_COPIES = 3

#: Bytes per obstacle outside the logs: its schema objects, belief rows and law tables.
OBSTACLE_BYTES = 4096

_GB = 1e9


def require(condition: bool, path: str, rule: str, value: Any) -> None:
    """Raise ScenarioError "<path>: <rule> (got <value>)" unless `condition` (the value
    echoed as :func:`stt_drake.config.source.short_repr`)."""
    if not condition:
        raise ScenarioError(f"{path}: {rule} (got {short_repr(value)})")


def check_numbers(value: Any, path: str) -> None:
    """Every float in `value` (a schema dataclass, a Drake-bound config, a list, or a
    number) finite and at most :data:`MAX_MAGNITUDE` in magnitude; ScenarioError naming
    the field path of the first one that is not. Integers (seeds, counts) and booleans
    have rules of their own."""
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ScenarioError(f"{path}: must be finite (got {value!r})")
        if abs(value) > MAX_MAGNITUDE:
            raise ScenarioError(
                f"{path}: must be at most {MAX_MAGNITUDE:g} in magnitude (a sane bound on "
                f"every number of a scenario) (got {value!r})"
            )
    elif isinstance(value, list):
        for i, item in enumerate(value):
            check_numbers(item, f"{path}[{i}]")
    elif dataclasses.is_dataclass(value):
        for field in dataclasses.fields(value):
            check_numbers(getattr(value, field.name), f"{path}.{field.name}")
    elif isinstance(value, SimulatorConfig):
        for field in type(value).__fields__:
            check_numbers(getattr(value, field.name), f"{path}.{field.name}")


def check_seed(value: int, path: str) -> None:
    """A seed is an integer in [0, :data:`MAX_SEED`]."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEED:
        raise ScenarioError(
            f"{path}: must be an integer in [0, 2^63 − 1] (a seed) (got {short_repr(value)})"
        )


def check_simulator(scenario: Scenario) -> None:
    """`simulator`: a scheme Drake knows (cenic for the arm only), max_step_size > 0,
    accuracy in (0, 1), start_time 0, target_realtime_rate 0 or ≥ :data:`MIN_REALTIME_RATE`
    (the numbers are already finite)."""
    config, path = scenario.simulator, "scenario.simulator"
    schemes = GetIntegrationSchemes()
    if config.integration_scheme not in schemes:
        raise ScenarioError(
            f"{path}.integration_scheme: must be one of Drake's integration schemes: "
            f"{', '.join(schemes)} (got {short_repr(config.integration_scheme)})"
        )
    if config.integration_scheme in MULTIBODY_SCHEMES and not isinstance(scenario.plant, FrankaArm):
        raise ScenarioError(
            f"{path}.integration_scheme: {config.integration_scheme} integrates a "
            "MultibodyPlant only (Drake's convex integrator), and only the FR3 arm is one; "
            f"use another scheme for {type(scenario.plant).__name__} "
            f"(got {short_repr(config.integration_scheme)})"
        )
    if not config.max_step_size > 0.0:
        raise ScenarioError(
            f"{path}.max_step_size: must be > 0 (seconds) (got {config.max_step_size!r})"
        )
    if not 0.0 < config.accuracy < 1.0:
        raise ScenarioError(
            f"{path}.accuracy: must lie in (0, 1) (the integrator's relative error target) "
            f"(got {config.accuracy!r})"
        )
    if config.start_time != 0.0:
        raise ScenarioError(
            f"{path}.start_time: must be 0 (a scenario's time starts at 0: the obstacles' "
            f"motions and the initial conditions are given at t = 0) (got {config.start_time!r})"
        )
    rate = config.target_realtime_rate
    if rate != 0.0 and not rate >= MIN_REALTIME_RATE:
        slower = (
            f" (this one would take duration/rate = {scenario.duration / rate:.4g} s)"
            if rate > 0.0
            else ""
        )
        raise ScenarioError(
            f"{path}.target_realtime_rate: must be 0 (as fast as possible) or ≥ "
            f"{MIN_REALTIME_RATE:g}: a slower pacing makes a run last over ten times its "
            f"duration in wall-clock time{slower} (got {rate!r})"
        )


def logged_samples(scenario: Scenario) -> int:
    """How many samples each logger records: one every `log_period` over the duration."""
    return int(scenario.duration / scenario.log_period) + 1


def estimate_run_bytes(
    samples: int, obstacles: int, dimension: int, covariance: bool = False
) -> int:
    """Bytes a run needs for its logs and obstacles (an estimate, see the constants):
    LOG_COPIES·8·samples·(obstacles·(n + OBSTACLE_VALUES_PER_SAMPLE) +
    FIXED_VALUES_PER_SAMPLE) + obstacles·OBSTACLE_BYTES; with `covariance` (some obstacle
    has a full covariance: every Σ_j is logged) n² more values per obstacle and sample."""
    per_obstacle = obstacle_values_per_sample(dimension, covariance)
    values = obstacles * per_obstacle + FIXED_VALUES_PER_SAMPLE
    return LOG_COPIES * 8 * samples * values + obstacles * OBSTACLE_BYTES


def obstacle_values_per_sample(dimension: int, covariance: bool = False) -> int:
    """Logged values per obstacle and sample: n + :data:`OBSTACLE_VALUES_PER_SAMPLE`, and
    the n² entries of Σ_j when the run logs full covariances."""
    extra = dimension * dimension if covariance else 0
    return dimension + OBSTACLE_VALUES_PER_SAMPLE + extra


def memory_budget_bytes(scenario: Scenario) -> tuple[float, str]:
    """The run's memory budget (bytes) and where it comes from: the scenario's
    `max_memory_gb` when > 0, else :data:`MEMORY_BUDGET_ENV`, else the default."""
    if scenario.max_memory_gb > 0.0:
        return scenario.max_memory_gb * _GB, "scenario.max_memory_gb"
    text = os.environ.get(MEMORY_BUDGET_ENV, "").strip()
    if not text:
        return DEFAULT_MEMORY_BUDGET_GB * _GB, "the default"
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise ScenarioError(
            f"{MEMORY_BUDGET_ENV}: must be a number of GB > 0 (got {short_repr(text)})"
        )
    return value * _GB, MEMORY_BUDGET_ENV


def drawn_count(scenario: Scenario) -> tuple[int, str]:
    """The most obstacles the random field can draw, and the field that sets it."""
    spec = scenario.random_obstacles
    if spec is None:
        return 0, ""
    path = "scenario.random_obstacles"
    if spec.count_range:
        return max(0, *spec.count_range), f"{path}.count_range"
    return max(spec.count, 0), f"{path}.count"


def check_memory(scenario: Scenario, drawn: bool = False) -> None:
    """Refuse a scenario whose estimated memory (:func:`estimate_run_bytes`) exceeds the
    budget (:func:`memory_budget_bytes`): the listed obstacles plus the random field at
    its largest count, or (`drawn`: the field is already among `obstacles`) the obstacles
    as they are. Needs a finite duration and log_period > 0 (checked first)."""
    budget, source = memory_budget_bytes(scenario)
    field_count, field_path = (0, "") if drawn else drawn_count(scenario)
    listed = len(scenario.obstacles)
    obstacles = listed + field_count
    samples = logged_samples(scenario)
    covariance = any(has_full_covariance(o) for o in scenario.obstacles)
    needed = estimate_run_bytes(samples, obstacles, scenario.dimension, covariance)
    if needed <= budget:
        return
    per_obstacle = obstacle_values_per_sample(scenario.dimension, covariance)
    if obstacles * per_obstacle <= FIXED_VALUES_PER_SAMPLE:
        path, value = "scenario.log_period", scenario.log_period
    elif field_count >= listed:
        path, value = field_path, field_count
    else:
        path, value = "scenario.obstacles", f"{listed} obstacles"
    raise ScenarioError(
        f"{path}: the run would need about {needed / _GB:.3g} GB ({samples} logged samples "
        f"of {obstacles} obstacles in {scenario.dimension}D: duration/log_period + 1 samples "
        f"× (n + {OBSTACLE_VALUES_PER_SAMPLE}{' + n²' if covariance else ''} values per "
        f"obstacle + {FIXED_VALUES_PER_SAMPLE})"
        f" × 8 B × {LOG_COPIES} copies), above the memory budget of {budget / _GB:.3g} GB "
        f"({source}); raise log_period, shorten duration or use fewer obstacles, or raise "
        f"the budget with max_memory_gb in the scenario or {MEMORY_BUDGET_ENV} "
        f"(got {short_repr(value)})"
    )


def check_limits(scenario: Scenario, drawn: bool = False) -> None:
    """Every limit of this module, in the order a user would fix them: numbers, seeds,
    the duration and log period, the simulator, the memory budget (`drawn`: the random
    field is already among the obstacles)."""
    check_numbers(scenario, "scenario")
    check_seed(scenario.seed, "scenario.seed")
    if scenario.random_obstacles is not None:
        check_seed(scenario.random_obstacles.seed, "scenario.random_obstacles.seed")
    if not scenario.duration > 0.0:
        raise ScenarioError(
            f"scenario.duration: must be finite and > 0 (seconds) (got {scenario.duration!r})"
        )
    if not 0.0 < scenario.log_period <= scenario.duration:
        raise ScenarioError(
            f"scenario.log_period: must be > 0 and ≤ duration = {scenario.duration:g} "
            f"(seconds between logged samples) (got {scenario.log_period!r})"
        )
    if scenario.max_memory_gb < 0.0:
        raise ScenarioError(
            "scenario.max_memory_gb: must be ≥ 0 (GB; 0 = the default budget) "
            f"(got {scenario.max_memory_gb!r})"
        )
    check_simulator(scenario)
    check_memory(scenario, drawn)
