"""The rules of the paper and of the file format that a scenario can be checked against
without building anything: the limits of :mod:`stt_drake.config.limits` (finite, sane
numbers, seeds, the simulator, memory, work, schedule lengths), the name, shapes, signs,
ranges, the obstacles' uncertainty (σ, σ schedules, full covariances Σ_j:
:mod:`stt_drake.config.covariance`), p_d < 1, ν, the plant's fields, the controller's
gains and funnels, the initial avoidance condition q_j(s, 0) > ε_j (J(0) > 0 in the proof
of Theorem 3.2 (ii)), Assumption 3 at the target in a strict scenario
(:mod:`stt_drake.config.assumptions`), the `perception:` section
(:mod:`stt_drake.config.validate_perception`) and the `guide:` section
(:mod:`stt_drake.config.validate_guide`). Every broken rule raises :class:`ScenarioError`
naming the full field path and the rule (:func:`require`, from
:mod:`stt_drake.config.limits`).

The rules of the core objects — the tube constants, ν against the obstacle count, an
obstacle's r_o, ε, p_d, the controller's gains and funnels, the initial avoidance condition
— are not written here: they are :mod:`stt_drake.core.rules` (an obstacle's, with its
motion and uncertainty: :func:`stt_drake.core.obstacle.check_obstacle`), which the
constructors of TubeLaw, Obstacle, the motion models, ObstacleTask, BoxFunnel,
FunnelController, SpatiotemporalTube and AddStt check too, called through
:func:`stt_drake.config.limits.rule_path` with the file's field path.
"""

import dataclasses
import math
import re

import numpy as np

from stt_drake.config.assumptions import check_target_separation
from stt_drake.config.limits import check_limits, require, rule_path
from stt_drake.config.schema import (
    PLANT_DIMENSION,
    PLANT_FUNNEL_DIMENSION,
    PLANT_STAGES,
    ControllerConfig,
    Obstacle,
    OmniRobot,
    Quadrotor,
    Scenario,
)
from stt_drake.config.validate_crowd import validate_crowd
from stt_drake.config.validate_guide import validate_guide
from stt_drake.config.validate_lcm import validate_lcm
from stt_drake.config.validate_perception import validate_perception
from stt_drake.core.belief import has_full_covariance
from stt_drake.core.motion import MotionTable, Recorded
from stt_drake.core.obstacle import UNCERTAINTY_FIELDS as UNCERTAINTY_FIELDS  # the loader's
from stt_drake.core.obstacle import check_obstacle
from stt_drake.core.obstacle import check_one_uncertainty as core_check_one_uncertainty
from stt_drake.core.rules import (
    check_box_funnel,
    check_center_speed,
    check_continuous_for_covariance,
    check_initial_avoidance,
    check_kappa,
    check_nu,
    check_nu_for_count,
    check_tube_constants,
    check_vector,
)

#: Fastest fixed-rate tube update (Hz): a real-time rate; faster is continuous time (0).
MAX_UPDATE_RATE_HZ = 1e4


#: What a scenario name may hold: it names the results folder, results/<name>/.
NAME_PATTERN = re.compile(r"[A-Za-z0-9_.-]{1,100}")


def name_from_stem(stem: str) -> str:
    """A valid scenario name from a file name's stem: every character a name may not hold
    made "_" (a stem of dots only, or none, gives "scenario")."""
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", stem)[:100]
    return name if name.strip(".") else "scenario"


def validate_name(name: str) -> None:
    """`name` is a name, not a path: letters, digits, "_", "-" and "." only (1-100 of
    them), not "." or ".." nor containing "..", so results/<name>/ stays inside results/."""
    require(
        bool(NAME_PATTERN.fullmatch(name)) and ".." not in name and name != ".",
        "scenario.name",
        "must be a name, not a path: 1-100 letters, digits, '_', '-' or '.', without '..' "
        "(it names the folder results/<name>/)",
        name,
    )


def check_one_uncertainty(given: list[str], path: str) -> None:
    """Of the uncertainty forms `given` at `path` at most one
    (:func:`stt_drake.core.obstacle.check_one_uncertainty`)."""
    with rule_path(path):
        core_check_one_uncertainty(given)


def require_vector(value: list[float], length: int, path: str) -> None:
    """`value` has `length` finite entries (:func:`stt_drake.core.rules.check_vector`)."""
    with rule_path(path):
        check_vector(value, "", length)


def require_range(value: list[float], path: str, low: float, high: float) -> None:
    """`value` is an interval [a, b] inside [low, high]."""
    require(len(value) == 2 and value[0] <= value[1], path, "must be [low, high]", value)
    require(low <= value[0] and value[1] <= high, path, f"must lie in [{low}, {high}]", value)


