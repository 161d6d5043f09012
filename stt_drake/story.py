"""What happened during a run beyond the guarantees: the assumptions the scenario broke,
the belief discontinuities, the stalls and, with a tracker, how consistent and calibrated
each track was (metrics.json keys `assumptions`, `belief_discontinuities`, `stalls` and
`tracks`, the rule of the stalls in
:mod:`stt_drake.core.progress`; the reach story is :func:`stt_drake.core.invariants.reach_story`,
the recovery episodes :class:`stt_drake.core.invariants.RecoveryTracker`, watched at every
step).

Pure numpy on the run log (any mapping with the :mod:`stt_drake.runlog` layout, read
through :class:`~stt_drake.runlog.RunLog`), except :func:`target_separation_violations`,
which reads the scenario before a run.

Assumption 3 of the paper: after some time t_1, P(‖c(t) − O_j(t)‖ ≥ r_o_j + r_min) ≥ p_d_j
for every obstacle j and t ≥ t_1 — the obstacles eventually leave the tube's centre, in
particular the target, alone. The tube needs it to stay in the target set; a scenario that
breaks it can make the tube leave T again after t_c.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from stt_drake.config import Scenario
from stt_drake.config.assumptions import (
    SEPARATION_CHECKPOINTS,
    VOIDED_CLAIM,
    VOIDED_CLAIM_TEXT,
    target_separation,
)
from stt_drake.core.consistency import (
    CALIBRATION_WARNING,
    CONSISTENCY_FIELDS,
    OVERCONFIDENT_SHARE,
    calibration_inside,
    calibration_upper_bound,
    run_nis_bounds,
)
from stt_drake.runlog import RunLog

#: Relative slack on the rate bounds when looking for a belief discontinuity (a smooth
#: motion at exactly its bound must not count).
RATE_SLACK = 1e-6
#: Absolute slack on a mean change (m) and on a σ change (m) between two samples.
MEAN_SLACK_M = 1e-9
SIGMA_SLACK_M = 1e-12


def belief_discontinuities(log: Mapping[str, np.ndarray]) -> list[dict[str, Any]]:
    """Belief jumps between consecutive samples k − 1, k that the motion model cannot make.

    Obstacle j jumps when ‖μ_k − μ_{k−1}‖ > v̄_j·Δt·(1 + RATE_SLACK) + MEAN_SLACK_M or
    |σ_k − σ_{k−1}| > s̄_j·Δt·(1 + RATE_SLACK) + SIGMA_SLACK_M, with v̄_j, s̄_j the logged
    `mean_speed_bound` and `sigma_rate_bound` (m/s, steps excluded).

    A run with a tracker (its log has `belief_updates`, the tracker's count of track
    changes per obstacle) instead lists every tracker update that changed a track — a
    correction, a birth or a loss — at the first logged sample after it (the motion model
    does not bound a tracked belief).

    Returns:
        One record per jump, in time order: `t` (t_k), `obstacle` (j), `kind` ("step" of
        the scripted belief, or a tracker's "correction", "birth" or "loss"),
        `mean_jump_m` (‖Δμ‖) and `sigma_jump_m` (Δσ, signed) between the samples (0 for a
        birth or loss: the slot holds no belief on one side), `q_before` and `q_after`
        (the tube's q_j(c) = `avoid_probability` at k − 1 and k).
    """
    run = RunLog.of(log)
    t = run.t
    if t.size < 2:
        return []
    dt = np.diff(t)[:, None]
    mean_jump = np.linalg.norm(np.diff(run.mean, axis=0), axis=2)
    sigma_jump = np.diff(run.sigma, axis=0)
    kind = np.full(mean_jump.shape, "step", dtype=object)
    if "belief_updates" in run:
        jumped = np.diff(run.rows("belief_updates"), axis=0) > 0.0
        before, after = run.active[:-1], run.active[1:]
        kind[:] = "correction"
        kind[~before & after], kind[before & ~after] = "birth", "loss"
        both = before & after
        mean_jump, sigma_jump = np.where(both, mean_jump, 0.0), np.where(both, sigma_jump, 0.0)
    else:
        mean_bound = run.mean_speed_bound[None, :]
        sigma_bound = run.sigma_rate_bound[None, :]
        jumped = (mean_jump > mean_bound * dt * (1.0 + RATE_SLACK) + MEAN_SLACK_M) | (
            np.abs(sigma_jump) > sigma_bound * dt * (1.0 + RATE_SLACK) + SIGMA_SLACK_M
        )
    q = run.avoid_probability
    records = []
    for step, j in zip(*np.nonzero(jumped), strict=True):
        k = int(step) + 1
        records.append(
            {
                "t": float(t[k]),
                "obstacle": int(j),
                "kind": str(kind[step, j]),
                "mean_jump_m": float(mean_jump[step, j]),
                "sigma_jump_m": float(sigma_jump[step, j]),
                "q_before": float(q[k - 1, j]),
                "q_after": float(q[k, j]),
            }
        )
    return records


def separation_after_entry(
    log: Mapping[str, np.ndarray], final_entry_s: float | None
) -> list[dict[str, Any]]:
    """Assumption 3 on the log: after the final entry into the target set, the tube's own
    q_j(c) (`avoid_probability`, buffered radius r_o + r_min) must stay ≥ p_d_j.

    Returns:
        One `assumptions` record per obstacle whose minimum q_j after `final_entry_s` is
        below p_d_j (none when the run never settles in the target set): `assumption`
        ("3"), `obstacle`, `t` (when the minimum occurred), `value` (that q_j),
        `required` (p_d_j), `claim` ("(i)") and `message`.
    """
    if final_entry_s is None:
        return []
    run = RunLog.of(log)
    t = run.t
    after = t >= final_entry_s
    if not np.any(after):
        return []
    q = run.avoid_probability[after]
    p_d = run.p_d[after]
    records = []
    for j in range(q.shape[1]):
        k = int(np.argmin(q[:, j] - p_d[:, j]))
        if q[k, j] < p_d[k, j]:
            when = float(t[after][k])
            records.append(
                {
                    "assumption": "3",
                    "obstacle": j,
                    "t": when,
                    "value": float(q[k, j]),
                    "required": float(p_d[k, j]),
                    "claim": VOIDED_CLAIM,
                    "message": (
                        f"obstacle {j} came within p_d of the tube's centre after it settled in "
                        f"the target set (t_c = {final_entry_s:.2f} s): q = {q[k, j]:.6g} < "
                        f"p_d = {p_d[k, j]:.6g} at t = {when:.2f} s, so Assumption 3 does "
                        f"not hold in this run: {VOIDED_CLAIM_TEXT}"
                    ),
                }
            )
    return records


def target_separation_violations(
    scenario: Scenario, checkpoints: int = SEPARATION_CHECKPOINTS
) -> list[dict[str, Any]]:
    """Assumption 3 at the target, checked on the scenario before a run.

    For each obstacle, q_j(η, t) = P(‖η − O_j(t)‖ ≥ r_o_j + r_min) is evaluated at
    `checkpoints` times evenly over [0, duration] (η: the scenario's final target,
    :func:`stt_drake.config.assumptions.target_separation`). An obstacle for which
    q_j(η, t) < p_d_j still at the last checkpoint is within p_d of the target at the end,
    so no t_1 exists: the assumption cannot hold, and claim (i) of Theorem 3.2 is void.
    (One that is there at every checkpoint is recorded the same way; a strict scenario
    refuses it when it is loaded, and a random field's draws are kept only if they satisfy
    it, see :class:`stt_drake.config.RandomObstacles`.)

    Returns:
        One `assumptions` record per such obstacle: `assumption` ("3"), `obstacle`, `t`
        (the last checkpoint, = duration), `value` (q_j(η, t)), `required` (p_d_j), `claim`
        ("(i)", the claim of Theorem 3.2 it voids) and `message` (which also says since
        when it has been below p_d).
    """
    if not scenario.obstacles:
        return []
    separation = target_separation(scenario, checkpoints)
    times, q, p_d = separation.times, separation.q, separation.p_d
    records = []
    for j in np.flatnonzero(q[-1] < p_d):
        clear = np.flatnonzero(q[:, j] >= p_d[j])
        since = float(times[0 if clear.size == 0 else clear[-1] + 1])
        records.append(
            {
                "assumption": "3",
                "obstacle": int(j),
                "t": float(times[-1]),
                "value": float(q[-1, j]),
                "required": float(p_d[j]),
                "claim": VOIDED_CLAIM,
                "message": (
                    f"obstacle {j} is within p_d of the target at the end (explicit obstacle): "
                    f"q = {q[-1, j]:.6g} < p_d = {p_d[j]:.6g} from t = {since:.2f} s to the "
                    f"end ({times[-1]:.2f} s), so Assumption 3 cannot hold: "
                    f"{VOIDED_CLAIM_TEXT}"
                ),
            }
        )
    return records


def stall_cause(stall: Mapping[str, Any]) -> str:
    """The `stop_reason` cause of a stall episode that lasts to the end (a `stalls` record
    of :func:`stt_drake.core.progress.find_stalls`)."""
    position = ", ".join(f"{x:.2f}" for x in stall["position"])
    return (
        "stall: the tube centre made no progress toward its attraction point from "
        f"t = {stall['start_s']:.2f} s to the end (c = [{position}], "
        f"{stall['distance_m']:.2f} m from it)"
    )


def track_consistency(log: Mapping[str, np.ndarray], confidence: float) -> list[dict[str, Any]]:
    """Per obstacle of a run with a monitored tracker (its log has `tracker_consistency`,
    :class:`stt_drake.systems.perception.ObstacleTracker`'s `consistency` output, and
    `true_obstacle_position`); [] otherwise. metrics.json key `tracks`.

    Returns:
        One record per obstacle: `index`; `calibration_95` (fraction of the logged times
        with a track at which the TRUE centre lay in the belief's 95 % ellipsoid,
        :func:`stt_drake.core.consistency.calibration_counts`; null without a tracked time)
        and `tracked_samples`; `nis_updates` (corrections), `nis_mean` (null without one)
        and `nis_interval` (the interval of the mean NIS of a consistent track at
        `confidence`, :func:`stt_drake.core.consistency.run_nis_bounds`);
        `nis_mean_above_interval` (the whole-run test failed high: informative; an adaptive
        filter on a manoeuvring obstacle is above it by construction, it reacts to high
        NIS); `events` — the episodes in which the window test was above its interval
        (the track overconfident): `count`, `first_s` (null: none), `duration_s` (an
        episode still open at the end lasts to the last logged time) and `share` (that
        duration over the tracked time; a consistent track's is about (1 − c)/2);
        `max_noise_scale` (the largest adaptive scale s, 1: never raised); `warning` (a
        sentence, or null when the belief was consistent and calibrated: share ≤
        :data:`~stt_drake.core.consistency.OVERCONFIDENT_SHARE` and the calibration's 99 %
        upper bound `calibration_95_upper_99` ≥
        :data:`~stt_drake.core.consistency.CALIBRATION_WARNING`: one run's logged times are
        correlated, worth `calibration_effective_samples` independent ones,
        :func:`~stt_drake.core.consistency.calibration_upper_bound`).
    """
    run = RunLog.of(log)
    if "tracker_consistency" not in run or "true_obstacle_position" not in run or not run.samples:
        return []
    count, n = run.count, run.dimension
    truth = run.rows("true_obstacle_position").reshape(run.samples, count, n)
    inside, active = calibration_inside(truth, run.mean, run.belief_covariance, run.active)
    tracked = active.sum(axis=0)
    stats = run.rows("tracker_consistency")[-1].reshape(count, CONSISTENCY_FIELDS)
    end = float(run.t[-1])
    step = float(np.median(np.diff(run.t))) if run.samples > 1 else 0.0
    records = []
    for j in range(count):
        total, updates, events, first, duration, since, scale = stats[j]
        if np.isfinite(since):
            duration += end - since
        mean = total / updates if updates else None
        interval = run_nis_bounds(int(updates), n, confidence) if updates else None
        series = inside[active[:, j], j]
        calibration = float(series.mean()) if tracked[j] else None
        upper, effective = calibration_upper_bound(series)
        over = bool(mean is not None and mean > interval[1])
        share = duration / (tracked[j] * step) if tracked[j] and step > 0.0 else 0.0
        problems = []
        if share > OVERCONFIDENT_SHARE:
            problems.append(
                f"overconfident (NIS window test above its {confidence:g} interval) for "
                f"{duration:.2f} s, {share:.0%} of its tracked time, in {int(events)} "
                f"episodes from {first:.2f} s; NIS mean {mean:.2f}"
            )
        if calibration is not None and upper < CALIBRATION_WARNING:
            problems.append(
                f"true centre in its 95 % ellipsoid at {calibration:.3f} of the tracked times "
                f"(99 % upper bound {upper:.3f} < {CALIBRATION_WARNING:g}, the times worth "
                f"{effective:.0f} independent samples)"
            )
        records.append(
            {
                "index": j,
                "calibration_95": calibration,
                "calibration_95_upper_99": upper if tracked[j] else None,
                "calibration_effective_samples": effective,
                "tracked_samples": int(tracked[j]),
                "nis_updates": int(updates),
                "nis_mean": mean,
                "nis_interval": None if interval is None else list(interval),
                "nis_mean_above_interval": over,
                "events": {
                    "count": int(events),
                    "first_s": float(first) if np.isfinite(first) else None,
                    "duration_s": float(duration),
                    "share": float(share),
                },
                "max_noise_scale": float(max(scale, 1.0)),
                "warning": f"track {j}: " + "; ".join(problems) if problems else None,
            }
        )
    return records
