"""The fixed-rate tube's output reads its period state whenever that state changes (the
period is read off the state once per change, not at every output)."""

from __future__ import annotations

import numpy as np
from pydrake.systems.analysis import Simulator

from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.fixed_rate import BeliefRateBounds
from stt_drake.core.tube import TubeLaw
from stt_drake.systems.tube import PeriodLayout, SpatiotemporalTube

BELIEF = ObstacleBelief(
    mean=np.array([[1.0, 0.3], [-4.0, 5.0]]),
    sigma=np.array([0.1, 0.2]),
    radius=np.array([0.15, 0.2]),
    epsilon=np.array([0.9, 0.8]),
    p_d=np.array([0.9999, 0.999]),
)
LAW = TubeLaw(
    target=np.array([2.0, 0.0]),
    k1=0.7,
    k2=0.4,
    k3=0.3,
    r_min=0.1,
    r_max=0.3,
    nu=40.0,
    max_center_speed=1.0,
)


def test_output_follows_the_state_within_a_period_and_after_set_center():
    """Within a period the `tube` output is [c, r] interpolated from the state at the
    evaluation time; writing the state (set_center, at the same time) changes the output
    at once."""
    start = np.array([0.4, -0.1])
    tube = SpatiotemporalTube(
        LAW, start, BELIEF.task, update_period=0.02, rate_bounds=BeliefRateBounds.still(2)
    )
    context = tube.CreateDefaultContext()
    tube.GetInputPort("obstacle_belief").FixValue(context, BELIEF.to_vector())
    simulator = Simulator(tube, context)
    simulator.Initialize()
    context = simulator.get_context()
    output = tube.GetOutputPort("tube")
    state = context.get_discrete_state(0).CopyToVector()
    layout = PeriodLayout(dimension=2, count=2)
    begin = state[: layout.dimension + 1]
    end = state[layout.end_center.start : layout.end_radius + 1]
    assert np.linalg.norm(end[:2] - begin[:2]) > 1e-3  # the update moved the centre
    np.testing.assert_array_equal(output.Eval(context), begin)
    context.SetTime(0.005)  # a quarter of the period
    np.testing.assert_allclose(output.Eval(context), begin + 0.25 * (end - begin), atol=1e-15)
    elsewhere = np.array([-0.3, 0.2])
    tube.set_center(context, elsewhere)  # no radius yet: the output is the law's there
    expected = LAW.evaluate(elsewhere, BELIEF).radius
    np.testing.assert_allclose(output.Eval(context), [*elsewhere, expected], rtol=1e-12)


def test_only_a_continuous_tube_computes_its_derivatives_in_python(monkeypatch):
    """A fixed-rate tube (the period by keyword or in its place) is a SpatiotemporalTube
    without continuous state whose derivatives Drake computes without calling into
    Python; a continuous one computes ċ there at each evaluation."""
    calls = []
    derivatives = SpatiotemporalTube.DoCalcTimeDerivatives

    def counted(tube, context, output):
        calls.append(tube)
        derivatives(tube, context, output)

    monkeypatch.setattr(SpatiotemporalTube, "DoCalcTimeDerivatives", counted)
    start, bounds = np.array([0.4, -0.1]), BeliefRateBounds.still(2)
    tubes = [
        SpatiotemporalTube(LAW, start, BELIEF.task, update_period=0.02, rate_bounds=bounds),
        SpatiotemporalTube(LAW, start, BELIEF.task, 0.02, False, bounds),
        SpatiotemporalTube(LAW, start, BELIEF.task),
    ]
    rates = []
    for tube in tubes:
        context = tube.CreateDefaultContext()
        tube.GetInputPort("obstacle_belief").FixValue(context, BELIEF.to_vector())
        rates.append(tube.EvalTimeDerivatives(context).CopyToVector())
    assert all(isinstance(tube, SpatiotemporalTube) for tube in tubes)
    assert [tube.update_period for tube in tubes] == [0.02, 0.02, None]
    assert len(calls) == 1 and calls[0] is tubes[2]
    assert rates[0].size == rates[1].size == 0
    np.testing.assert_array_equal(rates[2], LAW.evaluate(start, BELIEF).center_rate)
