"""Scenario files: one YAML file defines one experiment (``diagrams/*.yaml``).

Loaded into dataclasses with ``pydrake.common.yaml.yaml_load_typed`` and then validated
here, because the loader checks neither array shapes nor the paper's rules. Every rule
violation raises :class:`ScenarioError` naming the full field path and the rule.
"""

import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import SimulatorConfig

from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.motion import ConstantVelocity, Motion, Oscillation, SigmaSchedule, Waypoints
from stt_drake.core.probability import avoid_probability
from stt_drake.core.tube import default_nu, minimum_nu


class ScenarioError(ValueError):
    """A scenario file breaks a rule; the message names the field path and the rule."""


@dataclass
class Obstacle:
    """One uncertain obstacle (Def. 2.1): a ball of `radius` around a Gaussian centre.

    `sigma` is the standard deviation of the centre per axis in metres (σ, not σ²);
    `sigma_schedule`, when given, replaces it with a piecewise-linear σ(t).
    """

    motion: Motion = field(default_factory=ConstantVelocity)
    radius: float = 0.15
    sigma: float = 0.1
    sigma_schedule: SigmaSchedule | None = None
    epsilon: float = 0.9
    p_d: float = 0.9999


@dataclass
class RandomObstacles:
    """A field of oscillating obstacles drawn from a seeded generator.

    Means are uniform in [region_min, region_max]; sigma, epsilon, oscillation amplitude
    (per axis) and frequency are uniform in their [low, high] ranges. A draw is kept only
    if its whole path stays clear of the start and the target with probability ≥ p_d
    (checked with the buffered radius r_o + r_min; Assumption 3.1 and the initial
    condition of Def. 2.2). `count_range` = [low, high], when given instead of `count`,
    draws the number of obstacles uniformly from those integers (randomisation campaigns).
    """

    count: int = 0
    count_range: list[int] = field(default_factory=list)
    seed: int = 0
    region_min: list[float] = field(default_factory=list)
    region_max: list[float] = field(default_factory=list)
    radius: float = 0.3
    sigma_range: list[float] = field(default_factory=lambda: [0.1, 1.0])
    epsilon_range: list[float] = field(default_factory=lambda: [0.7, 0.99])
    p_d: float = 0.9999
    amplitude_range: list[float] = field(default_factory=lambda: [0.0, 1.0])
    frequency_range_hz: list[float] = field(default_factory=lambda: [0.01, 0.05])


@dataclass
class TubeConfig:
    """Tube law constants (eqs. cen_dynamic, rad_sol). `nu` = 0 means "derive it":
    ν = 2 ln(n_o + 1)/r_min, which keeps r ≥ r_min/2. `update_rate_hz` = 0 integrates the
    centre in continuous time; > 0 runs the fixed-rate (real-time) discrete update.
    `max_center_speed` (m/s) bounds |ċ| always, and is the speed of a recovery (0 derives
    it from what the plant can follow, see :func:`stt_drake.build.feasibility.following_speed`)."""

    r_min: float = 0.1
    r_max: float = 0.3
    k1: float = 0.5
    k2: float = 0.4
    k3: float = 0.4
    nu: float = 0.0
    update_rate_hz: float = 0.0
    max_center_speed: float = 0.0


@dataclass
class FunnelConfig:
    """Box funnel γ(t) = (start − end)e^{−rate t} + end of one stage k ≥ 2 (per axis)."""

    start: list[float] = field(default_factory=list)
    end: list[float] = field(default_factory=list)
    rate: list[float] = field(default_factory=list)


@dataclass
class ControllerConfig:
    """Funnel controller gains κ_1..κ_N and the box funnels of stages 2..N."""

    kappa: list[float] = field(default_factory=lambda: [1.0])
    funnels: list[FunnelConfig] = field(default_factory=list)


@dataclass
class OmniRobot:
    """Three-wheel omnidirectional base. True wheel and base radii differ from the nominal
    ones its drive interface uses; the STT controller knows neither. `disturbance_amplitude`
    (m/s per world axis) and `disturbance_frequency_hz` set an additive sinusoidal
    velocity disturbance. `initial_position` defaults to the scenario's start."""

    wheel_radius: float = 0.052
    base_radius: float = 0.21
    nominal_wheel_radius: float = 0.05
    nominal_base_radius: float = 0.2
    heading_gain: float = 2.0
    initial_heading: float = 0.0
    initial_position: list[float] = field(default_factory=list)
    disturbance_amplitude: list[float] = field(default_factory=lambda: [0.0, 0.0])
    disturbance_frequency_hz: float = 0.2


