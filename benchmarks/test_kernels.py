"""The benchmark history's kernel rows (pytest-benchmark; `make bench-history`,
`make bench-compare`): one call each of the tube step through the public law (50
obstacles, typical and worst fields, 2D and 3D; full covariances), the controller and the
tracker update. The workloads are `stt-drake bench`'s (:mod:`stt_drake.bench.workloads`),
so a row here and its line in `stt-drake bench` time the same call."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stt_drake.bench.workloads import anisotropic_field, obstacle_field
from stt_drake.core.consistency import Adaptation
from stt_drake.core.control import BoxFunnel, FunnelController
from stt_drake.core.tracking import KalmanTracker, birth, monitored_update, update

#: Obstacles of the kernel rows (the issue's "50-obstacle field").
COUNT = 50


@pytest.mark.parametrize("field", ["typical", "worst"])
@pytest.mark.parametrize("dimension", [2, 3])
def test_tube_step(benchmark, field, dimension):
    law, center, belief = obstacle_field(COUNT, dimension, field == "worst")
    evaluation = benchmark(law.evaluate, center, belief)
    assert np.isfinite(evaluation.radius) and evaluation.radius > 0.0


@pytest.mark.parametrize("dimension", [2, 3])
def test_tube_step_full_covariance(benchmark, dimension):
    law, center, belief = anisotropic_field(COUNT, dimension)
    evaluation = benchmark(law.evaluate, center, belief)
    assert np.isfinite(evaluation.radius) and evaluation.radius > 0.0


def test_controller_one_stage(benchmark):
    controller = FunnelController(kappa=[6.0])
    evaluation = benchmark(controller.evaluate, 1.5, np.array([0.12, -0.05]), np.zeros(2), 0.5)
    assert np.all(np.isfinite(evaluation.control))


def test_controller_two_stages(benchmark):
    funnel = BoxFunnel(np.full(3, 2.0), np.full(3, 1.0), np.full(3, 1.0))
    controller = FunnelController(kappa=[3.0, 4.0], funnels=[funnel])
    states = np.array([0.1, -0.2, 0.15, 0.3, -0.1, 0.2])
    evaluation = benchmark(controller.evaluate, 1.5, states, np.zeros(3), 0.5)
    assert np.all(np.isfinite(evaluation.control))


@pytest.mark.parametrize("dimension", [2, 3])
def test_tracker_update(benchmark, dimension):
    noise = 0.0025 * np.eye(dimension)
    z = np.random.default_rng(0).normal(size=(COUNT, dimension))
    state, covariance = birth(z, noise, 0.2)
    mean, _ = benchmark(update, state, covariance, 0.1, z, 1e-3, noise)
    assert np.all(np.isfinite(mean))


@pytest.mark.parametrize("dimension", [2, 3])
def test_monitored_tracker_update(benchmark, dimension):
    noise = 0.0025 * np.eye(dimension)
    z = np.random.default_rng(0).normal(size=(COUNT, dimension))
    state, covariance = birth(z, noise, 0.2)
    tracker = KalmanTracker(dimension, 1e-3, noise, 0.2, 1.0, adaptation=Adaptation(dimension))
    table = dataclasses.replace(tracker.empty(COUNT), state=state, covariance=covariance)
    every = np.ones(COUNT, dtype=bool)
    table = dataclasses.replace(table, detection_time=np.zeros(COUNT), active=every)
    updated = benchmark(monitored_update, table, every, 0.1, z, 1e-3, noise, tracker.adaptation)
    assert np.all(np.isfinite(updated[0]))  # the posterior means
