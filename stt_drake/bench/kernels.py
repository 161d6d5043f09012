"""`stt-drake bench`, the rows of the compiled kernels: the tube step (isotropic, against
the scipy baseline, and with full covariances), the tracker update and the controller."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np

from stt_drake.bench.timing import time_call
from stt_drake.bench.workloads import anisotropic_field, baseline_tube_step, obstacle_field
from stt_drake.core import backend

if TYPE_CHECKING:
    from stt_drake.core.tracking import KalmanTracker, TrackTable

#: Obstacle counts of the tube-step benchmark.
COUNTS = (10, 50, 200, 1000)


def bench_tube_steps(counts: tuple[int, ...], repeats: int) -> dict[str, Any]:
    """Tube-step timings (compiled kernel and baseline) for every dimension, count, field."""
    results: dict[str, Any] = {}
    for field in ("typical", "worst"):
        for dimension in (2, 3):
            for count in counts:
                law, center, belief = obstacle_field(count, dimension, field == "worst")
                evaluation = law.evaluate(center, belief)
                reference = baseline_tube_step(law, center, belief)
                exact = law.evaluate(center, belief, prune=False).quantile_distance
                kernel = time_call(lambda: law.evaluate(center, belief), repeats)  # noqa: B023
                baseline = time_call(
                    lambda: baseline_tube_step(law, center, belief),  # noqa: B023
                    max(3, repeats // 2),
                )
                results[f"{field}/{dimension}d/{count}"] = {
                    "kernel_us": kernel,
                    "baseline_us": baseline,
                    "speedup": baseline["median"] / kernel["median"],
                    "pruned": int(np.sum(evaluation.quantile_distance != exact)),
                    "active": int(np.sum(evaluation.theta > 0.0)),
                    "max_abs_difference_vs_baseline": {
                        "center_rate": float(np.max(np.abs(evaluation.center_rate - reference[0]))),
                        "radius": abs(evaluation.radius - reference[1]),
                        "q": float(np.max(np.abs(evaluation.avoid_probability - reference[2]))),
                    },
                }
    return results


def bench_anisotropic_tube_steps(repeats: int, count: int = 50) -> dict[str, Any]:
    """One tube step with full covariances (:func:`anisotropic_field`), 2D and 3D."""
    results: dict[str, Any] = {}
    for dimension in (2, 3):
        law, center, belief = anisotropic_field(count, dimension)
        evaluation = law.evaluate(center, belief)
        exact = law.evaluate(center, belief, prune=False).quantile_distance
        results[f"{dimension}d/{count}"] = {
            "kernel_us": time_call(lambda: law.evaluate(center, belief), repeats),  # noqa: B023
            "quantiles_computed": int(np.sum(evaluation.quantile_distance == exact)),
            "active": int(np.sum(evaluation.theta > 0.0)),
        }
    return results


@dataclasses.dataclass(frozen=True)
class TrackerWorkload:
    """`count` tracks in R^n just born from detections `z` (noise covariance `noise`,
    m²), for the plain update (`state`, `covariance`) and, as a table, for the monitored
    one (`monitored`: the NIS test and adaptive noise of a scenario's default tracker)."""

    z: np.ndarray
    noise: np.ndarray
    state: np.ndarray
    covariance: np.ndarray
    monitored: KalmanTracker  # with its Adaptation
    table: TrackTable  # of the monitored tracker, every slot active


def tracker_workload(n: int, count: int = 50) -> TrackerWorkload:
    """The tracker rows' workload (:class:`TrackerWorkload`), the same for every seed."""
    from stt_drake.core.consistency import Adaptation
    from stt_drake.core.tracking import KalmanTracker, birth

    noise = 0.0025 * np.eye(n)
    z = np.random.default_rng(0).normal(size=(count, n))
    state, covariance = birth(z, noise, 0.2)
    monitored = KalmanTracker(n, 1e-3, noise, 0.2, 1.0, adaptation=Adaptation(n))
    table = dataclasses.replace(monitored.empty(count), state=state, covariance=covariance)
    table = dataclasses.replace(
        table, detection_time=np.zeros(count), active=np.ones(count, dtype=bool)
    )
    return TrackerWorkload(z, noise, state, covariance, monitored, table)


def bench_tracker_update(repeats: int, count: int = 50) -> dict[str, Any]:
    """One Kalman tracker update (:func:`stt_drake.core.tracking.update`: predict over
    0.1 s, correct) of `count` tracks, 2D and 3D; and the whole
    :meth:`~stt_drake.core.tracking.KalmanTracker.step` (with the birth and loss rules);
    both also monitored (``monitored_update_us``, ``monitored_step_us``: the NIS test and
    the adaptive noise, :mod:`stt_drake.core.consistency`, the default of a scenario's
    tracker), on :func:`tracker_workload`."""
    from stt_drake.core.perception import Detections
    from stt_drake.core.tracking import KalmanTracker, TrackTable, monitored_update, update

    results: dict[str, Any] = {}
    for n in (2, 3):
        work = tracker_workload(n, count)
        state, covariance, z, noise = work.state, work.covariance, work.z, work.noise
        results[f"{n}d/{count}"] = {
            "update_us": time_call(
                lambda: update(state, covariance, 0.1, z, 1e-3, noise),  # noqa: B023
                repeats,
            )
        }
        tracker = KalmanTracker(n, 1e-3, noise, 0.2, 1.0)
        tracks = TrackTable(state, covariance, np.zeros(count), np.ones(count, dtype=bool))
        seen = Detections(z, np.ones(count, dtype=bool), np.full(count, 0.1))
        results[f"{n}d/{count}"]["step_us"] = time_call(
            lambda: tracker.step(tracks, seen, 0.1),  # noqa: B023
            repeats,
        )
        monitored, table = work.monitored, work.table
        every = np.ones(count, dtype=bool)
        results[f"{n}d/{count}"]["monitored_update_us"] = time_call(
            lambda: monitored_update(table, every, 0.1, z, 1e-3, noise, monitored.adaptation),  # noqa: B023
            repeats,
        )
        results[f"{n}d/{count}"]["monitored_step_us"] = time_call(
            lambda: monitored.step(table, seen, 0.1),  # noqa: B023
            repeats,
        )
    return results


def controller_cases() -> dict[str, tuple[Any, np.ndarray, np.ndarray]]:
    """The controller rows' cases by name: (FunnelController, plant state, tube centre) for
    one stage (n = 2) and two stages (n = 3); each is evaluated at t = 1.5 s, r = 0.5 m."""
    from stt_drake.core.control import BoxFunnel, FunnelController

    return {
        "stage1": (
            FunnelController(kappa=[6.0]),
            np.array([0.12, -0.05]),
            np.zeros(2),
        ),
        "stage2": (
            FunnelController(
                kappa=[3.0, 4.0],
                funnels=[BoxFunnel(np.full(3, 2.0), np.full(3, 1.0), np.full(3, 1.0))],
            ),
            np.array([0.1, -0.2, 0.15, 0.3, -0.1, 0.2]),
            np.zeros(3),
        ),
    }


def bench_controller(repeats: int) -> dict[str, Any]:
    """FunnelController.evaluate on :func:`controller_cases`, both paths."""
    results: dict[str, Any] = {}
    for name, (controller, states, center) in controller_cases().items():
        compiled = time_call(lambda: controller.evaluate(1.5, states, center, 0.5), repeats)  # noqa: B023
        with backend.pure_numpy():
            reference = time_call(
                lambda: controller.evaluate(1.5, states, center, 0.5),  # noqa: B023
                repeats,
            )
        results[name] = {
            "compiled_us": compiled,
            "numpy_us": reference,
            "speedup": reference["median"] / compiled["median"],
        }
    return results
