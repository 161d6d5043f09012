"""The limits every scenario is held to before anything is drawn, built or simulated:

* every number of the schema finite and at most :data:`MAX_MAGNITUDE` in magnitude (one
  walk over the dataclasses, the Drake ``SimulatorConfig`` and their lists, naming the
  field path of the first bad value);
* seeds: integers in [0, :data:`MAX_SEED`];
* the simulator: a Drake integration scheme, a step, an accuracy and a real-time pacing a
  run can work with (:func:`check_simulator`);
* a memory budget: the run's logs and obstacles are estimated (:func:`estimate_run_bytes`,
  with Drake's loggers' reserve of :data:`DRAKE_LOG_CAPACITY` samples), and so is what a
  `perception:` chain draws and holds (:mod:`stt_drake.config.perception_budget`); a
  scenario that would need more than the budget is refused, naming the field that drives
  the largest part, the estimate and the budget (:func:`check_memory`). The budget is
  :data:`DEFAULT_MEMORY_BUDGET_GB`; the scenario's `max_memory_gb` or the environment
  variable :data:`MEMORY_BUDGET_ENV` (in that order) replace it;
* a work budget: the wall time the obstacles and the schedules cost over the run's
  integrator steps, and the copies of a sensor's latency ring, must stay below
  :data:`DEFAULT_WORK_BUDGET_S` (or :data:`WORK_BUDGET_ENV`) (:func:`check_work`);
* the schedules' length (:func:`stt_drake.config.schedules.check_schedules`).

:func:`require` is how every rule of the scenario modules is checked (here so that
:mod:`stt_drake.config.validate` and the section modules it calls share it without an
import cycle; it is re-exported there); :func:`rule_path` checks a rule of
:mod:`stt_drake.core.rules`, the one place of the rules the core objects' constructors
check too, naming the file's field path.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from pydrake.systems.analysis import GetIntegrationSchemes, SimulatorConfig

from stt_drake.config.perception_budget import perception_demands, ring_copy_seconds
from stt_drake.config.schedules import check_schedules, schedule_entries
from stt_drake.config.schema import AssumptionError, FrankaArm, Scenario, ScenarioError
from stt_drake.config.source import short_repr
from stt_drake.core.consistency import CONSISTENCY_FIELDS
from stt_drake.core.rules import InitialConditionError, RuleError, join_field

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

#: Logged values per obstacle and sample beyond the n of its mean and the n² of its Σ_j (the
#: belief port carries both, isotropic or not): the active flag (belief), q_j, d̂_j, θ_j
#: (diagnostics), the recovery flag and two avoidance probabilities (measured on the built
#: diagrams' loggers in the tests).
OBSTACLE_VALUES_PER_SAMPLE = 7

#: How many times the logged data is held at once: Drake's loggers grow their storage by
#: doubling (up to 2×), and the run log copies it once.
LOG_COPIES = 3

#: Bytes per obstacle outside the logs: its schema objects, belief rows and law tables (and
#: a tracker's slot, a few hundred bytes).
OBSTACLE_BYTES = 4096

#: Samples Drake's loggers reserve at least (``VectorLog::kDefaultCapacity``): a short run
#: of many obstacles holds this many (measured: 5 000 tracked obstacles over 1 s took
#: 1.2 GB in the loggers for 51 samples).
DRAKE_LOG_CAPACITY = 1000

#: Logged values per obstacle and sample that perception adds beyond its true centre (n):
#: the tracker's update count (1) and its consistency statistics (7,
#: :data:`stt_drake.core.consistency.CONSISTENCY_FIELDS`); the belief's n² covariance
#: entries are logged as well.
PERCEPTION_VALUES_PER_SAMPLE = 1 + CONSISTENCY_FIELDS

#: Wall seconds one obstacle costs per integrator step, measured here: with perception
#: (the tracker's prediction, the monitor's exact full-covariance margins of every track in
#: numpy) 24-29 µs for 500-5 000 tracked obstacles (5 000: 113 steps in 16.2 s); a scripted
#: belief 16 µs (omni_cluttered_50, 0.8 ms per step), far less for pruned obstacles.
PERCEPTION_STEP_SECONDS = 30e-6
SCRIPTED_STEP_SECONDS = 16e-6

#: Wall seconds one schedule entry costs per integrator step: a schedule is evaluated from
#: its lists (O(N) each time; measured: a 9 996-entry 2D covariance schedule added 11 ms to
#: every step of the omni base, 1.1 µs per entry).
SCHEDULE_ENTRY_STEP_SECONDS = 1.1e-6

#: Steps per simulated second the obstacle count is judged at (the default max_step_size,
#: 0.01 s): a run over the work budget at this rate is too long for its obstacles; one
#: within it is over the budget for its step rate (max_step_size, log_period,
#: sensor_period).
NOMINAL_STEP_RATE = 100.0

#: The estimated wall time a run may cost (s): an hour; the environment variable
#: :data:`WORK_BUDGET_ENV` replaces it.
DEFAULT_WORK_BUDGET_S = 3600.0

#: Environment variable that replaces :data:`DEFAULT_WORK_BUDGET_S` (seconds).
WORK_BUDGET_ENV = "STT_DRAKE_WORK_BUDGET_S"

_GB = 1e9


def require(condition: bool, path: str, rule: str, value: Any) -> None:
    """Raise ScenarioError "<path>: <rule> (got <value>)" unless `condition` (the value
    echoed as :func:`stt_drake.config.source.short_repr`)."""
    if not condition:
        raise ScenarioError(f"{path}: {rule} (got {short_repr(value)})")


@contextmanager
def rule_path(path: str, hint: str = "") -> Iterator[None]:
    """Check a rule of :mod:`stt_drake.core.rules` (the one the constructors of the core
    objects check too) in the block: its RuleError becomes a ScenarioError
    "<path>.<field>: <rule> (got <value>)" (`hint` in parentheses after the rule), an
    InitialConditionError an AssumptionError."""
    try:
        yield
    except RuleError as error:
        rule = f"{error.rule} ({hint})" if hint else error.rule
        kind = AssumptionError if isinstance(error, InitialConditionError) else ScenarioError
        raise kind(
            f"{join_field(path, error.field)}: {rule} (got {short_repr(error.value)})"
        ) from None


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
    samples: int, obstacles: int, dimension: int, perception: bool = False
) -> int:
    """Bytes a run needs for its logs and obstacles (an estimate, see the constants):
    LOG_COPIES·8·samples·(obstacles·(n + n² + OBSTACLE_VALUES_PER_SAMPLE) +
    FIXED_VALUES_PER_SAMPLE) + obstacles·OBSTACLE_BYTES; with `perception` n +
    :data:`PERCEPTION_VALUES_PER_SAMPLE` more values per obstacle and sample (`samples`:
    what the loggers hold, at least :data:`DRAKE_LOG_CAPACITY` in a run, see
    :func:`check_memory`)."""
    per_obstacle = obstacle_values_per_sample(dimension, perception)
    values = obstacles * per_obstacle + FIXED_VALUES_PER_SAMPLE
    return LOG_COPIES * 8 * samples * values + obstacles * OBSTACLE_BYTES


def obstacle_values_per_sample(dimension: int, perception: bool = False) -> int:
    """Logged values per obstacle and sample: n + n² (the belief's mean and Σ_j) +
    :data:`OBSTACLE_VALUES_PER_SAMPLE`, and the true centre, update count and consistency
    statistics of a tracked obstacle."""
    extra = dimension + PERCEPTION_VALUES_PER_SAMPLE if perception else 0
    return dimension + dimension * dimension + OBSTACLE_VALUES_PER_SAMPLE + extra


def memory_budget_bytes(scenario: Scenario) -> tuple[float, str]:
    """The run's memory budget (bytes) and where it comes from: the scenario's
    `max_memory_gb` when > 0, else :data:`MEMORY_BUDGET_ENV`, else the default."""
    if scenario.max_memory_gb > 0.0:
        return scenario.max_memory_gb * _GB, "scenario.max_memory_gb"
    value, source = _positive_from_environment(MEMORY_BUDGET_ENV, DEFAULT_MEMORY_BUDGET_GB, "GB")
    return value * _GB, source


def _positive_from_environment(name: str, default: float, unit: str) -> tuple[float, str]:
    """(value, where it comes from): the environment variable `name` when set, a number
    > 0 (else ScenarioError naming it), or `default` ("the default")."""
    text = os.environ.get(name, "").strip()
    if not text:
        return default, "the default"
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise ScenarioError(f"{name}: must be a number of {unit} > 0 (got {short_repr(text)})")
    return value, name


def drawn_count(scenario: Scenario) -> tuple[int, str]:
    """The most obstacles the random field can draw, and the field that sets it."""
    spec = scenario.random_obstacles
    if spec is None:
        return 0, ""
    path = "scenario.random_obstacles"
    if spec.count_range:
        return max(0, *spec.count_range), f"{path}.count_range"
    return max(spec.count, 0), f"{path}.count"


def _obstacle_counts(scenario: Scenario, drawn: bool) -> tuple[int, int, str]:
    """(listed obstacles, the random field's largest count, the field that sets it); with
    `drawn` the field is already among the listed ones."""
    field_count, field_path = (0, "") if drawn else drawn_count(scenario)
    return len(scenario.obstacles), field_count, field_path


def _obstacle_field(listed: int, field_count: int, field_path: str) -> tuple[str, Any]:
    """The field that sets the obstacle count, and its value to echo."""
    if field_count >= listed and field_path:
        return field_path, field_count
    return "scenario.obstacles", f"{listed} obstacles"


def check_memory(scenario: Scenario, drawn: bool = False) -> None:
    """Refuse a scenario whose estimated memory exceeds the budget
    (:func:`memory_budget_bytes`): the logs (:func:`estimate_run_bytes`, for the logged
    samples but at least :data:`DRAKE_LOG_CAPACITY`) of the listed obstacles plus the
    random field at its largest count, or (`drawn`: the field is already among
    `obstacles`) the obstacles as they are, and the perception chain's draws and ring
    (:func:`stt_drake.config.perception_budget.perception_demands`). Names the field that
    drives the largest part. Needs a finite duration and log_period > 0 (checked first)."""
    budget, source = memory_budget_bytes(scenario)
    listed, field_count, field_path = _obstacle_counts(scenario, drawn)
    obstacles = listed + field_count
    samples = logged_samples(scenario)
    held = max(samples, DRAKE_LOG_CAPACITY)
    perception = scenario.perception
    n = scenario.dimension
    logs = estimate_run_bytes(held, obstacles, n, perception is not None)
    demands = []
    if perception is not None:
        demands = perception_demands(perception, obstacles, n, scenario.duration)
    needed = logs + sum(demand.bytes for demand in demands)
    if needed <= budget:
        return
    per_obstacle = obstacle_values_per_sample(n, perception is not None)
    largest = max(demands, key=lambda demand: demand.bytes, default=None)
    if largest is not None and largest.bytes > logs:
        path, value = largest.path, getattr(perception, largest.path.rsplit(".", 1)[1])
    elif obstacles * per_obstacle <= FIXED_VALUES_PER_SAMPLE:
        path, value = "scenario.log_period", scenario.log_period
    else:
        path, value = _obstacle_field(listed, field_count, field_path)
    parts = [
        f"logs {logs / _GB:.3g} GB: {samples} logged samples (Drake's loggers hold "
        f"{DRAKE_LOG_CAPACITY} at least) of {obstacles} obstacles in {n}D: duration/log_period "
        f"+ 1 samples × (n + n² + {OBSTACLE_VALUES_PER_SAMPLE}"
        f"{f' + n + {PERCEPTION_VALUES_PER_SAMPLE}' if perception is not None else ''} values "
        "per obstacle + "
        f"{FIXED_VALUES_PER_SAMPLE}) × 8 B × {LOG_COPIES} copies"
    ]
    parts += [f"{demand.what} = {demand.bytes / _GB:.3g} GB" for demand in demands]
    raise ScenarioError(
        f"{path}: the run would need about {needed / _GB:.3g} GB ({'; '.join(parts)}), above "
        f"the memory budget of {budget / _GB:.3g} GB ({source}); {_advice(path)}, or raise "
        f"the budget with max_memory_gb in the scenario or {MEMORY_BUDGET_ENV} "
        f"(got {short_repr(value)})"
    )


def _advice(path: str) -> str:
    """What to change, for the field a budget names."""
    if path.startswith("scenario.perception."):
        return (
            "raise truth_period or sensor_period, lower latency, shorten duration or use "
            "fewer obstacles"
        )
    return "raise log_period, shorten duration or use fewer obstacles"


def work_budget_seconds() -> tuple[float, str]:
    """The work budget (s) and where it comes from: :data:`WORK_BUDGET_ENV`, else the
    default."""
    return _positive_from_environment(WORK_BUDGET_ENV, DEFAULT_WORK_BUDGET_S, "seconds")


def step_rate(scenario: Scenario) -> tuple[float, str]:
    """Integrator steps per simulated second a run takes at least, and the field that sets
    it: Drake never steps longer than max_step_size and ends a step at every periodic event
    (a logged sample, a sensor sample)."""
    rates = [
        (1.0 / scenario.simulator.max_step_size, "scenario.simulator.max_step_size"),
        (1.0 / scenario.log_period, "scenario.log_period"),
    ]
    perception = scenario.perception
    if perception is not None and perception.sensor_period > 0.0:
        rates.append((1.0 / perception.sensor_period, "scenario.perception.sensor_period"))
    return max(rates)


def check_work(scenario: Scenario, drawn: bool = False) -> None:
    """Refuse a scenario whose estimated wall time exceeds the work budget
    (:func:`work_budget_seconds`): obstacles × integrator steps (duration × :func:`step_rate`)
    × the cost of one obstacle per step (:data:`PERCEPTION_STEP_SECONDS` or
    :data:`SCRIPTED_STEP_SECONDS`), plus the copies of a sensor's latency ring
    (:func:`stt_drake.config.perception_budget.ring_copy_seconds`) and the evaluations of
    the schedules (entries × steps × :data:`SCHEDULE_ENTRY_STEP_SECONDS`). Names the obstacle
    count (or the duration, for one obstacle) when the run is over the budget at
    :data:`NOMINAL_STEP_RATE`, else the field that sets the step rate; the latency when the
    ring's copies are the largest part, the longest schedule when the schedules are."""
    budget, source = work_budget_seconds()
    listed, field_count, field_path = _obstacle_counts(scenario, drawn)
    obstacles = listed + field_count
    perception = scenario.perception
    cost = PERCEPTION_STEP_SECONDS if perception is not None else SCRIPTED_STEP_SECONDS
    rate, rate_path = step_rate(scenario)
    steps = scenario.duration * rate
    stepping = obstacles * steps * cost
    copying = 0.0
    if perception is not None:
        copying = ring_copy_seconds(perception, obstacles, scenario.dimension, scenario.duration)
    schedules = schedule_entries(scenario)
    entries = sum(count for _path, count in schedules)
    scheduling = steps * entries * SCHEDULE_ENTRY_STEP_SECONDS
    total = stepping + copying + scheduling
    if total <= budget:
        return
    if scheduling > max(stepping, copying):
        path, value = max(schedules, key=lambda item: item[1])
        value = f"{value} entries"
    elif copying > stepping:
        path, value = "scenario.perception.latency", perception.latency
    elif obstacles * scenario.duration * NOMINAL_STEP_RATE * cost > budget:
        if obstacles > 1:
            path, value = _obstacle_field(listed, field_count, field_path)
        else:
            path, value = "scenario.duration", scenario.duration
    else:
        path = rate_path
        value = scenario.simulator.max_step_size if "simulator" in path else 1.0 / rate
    ring = f" + copying the latency ring {copying:.3g} s" if copying > 0.0 else ""
    if scheduling > 0.0:
        ring += (
            f" + evaluating {entries} schedule entries at every step "
            f"({SCHEDULE_ENTRY_STEP_SECONDS * 1e6:.2g} µs each) {scheduling:.3g} s"
        )
    raise ScenarioError(
        f"{path}: the run would take about {total:.3g} s of wall time ({obstacles} obstacles × "
        f"{steps:.3g} integrator steps (duration × {rate:.4g} steps/s, set by {rate_path}) × "
        f"{cost * 1e6:.3g} µs per obstacle and step = {stepping:.3g} s{ring}), above the work "
        f"budget of {budget:.4g} s ({source}); use fewer obstacles, a shorter duration or "
        f"fewer steps, or raise the budget with {WORK_BUDGET_ENV} (got {short_repr(value)})"
    )


def check_limits(scenario: Scenario, drawn: bool = False) -> None:
    """Every limit of this module, in the order a user would fix them: numbers, seeds,
    the duration and log period, the simulator, the schedules' length, the memory budget
    and the work budget (`drawn`: the random field is already among the obstacles)."""
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
    check_schedules(scenario)
    check_memory(scenario, drawn)
    check_work(scenario, drawn)
