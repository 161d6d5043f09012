"""benchmarks/structure_bound.py: the stand-ins replace each compiled computation of a
closed loop by a result the real one made, count their calls, and leave the library as it
was (no timing is asserted: speed is measured by the script itself)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.structure_bound import _targets, captured_results, main, stand_ins, structure_bound
from stt_drake.bench.loops import closed_loop_scenario, ready_simulator


@pytest.fixture(scope="module")
def short_loop():
    return closed_loop_scenario("omni_cluttered_50", 0.3, None)


def _originals() -> list[object]:
    return [getattr(holder, attribute) for _, holder, attribute in _targets()]


def test_stand_ins_return_the_captured_results_and_are_undone(short_loop):
    before = _originals()
    results = captured_results(short_loop, 0.2)
    assert _originals() == before  # the recorders are gone again
    # The continuous omni loop calls these four; it has no tracker and no fixed-rate update.
    assert set(results) == {
        "ObstacleBeliefSource.belief_vector",
        "TubeLaw.evaluate_port",
        "FunnelController.control_from_tube",
        "monitor.port_invariants",
    }
    calls = {label: 0 for label, _, _ in _targets()}
    controls = []
    with stand_ins(results, calls):
        simulator, _ = ready_simulator(short_loop)
        controller = simulator.get_system().GetSubsystemByName("stt_controller")
        port = controller.get_output_port(0)
        for t in (0.1, 0.2, 0.3):
            simulator.AdvanceTo(t)
            controls.append(port.Eval(controller.GetMyContextFromRoot(simulator.get_context())))
    assert _originals() == before
    for control in controls:  # the controller's output is the captured control throughout
        np.testing.assert_array_equal(control, results["FunnelController.control_from_tube"])
    assert all(calls[label] > 0 for label in results)
    assert calls["ObstacleTracker.belief_vector"] == calls["tube.advance_port"] == 0
    # Undone: the real controller's output moves with the plant again.
    simulator, _ = ready_simulator(short_loop)
    simulator.AdvanceTo(0.3)
    controller = simulator.get_system().GetSubsystemByName("stt_controller")
    context = controller.GetMyContextFromRoot(simulator.get_context())
    control = controller.get_output_port(0).Eval(context)
    assert not np.array_equal(control, results["FunnelController.control_from_tube"])


def test_the_bound_reports_both_loops_and_the_stand_ins_used(short_loop):
    bound = structure_bound(short_loop, repeats=1, capture=0.2)
    assert bound["real_evaluations"] > 0 and bound["structure_evaluations"] > 0
    assert bound["real_us_per_evaluation"] > 0.0 and bound["structure_us_per_evaluation"] > 0.0
    assert bound["stand_in_calls"]["TubeLaw.evaluate_port"] > 0
    assert bound["stand_in_calls"]["tube.advance_port"] == 0


def test_an_unknown_scenario_is_named_with_exit_code_2(capsys):
    assert main(["no_such_scenario"]) == 2
    assert "no packaged scenario named 'no_such_scenario'" in capsys.readouterr().err
