"""InvariantMonitor: evaluates every guarantee during a run, and the Simulator hook."""

from __future__ import annotations

from collections.abc import Callable

from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import (
    BasicVector,
    Context,
    EventStatus,
    LeafSystem,
    ValueProducer,
)

from stt_drake.belief import belief_size
from stt_drake.invariants import INVARIANT_NAMES, InvariantTracker, evaluate_invariants_packed


class InvariantMonitor(LeafSystem):
    """Inputs `tube`, `obstacle_belief`, `output` (y); outputs `margins` (one per name in
    :data:`stt_drake.invariants.INVARIANT_NAMES`), `output_avoid_probability` (m) and
    `tube_avoid_probability` (m). Recomputes every probability itself rather than trusting
    the tube's diagnostics, so a bug in the tube cannot hide from it."""

    def __init__(self, dimension: int, obstacle_count: int, r_min: float) -> None:
        super().__init__()
        self.set_name("invariant_monitor")
        self._dimension = dimension
        self._r_min = r_min
        self._tube_port = self.DeclareVectorInputPort("tube", dimension + 1)
        self._belief_port = self.DeclareVectorInputPort(
            "obstacle_belief", belief_size(obstacle_count, dimension)
        )
        self._output_port = self.DeclareVectorInputPort("output", dimension)
        self._sample = self.DeclareCacheEntry(
            description="invariant margins",
            value_producer=ValueProducer(
                allocate=AbstractValue.Make(object()).Clone, calc=self._calc_sample
            ),
            prerequisites_of_calc={self.all_input_ports_ticket()},
        )
        depends = {self._sample.ticket()}
        self.margins_port = self.DeclareVectorOutputPort(
            "margins",
            len(INVARIANT_NAMES),
            lambda context, output: output.SetFromVector(self._sample.Eval(context).margins),
            prerequisites_of_calc=depends,
        )
        self.DeclareVectorOutputPort(
            "output_avoid_probability",
            obstacle_count,
            self._calc_output_avoid,
            prerequisites_of_calc=depends,
        )
        self.DeclareVectorOutputPort(
            "tube_avoid_probability",
            obstacle_count,
            self._calc_tube_avoid,
            prerequisites_of_calc=depends,
        )

    def _calc_sample(self, context: Context, value: AbstractValue) -> None:
        value.set_value(
            evaluate_invariants_packed(
                self._output_port.Eval(context),
                self._tube_port.Eval(context),
                self._belief_port.Eval(context),
                self._r_min,
            )
        )

    def _calc_output_avoid(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._sample.Eval(context).output_avoid_probability)

    def _calc_tube_avoid(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._sample.Eval(context).tube_avoid_probability)

    def attach(
        self, simulator: Simulator, tracker: InvariantTracker, strict: bool
    ) -> Callable[[Context], EventStatus]:
        """Install a Simulator monitor that folds every step's margins into `tracker`.

        In strict mode the first violation stops the run: ``AdvanceTo`` raises a
        RuntimeError whose message names the invariant, the time and the margin.
        """

        def monitor(root_context: Context) -> EventStatus:
            context = self.GetMyContextFromRoot(root_context)
            message = tracker.update(context.get_time(), self.margins_port.Eval(context))
            if strict and message is not None:
                # Failed(None, ...): passing a Python LeafSystem here segfaults (DRAKE_NOTES).
                return EventStatus.Failed(None, message)
            return EventStatus.DidNothing()

        simulator.set_monitor(monitor)
        return monitor
