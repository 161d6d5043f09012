"""Crowd-navigation metrics of one run against the TRUE obstacle (pedestrian) centres.

What people who work on crowd navigation report per run, computed from logged samples
(t_k, y(t_k), O_j(t_k)): collision, time to goal, path length, minimum distance to a
pedestrian and the time spent closer than a comfort distance. Pure numpy.

Conventions:

* **Surface distance** d_j(t) = ‖y(t) − O_j(t)‖ − r_o_j − r_robot (m). The paper's task
  treats the output y as a point and obstacle j as the ball B(O_j, r_o_j) (Definition 2.3:
  a collision is ‖y − O_j‖ < r_o_j), so r_o_j already holds the robot's own extent and the
  project's default robot radius is 0 (the plants' ``body_radius`` only sizes the Meshcat
  visual; the omni robot's ``base_radius`` is its wheel lever arm). A caller with a robot
  footprint passes `robot_radius`.
* **Collision** with obstacle j at logged time t_k: d_j(t_k) < 0, i.e.
  ‖y − O_j‖ < r_o_j + r_robot (strict, as the campaigns count it). Only logged samples are
  checked: a contact shorter than the log period between two samples is not seen.
* **Minimum distance**: min over logged samples and obstacles of d_j (negative: a
  collision, by how deep).
* **Comfort violation time** (s): ∫ 1[D(t) < d_c] dt over [t_0, t_{T−1}], D(t) the
  piecewise-linear interpolant of the sampled D_k = min_j d_j(t_k). The quadrature is
  exact for that interpolant: on each interval the part below d_c is found at the linear
  crossing (:func:`time_below`), so for a smooth D it errs by O(h²) per crossing (h the log
  period), where a rectangle rule on the indicator errs by O(h).
* **Comfort distance** d_c, default :data:`DEFAULT_COMFORT_DISTANCE` = 0.5 m: Hall's
  proxemics puts the boundary of intimate space at about 0.45 m (personal space 0.45–1.2
  m), the convention social-navigation work measures intrusions against; 0.5 m of
  *surface* distance is that boundary rounded up. (CrowdNav-style RL benchmarks use a
  tighter 0.2 m "discomfort distance" in their reward; pass it to compare with them.)
* **Path length**: Σ_k ‖y(t_{k+1}) − y(t_k)‖ (polygonal, m).
* **Time to goal**: the first sample time from which ‖y − η‖ ≤ R_T holds to the last
  sample (:func:`output_reach_time`; None if the output is outside the target set at the
  end).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stt_drake.core.rules import require

#: The default comfort distance d_c (m of surface distance; module docstring).
DEFAULT_COMFORT_DISTANCE = 0.5
#: The rule of a comfort distance (and of a robot radius).
DISTANCE_RULE = "must be a finite distance ≥ 0 m"


def check_comfort_distance(value: float, field: str = "comfort_distance") -> float:
    """`value` as a float; :class:`~stt_drake.core.rules.RuleError` naming `field` unless
    it is a finite number ≥ 0 (0 measures the time spent in collision)."""
    good = isinstance(value, int | float) and not isinstance(value, bool)
    require(good and math.isfinite(value) and value >= 0.0, field, DISTANCE_RULE, value)
    return float(value)


def output_reach_time(
    t: np.ndarray, output: np.ndarray, target: np.ndarray, target_set_radius: float
) -> float | None:
    """The first sample time from which ‖y − η‖ ≤ R_T holds to the last sample; None if
    the output is outside the target set at the end."""
    inside = np.linalg.norm(output - target, axis=1) <= target_set_radius
    if not inside.size or not inside[-1]:
        return None
    outside = np.flatnonzero(~inside)
    return float(t[outside[-1] + 1] if outside.size else t[0])


def surface_distances(
    output: np.ndarray, centres: np.ndarray, radius: np.ndarray, robot_radius: float = 0.0
) -> np.ndarray:
    """(T, m) d_j(t_k) = ‖y(t_k) − O_j(t_k)‖ − r_o_j − r_robot (m), from the output (T, n),
    the true centres (T, m, n) and the radii r_o (m,); +inf where a centre is NaN (the
    obstacle does not exist then: a recorded track outside its span)."""
    gap = np.asarray(output, dtype=float)[:, None, :] - np.asarray(centres, dtype=float)
    distance = np.linalg.norm(gap, axis=2) - np.asarray(radius, dtype=float) - robot_radius
    return np.where(np.isnan(distance), np.inf, distance)


def time_below(t: np.ndarray, values: np.ndarray, level: float) -> float:
    """Seconds during which the piecewise-linear interpolant of the samples (t_k, v_k) is
    strictly below `level`: per interval, all of it (both ends below), none (neither), or
    the part on the low side of the linear crossing (module docstring)."""
    t = np.asarray(t, dtype=float)
    low = np.asarray(values, dtype=float) - level
    if t.size < 2:
        return 0.0
    h, a, b = np.diff(t), low[:-1], low[1:]
    fraction = np.zeros_like(h)
    fraction[(a < 0.0) & (b < 0.0)] = 1.0
    rising = (a < 0.0) & (b >= 0.0)
    fraction[rising] = -a[rising] / (b[rising] - a[rising])
    falling = (a >= 0.0) & (b < 0.0)
    fraction[falling] = -b[falling] / (a[falling] - b[falling])
    return float(np.sum(h * fraction))


@dataclass(frozen=True)
class CrowdMetrics:
    """One run's crowd-navigation metrics (module docstring; SI units)."""

    collided: bool
    first_collision_s: float | None
    obstacle_collisions: list[bool]
    min_distance_m: float
    comfort_violation_s: float
    path_length_m: float
    time_to_goal_s: float | None


def crowd_metrics(
    t: np.ndarray,
    output: np.ndarray,
    centres: np.ndarray,
    radius: np.ndarray,
    target: np.ndarray,
    target_set_radius: float,
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE,
    robot_radius: float = 0.0,
) -> CrowdMetrics:
    """The metrics of the run logged at times `t` (T,) with output `output` (T, n) among
    true obstacle centres `centres` (T, m, n) of radii `radius` (m,), towards the target
    set B(`target`, `target_set_radius`).

    Raises:
        RuleError: `comfort_distance` or `robot_radius` is negative or not finite.
    """
    comfort_distance = check_comfort_distance(comfort_distance)
    robot_radius = check_comfort_distance(robot_radius, "robot_radius")
    t = np.asarray(t, dtype=float)
    output = np.asarray(output, dtype=float)
    distance = surface_distances(output, centres, radius, robot_radius)
    hits = distance < 0.0
    any_hit = np.flatnonzero(hits.any(axis=1))
    nearest = distance.min(axis=1) if distance.shape[1] else np.full(t.shape, math.inf)
    steps = np.linalg.norm(np.diff(output, axis=0), axis=1)
    return CrowdMetrics(
        collided=bool(any_hit.size),
        first_collision_s=float(t[any_hit[0]]) if any_hit.size else None,
        obstacle_collisions=[bool(h) for h in hits.any(axis=0)],
        min_distance_m=float(nearest.min()) if nearest.size else math.inf,
        comfort_violation_s=time_below(t, nearest, comfort_distance),
        path_length_m=float(steps.sum()),
        time_to_goal_s=output_reach_time(t, output, target, target_set_radius),
    )