def _validate_recorded_span(motion: Recorded, scenario: Scenario, path: str) -> None:
    """A recorded track (read by :mod:`stt_drake.config.tracks`) does not end before the
    run starts (a track that starts after the run ends is a pedestrian this run never
    meets: allowed, so a shorter run of a recording loads; that *no* track overlaps the run
    is refused by :func:`_validate_recorded_overlap`); with the fixed-rate tube it covers
    the whole run: that tube's period guarantee needs every slot active
    (:mod:`stt_drake.core.fixed_rate`)."""
    require(
        motion.loaded,
        f"{path}.file",
        "the track file was not read (load the scenario with stt_drake.config)",
        motion.file,
    )
    first, last = motion.track.span
    duration = scenario.duration
    require(
        last >= 0.0,
        f"{path}.id",
        f"the track spans [{first:g}, {last:g}] s and ends before the run starts: its times "
        "must be seconds from the run's start",
        motion.id,
    )
    require(
        scenario.tube.update_rate_hz == 0.0 or (first <= 0.0 and last >= duration),
        f"{path}.id",
        f"the track spans [{first:g}, {last:g}] s and the obstacle exists over that span only; "
        f"the fixed-rate tube (tube.update_rate_hz > 0) needs every obstacle for the whole run "
        f"[0, {duration:g}] s: give a track that covers it, or use update_rate_hz: 0 "
        "(continuous time)",
        motion.id,
    )


def _validate_recorded_overlap(scenario: Scenario) -> None:
    """Some recorded track overlaps the run [0, duration]: tracks that all start after the
    run ends are stamped in another clock (e.g. Unix time), not seconds from the start."""
    spans = [
        (i, o.motion.track.span)
        for i, o in enumerate(scenario.obstacles)
        if isinstance(o.motion, Recorded)
    ]
    if spans:
        first = min(span[0] for _, span in spans)
        require(
            first <= scenario.duration,
            f"scenario.obstacles[{spans[0][0]}].motion.file",
            f"every recorded track starts after the run [0, {scenario.duration:g}] s ends "
            f"(the first at {first:g} s): times must be seconds from the run's start",
            spans[0][1][0],
        )


def _validate_obstacle(obstacle: Obstacle, n: int, path: str) -> None:
    """Every rule of one obstacle (:func:`stt_drake.core.obstacle.check_obstacle`, which
    its constructor checks too)."""
    with rule_path(path):
        check_obstacle(obstacle, n)


def _validate_controller(config: ControllerConfig, n: int, stages: int) -> None:
    path = "scenario.controller"
    require(
        len(config.kappa) == stages,
        f"{path}.kappa",
        f"this plant has {stages} stage(s): give {stages} gain(s)",
        config.kappa,
    )
    with rule_path(path):  # the FunnelController's rule
        check_kappa(config.kappa)
    require(
        len(config.funnels) == stages - 1,
        f"{path}.funnels",
        f"need {stages - 1} box funnel(s) for stages 2..{stages}",
        len(config.funnels),
    )
    for i, funnel in enumerate(config.funnels):
        where = f"{path}.funnels[{i}]"
        for name in ("start", "end", "rate"):
            require_vector(getattr(funnel, name), n, f"{where}.{name}")
        with rule_path(where):  # the BoxFunnel's rules
            check_box_funnel(funnel.start, funnel.end, funnel.rate)


