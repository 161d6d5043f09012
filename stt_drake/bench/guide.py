"""`stt-drake bench`, the guide's rows: how long one replan takes and what a guide costs a
closed loop.

1. ``guide_plan_ms``: one whole replan — the scripted forecast over the horizon, the
   level-set radii and the space-time A* (:meth:`stt_drake.core.guide.RoutePlanner.plan`)
   — on 50-obstacle fields: ``omni_cluttered_50`` (2D) and ``uav_cluttered``'s random
   field drawn with 50 obstacles instead of its 40 (3D), from points along the straight
   line at times 0 … 40 s; median and 99th percentile (ms) over those plans;
2. ``guided_over_unguided``: the real-time factor of ``liveness_clutter_2d`` with its guide
   over the same draw without it, for draws 0 … 7 in interleaved pairs: the median ratio
   over the draws, and the worst draw's. One draw is not a measurement: the ratio is set
   by how long each tube moves (a guided tube goes round what the reactive one goes
   through or stalls in), and ranges over ~0.75-1.0 from draw to draw.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from importlib.resources import files
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from stt_drake.core.guide import Route, RoutePlanner, ScriptedForecast

#: The fields the replan is timed on (packaged scenario names) by dimension.
PLAN_FIELDS = {"2d": "omni_cluttered_50", "3d": "uav_cluttered"}
#: Obstacles in the fields the replan is timed on.
PLAN_COUNT = 50
#: The guided closed loop (packaged scenario) and the draws it is timed on.
GUIDED_LOOP, GUIDED_SEEDS = "liveness_clutter_2d", tuple(range(8))


@dataclass(frozen=True)
class PlanWorkload:
    """One dimension's replan workload: the planner, the scripted forecast of the field's
    obstacles, its knot offsets, the start and goal, and the field's obstacle count."""

    planner: RoutePlanner
    forecast: ScriptedForecast
    knots: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    count: int

    def plan(self, k: int, plans: int) -> Route:
        """Replan `k` of `plans`: from the point 0.6·k/plans of the way to the goal, at
        t = 40·k/plans s."""
        t0 = 40.0 * k / plans
        origin = self.start + (self.goal - self.start) * (0.6 * k / plans)
        return self.planner.plan(origin, self.goal, t0, self.forecast(t0 + self.knots))


def plan_workload(key: str) -> PlanWorkload:
    """The replan workload of :data:`PLAN_FIELDS`[`key`] ("2d" or "3d") with
    :data:`PLAN_COUNT` obstacles and the default guide, after one warm-up plan that loads
    the compiled search."""
    from stt_drake.assembly import prepare_scenario
    from stt_drake.assembly.guide import guide_settings
    from stt_drake.assembly.laws import make_tube_law
    from stt_drake.config import GuideConfig, parse_schema
    from stt_drake.core.belief import ObstacleTask
    from stt_drake.core.guide import RoutePlanner, ScriptedForecast

    name = PLAN_FIELDS[key]
    text = (files("stt_drake.diagrams") / f"{name}.yaml").read_text()
    schema = parse_schema(text, name)
    schema.random_obstacles.count = PLAN_COUNT
    schema.guide = GuideConfig()
    scenario = prepare_scenario(schema)
    law = make_tube_law(scenario)
    settings = guide_settings(scenario, law)
    task = ObstacleTask.of(scenario.obstacles)
    workload = PlanWorkload(
        planner=RoutePlanner(settings, task.radius, task.epsilon, law.r_min, scenario.dimension),
        forecast=ScriptedForecast(scenario.obstacles, scenario.dimension),
        knots=settings.knots,
        start=np.asarray(scenario.start, dtype=float),
        goal=np.asarray(scenario.target, dtype=float),
        count=len(scenario.obstacles),
    )
    workload.plan(0, 1)  # warm-up
    return workload


def bench_guide_plans(plans: int = 60) -> dict[str, Any]:
    """Per dimension: ``median`` and ``p99`` of one replan (ms, wall clock, after a warm-up
    plan that loads the compiled search), its ``expansions`` median and the field's
    obstacle ``count``."""
    results: dict[str, Any] = {}
    for key in PLAN_FIELDS:
        workload = plan_workload(key)
        times, expansions = [], []
        for k in range(plans):
            begin = time.perf_counter()
            route = workload.plan(k, plans)
            times.append(1e3 * (time.perf_counter() - begin))
            expansions.append(route.expansions)
        results[key] = {
            "median": statistics.median(times),
            "p99": float(np.percentile(times, 99)),
            "expansions": statistics.median(expansions),
            "count": workload.count,
            "plans": plans,
        }
    return results


def bench_guided_loop(pairs: int = 1, duration: float | None = None) -> dict[str, Any]:
    """Real-time factors of :data:`GUIDED_LOOP` with and without its guide on each of
    :data:`GUIDED_SEEDS` (simulated for at most `duration` seconds), `pairs` interleaved
    pairs per draw: per draw the median ratio guided / unguided; over the draws the median
    (``ratio``) and the smallest (``worst_ratio``, its draw ``worst_seed``)."""
    from stt_drake.assembly import prepare_scenario
    from stt_drake.config import parse_schema
    from stt_drake.run import simulate

    text = (files("stt_drake.diagrams") / f"{GUIDED_LOOP}.yaml").read_text()
    factors: dict[str, list[float]] = {"guided": [], "unguided": []}
    ratios: dict[int, float] = {}
    for seed in GUIDED_SEEDS:
        pair_ratios = []
        for _ in range(pairs):
            pair = {}
            for mode in ("guided", "unguided"):
                schema = parse_schema(text, GUIDED_LOOP)
                if mode == "unguided":
                    schema.guide = None
                if duration is not None:
                    schema.duration = min(schema.duration, duration)
                pair[mode] = simulate(prepare_scenario(schema, seed)).metrics.realtime_factor
                factors[mode].append(pair[mode])
            pair_ratios.append(pair["guided"] / pair["unguided"])
        ratios[seed] = statistics.median(pair_ratios)
    worst = min(ratios, key=ratios.__getitem__)
    return {
        "guided_realtime_factor": statistics.median(factors["guided"]),
        "unguided_realtime_factor": statistics.median(factors["unguided"]),
        "ratio": statistics.median(ratios.values()),
        "worst_ratio": ratios[worst],
        "worst_seed": worst,
        "ratios": {str(seed): ratio for seed, ratio in ratios.items()},
    }