@dataclass
class Quadrotor:
    """UAV as a second-order point mass in 3D (case study 2): m·v̇ = u − m·g·e_z − c_d·v + w.

    `mass` (kg), `drag` (linear drag c_d, N·s/m) and `gravity` (m/s²) are the true values;
    the STT controller knows none of them. `initial_position` defaults to the start;
    `initial_velocity` (m/s) must lie inside stage 2's first box funnel. The wind is a
    bounded force (N): per axis i, w_i(t) = A_i/K · Σ_k sin(2π f_k t + φ_ik) over the K
    `wind_frequencies_hz`, so |w_i| ≤ A_i = `wind_amplitude[i]`; the phases φ_ik are drawn
    from the scenario seed. `body_radius` (m) only sizes the Meshcat visual.
    """

    mass: float = 1.0
    drag: float = 0.2
    gravity: float = 9.81
    initial_position: list[float] = field(default_factory=list)
    initial_velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    wind_amplitude: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    wind_frequencies_hz: list[float] = field(default_factory=lambda: [0.1])
    body_radius: float = 0.25


@dataclass
class ArmJerk:
    """One impulsive external push on an arm link: a half-sine force pulse of peak `force`
    (N, world frame) at `point` (m, in the link frame) on `link`, from `time` for `duration`
    seconds. `link` is one of fr3_link1..fr3_link7 or fr3_hand."""

    time: float = 0.0
    duration: float = 0.1
    link: str = "fr3_link7"
    force: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    point: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


#: libfranka's start ("ready") configuration of the FR3, rad.
_FR3_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)


@dataclass
class FrankaArm:
    """Franka Research 3 arm with a welded Franka Hand (case study 3); y = the hand's TCP.

    Robot: `initial_configuration` q(0) (rad, at rest); `gravity_compensation`: the robot
    interface adds g(q) of the robot's own model to the commanded torque, as the real FR3
    does (false: the STT controller alone carries the arm's weight); `jerks`: external
    pushes. Task: the tube visits the `waypoints` (m, in order) and then the scenario's
    `target`, one reach-avoid-stay task each; a task is done when Γ(t) ⊂ B(η_k,
    target_set_radius) held for `hold_time` seconds. Controller mapping (kinematics only):
    damped least squares with `jacobian_damping` λ (m), and a null-space term pulling to the
    home posture with `posture_gain` (1/s) and away from joint limits within `limit_margin`
    (rad) at up to `limit_gain` (rad/s).
    """

    initial_configuration: list[float] = field(default_factory=lambda: list(_FR3_READY))
    gravity_compensation: bool = True
    waypoints: list[list[float]] = field(default_factory=list)
    hold_time: float = 0.3
    jacobian_damping: float = 0.02
    posture_gain: float = 1.0
    limit_margin: float = 0.25
    limit_gain: float = 1.0
    jerks: list[ArmJerk] = field(default_factory=list)


# OmniRobot first: an untagged `plant:` mapping is an OmniRobot (Drake's yaml takes the
# first variant); a UAV is written `plant: !Quadrotor {...}`, the arm `plant: !FrankaArm`.
Plant = Union[OmniRobot, Quadrotor, FrankaArm]  # noqa: UP007 (drake yaml needs typing.Union)

#: Output-space dimension each plant works in.
PLANT_DIMENSION = {OmniRobot: 2, Quadrotor: 3, FrankaArm: 3}

#: Number of stages N of eq. (sysdyn) each plant has: the controller needs N gains κ and
#: N − 1 box funnels.
PLANT_STAGES = {OmniRobot: 1, Quadrotor: 2, FrankaArm: 2}

#: Size of the box funnels of stages 2..N where it is not n: the arm's stage 2 is on its
#: 7 joint velocities.
PLANT_FUNNEL_DIMENSION = {FrankaArm: 7}


def _default_simulator_config() -> SimulatorConfig:
    return SimulatorConfig(
        integration_scheme="runge_kutta3",
        max_step_size=0.01,
        accuracy=1e-6,
        use_error_control=True,
    )


