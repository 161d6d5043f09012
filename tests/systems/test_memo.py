"""The one-entry memo of the tube evaluation and the scripted belief
(:mod:`stt_drake.systems.memo`): it returns the law's result for bit-identical inputs
only, and in a closed loop it saves the evaluation a step's first stage repeats."""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np
import pytest

from stt_drake.assembly import load_scenario
from stt_drake.assembly.diagram import build_diagram
from stt_drake.core.invariants import InvariantTracker
from stt_drake.core.tube import TubeLaw
from stt_drake.run import make_simulator
from stt_drake.systems.memo import LastResult
from stt_drake.systems.tube import SpatiotemporalTube
from tests.conftest import DIAGRAMS
from tests.systems.test_systems import TUBE_BELIEF, make_law, tube_context


@pytest.fixture
def law_calls(monkeypatch):
    """The number of law evaluations the tube system made so far (its calls of
    TubeLaw.evaluate_port; a list holding one count; the guide's own calls of the law are
    not counted)."""
    calls = [0]
    evaluate = TubeLaw.evaluate_port

    def counted(self, *args, **kwargs):
        if sys._getframe(1).f_code is SpatiotemporalTube._calc_evaluation.__code__:
            calls[0] += 1
        return evaluate(self, *args, **kwargs)

    monkeypatch.setattr(TubeLaw, "evaluate_port", counted)
    return calls


def test_last_result_matches_exact_inputs_only():
    memo = LastResult()
    key, result = memo.lookup(np.array([1.0, 2.0]), 0.5, None)
    assert result is None
    memo.store(key, "stored")
    assert memo.lookup(np.array([1.0, 2.0]), 0.5, None)[1] == "stored"
    assert memo.lookup(np.array([1.0, 2.0 + 1e-15]), 0.5, None)[1] is None
    assert memo.lookup(np.array([1.0, 2.0]), 0.5, np.zeros(1))[1] is None  # None ≠ an array


def test_last_result_keys_a_value_by_its_float64_bytes_whatever_its_type():
    """A float, a numpy scalar, an int array and a float64 array of the same values are the
    same key (the fast paths for a float and a float64 array give numpy's bytes)."""
    memo = LastResult()
    memo.store(memo.lookup(0.5, np.array([1.0, 2.0]))[0], "stored")
    assert memo.lookup(np.float64(0.5), np.array([1, 2]))[1] == "stored"
    assert memo.lookup(0.5, [1.0, 2.0])[1] == "stored"
    assert memo.lookup(-0.0, np.array([1.0, 2.0]))[1] is None
    memo.store(memo.lookup(0.0, None)[0], "zero")
    assert memo.lookup(-0.0, None)[1] is None  # the bytes differ though the values are equal
    assert memo.lookup(np.zeros(1), None)[1] == "zero"


def test_tube_contexts_alternating_get_each_their_own_evaluation(law_calls):
    """Two contexts of one tube, alternately: every switch is a miss and recomputes, and
    each context reads the law's own result at its centre."""
    law = make_law()
    tube = SpatiotemporalTube(law, np.zeros(2), TUBE_BELIEF.task)
    centers = (np.array([0.5, 0.0]), np.array([0.6, 0.35]))
    contexts = [tube_context(tube, center, TUBE_BELIEF) for center in centers]
    for _ in range(2):
        for context, center in zip(contexts, centers, strict=True):
            tube.set_center(context, center)  # the same centre: invalidates the Drake cache
            rate = tube.EvalTimeDerivatives(context).CopyToVector()
            # Equal bit for bit: both run the compiled tube_step's arithmetic (no fast-math,
            # so no reordering) on the same values, since the port's σ = √λ_max(σ²I) is σ
            # exactly (the square root of a rounded square is exact in binary floating
            # point); a memo hit returns that result itself, a miss recomputes it.
            np.testing.assert_array_equal(rate, law.evaluate(center, TUBE_BELIEF).center_rate)
    assert law_calls[0] == 2 * 2  # each Eval a miss (the test's own calls not counted)


@pytest.mark.parametrize(
    "name", ["omni_hardware_case1", "liveness_clutter_2d", "uav_authors_field"]
)
def test_a_closed_loop_evaluates_the_law_once_per_stage(law_calls, name):
    """1 s with the monitor (Runge-Kutta 3), with a fixed target, with the guide moving
    it (the tube's `target` input) and in 3D with obstacles acting from the start (their
    circulation axes carried at every step): the law runs once per derivative evaluation
    (plus the initial one, plus one per guide update); the monitor's evaluation at the end
    of each step is the next step's first stage, not a second call, also after the axes
    were carried (the same ċ there: :meth:`SpatiotemporalTube.keep_evaluation`)."""
    scenario = dataclasses.replace(load_scenario(DIAGRAMS / f"{name}.yaml"), duration=1.0)
    simulator = make_simulator(build_diagram(scenario), scenario, InvariantTracker())
    simulator.Initialize()
    simulator.AdvanceTo(scenario.duration)
    derivatives = simulator.get_integrator().get_num_derivative_evaluations()
    steps = simulator.get_num_steps_taken()
    assert steps > 50
    # A guide update between two steps moves the target: the first stage then differs.
    updates = 0 if scenario.guide is None else math.ceil(scenario.guide.rate_hz) + 1
    assert law_calls[0] <= derivatives + 1 + updates < derivatives + steps


