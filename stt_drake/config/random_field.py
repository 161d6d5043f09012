"""Random obstacle fields: a scenario's ``random_obstacles`` drawn into obstacles."""

import math

import numpy as np

from stt_drake.config.covariance import SIGMA_MIN
from stt_drake.config.schema import AssumptionError, Obstacle, RandomObstacles, Scenario
from stt_drake.config.validate import require, require_range, require_vector
from stt_drake.core.motion import Oscillation, oscillation_positions
from stt_drake.core.probability import avoid_probability
from stt_drake.core.rules import GAUSSIAN_P_D_RULE

#: Draws tried per obstacle before the field is refused; a field that has placed none
#: after this many draws is refused at once (its region leaves almost no room).
ATTEMPTS_PER_OBSTACLE = 1000


def has_random_field(spec: RandomObstacles | None) -> bool:
    """Whether `spec` draws any obstacle: a `count` > 0 or a `count_range`."""
    return spec is not None and (spec.count > 0 or bool(spec.count_range))


def draws_obstacles(scenario: Scenario) -> bool:
    """Whether each seed draws the scenario's obstacles afresh: a random field, or a crowd
    (its pedestrians are drawn from the crowd's and the scenario's seeds)."""
    return has_random_field(scenario.random_obstacles) or scenario.crowd is not None


def expand_random_obstacles(scenario: Scenario) -> None:
    """Append the `random_obstacles` draws to `scenario.obstacles`.

    Reproducible: the draws depend only on (random_obstacles.seed, scenario seed). At most
    :data:`ATTEMPTS_PER_OBSTACLE` draws per obstacle are tried (AssumptionError when they
    do not place them all).
    """
    spec, path = scenario.random_obstacles, "scenario.random_obstacles"
    if spec is not None:
        require(spec.count >= 0, f"{path}.count", "must be ≥ 0", spec.count)
    if not has_random_field(spec):
        return
    n = scenario.dimension
    if spec.count_range:
        require(spec.count == 0, f"{path}.count", "give count or count_range, not both", spec.count)
        require_range(spec.count_range, f"{path}.count_range", 1, math.inf)
    require_vector(spec.region_min, n, f"{path}.region_min")
    require_vector(spec.region_max, n, f"{path}.region_max")
    require(
        all(low < high for low, high in zip(spec.region_min, spec.region_max, strict=True)),
        f"{path}.region_max",
        "must exceed region_min on every axis",
        spec.region_max,
    )
    require_range(spec.sigma_range, f"{path}.sigma_range", SIGMA_MIN, math.inf)
    require_range(spec.epsilon_range, f"{path}.epsilon_range", 1e-9, 1.0)
    require(
        spec.epsilon_range[1] < spec.p_d <= 1.0,
        f"{path}.p_d",
        "must lie in (epsilon_range high, 1]",
        spec.p_d,
    )
    require(spec.p_d < 1.0, f"{path}.p_d", GAUSSIAN_P_D_RULE, spec.p_d)
    require_range(spec.amplitude_range, f"{path}.amplitude_range", 0.0, math.inf)
    require_range(spec.frequency_range_hz, f"{path}.frequency_range_hz", 0.0, math.inf)
    rng = np.random.default_rng([spec.seed, scenario.seed])
    count = (
        int(rng.integers(spec.count_range[0], spec.count_range[1] + 1))
        if spec.count_range
        else spec.count
    )
    checkpoints = np.linspace(0.0, scenario.duration, 200)
    anchors = np.array([scenario.start, scenario.target], dtype=float)
    accepted: list[Obstacle] = []
    for attempt in range(ATTEMPTS_PER_OBSTACLE * count):
        if len(accepted) == count or (attempt == ATTEMPTS_PER_OBSTACLE and not accepted):
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
        motion = candidate.motion
        path_points = oscillation_positions(
            np.asarray(motion.center),
            np.asarray(motion.amplitude),
            2.0 * np.pi * motion.frequency_hz,
            np.asarray(motion.phase),
            checkpoints[:, None],
        )
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
    if len(accepted) < count:
        where = f"{path}.count_range" if spec.count_range else f"{path}.count"
        raise AssumptionError(
            f"{where}: could not place that many obstacles clear of start and target; "
            f"enlarge the region (got {count!r})"
        )
    scenario.obstacles = scenario.obstacles + accepted
