"""The rules of the scenario's `guide:` section (:class:`stt_drake.config.schema.GuideConfig`),
checked by :func:`stt_drake.config.validate.validate` after the obstacles: a known planner,
rates and times that are finite, positive and bounded (a replan happens on a guide tick;
at most :data:`MAX_PREDICTION_KNOTS` prediction knots), a planning grid of at most
:data:`MAX_GRID_CELLS` cells, an avoidance level no looser than any obstacle's ε, and
non-negative distances and speeds (0 derives them). Every broken rule raises
:class:`stt_drake.config.schema.ScenarioError` naming ``scenario.guide.<field>``, the rule
and the value.

The guide may run with the continuous-time or the fixed-rate tube, with perception and with
any plant; a scenario without `guide:` runs the reactive tube as before. Non-finite
numbers are refused earlier, by :func:`stt_drake.config.limits.check_numbers`.
"""

import math

from stt_drake.config.limits import drawn_count, require
from stt_drake.config.schema import GuideConfig, Scenario

#: The route planners a guide can use.
GUIDE_PLANNERS = ("grid",)

#: Fastest guide rate (Hz): η moves at most this often.
MAX_GUIDE_RATE_HZ = 1000.0

#: Longest replan period, horizon and stall time (s).
MAX_GUIDE_SECONDS = 1e4

#: Most prediction knots (horizon/time_step): bounds the work of one prediction.
MAX_PREDICTION_KNOTS = 10_000

#: Most cells of the planning grid with a given resolution (:func:`guide_grid_cells`).
MAX_GRID_CELLS = 4_000_000

#: Margin (m) by which the box of start and target is grown on every side to size the grid.
GRID_MARGIN = 3.0

#: Relative slack of the ratio rules (replan_period·rate_hz ≥ 1, horizon/time_step knots,
#: cells per axis), so values written exactly at a bound are not refused by rounding.
_SLACK = 1e-12


def guide_grid_cells(start: list[float], target: list[float], resolution: float) -> float:
    """Cells of a grid of `resolution` metres over the box of `start` and `target` grown by
    :data:`GRID_MARGIN` on every side: Π_i ceil(side_i/resolution). An axis of more than
    :data:`MAX_GRID_CELLS` cells is counted as its exact ratio (possibly ∞), so no huge
    integer is formed."""
    cells: float = 1
    for a, b in zip(start, target, strict=True):
        ratio = (abs(b - a) + 2.0 * GRID_MARGIN) / resolution
        cells *= math.ceil(ratio * (1.0 - _SLACK)) if ratio <= MAX_GRID_CELLS else ratio
    return cells


def _count_text(cells: float) -> str:
    return str(int(cells)) if cells < 1e15 else f"{cells:.3g}"


def _require_in(value: float, path: str, low: str, high: float, unit: str) -> None:
    """`value` finite, > 0 (`low` ">") or ≥ 0 (`low` "≥"), and ≤ `high`."""
    above = value > 0.0 if low == ">" else value >= 0.0
    require(
        above and value <= high and math.isfinite(value),
        path,
        f"must be finite, {low} 0 and ≤ {high:g} ({unit})",
        value,
    )


def _require_non_negative(value: float, path: str, meaning: str) -> None:
    require(0.0 <= value < math.inf, path, f"must be finite and ≥ 0 ({meaning})", value)


