"""Crowd-navigation metrics (:mod:`stt_drake.core.crowd_metrics`) of a logged run against its TRUE
obstacles, as run-record keys, and their summary over many runs — one place for the
randomisation and end-to-end campaigns and for ``stt-drake compare`` (which sits above
the campaigns in the import layers and imports this module).

**The true obstacles of a run.** With a ``perception:`` section the diagram logs the
TrueObstacles system's ``true_obstacle_position`` (scripted mean plus the drawn process
deviation, :class:`stt_drake.systems.perception.TrueObstacles`), the same member the
end-to-end campaign counts collisions against; it is used whenever the log has it. Without
perception the world is the scripted one: the truth is the obstacles' mean μ_j(t) (no
deviation), which is the belief mean the scripted belief source logs (every slot active).
The belief-sampling check of the true-obstacle campaign (O_j = μ_j + σ_j ξ_j) is a different
question and stays in the campaign's own `worst_collision_frequency`.

**Per-run keys** (:data:`CROWD_KEYS`, :func:`crowd_record`): `collided` (any logged time
with ‖y − O_j‖ < r_o_j for some j), `first_collision_s` (null if none),
`obstacle_collisions` (per obstacle j: collided with it at some logged time),
`obstacle_epsilon` (ε_j of the run's obstacles, for the check against 1 − ε_j),
`min_distance_m`, `comfort_violation_s`, `path_length_m`, `time_to_goal_s` (the output's
reach-and-stay time on the logged samples, null if never). A run that stops early is
judged on its logged samples only.

**Summary** (:func:`crowd_summary`, over the simulated runs that have the keys; a record
written before them has none and is left out): `crowd_runs`, `comfort_distance_m`,
`collision_rate` (runs with a true collision / runs), `min_distance_m` {p5, p50},
`comfort_violation_s` {p50, p90}, `path_length_mean_m`, `obstacle_collision_frequency`
(:func:`obstacle_frequencies`) and `collision_within_allowed`.

**The check against 1 − ε_j.** Per obstacle index j: the fraction of runs that collided
with obstacle j at *some* logged time, against the allowed collision probability 1 − ε_j
(averaged over the runs when ε_j is drawn per run). The paper bounds the collision
probability at each time, P(‖y(t) − O_j(t)‖ < r_o_j) ≤ 1 − ε_j; the probability of a
collision at any time is at least the worst single-time one, so a per-run frequency within
1 − ε_j is a conservative pass (a frequency above it is not by itself a violation).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import numpy as np

from stt_drake.campaign.folder import is_number
from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE, crowd_metrics

if TYPE_CHECKING:
    from stt_drake.runlog import RunLog

#: The crowd-navigation keys of a run record (module docstring).
CROWD_KEYS = (
    "collided",
    "first_collision_s",
    "obstacle_collisions",
    "obstacle_epsilon",
    "min_distance_m",
    "comfort_violation_s",
    "path_length_m",
    "time_to_goal_s",
)
#: Where the log holds the true obstacle centres (a run with perception).
TRUTH_KEY = "true_obstacle_position"


def true_centres(log: RunLog) -> np.ndarray:
    """(T, m, n) the run's true obstacle centres (module docstring): the logged
    ``true_obstacle_position``, else the scripted means μ_j(t); NaN where an obstacle does
    not exist (a recorded track outside its span: its belief slot is inactive)."""
    if TRUTH_KEY in log:
        return log.rows(TRUTH_KEY).reshape(log.samples, log.count, log.dimension)
    return np.where(np.asarray(log.active, dtype=bool)[..., None], log.mean, np.nan)


def crowd_record(
    log: RunLog, comfort_distance: float = DEFAULT_COMFORT_DISTANCE, robot_radius: float = 0.0
) -> dict[str, Any]:
    """The :data:`CROWD_KEYS` of the run `log` against its true obstacles."""
    metrics = crowd_metrics(
        log.t,
        log.output,
        true_centres(log),
        np.asarray(log["obstacle_radius"], dtype=float).reshape(log.count),
        log.target,
        log.target_set_radius,
        comfort_distance,
        robot_radius,
    )
    epsilon = np.asarray(log["epsilon"], dtype=float).reshape(log.count)
    record = {**asdict(metrics), "obstacle_epsilon": [float(e) for e in epsilon]}
    return {key: record[key] for key in CROWD_KEYS}


def is_crowd_record(record: dict[str, Any], count: int | None = None) -> bool:
    """Whether `record` has none of :data:`CROWD_KEYS` (a record written before them), or
    all of them with their types (`count` obstacles, when given)."""
    present = [key in record for key in CROWD_KEYS]
    if not any(present):
        return True
    if not all(present):
        return False
    flags, epsilon = record["obstacle_collisions"], record["obstacle_epsilon"]
    optional = (record["first_collision_s"], record["time_to_goal_s"])
    return (
        isinstance(record["collided"], bool)
        and isinstance(flags, list)
        and all(isinstance(f, bool) for f in flags)
        and isinstance(epsilon, list)
        and len(epsilon) == len(flags)
        and all(is_number(e) for e in epsilon)
        and (count is None or len(flags) == count)
        and record["collided"] == any(flags)
        and all(v is None or is_number(v) for v in optional)
        and all(is_number(record[k]) for k in ("min_distance_m", "comfort_violation_s"))
        and is_number(record["path_length_m"])
    )


def has_crowd(record: dict[str, Any]) -> bool:
    """Whether a run record carries the crowd keys (simulated, written since they exist)."""
    return record.get("status", "simulated") == "simulated" and "collided" in record


def obstacle_frequencies(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per obstacle index j over the `records` that have obstacle j: `index`, `runs`,
    `collisions` (runs that collided with j), `frequency`, `allowed_collision_probability`
    (the mean of 1 − ε_j over those runs) and `within_allowed` (frequency ≤ allowed)."""
    count = max((len(r["obstacle_collisions"]) for r in records), default=0)
    entries = []
    for j in range(count):
        having = [r for r in records if len(r["obstacle_collisions"]) > j]
        collisions = sum(r["obstacle_collisions"][j] for r in having)
        allowed = float(np.mean([1.0 - r["obstacle_epsilon"][j] for r in having]))
        frequency = collisions / len(having)
        entries.append(
            {
                "index": j,
                "runs": len(having),
                "collisions": collisions,
                "frequency": frequency,
                "allowed_collision_probability": allowed,
                "within_allowed": frequency <= allowed,
            }
        )
    return entries