def test_a_changed_belief_is_a_miss_and_the_evaluation_reads_it():
    """The evaluation reads the port itself (not the `belief` cache entry): a moved
    obstacle gives a new evaluation of the new belief, equal to the law's."""
    law = make_law()
    tube = SpatiotemporalTube(law, np.zeros(2), TUBE_BELIEF.task)
    center = np.array([0.6, 0.35])
    context = tube_context(tube, center, TUBE_BELIEF)
    first = tube.evaluation(context)
    moved = dataclasses.replace(TUBE_BELIEF, mean=TUBE_BELIEF.mean + np.array([0.05, 0.0]))
    tube.GetInputPort("obstacle_belief").FixValue(context, moved.to_vector())
    evaluation, port_tube = tube.evaluated(context)
    np.testing.assert_array_equal(tube.belief(context).vector, moved.to_vector())
    # The same compiled call on the same inputs in this process: equal bit for bit.
    np.testing.assert_array_equal(
        evaluation.center_rate, law.evaluate(center, moved).center_rate
    )
    assert port_tube[-1] == law.evaluate(center, moved).radius
    assert not np.array_equal(evaluation.avoid_probability, first.avoid_probability)


@pytest.mark.parametrize("full_covariance", [False, True])
def test_the_carry_keeps_the_evaluation_only_where_the_rate_stays(law_calls, full_covariance):
    """3D, one obstacle acting with a held circulation axis the carry turns (it is not
    orthogonal to m̂): after the carry the first stage reads ċ at the new axis. With σ² I
    that is the memo's result (no law call; the law's own evaluation at the new axis agrees
    to rounding); with a full Σ the carried axis does change v_j (∇̂q_j is not along
    c − μ_j), so the law runs again and gives its own result."""
    law = TubeLaw(
        target=np.array([3.0, 0.5, 0.2]),
        k1=0.7,
        k2=0.4,
        k3=0.8,
        r_min=0.1,
        r_max=0.3,
        nu=40.0,
        max_center_speed=np.inf,
    )
    covariance = np.diag([0.09, 0.01, 0.04]) if full_covariance else 0.04 * np.eye(3)
    belief = dataclasses.replace(
        TUBE_BELIEF,
        mean=np.array([[1.0, 0.3, -0.1], [-4.0, 5.0, 1.0]]),
        sigma=np.array([0.3, 0.2]),
        covariance=np.stack([covariance, 0.04 * np.eye(3)]) if full_covariance else None,
    )
    tube = SpatiotemporalTube(law, np.zeros(3), belief.task, full_covariance=full_covariance)
    center = np.array([0.45, 0.1, 0.05])
    context = tube_context(tube, center, belief)
    held = np.array([[0.6, 0.0, 0.8], [0.0, 0.0, 0.0]])  # unit, 0.46 rad off ⟂ m̂
    context.SetDiscreteState(held.ravel())
    evaluation = tube.evaluation(context)
    assert evaluation.theta[0] > 0.0 and evaluation.avoid_probability[0] > belief.epsilon[0]
    before = tube.EvalTimeDerivatives(context).CopyToVector()
    discrete = context.get_discrete_state().Clone()
    tube._mode._carry_circulation(context, discrete)  # the per-step event's callback
    carried = discrete.get_vector(0).CopyToVector()
    assert not np.allclose(carried, held.ravel())  # the carry did turn the axis
    context.SetDiscreteState(carried)
    calls = law_calls[0]
    after = tube.EvalTimeDerivatives(context).CopyToVector()
    vector = belief.to_vector()
    fresh = law.evaluate_port(center, vector, belief.task, full_covariance, carried.reshape(2, 3))
    if full_covariance:
        assert law_calls[0] == calls + 1
        # The same compiled call on the same inputs in this process: equal bit for bit.
        np.testing.assert_array_equal(after, fresh.center_rate)
        assert not np.allclose(after, before, rtol=1e-6)
    else:
        assert law_calls[0] == calls
        np.testing.assert_array_equal(after, before)
        # The attraction k1·∛(η − c), k2·θ·m and k3·θ·v (|v| = |m| = d/(q − ε)), each to a
        # few roundings: 1e-14 of their sum bounds the difference.
        q, theta = evaluation.avoid_probability[0], evaluation.theta[0]
        m = np.linalg.norm(center - belief.mean[0]) / (q - belief.epsilon[0])
        size = 0.7 * np.abs(np.cbrt(law.target - center)).sum() + (0.4 + 0.8) * theta * m
        np.testing.assert_allclose(after, fresh.center_rate, rtol=0, atol=1e-14 * size)