def validate_guide(guide: GuideConfig, scenario: Scenario) -> None:
    """Every rule of the `guide:` section (module docstring); the obstacles are already
    valid (their ε in (0, 1])."""
    path = "scenario.guide"
    require(
        guide.planner in GUIDE_PLANNERS,
        f"{path}.planner",
        f"must be one of: {', '.join(GUIDE_PLANNERS)} (the route planner)",
        guide.planner,
    )
    _require_in(
        guide.rate_hz, f"{path}.rate_hz", ">", MAX_GUIDE_RATE_HZ, "Hz: η moves every 1/rate_hz s"
    )
    _require_in(guide.replan_period, f"{path}.replan_period", ">", MAX_GUIDE_SECONDS, "s")
    require(
        guide.replan_period * guide.rate_hz >= 1.0 - _SLACK,
        f"{path}.replan_period",
        f"must be ≥ 1/rate_hz = {1.0 / guide.rate_hz:g} s (a replan happens on a guide tick)",
        guide.replan_period,
    )
    _require_in(guide.horizon, f"{path}.horizon", ">", MAX_GUIDE_SECONDS, "s")
    require(
        0.0 < guide.time_step <= guide.horizon,
        f"{path}.time_step",
        f"must be finite, > 0 and ≤ horizon = {guide.horizon:g} s (the spacing of the "
        "prediction knots)",
        guide.time_step,
    )
    knots = guide.horizon / guide.time_step
    require(
        knots <= MAX_PREDICTION_KNOTS * (1.0 + _SLACK),
        f"{path}.time_step",
        f"at most {MAX_PREDICTION_KNOTS} prediction knots: horizon/time_step = "
        f"{guide.horizon:g}/{guide.time_step:g} = {knots:.6g} (bounded work per prediction; "
        "raise time_step or shorten horizon)",
        guide.time_step,
    )
    _validate_grid(guide, scenario, path)
    _validate_avoid_level(guide, scenario, path)
    require(
        guide.clearance is None or 0.0 <= guide.clearance < math.inf,
        f"{path}.clearance",
        "must be finite and ≥ 0 (m; leave it out for the tube's r_max − r_min)",
        guide.clearance,
    )
    _require_non_negative(guide.speed, f"{path}.speed", "m/s; 0 derives it")
    require(
        0.0 <= guide.max_wait <= guide.horizon,
        f"{path}.max_wait",
        f"must be finite, ≥ 0 and ≤ horizon = {guide.horizon:g} s (a wait is planned within "
        "the predictions)",
        guide.max_wait,
    )
    _require_non_negative(guide.lookahead, f"{path}.lookahead", "m; 0 derives it")
    _require_in(guide.stall_time, f"{path}.stall_time", ">", MAX_GUIDE_SECONDS, "s")
    _require_non_negative(guide.stall_progress, f"{path}.stall_progress", "m; 0 derives r_min")


def _validate_grid(guide: GuideConfig, scenario: Scenario, path: str) -> None:
    """`resolution` finite and ≥ 0; a given one keeps the grid within :data:`MAX_GRID_CELLS`."""
    _require_non_negative(guide.resolution, f"{path}.resolution", "m; 0 derives it")
    if guide.resolution == 0.0:
        return
    cells = guide_grid_cells(scenario.start, scenario.target, guide.resolution)
    require(
        cells <= MAX_GRID_CELLS,
        f"{path}.resolution",
        f"must keep the planning grid at most {MAX_GRID_CELLS} cells (the box of start and "
        f"target grown by {GRID_MARGIN:g} m on every side, ceil(side/resolution) cells per "
        f"axis): this resolution gives {_count_text(cells)} cells; coarsen it, or give 0 to "
        "derive it",
        guide.resolution,
    )


def _validate_avoid_level(guide: GuideConfig, scenario: Scenario, path: str) -> None:
    """`avoid_level` 0 (each obstacle's p_d) or in (0, 1), and not below any obstacle's ε:
    a route closer to an obstacle than the tube may go is one the tube cannot follow. A
    random field is held to its highest ε, so no draw can break the rule."""
    level, where = guide.avoid_level, f"{path}.avoid_level"
    require(
        0.0 <= level < 1.0,
        where,
        "must be 0 (each obstacle's own p_d) or in (0, 1) (a probability the route keeps "
        "from every obstacle)",
        level,
    )
    if level == 0.0:
        return
    spec = scenario.random_obstacles
    if spec is not None and drawn_count(scenario)[0] > 0 and len(spec.epsilon_range) == 2:
        high = spec.epsilon_range[1]
        require(
            level >= high,
            where,
            f"must be ≥ the random field's highest epsilon = {high:g} "
            "(scenario.random_obstacles.epsilon_range): a route planned closer to an obstacle "
            "than the tube may go is pointless (0 uses each obstacle's p_d)",
            level,
        )
    for j, obstacle in enumerate(scenario.obstacles):
        require(
            level >= obstacle.epsilon,
            where,
            f"must be ≥ epsilon = {obstacle.epsilon:g} of obstacle {j}: a route planned "
            "closer to it than the tube may go is pointless (0 uses each obstacle's p_d)",
            level,
        )