@dataclass
class Scenario:
    """One PrT-RAS experiment: task, obstacles, tube, controller, plant, simulation."""

    name: str = ""
    start: list[float] = field(default_factory=list)
    initial_set_radius: float = 0.5
    target: list[float] = field(default_factory=list)
    target_set_radius: float = 0.5
    duration: float = 30.0
    seed: int = 0
    obstacles: list[Obstacle] = field(default_factory=list)
    random_obstacles: RandomObstacles | None = None
    tube: TubeConfig = field(default_factory=TubeConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    plant: Plant = field(default_factory=OmniRobot)
    simulator: SimulatorConfig = field(default_factory=_default_simulator_config)
    log_period: float = 0.02
    strict: bool = False
    max_steps_per_second: float = 0.0

    @property
    def dimension(self) -> int:
        return len(self.start)

    @property
    def nu(self) -> float:
        """The soft-min sharpness in use (the given one, or the derived default)."""
        if self.tube.nu > 0.0:
            return self.tube.nu
        return default_nu(len(self.obstacles), self.tube.r_min)

    def belief_at(self, t: float) -> ObstacleBelief:
        """The belief of every obstacle at time t."""
        return obstacle_belief(self.obstacles, self.dimension, t)


def obstacle_belief(obstacles: list[Obstacle], dimension: int, t: float) -> ObstacleBelief:
    """The belief of every obstacle in `obstacles` at time t."""
    return ObstacleBelief(
        mean=np.array([o.motion.position(t) for o in obstacles]).reshape(len(obstacles), dimension),
        sigma=np.array([obstacle_sigma(o, t) for o in obstacles]),
        radius=np.array([o.radius for o in obstacles]),
        epsilon=np.array([o.epsilon for o in obstacles]),
        p_d=np.array([o.p_d for o in obstacles]),
    )


def obstacle_rate_bounds(obstacles: list[Obstacle]) -> tuple[np.ndarray, np.ndarray]:
    """Per obstacle, sup ‖μ̇_j‖ and sup |σ̇_j| (m/s) from its motion model and σ schedule,
    steps excluded (a step is a belief discontinuity, see :mod:`stt_drake.core.motion`)."""
    mean_speed = np.array([o.motion.speed_bound() for o in obstacles], dtype=float)
    sigma_rate = np.array(
        [0.0 if o.sigma_schedule is None else o.sigma_schedule.rate_bound() for o in obstacles],
        dtype=float,
    )
    return mean_speed, sigma_rate


def obstacle_sigma(obstacle: Obstacle, t: float) -> float:
    """σ_j(t): the schedule where given, else the constant `sigma`."""
    if obstacle.sigma_schedule is not None:
        return obstacle.sigma_schedule.sigma(t)
    return obstacle.sigma


# --------------------------------------------------------------------------- loading


class _TaggedLoader(yaml.SafeLoader):
    """Reads Drake's ``!Tag {...}`` variant syntax as plain mappings for the key check."""


_TaggedLoader.add_multi_constructor(
    "!", lambda loader, suffix, node: {"__tag__": suffix, **loader.construct_mapping(node)}
)


def _check_keys(schema: Any, data: Any, path: str) -> None:
    """Reject unknown keys and unknown ``!Tags`` with their full path (Drake's loader omits
    the nesting path)."""
    if not isinstance(data, dict):
        return
    variants = getattr(schema, "__args__", None)
    if variants is not None:  # Union / Optional: pick the tagged (or the only data) class
        classes = [v for v in variants if v is not type(None)]
        tag = data.get("__tag__")
        named = [c for c in classes if c.__name__ == tag]
        if tag is not None and not named:
            known = ", ".join("!" + c.__name__ for c in classes)
            raise ScenarioError(f"{path}: unknown type !{tag}; expected one of {known}")
        schema = named[0] if named else classes[0]
    elif data.get("__tag__") is not None:  # a tag where the field is not a variant
        tag, name = data["__tag__"], getattr(schema, "__name__", "?")
        if tag != name:
            raise ScenarioError(f"{path}: unknown type !{tag}; expected {name} (untagged)")
        raise ScenarioError(f"{path}: {name} is the only type here: drop the !{tag} tag")
    hints = _field_types(schema)
    if hints is None:
        return
    for key, value in data.items():
        if key == "__tag__":
            continue
        if key not in hints:
            known = ", ".join(hints)
            raise ScenarioError(f"{path}.{key}: unknown field; known fields are: {known}")
        hint = hints[key]
        item_schema = getattr(hint, "__args__", [None])[0] if _is_list(hint) else hint
        if isinstance(value, list):
            for i, item in enumerate(value):
                _check_keys(item_schema, item, f"{path}.{key}[{i}]")
        else:
            _check_keys(hint, value, f"{path}.{key}")


def _is_list(hint: Any) -> bool:
    return getattr(hint, "__origin__", None) is list


def _type_hints(schema: type) -> dict[str, Any]:
    return typing.get_type_hints(schema)


def _field_types(schema: Any) -> dict[str, Any] | None:
    """{field: type} of a dataclass or of a Drake-bound config (``__fields__``), else None."""
    if hasattr(schema, "__dataclass_fields__"):
        return _type_hints(schema)
    drake_fields = getattr(schema, "__fields__", None)
    if isinstance(schema, type) and isinstance(drake_fields, tuple):
        return {f.name: f.type for f in drake_fields}
    return None


def _locate_type_error(schema: Any, data: Any, path: str) -> str | None:
    """Find the value Drake's loader choked on, so its message can name the full path.

    Only called after ``yaml_load_typed`` failed; returns None when nothing is found (the
    caller then reports Drake's own message)."""
    variants = getattr(schema, "__args__", None)
    if variants is not None and not _is_list(schema):  # Union / Optional
        if data is None and type(None) in variants:
            return None
        classes = [v for v in variants if v is not type(None)]
        tag = data.get("__tag__") if isinstance(data, dict) else None
        named = [c for c in classes if c.__name__ == tag]
        schema = named[0] if named else classes[0]
    got = f" (got {data!r})"
    if _is_list(schema):
        if not isinstance(data, list):
            return f"{path}: must be a list{got}"
        for i, item in enumerate(data):
            found = _locate_type_error(schema.__args__[0], item, f"{path}[{i}]")
            if found:
                return found
        return None
    if schema is bool:
        return None if isinstance(data, bool) else f"{path}: must be true or false{got}"
    if schema is int:
        ok = isinstance(data, int) and not isinstance(data, bool)
        return None if ok or _parses(int, data) else f"{path}: must be an integer{got}"
    if schema is float:
        ok = isinstance(data, int | float) and not isinstance(data, bool)
        return None if ok or _parses(float, data) else f"{path}: must be a number{got}"
    if schema is str:
        return None if isinstance(data, str) else f"{path}: must be a string{got}"
    hints = _field_types(schema)
    if hints is None:
        return None
    if not isinstance(data, dict):
        return f"{path}: must be a mapping of fields{got}"
    for key, value in data.items():
        if key in hints:
            found = _locate_type_error(hints[key], value, f"{path}.{key}")
            if found:
                return found
    return None


def _parses(kind: type, data: Any) -> bool:
    if not isinstance(data, str):
        return False
    try:
        kind(data)
    except ValueError:
        return False
    return True


def load_scenario(path: str | Path, seed: int | None = None) -> Scenario:
    """Load, expand and validate a scenario file; raises ScenarioError on any bad input.

    `seed`, when given, replaces the file's `seed` before anything random is drawn, so a
    run is reproduced from (file, seed) alone.
    """
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{path}: no such scenario file")
    return parse_scenario(path.read_text(), default_name=path.stem, seed=seed)


def parse_scenario(text: str, default_name: str = "scenario", seed: int | None = None) -> Scenario:
    """Parse scenario YAML text (see :func:`load_scenario`)."""
    try:
        raw = yaml.load(text, Loader=_TaggedLoader)
    except yaml.YAMLError as error:
        raise ScenarioError(f"scenario: not valid YAML: {error}") from None
    if not isinstance(raw, dict):
        raise ScenarioError("scenario: the file must be a mapping of fields")
    _check_keys(Scenario, raw, "scenario")
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except (RuntimeError, ValueError, TypeError, AssertionError) as error:
        located = _locate_type_error(Scenario, raw, "scenario")
        raise ScenarioError(located or f"scenario: {error}") from None
    if not scenario.name:
        scenario.name = default_name
    if seed is not None:
        scenario.seed = seed
    _validate_dimension(scenario)
    expand_random_obstacles(scenario)
    validate(scenario)
    return scenario


# --------------------------------------------------------------------------- validation


def _require(condition: bool, path: str, rule: str, value: Any) -> None:
    if not condition:
        raise ScenarioError(f"{path}: {rule} (got {value!r})")


def _require_vector(value: list[float], length: int, path: str) -> None:
    _require(len(value) == length, path, f"must have {length} entries", value)
    _require(all(math.isfinite(v) for v in value), path, "must be finite", value)


def _require_range(value: list[float], path: str, low: float, high: float) -> None:
    _require(len(value) == 2 and value[0] <= value[1], path, "must be [low, high]", value)
    _require(low <= value[0] and value[1] <= high, path, f"must lie in [{low}, {high}]", value)


def _require_step_times(times: list[float], path: str) -> None:
    """Times of a piecewise-linear model: finite, non-decreasing, each at most twice (a
    repeated time is a step, see :mod:`stt_drake.core.motion`)."""
    _require(all(math.isfinite(t) for t in times), path, "must be finite", times)
    steps = np.diff(np.asarray(times, dtype=float))
    _require(
        bool(np.all(steps >= 0.0)) and not bool(np.any((steps[1:] == 0.0) & (steps[:-1] == 0.0))),
        path,
        "must increase (a time may be repeated once: a step)",
        times,
    )


def _validate_motion(motion: Motion, n: int, path: str) -> None:
    if isinstance(motion, ConstantVelocity):
        _require_vector(motion.start, n, f"{path}.start")
        _require_vector(motion.velocity, n, f"{path}.velocity")
    elif isinstance(motion, Oscillation):
        _require_vector(motion.center, n, f"{path}.center")
        _require_vector(motion.amplitude, n, f"{path}.amplitude")
        if motion.phase:
            _require_vector(motion.phase, n, f"{path}.phase")
        _require(
            motion.frequency_hz >= 0.0, f"{path}.frequency_hz", "must be ≥ 0", motion.frequency_hz
        )
    elif isinstance(motion, Waypoints):
        _require(len(motion.times) >= 1, f"{path}.times", "needs at least one time", motion.times)
        _require(
            len(motion.positions) == len(motion.times),
            f"{path}.positions",
            "needs one position per time",
            motion.positions,
        )
        _require_step_times(motion.times, f"{path}.times")
        for i, position in enumerate(motion.positions):
            _require_vector(position, n, f"{path}.positions[{i}]")


def _validate_obstacle(obstacle: Obstacle, n: int, path: str) -> None:
    _validate_motion(obstacle.motion, n, f"{path}.motion")
    _require(obstacle.radius > 0.0, f"{path}.radius", "must be > 0 (metres)", obstacle.radius)
    _require(
        obstacle.sigma > 0.0,
        f"{path}.sigma",
        "must be > 0 (a standard deviation in metres)",
        obstacle.sigma,
    )
    if obstacle.sigma_schedule is not None:
        schedule = obstacle.sigma_schedule
        _require(
            len(schedule.times) >= 1 and len(schedule.times) == len(schedule.values),
            f"{path}.sigma_schedule",
            "needs as many values as times (≥ 1)",
            schedule,
        )
        _require_step_times(schedule.times, f"{path}.sigma_schedule.times")
        _require(
            all(v > 0.0 for v in schedule.values),
            f"{path}.sigma_schedule.values",
            "must all be > 0 (standard deviations in metres)",
            schedule.values,
        )
    _require(
        0.0 < obstacle.epsilon <= 1.0, f"{path}.epsilon", "must lie in (0, 1]", obstacle.epsilon
    )
    _require(
        obstacle.epsilon < obstacle.p_d <= 1.0,
        f"{path}.p_d",
        f"must lie in (epsilon, 1] = ({obstacle.epsilon}, 1]",
        obstacle.p_d,
    )


def _validate_controller(config: ControllerConfig, n: int, stages: int) -> None:
    path = "scenario.controller"
    _require(
        len(config.kappa) == stages,
        f"{path}.kappa",
        f"this plant has {stages} stage(s): give {stages} gain(s)",
        config.kappa,
    )
    _require(all(k > 0.0 for k in config.kappa), f"{path}.kappa", "must all be > 0", config.kappa)
    _require(
        len(config.funnels) == stages - 1,
        f"{path}.funnels",
        f"need {stages - 1} box funnel(s) for stages 2..{stages}",
        len(config.funnels),
    )
    for i, funnel in enumerate(config.funnels):
        where = f"{path}.funnels[{i}]"
        for name in ("start", "end", "rate"):
            _require_vector(getattr(funnel, name), n, f"{where}.{name}")
        _require(
            all(0.0 < e < s for s, e in zip(funnel.start, funnel.end, strict=True)),
            f"{where}.end",
            "must satisfy 0 < end < start per axis",
            funnel.end,
        )
        _require(all(r >= 0.0 for r in funnel.rate), f"{where}.rate", "must be ≥ 0", funnel.rate)


def _validate_dimension(scenario: Scenario) -> None:
    """The plant fixes n; `start` must match it before any other vector is checked."""
    expected = PLANT_DIMENSION[type(scenario.plant)]
    _require(
        scenario.dimension == expected,
        "scenario.start",
        f"{type(scenario.plant).__name__} works in {expected} dimensions: give {expected} entries",
        scenario.start,
    )


def _validate_plant(scenario: Scenario) -> None:
    plant, n = scenario.plant, scenario.dimension
    path = "scenario.plant"
    if isinstance(plant, OmniRobot):
        for name in ("wheel_radius", "base_radius", "nominal_wheel_radius", "nominal_base_radius"):
            value = getattr(plant, name)
            _require(value > 0.0, f"{path}.{name}", "must be > 0 (metres)", value)
        _require(
            plant.heading_gain > 0.0, f"{path}.heading_gain", "must be > 0", plant.heading_gain
        )
        _require_vector(plant.disturbance_amplitude, n, f"{path}.disturbance_amplitude")
        if plant.initial_position:
            _require_vector(plant.initial_position, n, f"{path}.initial_position")
    elif isinstance(plant, Quadrotor):
        _require(plant.mass > 0.0, f"{path}.mass", "must be > 0 (kg)", plant.mass)
        _require(plant.drag >= 0.0, f"{path}.drag", "must be ≥ 0 (N·s/m)", plant.drag)
        _require(plant.gravity >= 0.0, f"{path}.gravity", "must be ≥ 0 (m/s²)", plant.gravity)
        if plant.initial_position:
            _require_vector(plant.initial_position, n, f"{path}.initial_position")
        _require_vector(plant.initial_velocity, n, f"{path}.initial_velocity")
        _require_vector(plant.wind_amplitude, n, f"{path}.wind_amplitude")
        _require(
            all(a >= 0.0 for a in plant.wind_amplitude),
            f"{path}.wind_amplitude",
            "must all be ≥ 0 (N, the bound |w_i| ≤ A_i)",
            plant.wind_amplitude,
        )
        frequencies = plant.wind_frequencies_hz
        _require(
            len(frequencies) >= 1 and all(math.isfinite(f) and f >= 0.0 for f in frequencies),
            f"{path}.wind_frequencies_hz",
            "needs at least one finite frequency ≥ 0 (Hz)",
            frequencies,
        )
        _require(
            plant.body_radius > 0.0,
            f"{path}.body_radius",
            "must be > 0 (metres)",
            plant.body_radius,
        )


def _validate_franka(scenario: Scenario) -> None:
    """The arm's fields, q(0) inside the joint limits, y(0) = TCP(q(0)) within r_min of the
    start (so y(0) ∈ Γ(0)), and stage 2's funnel around the initial joint-velocity error —
    all on one parse of the arm model."""
    # Lazy: loading the arm model needs pydrake.multibody, which other plants do not;
    # builders imports this module and holds the one scenario → law construction.
    from stt_drake.build.diagram import make_arm_law, make_tube_law
    from stt_drake.core.arm import ArmLimits
    from stt_drake.systems.plants.franka import FR3_JOINTS, FR3_LINKS, ArmKinematics

    plant, path = scenario.plant, "scenario.plant"
    _require_vector(plant.initial_configuration, FR3_JOINTS, f"{path}.initial_configuration")
    for i, waypoint in enumerate(plant.waypoints):
        _require_vector(waypoint, scenario.dimension, f"{path}.waypoints[{i}]")
    _require(plant.hold_time >= 0.0, f"{path}.hold_time", "must be ≥ 0 (s)", plant.hold_time)
    _require(
        plant.jacobian_damping > 0.0,
        f"{path}.jacobian_damping",
        "must be > 0 (m)",
        plant.jacobian_damping,
    )
    for name in ("posture_gain", "limit_gain"):
        value = getattr(plant, name)
        _require(value >= 0.0, f"{path}.{name}", "must be ≥ 0", value)
    _require(
        plant.limit_margin > 0.0, f"{path}.limit_margin", "must be > 0 (rad)", plant.limit_margin
    )
    for i, jerk in enumerate(plant.jerks):
        where = f"{path}.jerks[{i}]"
        _require(jerk.time >= 0.0, f"{where}.time", "must be ≥ 0 (s)", jerk.time)
        _require(jerk.duration > 0.0, f"{where}.duration", "must be > 0 (s)", jerk.duration)
        _require(jerk.link in FR3_LINKS, f"{where}.link", f"must be one of {FR3_LINKS}", jerk.link)
        _require_vector(jerk.force, 3, f"{where}.force")
        _require_vector(jerk.point, 3, f"{where}.point")
    kinematics = ArmKinematics()
    limits = ArmLimits.of(kinematics.plant)
    q0 = np.asarray(plant.initial_configuration, dtype=float)
    _require(
        bool(np.all((limits.position_lower < q0) & (q0 < limits.position_upper))),
        f"{path}.initial_configuration",
        f"must lie inside the joint limits {limits.position_lower.tolist()} .. "
        f"{limits.position_upper.tolist()} (rad)",
        plant.initial_configuration,
    )
    tcp = kinematics.position(q0)
    _require(
        float(np.linalg.norm(tcp - np.asarray(scenario.start))) < scenario.tube.r_min,
        "scenario.start",
        f"must lie within r_min = {scenario.tube.r_min} m of the TCP at the initial "
        f"configuration, {np.round(tcp, 6).tolist()}, so y(0) ∈ Γ(0)",
        scenario.start,
    )
    _validate_arm_funnel_start(
        scenario, make_arm_law(scenario, limits), make_tube_law(scenario), kinematics
    )


def initial_stage_states(scenario: Scenario) -> np.ndarray:
    """x(0) = [x_1(0); ...; x_N(0)] as an (N, n) array: the position y(0) and, for a
    second-order plant, the initial velocity."""
    states = [initial_output(scenario)]
    if isinstance(scenario.plant, Quadrotor):
        states.append(np.asarray(scenario.plant.initial_velocity, dtype=float))
    return np.vstack(states)


def _validate_funnel_starts(scenario: Scenario) -> None:
    """Sec. 5: each box funnel must contain its stage's initial error,
    |x_k,i(0) − r_k,i(0)| < p_k,i, with r_k(0) from the control law at t = 0 (so r_2(0) = 0
    when y(0) = s, and p_2 must exceed |v(0)| per axis)."""
    if PLANT_STAGES[type(scenario.plant)] < 2:
        return
    # Lazy: builders imports this module; it holds the one scenario → law construction.
    from stt_drake.build.diagram import make_funnel_controller, make_tube_law

    start = np.asarray(scenario.start, dtype=float)
    radius = make_tube_law(scenario).evaluate(start, scenario.belief_at(0.0)).radius
    states = initial_stage_states(scenario)
    evaluation = make_funnel_controller(scenario).evaluate(0.0, states, start, radius)
    for k, error in enumerate(evaluation.normalized_errors[1:]):
        funnel = scenario.controller.funnels[k]
        initial_error = np.abs(error) * np.asarray(funnel.start, dtype=float)
        _require(
            bool(np.all(np.abs(error) < 1.0)),
            f"scenario.controller.funnels[{k}].start",
            f"must exceed the initial error |x_{k + 2}(0) − r_{k + 2}(0)| = "
            f"{np.round(initial_error, 6).tolist()} on every axis (Sec. 5)",
            funnel.start,
        )


def _validate_arm_funnel_start(
    scenario: Scenario, law: Any, tube_law: Any, kinematics: Any
) -> None:
    """The arm starts at rest: stage 2's funnel must contain |0 − q̇_ref(0)| per joint,
    with q̇_ref(0) from the law at t = 0 (the null-space posture term when q(0) is not the
    home posture)."""
    q0 = np.asarray(scenario.plant.initial_configuration, dtype=float)
    start = np.asarray(scenario.start, dtype=float)
    radius = tube_law.evaluate(start, scenario.belief_at(0.0)).radius
    evaluation = law.evaluate(
        0.0, kinematics.position(q0), q0, np.zeros_like(q0), kinematics.jacobian(q0), start, radius
    )
    _require(
        bool(np.all(np.abs(evaluation.normalized_errors[1:]) < 1.0)),
        "scenario.controller.funnels[0].start",
        "must exceed the initial joint-velocity error |q̇(0) − q̇_ref(0)| = "
        f"{np.round(np.abs(evaluation.joint_velocity), 6).tolist()} rad/s on every joint (Sec. 5)",
        scenario.controller.funnels[0].start,
    )


def task_targets(scenario: Scenario) -> list[np.ndarray]:
    """The reach-avoid-stay targets in order: the arm's waypoints, then `target`."""
    waypoints = getattr(scenario.plant, "waypoints", [])
    return [np.asarray(p, dtype=float) for p in [*waypoints, scenario.target]]


def initial_output(scenario: Scenario) -> np.ndarray:
    """y(0): the plant's initial position where given, else the start point s."""
    position = getattr(scenario.plant, "initial_position", None)
    return np.asarray(position if position else scenario.start, dtype=float)


def validate(scenario: Scenario) -> None:
    """Check every rule of the paper and of the file format; raise ScenarioError."""
    _validate_dimension(scenario)
    n = scenario.dimension
    _require(n >= 1, "scenario.start", "must have at least one entry", scenario.start)
    _require_vector(scenario.start, n, "scenario.start")
    _require_vector(scenario.target, n, "scenario.target")
    _require(
        0.0 < scenario.duration < math.inf,
        "scenario.duration",
        "must be finite and > 0 (seconds)",
        scenario.duration,
    )
    _require(
        scenario.log_period > 0.0,
        "scenario.log_period",
        "must be > 0 (seconds)",
        scenario.log_period,
    )
    _require(
        0.0 <= scenario.max_steps_per_second < math.inf,
        "scenario.max_steps_per_second",
        "must be finite and ≥ 0 (steps per simulated second; 0 = the watchdog's default)",
        scenario.max_steps_per_second,
    )
    tube = scenario.tube
    _require(tube.r_min > 0.0, "scenario.tube.r_min", "must be > 0 (metres)", tube.r_min)
    _require(
        tube.r_min < tube.r_max,
        "scenario.tube.r_max",
        f"must be > r_min = {tube.r_min}",
        tube.r_max,
    )
    _require(
        tube.r_max <= scenario.initial_set_radius,
        "scenario.tube.r_max",
        f"must be ≤ initial_set_radius = {scenario.initial_set_radius} so Γ(0) ⊂ S",
        tube.r_max,
    )
    _require(
        tube.r_max <= scenario.target_set_radius,
        "scenario.tube.r_max",
        f"must be ≤ target_set_radius = {scenario.target_set_radius} so Γ ⊂ T can hold",
        tube.r_max,
    )
    for name in ("k1", "k2"):
        _require(
            getattr(tube, name) > 0.0, f"scenario.tube.{name}", "must be > 0", getattr(tube, name)
        )
    _require(tube.k3 >= 0.0, "scenario.tube.k3", "must be ≥ 0", tube.k3)
    _require(
        tube.update_rate_hz >= 0.0,
        "scenario.tube.update_rate_hz",
        "must be ≥ 0 (0 = continuous time)",
        tube.update_rate_hz,
    )
    for i, obstacle in enumerate(scenario.obstacles):
        _validate_obstacle(obstacle, n, f"scenario.obstacles[{i}]")
    bound = minimum_nu(len(scenario.obstacles), tube.r_min)
    _require(
        tube.nu == 0.0 or tube.nu > bound,
        "scenario.tube.nu",
        f"must exceed ln(n_o + 1)/r_min = {bound:.4g} for {len(scenario.obstacles)} "
        "obstacles, or the soft-min radius can go negative (0 derives it)",
        tube.nu,
    )
    _validate_plant(scenario)
    stages = PLANT_STAGES[type(scenario.plant)]
    funnel_dimension = PLANT_FUNNEL_DIMENSION.get(type(scenario.plant), n)
    _validate_controller(scenario.controller, funnel_dimension, stages)
    _validate_initial_condition(scenario)
    if isinstance(scenario.plant, FrankaArm):
        _validate_franka(scenario)  # after the controller: its funnel check needs them
    else:
        _validate_funnel_starts(scenario)
    # Lazy: feasibility builds on this module's schema (speeds, periods, warnings).
    from stt_drake.build.feasibility import validate_real_time

    validate_real_time(scenario)


def _validate_initial_condition(scenario: Scenario) -> None:
    """q_j(s, 0) > ε_j for every obstacle (J(0) > 0 in the proof of claim ii), and y(0) ∈ S."""
    if scenario.obstacles:
        belief = scenario.belief_at(0.0)
        q = avoid_probability(
            np.asarray(scenario.start),
            belief.mean,
            belief.sigma,
            belief.radius + scenario.tube.r_min,
        )
        for j in np.flatnonzero(q <= belief.epsilon):
            raise ScenarioError(
                f"scenario.start: the initial avoidance condition fails for obstacle {j}: "
                f"q_{j}(s, 0) = {q[j]:.6g} must exceed epsilon = {belief.epsilon[j]} "
                f"(move the start or the obstacle) (got {scenario.start!r})"
            )
    offset = float(np.linalg.norm(initial_output(scenario) - np.asarray(scenario.start)))
    _require(
        offset < scenario.tube.r_min,
        "scenario.plant.initial_position",
        f"must lie within r_min = {scenario.tube.r_min} of start so y(0) ∈ Γ(0)",
        initial_output(scenario).tolist(),
    )


# --------------------------------------------------------------------------- random fields


def expand_random_obstacles(scenario: Scenario) -> None:
    """Append the `random_obstacles` draws to `scenario.obstacles`.

    Reproducible: the draws depend only on (random_obstacles.seed, scenario seed).
    """
    spec = scenario.random_obstacles
    if spec is None or (spec.count == 0 and not spec.count_range):
        return
    n, path = scenario.dimension, "scenario.random_obstacles"
    _require(spec.count > 0 or bool(spec.count_range), f"{path}.count", "must be ≥ 0", spec.count)
    if spec.count_range:
        _require(
            spec.count == 0, f"{path}.count", "give count or count_range, not both", spec.count
        )
        _require_range(spec.count_range, f"{path}.count_range", 1, math.inf)
    _require_vector(spec.region_min, n, f"{path}.region_min")
    _require_vector(spec.region_max, n, f"{path}.region_max")
    _require(
        all(low < high for low, high in zip(spec.region_min, spec.region_max, strict=True)),
        f"{path}.region_max",
        "must exceed region_min on every axis",
        spec.region_max,
    )
    _require(
        0.0 < scenario.duration < math.inf,
        "scenario.duration",
        "must be finite and > 0 (seconds)",
        scenario.duration,
    )
    _require_range(spec.sigma_range, f"{path}.sigma_range", 1e-9, math.inf)
    _require_range(spec.epsilon_range, f"{path}.epsilon_range", 1e-9, 1.0)
    _require(
        spec.epsilon_range[1] < spec.p_d <= 1.0,
        f"{path}.p_d",
        "must lie in (epsilon_range high, 1]",
        spec.p_d,
    )
    _require_range(spec.amplitude_range, f"{path}.amplitude_range", 0.0, math.inf)
    _require_range(spec.frequency_range_hz, f"{path}.frequency_range_hz", 0.0, math.inf)
    rng = np.random.default_rng([spec.seed, scenario.seed])
    count = (
        int(rng.integers(spec.count_range[0], spec.count_range[1] + 1))
        if spec.count_range
        else spec.count
    )
    checkpoints = np.linspace(0.0, scenario.duration, 200)
    anchors = np.array([scenario.start, scenario.target], dtype=float)
    accepted: list[Obstacle] = []
    for _attempt in range(1000 * count):
        if len(accepted) == count:
            break
        candidate = Obstacle(
            motion=Oscillation(
                center=rng.uniform(spec.region_min, spec.region_max).tolist(),
                amplitude=rng.uniform(*spec.amplitude_range, size=n).tolist(),
                frequency_hz=float(rng.uniform(*spec.frequency_range_hz)),
                phase=rng.uniform(0.0, 2.0 * np.pi, size=n).tolist(),
            ),
            radius=spec.radius,
            sigma=float(rng.uniform(*spec.sigma_range)),
            epsilon=float(rng.uniform(*spec.epsilon_range)),
            p_d=spec.p_d,
        )
        path_points = np.array([candidate.motion.position(t) for t in checkpoints])
        clear = all(
            np.all(
                avoid_probability(
                    anchor,
                    path_points,
                    np.full(len(checkpoints), candidate.sigma),
                    candidate.radius + scenario.tube.r_min,
                )
                > spec.p_d
            )
            for anchor in anchors
        )
        if clear:
            accepted.append(candidate)
    _require(
        len(accepted) == count,
        f"{path}.count_range" if spec.count_range else f"{path}.count",
        "could not place that many obstacles clear of start and target; enlarge the region",
        count,
    )
    scenario.obstacles = scenario.obstacles + accepted