def collision_check(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The per-obstacle true-collision check of `records` (crowd records): the keys
    `obstacle_collision_frequency` (:func:`obstacle_frequencies`) and
    `collision_within_allowed` (every obstacle within its 1 − ε_j; None without records)."""
    frequencies = obstacle_frequencies(records)
    return {
        "obstacle_collision_frequency": frequencies,
        "collision_within_allowed": all(e["within_allowed"] for e in frequencies)
        if records
        else None,
    }


def _quantiles(values: Sequence[float], levels: dict[str, float]) -> dict[str, float] | None:
    """{name: the `levels[name]` percentile of `values`} (None when there are none)."""
    if not values:
        return None
    data = np.asarray(values, dtype=float)
    return {name: float(np.percentile(data, q)) for name, q in levels.items()}


def crowd_summary(
    records: Sequence[dict[str, Any]], comfort_distance: float = DEFAULT_COMFORT_DISTANCE
) -> dict[str, Any]:
    """The summary keys of the runs in `records` that have the crowd keys (module
    docstring); every rate and percentile is None when none has them."""
    crowd = [r for r in records if has_crowd(r)]
    count = len(crowd)
    return {
        "crowd_runs": count,
        "comfort_distance_m": comfort_distance,
        "collision_rate": sum(r["collided"] for r in crowd) / count if count else None,
        "min_distance_m": _quantiles([r["min_distance_m"] for r in crowd], {"p5": 5, "p50": 50}),
        "comfort_violation_s": _quantiles(
            [r["comfort_violation_s"] for r in crowd], {"p50": 50, "p90": 90}
        ),
        "path_length_mean_m": float(np.mean([r["path_length_m"] for r in crowd]))
        if count
        else None,
        **collision_check(crowd),
    }


def crowd_line(summary: dict[str, Any]) -> str:
    """The printed line of a campaign summary's crowd keys."""
    if not summary.get("crowd_runs"):
        return "  true-obstacle crowd metrics: none (no run recorded them)"
    distance, comfort = summary["min_distance_m"], summary["comfort_violation_s"]
    within = "within" if summary["collision_within_allowed"] else "NOT within"
    return (
        f"  true obstacles over {summary['crowd_runs']} runs: collision rate "
        f"{summary['collision_rate']:.3f} (per obstacle {within} 1 − ε_j); min distance p5 "
        f"{_metres(distance['p5'])}, p50 {_metres(distance['p50'])}; closer than "
        f"{summary['comfort_distance_m']:g} m: p50 {comfort['p50']:.2f} s, p90 "
        f"{comfort['p90']:.2f} s"
    )


def _metres(value: float) -> str:
    return f"{value:.3f} m" if math.isfinite(value) else str(value)
