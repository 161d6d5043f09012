"""The rules of the scenario's `crowd:` section (:class:`stt_drake.config.schema.CrowdConfig`).

:func:`validate_crowd_section` checks the section itself: a known scene, 1 ≤ pedestrians ≤
:data:`MAX_INTERACTIVE_PEDESTRIANS`, a seed, an area of four numbers with positive size,
radius in (0, 1] m, robot_radius in [0, 5] m, a speed range 0 < low ≤ high ≤ 5 m/s, a
period in (0, 1] s, the required sigma (≥ 1 mm), epsilon and p_d (the ObstacleTask's
rules), a 2-D plant, for an interactive crowd a `perception:` section (the belief must come
from a tracker: nothing else knows where the pedestrians will go) and no other obstacles
(the pedestrians are the obstacles). :func:`validate_crowd`, called by
:func:`stt_drake.config.validate.validate`, adds that the obstacle list holds exactly the N
pedestrian slots, which :func:`stt_drake.assembly.load_scenario` appends (the scene is drawn
there: :mod:`stt_drake.crowd` sits above this package). Every broken rule raises
:class:`stt_drake.config.schema.ScenarioError` naming ``scenario.crowd.<field>``.
"""

from stt_drake.config.covariance import require_sigma
from stt_drake.config.limits import check_seed, require, rule_path
from stt_drake.config.schema import CrowdConfig, Scenario, ScenarioError
from stt_drake.core.rules import check_obstacle_task

#: The scenes (:data:`stt_drake.crowd.scenes.SCENE_NAMES`; this package cannot import it).
CROWD_SCENES = ("crossing", "circle", "corridor", "bidirectional")
#: Most pedestrians of an interactive crowd (each is an obstacle slot of the tube).
MAX_INTERACTIVE_PEDESTRIANS = 500
#: Largest robot disc the pedestrians avoid (m).
MAX_ROBOT_RADIUS = 5.0
#: Fastest desired walking speed (m/s).
MAX_SPEED = 5.0
#: Longest crowd period (s).
MAX_PERIOD = 1.0

#: What each required field is.
CROWD_REQUIRED = {
    "sigma": "the standard deviation of a pedestrian's centre in the load-time prior, m "
    "(the tube reads the tracker's covariances)",
    "epsilon": "the probability ε ∈ (0, 1] with which the tube must avoid each pedestrian",
    "p_d": "the probability p_d ∈ (ε, 1) of Assumption 3 for each pedestrian",
}

_PATH = "scenario.crowd"


def validate_crowd_section(scenario: Scenario) -> None:
    """The `crowd:` section's own rules (module docstring); nothing if there is none."""
    crowd: CrowdConfig | None = scenario.crowd
    if crowd is None:
        return
    require(
        crowd.scene in CROWD_SCENES,
        f"{_PATH}.scene",
        f"must be one of {', '.join(CROWD_SCENES)}",
        crowd.scene,
    )
    require(
        1 <= crowd.pedestrians <= MAX_INTERACTIVE_PEDESTRIANS,
        f"{_PATH}.pedestrians",
        f"must lie in [1, {MAX_INTERACTIVE_PEDESTRIANS}] (each pedestrian is an obstacle slot)",
        crowd.pedestrians,
    )
    check_seed(crowd.seed, f"{_PATH}.seed")
    if crowd.area:
        require(
            len(crowd.area) == 4,
            f"{_PATH}.area",
            "must be [x_min, y_min, x_max, y_max] (m), or empty for the scene's default",
            crowd.area,
        )
        x0, y0, x1, y1 = crowd.area
        require(
            x1 > x0 and y1 > y0,
            f"{_PATH}.area",
            "must have x_max > x_min and y_max > y_min",
            crowd.area,
        )
    require(0.0 < crowd.radius <= 1.0, f"{_PATH}.radius", "must lie in (0, 1] (m)", crowd.radius)
    require(
        0.0 <= crowd.robot_radius <= MAX_ROBOT_RADIUS,
        f"{_PATH}.robot_radius",
        f"must lie in [0, {MAX_ROBOT_RADIUS:g}] (m; 0: the pedestrians do not see the robot)",
        crowd.robot_radius,
    )
    speeds = crowd.speed_range
    require(
        len(speeds) == 2 and 0.0 < speeds[0] <= speeds[1] <= MAX_SPEED,
        f"{_PATH}.speed_range",
        f"must be [low, high] with 0 < low ≤ high ≤ {MAX_SPEED:g} (m/s)",
        speeds,
    )
    require(
        0.0 < crowd.period <= MAX_PERIOD,
        f"{_PATH}.period",
        f"must lie in (0, {MAX_PERIOD:g}] (s)",
        crowd.period,
    )
    for name, meaning in CROWD_REQUIRED.items():
        if getattr(crowd, name) is None:
            raise ScenarioError(f"{_PATH}.{name}: required ({meaning})")
    require(
        crowd.sigma > 0.0,
        f"{_PATH}.sigma",
        "must be > 0 (a standard deviation in metres)",
        crowd.sigma,
    )
    require_sigma(crowd.sigma, f"{_PATH}.sigma")
    with rule_path(_PATH):  # r_o > 0, ε ∈ (0, 1], p_d ∈ (ε, 1): the ObstacleTask's rules
        check_obstacle_task(crowd.radius, crowd.epsilon, crowd.p_d)
    require(
        scenario.dimension == 2,
        _PATH,
        "crowds walk in the plane: it needs a 2-D plant (the omni robot)",
        type(scenario.plant).__name__,
    )
    require(
        scenario.perception is not None or not crowd.interactive,
        "scenario.perception",
        "an interactive crowd needs a perception section: the belief about the pedestrians "
        "must come from the sensor and the tracker",
        None,
    )
    spec = scenario.random_obstacles
    require(
        spec is None or (spec.count == 0 and not spec.count_range),
        "scenario.random_obstacles",
        "must draw nothing with a crowd (the pedestrians are the obstacles)",
        "a random field",
    )


def validate_crowd(scenario: Scenario) -> None:
    """The section's rules, and that the obstacle list is exactly the N pedestrian slots
    (appended by :func:`stt_drake.assembly.load_scenario`, which draws the scene)."""
    if scenario.crowd is None:
        return
    validate_crowd_section(scenario)
    count = scenario.crowd.pedestrians
    require(
        len(scenario.obstacles) == count,
        "scenario.obstacles",
        f"must be empty with a crowd: its {count} pedestrians are the obstacles, placed by "
        "the loader (stt_drake.assembly.load_scenario)",
        f"{len(scenario.obstacles)} obstacle slots",
    )
