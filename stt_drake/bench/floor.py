"""`stt-drake bench`, the floor under a closed loop: what Drake and pybind alone cost per
derivative evaluation for a Diagram of the omni loop's shape, made of Python systems that
do no work.

The omni loop's derivative chain: the belief source feeds the tube (its centre is
continuous state), the tube the controller, the controller the drive interface and that the
plant (continuous state). :func:`bench_drake_floor` builds that chain as five Python
systems, the shape the loop had when the floor was made (its drive and plant are Drake's
symbolic systems now, so the floor is a fixed reference, a little above the loop's own
framework cost), with the same port sizes (50 obstacle slots in 2D), each system only
evaluating its input and writing a constant, and simulates it with the scenarios'
integrator (Runge-Kutta 3) at a fixed step near their mean step, so a second holds about
as many derivative evaluations as the real loop. The real loop's wall time per derivative
evaluation (monitor included) over this floor says how much of a loop is its systems' own
work, and how much the framework."""

from __future__ import annotations

import statistics
import time
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from pydrake.systems.framework import Diagram

#: Obstacle slots and dimension of the floor's belief port (omni_cluttered_50's).
SLOTS, DIMENSION = 50, 2
#: The fixed integration step (s): omni_cluttered_50's mean error-controlled step.
STEP = 0.0085


def _floor_diagram() -> Diagram:
    """belief source → tube (continuous c) → controller → drive interface → plant
    (continuous y), each a Python LeafSystem that evaluates its input and writes zeros."""
    from pydrake.systems.framework import DiagramBuilder, LeafSystem

    from stt_drake.core.belief import belief_size

    class Stage(LeafSystem):
        """An input (optional) and an output of zeros that evaluates the input, as the real
        systems' outputs do."""

        def __init__(self, inputs: int, outputs: int) -> None:
            super().__init__()
            self._input = self.DeclareVectorInputPort("in", inputs) if inputs else None
            self._zeros = np.zeros(outputs)
            self.DeclareVectorOutputPort("out", outputs, self._calc)

        def _read(self, context: Any) -> None:
            if self._input is not None:
                self._input.Eval(context)

        def _calc(self, context: Any, output: Any) -> None:
            self._read(context)
            output.SetFromVector(self._zeros)

    class StatefulStage(Stage):
        """A stage with continuous state whose derivatives (zeros) evaluate the input; only
        these override DoCalcTimeDerivatives (a Python override is called for every
        derivative evaluation, state or not), as the tube and the plant do."""

        def __init__(self, inputs: int, outputs: int, states: int) -> None:
            super().__init__(inputs, outputs)
            self.DeclareContinuousState(states)
            self._rates = np.zeros(states)

        def DoCalcTimeDerivatives(self, context: Any, derivatives: Any) -> None:  # noqa: N802
            self._read(context)
            derivatives.get_mutable_vector().SetFromVector(self._rates)

    builder = DiagramBuilder()
    chain = [
        Stage(0, belief_size(SLOTS, DIMENSION)),  # belief source
        StatefulStage(belief_size(SLOTS, DIMENSION), DIMENSION + 1, DIMENSION),  # tube
        Stage(DIMENSION + 1, DIMENSION),  # controller
        Stage(DIMENSION, 3),  # drive interface (three wheel speeds)
        StatefulStage(3, DIMENSION, 3),  # plant
    ]
    for stage in chain:
        builder.AddSystem(stage)
    for upstream, downstream in pairwise(chain):
        builder.Connect(upstream.get_output_port(), downstream.get_input_port())
    return builder.Build()


def _time_floor(duration: float) -> float:
    """Wall µs per derivative evaluation of one simulation of the floor Diagram."""
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig

    simulator = Simulator(_floor_diagram())
    config = SimulatorConfig(
        integration_scheme="runge_kutta3", max_step_size=STEP, use_error_control=False
    )
    ApplySimulatorConfig(config, simulator)
    simulator.Initialize()
    wall = time.perf_counter()
    simulator.AdvanceTo(duration)
    wall = time.perf_counter() - wall
    return 1e6 * wall / simulator.get_integrator().get_num_derivative_evaluations()


def bench_drake_floor(repeats: int, duration: float = 10.0) -> dict[str, Any]:
    """The floor's wall µs per derivative evaluation over `repeats` simulations of
    `duration` simulated seconds: median, min and max."""
    runs = [_time_floor(duration) for _ in range(repeats)]
    return {
        "us_per_derivative_evaluation": statistics.median(runs),
        "min": min(runs),
        "max": max(runs),
        "repeats": repeats,
        "systems": 5,
    }
