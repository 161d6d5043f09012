"""Loading a scenario completely: read and validate it (:mod:`stt_drake.config`), then
the checks that need the built laws (:mod:`stt_drake.assembly.checks`).

A scenario with a `crowd:` section gets its pedestrians here, before the rules are checked
(:func:`with_crowd`): the scene is drawn (:mod:`stt_drake.crowd.scenes`, numpy only) and
each pedestrian becomes an obstacle slot, so the initial avoidance condition, the
perception rules and the budgets see them."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from stt_drake.assembly.checks import check_buildable
from stt_drake.config import (
    Obstacle,
    Scenario,
    ScenarioError,
    complete_scenario,
    parse_schema,
    read_scenario_file,
)
from stt_drake.config.assumptions import check_target_separation
from stt_drake.config.limits import check_numbers, check_seed, require, rule_path
from stt_drake.config.validate import validate_dimension
from stt_drake.config.validate_crowd import validate_crowd_section
from stt_drake.core.motion import Recorded, Waypoints
from stt_drake.crowd.engine import CrowdUnavailableError, load_jupedsim
from stt_drake.crowd.scenes import CrowdSetup, make_scene
from stt_drake.crowd.tracks import Tracks, run_tracks
from stt_drake.diagrams import scenario_file


def crowd_setup(scenario: Scenario) -> CrowdSetup:
    """The scene of `scenario.crowd`, drawn from (crowd.seed, scenario.seed): the same
    scenario and seed always give the same crowd; a campaign's run seeds give each run its
    own. RuleError of the scene becomes ScenarioError naming ``scenario.crowd.<field>``."""
    crowd = scenario.crowd
    state = np.random.SeedSequence([crowd.seed, scenario.seed]).generate_state(1, np.uint64)
    with rule_path("scenario.crowd"):
        return make_scene(
            crowd.scene,
            crowd.pedestrians,
            int(state[0]) % 2**63,
            speed_range=crowd.speed_range,
            area=crowd.area,
            radius=crowd.radius,
        )


def crowd_obstacles(scenario: Scenario, setup: CrowdSetup) -> list[Obstacle]:
    """One obstacle slot per pedestrian: r_o = crowd.radius + crowd.robot_radius (the
    pedestrian's disc grown by the robot's: the tube keeps the robot's centre out of it),
    crowd.sigma, ε, p_d. Its motion:

    * interactive: the pedestrian's free path (straight from its start to its exit's centre
      at its desired speed, then held), which only the load-time checks read (the initial
      avoidance at t = 0, Assumption 3 at the end); the truth is the crowd simulator's;
    * not interactive: the crowd simulated here without the robot over the run (sampled at
      1/crowd.period), each pedestrian a recorded track over its time in the scene
      (:class:`~stt_drake.core.motion.Recorded`): the same crowd a track file of
      ``stt-drake crowd`` holds, drawn afresh for every seed."""
    crowd = scenario.crowd
    if crowd.interactive:
        goals, times = setup.goals(), setup.free_walk_times()
        motions = [
            Waypoints(
                times=[0.0, max(float(times[i]), 1e-3)],
                positions=[setup.starts[i].tolist(), goals[i].tolist()],
            )
            for i in range(setup.count)
        ]
    else:
        tracks = run_tracks(setup, scenario.duration, 1.0 / crowd.period)
        motions = [Recorded.of(*_held_track(tracks, i)) for i in range(setup.count)]
    return [
        Obstacle(
            motion=motion,
            radius=crowd.radius + crowd.robot_radius,
            sigma=crowd.sigma,
            epsilon=crowd.epsilon,
            p_d=crowd.p_d,
        )
        for motion in motions
    ]


def _held_track(tracks: Tracks, pedestrian: int) -> tuple[np.ndarray, np.ndarray]:
    """A pedestrian's samples while in the scene; one that left after a single sample is
    held there for one more sample time (a track needs two samples)."""
    times, positions = tracks.track(pedestrian)
    if len(times) == 1:
        step = float(tracks.times[1] - tracks.times[0]) if len(tracks.times) > 1 else 1e-3
        times, positions = np.append(times, times[0] + step), np.repeat(positions, 2, axis=0)
    return times, positions


def with_crowd(schema: Scenario, seed: int | None = None) -> Scenario:
    """`schema` with its crowd's pedestrians as obstacles (a copy; `schema` itself when it
    has no `crowd:`), `seed` in place when given. The section's rules are checked first
    (:func:`stt_drake.config.validate_crowd.validate_crowd_section`), and the file may give
    no obstacles of its own. Without JuPedSim (the `crowd` extra) the scenario is refused
    here, naming ``scenario.crowd`` and the extra."""
    if schema.crowd is None:
        return schema
    scenario = copy.deepcopy(schema)
    if seed is not None:
        check_seed(seed, "seed")
        scenario.seed = seed
    validate_dimension(scenario)
    check_numbers(scenario.crowd, "scenario.crowd")
    check_seed(scenario.seed, "scenario.seed")
    validate_crowd_section(scenario)
    try:  # refused here, with exit code 2, rather than when the diagram is built
        load_jupedsim()
    except CrowdUnavailableError as error:
        raise ScenarioError(f"scenario.crowd: {error}") from None
    require(
        not scenario.obstacles,
        "scenario.obstacles",
        "must be empty with a crowd (its pedestrians are the obstacles)",
        f"{len(scenario.obstacles)} obstacles",
    )
    scenario.obstacles = crowd_obstacles(scenario, crowd_setup(scenario))
    return scenario


def load_scenario(path: str | Path, seed: int | None = None, strict: bool = False) -> Scenario:
    """Load, expand and validate a scenario file, or a packaged scenario by name
    (``load_scenario("omni_hardware_case1")``, :func:`stt_drake.diagrams.scenario_file`: an
    existing file wins); raises ScenarioError on any bad input, for an unknown name with
    the packaged names closest to it.

    `seed`, when given, replaces the file's `seed` before anything random is drawn, so a
    run is reproduced from (file, seed) alone. `strict` (``stt-drake run --strict``) makes
    the scenario strict, as `strict: true` in the file does: a broken assumption of the
    theorem that the run would otherwise record is refused
    (:func:`stt_drake.config.assumptions.check_target_separation`).
    """
    try:
        path = scenario_file(path)
    except FileNotFoundError as error:
        raise ScenarioError(str(error)) from None
    schema = parse_schema(read_scenario_file(path), default_name=path.stem, base=path.parent)
    scenario = complete_scenario(with_crowd(schema, seed), seed)
    if strict:
        scenario.strict = True
        check_target_separation(scenario)
    check_buildable(scenario)
    return scenario


def parse_scenario(text: str, default_name: str = "scenario", seed: int | None = None) -> Scenario:
    """Parse and validate scenario YAML text (see :func:`load_scenario`)."""
    return prepare_scenario(parse_schema(text, default_name), seed)


def prepare_scenario(schema: Scenario, seed: int | None = None) -> Scenario:
    """A scenario from a parsed schema (:func:`stt_drake.config.parse_schema`) with `seed`:
    its random field (and crowd) drawn and every rule checked, as :func:`parse_scenario`
    would; the YAML is not parsed again (a campaign's runs)."""
    scenario = complete_scenario(with_crowd(schema, seed), seed)
    check_buildable(scenario)
    return scenario
