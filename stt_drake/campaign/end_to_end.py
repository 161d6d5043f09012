"""The end-to-end campaign's runs: truth, sensor, tracker, tube, controller and plant all
simulated per run, collisions counted against the TRUE obstacles.

Run i loads the scenario with its own seed (:func:`stt_drake.campaign.sampling.run_seed`),
which draws the obstacles' process noise, the sensor's noise and dropouts (and the plant's
seeded disturbance) afresh (:func:`stt_drake.assembly.perception.add_perception`); the scenario
must have a `perception:` section. At every logged time k the run records:

* a collision of the output with obstacle j when ‖y(t_k) − O_j^true(t_k)‖ < r_o_j, and of
  the tube when ‖c(t_k) − O_j^true(t_k)‖ < r_o_j + r(t_k);
* the belief's calibration: whether the true centre lies in the belief's 95 % ellipsoid,
  (O − μ)ᵀ Σ⁻¹ (O − μ) ≤ χ²_n(0.95), counted over the times slot j holds a track.

A run that stops early (an error, a stalled integrator) is counted as colliding with every
obstacle from its last logged sample to the end: the collision frequencies stay upper
bounds of what complete runs would give.

A simulated run also records the crowd metrics against its true obstacles
(:data:`stt_drake.campaign.crowd_metrics.CROWD_KEYS`: `collided`, `min_distance_m`,
`comfort_violation_s`, ...), judged on the logged samples only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from stt_drake.campaign.crowd_metrics import crowd_record, is_crowd_record
from stt_drake.campaign.randomisation import has_run_story
from stt_drake.campaign.sampling import CHECKS, hit_intervals
from stt_drake.core import consistency
from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE

if TYPE_CHECKING:
    from stt_drake.config import Scenario, ScenarioText
    from stt_drake.runlog import RunLog


def logged_times(scenario: Scenario) -> int:
    """How many samples a complete run logs: t = 0, log_period, ..., duration."""
    return round(scenario.duration / scenario.log_period) + 1


def _truth(log: RunLog, steps: int) -> tuple[int, np.ndarray]:
    """(samples, the true centres (samples, m, n)) of the log's first `steps` samples."""
    samples = min(log.samples, steps)
    positions = log.rows("true_obstacle_position")[:samples]
    return samples, positions.reshape(samples, log.count, log.dimension)


def true_collisions(log: RunLog, steps: int) -> dict[str, np.ndarray]:
    """Per check, (m, steps) booleans: the output / the tube hit the true obstacle j at
    logged time k; samples past the log's end count as hits (module docstring)."""
    count = log.count
    samples, truth = _truth(log, steps)
    radius = np.asarray(log["obstacle_radius"], dtype=float)
    reach = {
        "output": (log.output[:samples], np.broadcast_to(radius, (samples, count))),
        "tube": (log.center[:samples], radius + np.maximum(log.radius[:samples], 0.0)[:, None]),
    }
    hits = {}
    for check, (point, limit) in reach.items():
        hit = np.ones((count, steps), dtype=bool)
        gap = point[:, None, :] - truth
        hit[:, :samples] = (np.einsum("tjk,tjk->tj", gap, gap) < limit**2).T
        hits[check] = hit
    return hits


def calibration_counts(log: RunLog, steps: int) -> tuple[list[int], list[int]]:
    """Per obstacle, (logged times with the true centre inside the belief's
    :data:`CALIBRATION_LEVEL` ellipsoid, logged times with a track)
    (:func:`stt_drake.core.consistency.calibration_counts`)."""
    samples, truth = _truth(log, steps)
    inside, tracked = consistency.calibration_counts(
        truth, log.mean[:samples], log.belief_covariance[:samples], log.active[:samples]
    )
    return inside.tolist(), tracked.tolist()


