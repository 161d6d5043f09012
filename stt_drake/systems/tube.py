"""SpatiotemporalTube: the STT centre as Drake state, radius and diagnostics as outputs."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import (
    BasicVector,
    Context,
    ContinuousState,
    DiscreteValues,
    LeafSystem,
    ValueProducer,
)

from stt_drake.belief import ObstacleBelief, belief_size
from stt_drake.tube import TubeEvaluation, TubeLaw


class SpatiotemporalTube(LeafSystem):
    """The tube Γ(t) = B(c(t), r(t)) of Sec. 3, driven online by the obstacle belief.

    Input `obstacle_belief`; outputs `tube` = [c, r] (n + 1) and `diagnostics` =
    [q_j (m), d̂_j (m), θ_j (m)].

    Two modes:

    * continuous (``update_period=None``): c is continuous state, ċ from eq. (cen_dynamic)
      integrated by the Simulator. Near the ε level set ċ is stiff; run it with error
      control and a bounded max step (the scenarios' default SimulatorConfig), and the
      invariant monitor reports a crossing if one ever happens.
    * fixed rate (``update_period=h``): c is discrete state, updated every h seconds with the
      belief sampled at the update, the way it runs on a robot; :meth:`TubeLaw.advance`
      sub-steps so that no q_j can cross ε_j within a period.

    The radius is always evaluated at the current belief, so r ≤ min_j d̂_j at every instant.
    """

    def __init__(
        self,
        law: TubeLaw,
        initial_center: np.ndarray,
        obstacle_count: int,
        update_period: float | None = None,
    ) -> None:
        super().__init__()
        self.set_name("spatiotemporal_tube")
        self._law = law
        self._dimension = len(initial_center)
        self._count = obstacle_count
        self.update_period = update_period
        self._belief_port = self.DeclareVectorInputPort(
            "obstacle_belief", belief_size(obstacle_count, self._dimension)
        )
        initial_center = np.asarray(initial_center, dtype=float)
        if update_period is None:
            self.DeclareContinuousState(BasicVector(initial_center))
            state_ticket = self.xc_ticket()
        else:
            self._state_index = self.DeclareDiscreteState(initial_center)
            self.DeclarePeriodicDiscreteUpdateEvent(update_period, 0.0, self._discrete_update)
            state_ticket = self.xd_ticket()
        self._evaluation = self.DeclareCacheEntry(
            description="tube law evaluation",
            value_producer=ValueProducer(
                allocate=AbstractValue.Make(object()).Clone, calc=self._calc_evaluation
            ),
            prerequisites_of_calc={state_ticket, self.all_input_ports_ticket()},
        )
        depends = {self._evaluation.ticket()}
        self.DeclareVectorOutputPort(
            "tube", self._dimension + 1, self._calc_tube, prerequisites_of_calc=depends
        )
        self.DeclareVectorOutputPort(
            "diagnostics", 3 * obstacle_count, self._calc_diagnostics, prerequisites_of_calc=depends
        )

    @property
    def law(self) -> TubeLaw:
        return self._law

    def center(self, context: Context) -> np.ndarray:
        """The tube centre c held in `context`."""
        if self.update_period is None:
            return context.get_continuous_state_vector().CopyToVector()
        return context.get_discrete_state(self._state_index).CopyToVector()

    def _belief(self, context: Context) -> ObstacleBelief:
        return ObstacleBelief.from_vector(self._belief_port.Eval(context), self._dimension)

    def _calc_evaluation(self, context: Context, value: AbstractValue) -> None:
        evaluation = self._law.evaluate(self.center(context), self._belief(context))
        if not np.all(np.isfinite(evaluation.center_rate)) or not np.isfinite(evaluation.radius):
            raise RuntimeError(
                f"tube law produced a non-finite value at t = {context.get_time():.6g} s: "
                f"ċ = {evaluation.center_rate}, r = {evaluation.radius}"
            )
        value.set_value(evaluation)

    def evaluation(self, context: Context) -> TubeEvaluation:
        """The cached law evaluation (ċ, r, q_j, d̂_j, θ_j) in `context`."""
        return self._evaluation.Eval(context)

    def _calc_tube(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(np.append(self.center(context), self.evaluation(context).radius))

    def _calc_diagnostics(self, context: Context, output: BasicVector) -> None:
        evaluation = self.evaluation(context)
        output.SetFromVector(
            np.concatenate(
                [evaluation.avoid_probability, evaluation.quantile_distance, evaluation.theta]
            )
        )

    def DoCalcTimeDerivatives(  # noqa: N802 (Drake API)
        self, context: Context, derivatives: ContinuousState
    ) -> None:
        if self.update_period is None:  # a fixed-rate tube has no continuous state
            derivatives.get_mutable_vector().SetFromVector(self.evaluation(context).center_rate)

    def _discrete_update(self, context: Context, discrete_state: DiscreteValues) -> None:
        center, _ = self._law.advance(
            self.center(context), self._belief(context), self.update_period
        )
        discrete_state.set_value(self._state_index, center)