def validate_dimension(scenario: Scenario) -> None:
    """The plant fixes n; `start` must match it before any other vector is checked."""
    expected = PLANT_DIMENSION[type(scenario.plant)]
    require(
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
            require(value > 0.0, f"{path}.{name}", "must be > 0 (metres)", value)
        require(plant.heading_gain > 0.0, f"{path}.heading_gain", "must be > 0", plant.heading_gain)
        require(
            plant.disturbance_frequency_hz >= 0.0,
            f"{path}.disturbance_frequency_hz",
            "must be ≥ 0 (Hz)",
            plant.disturbance_frequency_hz,
        )
        require_vector(plant.disturbance_amplitude, n, f"{path}.disturbance_amplitude")
        if plant.initial_position:
            require_vector(plant.initial_position, n, f"{path}.initial_position")
    elif isinstance(plant, Quadrotor):
        require(plant.mass > 0.0, f"{path}.mass", "must be > 0 (kg)", plant.mass)
        require(plant.drag >= 0.0, f"{path}.drag", "must be ≥ 0 (N·s/m)", plant.drag)
        require(plant.gravity >= 0.0, f"{path}.gravity", "must be ≥ 0 (m/s²)", plant.gravity)
        if plant.initial_position:
            require_vector(plant.initial_position, n, f"{path}.initial_position")
        require_vector(plant.initial_velocity, n, f"{path}.initial_velocity")
        require_vector(plant.wind_amplitude, n, f"{path}.wind_amplitude")
        require(
            all(a >= 0.0 for a in plant.wind_amplitude),
            f"{path}.wind_amplitude",
            "must all be ≥ 0 (N, the bound |w_i| ≤ A_i)",
            plant.wind_amplitude,
        )
        frequencies = plant.wind_frequencies_hz
        require(
            len(frequencies) >= 1 and all(math.isfinite(f) and f >= 0.0 for f in frequencies),
            f"{path}.wind_frequencies_hz",
            "needs at least one finite frequency ≥ 0 (Hz)",
            frequencies,
        )
        require(
            plant.body_radius > 0.0,
            f"{path}.body_radius",
            "must be > 0 (metres)",
            plant.body_radius,
        )


def validate(scenario: Scenario) -> None:
    """Check every rule of the paper and of the file format that needs no built law or
    plant model (those are :func:`stt_drake.assembly.checks.check_buildable`); raise
    ScenarioError (AssumptionError when the initial avoidance condition fails)."""
    validate_dimension(scenario)
    check_limits(scenario, drawn=True)
    validate_name(scenario.name)
    n = scenario.dimension
    require(n >= 1, "scenario.start", "must have at least one entry", scenario.start)
    require_vector(scenario.start, n, "scenario.start")
    require_vector(scenario.target, n, "scenario.target")
    require(
        0.0 <= scenario.max_steps_per_second < math.inf,
        "scenario.max_steps_per_second",
        "must be finite and ≥ 0 (steps per simulated second; 0 = the watchdog's default)",
        scenario.max_steps_per_second,
    )
    tube = scenario.tube
    with rule_path("scenario.tube"):  # the TubeLaw's rules
        check_tube_constants(tube.k1, tube.k2, tube.k3, tube.r_min, tube.r_max)
    with rule_path("scenario.tube", "0 derives it"):
        check_center_speed(tube.max_center_speed, finite=True)
        if tube.nu != 0.0:
            check_nu(tube.nu)
    require(
        tube.r_max <= scenario.initial_set_radius,
        "scenario.tube.r_max",
        f"must be ≤ initial_set_radius = {scenario.initial_set_radius} so Γ(0) ⊂ S",
        tube.r_max,
    )
    require(
        tube.r_max <= scenario.target_set_radius,
        "scenario.tube.r_max",
        f"must be ≤ target_set_radius = {scenario.target_set_radius} so Γ ⊂ T can hold",
        tube.r_max,
    )
    require(
        0.0 <= tube.update_rate_hz <= MAX_UPDATE_RATE_HZ,
        "scenario.tube.update_rate_hz",
        f"must be ≥ 0 (0 = continuous time) and ≤ {MAX_UPDATE_RATE_HZ:g} (a real-time rate)",
        tube.update_rate_hz,
    )
    for i, obstacle in enumerate(scenario.obstacles):
        _validate_obstacle(obstacle, n, f"scenario.obstacles[{i}]")
        if isinstance(obstacle.motion, Recorded):
            _validate_recorded_span(obstacle.motion, scenario, f"scenario.obstacles[{i}].motion")
    _validate_recorded_overlap(scenario)
    full = [i for i, obstacle in enumerate(scenario.obstacles) if has_full_covariance(obstacle)]
    if full:
        hint = f"use 0 (continuous): obstacle {full[0]} has a full covariance"
        with rule_path("scenario.tube", hint):
            check_continuous_for_covariance(
                True, tube.update_rate_hz != 0.0, "update_rate_hz", tube.update_rate_hz, "0"
            )
    if tube.nu != 0.0:  # the SpatiotemporalTube's and AddStt's rule
        with rule_path("scenario.tube", "0 derives it"):
            check_nu_for_count(tube.nu, tube.r_min, len(scenario.obstacles))
    validate_crowd(scenario)  # before perception: a crowd's pedestrians are its obstacles
    if scenario.perception is not None:
        validate_perception(scenario.perception, scenario)
    if scenario.guide is not None:
        validate_guide(scenario.guide, scenario)
    if scenario.lcm is not None:
        validate_lcm(scenario.lcm)
    _validate_plant(scenario)
    stages = PLANT_STAGES[type(scenario.plant)]
    funnel_dimension = PLANT_FUNNEL_DIMENSION.get(type(scenario.plant), n)
    _validate_controller(scenario.controller, funnel_dimension, stages)
    _validate_initial_condition(scenario)
    check_target_separation(scenario)


def _validate_initial_condition(scenario: Scenario) -> None:
    """q_j(s, 0) > ε_j for every obstacle (J(0) > 0 in the proof of Theorem 3.2 (ii); the
    rule AddStt checks, with Σ_j exactly for the obstacles that give one), and y(0) ∈ S.
    An obstacle that does not exist at t = 0 (a recorded track that starts later) is not
    checked: it is given ε = −1, which every probability exceeds (the others keep their
    index in the message)."""
    if scenario.obstacles:
        exact = [has_full_covariance(obstacle) for obstacle in scenario.obstacles]
        belief = scenario.belief_at(0.0)
        motions = MotionTable([o.motion for o in scenario.obstacles], scenario.dimension)
        present = motions.active(0.0)
        if not present.all():
            belief = dataclasses.replace(belief, epsilon=np.where(present, belief.epsilon, -1.0))
        with rule_path("scenario"):
            check_initial_avoidance(scenario.start, belief, scenario.tube.r_min, exact)
    offset = float(np.linalg.norm(scenario.initial_output() - np.asarray(scenario.start)))
    require(
        offset < scenario.tube.r_min,
        "scenario.plant.initial_position",
        f"must lie within r_min = {scenario.tube.r_min} of start so y(0) ∈ Γ(0)",
        scenario.initial_output().tolist(),
    )
