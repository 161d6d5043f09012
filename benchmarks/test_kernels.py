"""The benchmark history's kernel rows (pytest-benchmark; `make bench-history`,
`make bench-compare`): one call each of the tube step through the public law (50
obstacles, typical and worst fields, 2D and 3D; full covariances), the controller, the
tracker update and the arm's law. The workloads are `stt-drake bench`'s
(:mod:`stt_drake.bench.workloads`, :mod:`stt_drake.bench.kernels`), so a row here and its
line in `stt-drake bench` time the same call."""

from __future__ import annotations

import numpy as np
import pytest

from stt_drake.bench.kernels import controller_cases, tracker_workload
from stt_drake.bench.loops import DIAGRAMS
from stt_drake.bench.workloads import anisotropic_field, obstacle_field
from stt_drake.core.tracking import monitored_update, update

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


@pytest.mark.parametrize("case", ["stage1", "stage2"])
def test_controller(benchmark, case):
    controller, states, center = controller_cases()[case]
    evaluation = benchmark(controller.evaluate, 1.5, states, center, 0.5)
    assert np.all(np.isfinite(evaluation.control))


@pytest.mark.parametrize("dimension", [2, 3])
def test_tracker_update(benchmark, dimension):
    work = tracker_workload(dimension, COUNT)
    mean, _ = benchmark(update, work.state, work.covariance, 0.1, work.z, 1e-3, work.noise)
    assert np.all(np.isfinite(mean))


@pytest.mark.parametrize("dimension", [2, 3])
def test_monitored_tracker_update(benchmark, dimension):
    work = tracker_workload(dimension, COUNT)
    every = np.ones(COUNT, dtype=bool)
    arguments = (work.table, every, 0.1, work.z, 1e-3, work.noise, work.monitored.adaptation)
    updated = benchmark(monitored_update, *arguments)
    assert np.all(np.isfinite(updated[0]))  # the posterior means


def test_arm_law(benchmark):
    """The FR3's law (stage 1, the damped least-squares mapping, stage 2) of
    franka_pick_place_case1 at its initial configuration, the tube 5 cm from the hand."""
    from stt_drake.assembly import load_scenario
    from stt_drake.assembly.laws import make_arm_law
    from stt_drake.systems.plants.franka import ArmKinematics

    scenario = load_scenario(DIAGRAMS / "franka_pick_place_case1.yaml")
    law = make_arm_law(scenario)
    q = np.asarray(scenario.plant.initial_configuration, dtype=float)
    kinematics = ArmKinematics()
    position, jacobian = kinematics.position(q), kinematics.jacobian(q)
    center = position + np.array([0.05, 0.0, 0.0])
    arguments = (1.5, position, q, np.full(7, 0.05), jacobian, center, 0.08)
    evaluation = benchmark(law.evaluate, *arguments)
    assert np.all(np.isfinite(evaluation.torque))
