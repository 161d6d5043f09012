"""SpatiotemporalTube: the STT centre as Drake state, radius and diagnostics as outputs."""

from __future__ import annotations

import math
from dataclasses import replace

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

    With ``target_input=True`` the target η is read from an extra input port `target` (n)
    instead of ``law.target`` — a task sequencer switches it (e.g. a pick-and-place).
    """

    def __init__(
        self,
        law: TubeLaw,
        initial_center: np.ndarray,
        obstacle_count: int,
        update_period: float | None = None,
        target_input: bool = False,
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
        self._target_port = (
            self.DeclareVectorInputPort("target", self._dimension) if target_input else None
        )
        self._laws_by_target: dict[bytes, TubeLaw] = {}
        self._last_key: tuple[bytes, bytes, bytes] | None = None
        self._last_evaluation: tuple[TubeEvaluation, np.ndarray] | None = None
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
            # (TubeEvaluation, the `tube` port value [c, r])
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
        self.DeclareVectorOutputPort(
            "recovery", obstacle_count, self._calc_recovery, prerequisites_of_calc=depends
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

    def _law_in(self, context: Context) -> TubeLaw:
        """The law with the target in use: ``law.target``, or the `target` input if declared.

        One law per distinct target is kept (a task sequence has a handful), so a law's
        cached constants survive across evaluations.
        """
        if self._target_port is None:
            return self._law
        target = self._target_port.Eval(context)
        key = target.tobytes()
        law = self._laws_by_target.get(key)
        if law is None:
            if len(self._laws_by_target) >= 64:  # a continuously moving target: do not grow
                self._laws_by_target.clear()
            law = self._laws_by_target[key] = replace(self._law, target=np.array(target))
        return law

    def _calc_evaluation(self, context: Context, value: AbstractValue) -> None:
        law = self._law_in(context)
        center = self.center(context)
        belief = self._belief_port.Eval(context)
        # The evaluation is a pure function of (c, belief, η). The integrator asks again for
        # the point the monitor has just checked (start of the next step) after its cache
        # was invalidated, so the last evaluation is kept and reused when its inputs match.
        target = b"" if self._target_port is None else np.asarray(law.target).tobytes()
        key = (center.tobytes(), belief.tobytes(), target)
        if key == self._last_key:
            value.set_value(self._last_evaluation)
            return
        evaluation = law.evaluate_packed(center, belief)
        tube = np.empty(self._dimension + 1)  # the `tube` port value, [c, r]
        tube[:-1] = center
        tube[-1] = evaluation.radius
        rate = evaluation.center_rate.tolist()
        if not (all(map(math.isfinite, rate)) and math.isfinite(evaluation.radius)):
            raise RuntimeError(
                f"tube law produced a non-finite value at t = {context.get_time():.6g} s: "
                f"ċ = {evaluation.center_rate}, r = {evaluation.radius}"
            )
        self._last_key, self._last_evaluation = key, (evaluation, tube)
        value.set_value(self._last_evaluation)

    def evaluation(self, context: Context) -> TubeEvaluation:
        """The cached law evaluation (ċ, r, q_j, d̂_j, θ_j) in `context`."""
        return self._evaluation.Eval(context)[0]

    def _calc_tube(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._evaluation.Eval(context)[1])

    def _calc_diagnostics(self, context: Context, output: BasicVector) -> None:
        evaluation = self.evaluation(context)
        output.SetFromVector(
            np.concatenate(
                [evaluation.avoid_probability, evaluation.quantile_distance, evaluation.theta]
            )
        )

    def _calc_recovery(self, context: Context, output: BasicVector) -> None:
        evaluation = self.evaluation(context)
        epsilon = self._belief(context).epsilon
        output.SetFromVector((evaluation.avoid_probability <= epsilon).astype(float))

    def DoCalcTimeDerivatives(  # noqa: N802 (Drake API)
        self, context: Context, derivatives: ContinuousState
    ) -> None:
        if self.update_period is None:  # a fixed-rate tube has no continuous state
            derivatives.get_mutable_vector().SetFromVector(self.evaluation(context).center_rate)

    def _discrete_update(self, context: Context, discrete_state: DiscreteValues) -> None:
        center, _ = self._law_in(context).advance(
            self.center(context), self._belief(context), self.update_period
        )
        discrete_state.set_value(self._state_index, center)