def end_to_end_run(
    schema: Scenario,
    index: int,
    seed: int,
    steps: int,
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE,
) -> dict[str, Any]:
    """Complete the parsed scenario `schema` with `seed`, simulate truth to plant, check.

    Record: ``{"run", "seed", "status"}`` with status ``error`` (the run could not be built
    or simulated; `reason`; every time counts as a collision) or ``simulated``; then
    ``output`` and ``tube`` ([start, stop) ranges of logged-time indices per obstacle, as
    the true-obstacle kind's), ``inside`` and ``tracked`` (calibration counts per
    obstacle), ``samples`` (logged), ``holds``, ``reached``, ``success``,
    ``stop_reason`` and ``stalls`` (as in metrics.json) and ``belief_updates`` (tracker
    updates that changed a track) and the crowd keys (comfort distance `comfort_distance`
    m, :mod:`stt_drake.campaign.crowd_metrics`).
    """
    from stt_drake.assembly import prepare_scenario
    from stt_drake.run import simulate

    record: dict[str, Any] = {"run": index, "seed": seed}
    count = len(schema.obstacles)
    try:
        scenario = prepare_scenario(schema, seed)
        result = simulate(scenario)
    except Exception as error:  # a crash on one run is a finding, not the end of the campaign
        every = [[[0, steps]] for _ in range(count)]
        return {
            **record,
            "status": "error",
            "reason": f"{type(error).__name__}: {error}",
            "output": every,
            "tube": every,
        }
    log = result.log
    hits = true_collisions(log, steps)
    inside, tracked = calibration_counts(log, steps)
    return {
        **record,
        "status": "simulated",
        **{check: hit_intervals(hits[check][None])[0] for check in CHECKS},
        "inside": inside,
        "tracked": tracked,
        "samples": int(log.samples),
        "holds": bool(result.metrics.holds),
        "reached": bool(result.metrics.reached),
        "success": bool(result.success),
        "stop_reason": result.metrics.stop_reason,
        "stalls": result.metrics.stalls,
        "belief_updates": len(result.metrics.belief_discontinuities),
        **crowd_record(log, comfort_distance),
    }


def end_to_end_task(
    source: ScenarioText,
    steps: int,
    guide: bool,
    comfort_distance: float,
    runs: Sequence[tuple[int, int]],
) -> list[dict[str, Any]]:
    """One executor task: the records of a batch of (run index, seed), the YAML parsed once
    for the batch (the schema holds Drake objects that do not pickle, so the text travels);
    `guide` False drops the scenario's guide section."""
    schema = source.parse(guide)
    return [end_to_end_run(schema, index, seed, steps, comfort_distance) for index, seed in runs]


def is_end_to_end_record(record: dict[str, Any], count: int, steps: int) -> bool:
    """Whether a record read back from ``runs.jsonl`` has the shape :func:`end_to_end_run`
    gives for `count` obstacles and `steps` logged times (`stop_reason`, `stalls` and the
    crowd keys may be missing, as in records of older versions)."""
    status = record.get("status")
    for check in CHECKS:
        ranges = record.get(check)
        if not (isinstance(ranges, list) and len(ranges) == count):
            return False
        for per_obstacle in ranges:
            if not all(
                isinstance(r, list) and len(r) == 2 and 0 <= r[0] < r[1] <= steps
                for r in per_obstacle
            ):
                return False
    if status == "error":
        return isinstance(record.get("reason"), str)
    if status != "simulated":
        return False
    counts = [record.get("inside"), record.get("tracked")]
    return (
        all(isinstance(c, list) and len(c) == count for c in counts)
        and all(isinstance(record.get(key), bool) for key in ("holds", "reached", "success"))
        and isinstance(record.get("belief_updates"), int)
        and has_run_story(record)
        and is_crowd_record(record, count)
    )


def end_to_end_failed(record: dict[str, Any]) -> bool:
    """Whether a run collided with a true obstacle (output) or did not simulate."""
    return record["status"] == "error" or any(record["output"])
