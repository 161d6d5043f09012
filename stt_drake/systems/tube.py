"""SpatiotemporalTube: the STT centre as Drake state, radius and diagnostics as outputs."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import (
    BasicVector,
    Context,
    ContinuousState,
    DiscreteValues,
    EventStatus,
    LeafSystem,
    ValueProducer,
)

from stt_drake.core.belief import GaussianBelief, ObstacleBelief, ObstacleTask, belief_size
from stt_drake.core.circulation import carry_circulation
from stt_drake.core.fixed_rate import BeliefRateBounds
from stt_drake.core.rules import NU_HINT, check_nu_for_count, checked_by
from stt_drake.core.tube import TubeEvaluation, TubeLaw


class SpatiotemporalTube(LeafSystem):
    """The tube Γ(t) = B(c(t), r(t)) of Sec. 3, driven online by the obstacle belief.

    Input `obstacle_belief` (mean, covariance and active flag per slot:
    :class:`stt_drake.core.belief.GaussianBelief`); `task` gives each slot's r_o, ε, p_d.
    With ``full_covariance=True`` the law uses each Σ_j exactly
    (:mod:`stt_drake.core.anisotropic_tube`; continuous mode only), else σ_j² = λ_max(Σ_j)
    (exact for Σ_j = σ_j² I; :func:`stt_drake.core.belief.largest_sigma`). Only active slots
    reach ċ and r; an inactive slot's diagnostics read q = 1, d̂ = +∞, θ = 0. Outputs `tube`
    = [c, r] (n + 1), `diagnostics` = [q_j (m), d̂_j (m), θ_j (m)] and `recovery` (m): 1
    while the tube is recovering from obstacle j (its belief left the bounds the guarantee
    relies on; see :mod:`stt_drake.core.tube`), else 0.

    Two modes:

    * continuous (``update_period=None``): c is continuous state, ċ from Eq. (4)
      (|ċ| ≤ max_center_speed, recovery where q_j ≤ ε_j) integrated by the Simulator with
      error control and a bounded max step (the scenarios' default SimulatorConfig);
      recovery is q_j(c) ≤ ε_j.
    * fixed rate (``update_period=h``): at initialisation and then every h seconds
      :meth:`TubeLaw.advance` computes the next centre and radius from the belief sampled
      at the update, the way it runs on a robot; the output moves linearly from the values
      at the update to those at the end of the period, and q_j(c(t), t) > ε_j and
      r(t) ≤ d̂_j(c(t), t) are certified for the whole period from `rate_bounds` (required
      in this mode: the guarantee needs to know how fast each belief may move). Between
      updates the output costs an interpolation, no probability. Recovery is "period not
      certified for obstacle j".

    In continuous time the radius is evaluated at the current centre and belief, so
    r ≤ min_j d̂_j at every instant; at a fixed rate it is a certified lower bound of that.
    `diagnostics` always holds the law at the current centre and belief.

    In 3D the null-space directions follow circulation axes held in the Context (chosen
    when an obstacle activates, carried while it stays active; :func:`carry_circulation`),
    updated at every Simulator step (continuous) or update (fixed rate).

    The law's ν must exceed ln(n_o + 1)/r_min for the task's n_o slots (Theorem 3.2 (iii),
    :func:`stt_drake.core.rules.check_nu_for_count`), else ValueError at construction.

    With ``target_input=True`` the target η is read from an extra input port `target` (n)
    instead of ``law.target`` — a task sequencer switches it (e.g. a pick-and-place).
    """

    def __init__(
        self,
        law: TubeLaw,
        initial_center: np.ndarray,
        task: ObstacleTask,
        update_period: float | None = None,
        target_input: bool = False,
        rate_bounds: BeliefRateBounds | None = None,
        full_covariance: bool = False,
    ) -> None:
        super().__init__()
        if full_covariance and update_period is not None:
            raise ValueError(
                "full_covariance: the fixed-rate tube's period guarantee is derived for "
                "isotropic beliefs (sigma) only; use update_period=None (continuous) with "
                "covariances"
            )
        if update_period is not None and rate_bounds is None:
            raise ValueError(
                "rate_bounds: a fixed-rate tube needs each obstacle's belief rate bounds "
                "(BeliefRateBounds; .still(count) for beliefs that do not move) to keep its "
                "guarantee over a whole period"
            )
        with checked_by("SpatiotemporalTube", "law", NU_HINT):
            check_nu_for_count(law.nu, law.r_min, task.count)
        self._law = law
        self._dimension = len(initial_center)
        self._task = task
        self._task_table = task.table()
        self._full_covariance = full_covariance
        obstacle_count = self._count = task.count
        self.update_period = update_period
        self._rate_bounds = rate_bounds
        self._belief_port = self.DeclareVectorInputPort(
            "obstacle_belief", belief_size(obstacle_count, self._dimension)
        )
        self._target_port = (
            self.DeclareVectorInputPort("target", self._dimension) if target_input else None
        )
        initial_center = np.asarray(initial_center, dtype=float)
        circulates = self._dimension == 3 and obstacle_count > 0
        self._circulation_index = (
            self.DeclareDiscreteState(np.zeros(3 * obstacle_count)) if circulates else None
        )
        if update_period is None:
            self.DeclareContinuousState(BasicVector(initial_center))
            tickets = {self.xc_ticket(), self.xd_ticket()}
            if circulates:
                self.DeclarePerStepDiscreteUpdateEvent(self._carry_circulation)
        else:
            # [c, r] at the last update, [c, r] at the end of its period, its time, flags
            self._state_index = self.DeclareDiscreteState(
                _period_state(initial_center, obstacle_count)
            )
            # The first update at initialisation, then every period on the grid k·h with
            # offset 0 (the grid Drake puts a logger's samples on: fewer update and log times
            # one rounding apart, each of which costs the integrator a ~1e-15 s step); the
            # periodic event at t = 0 finds that update done and leaves it.
            self.DeclareInitializationDiscreteUpdateEvent(self._discrete_update)
            self.DeclarePeriodicDiscreteUpdateEvent(update_period, 0.0, self._discrete_update)
            tickets = {self.xd_ticket(), self.time_ticket()}
        # The law with the target in use: rebuilt only when the `target` input changes.
        self._target_law = (
            self.DeclareCacheEntry(
                description="tube law for the current target",
                value_producer=ValueProducer(
                    allocate=AbstractValue.Make(object()).Clone, calc=self._calc_target_law
                ),
                prerequisites_of_calc={self.input_port_ticket(self._target_port.get_index())},
            )
            if target_input
            else None
        )
        self._evaluation = self.DeclareCacheEntry(
            description="tube law evaluation",
            # (TubeEvaluation, [c, r] with the law's exact radius)
            value_producer=ValueProducer(
                allocate=AbstractValue.Make(object()).Clone, calc=self._calc_evaluation
            ),
            prerequisites_of_calc=tickets | {self.all_input_ports_ticket()},
        )
        depends = {self._evaluation.ticket()}
        self.DeclareVectorOutputPort(
            "tube",
            self._dimension + 1,
            self._calc_tube,
            prerequisites_of_calc=tickets | {self.all_input_ports_ticket()},
        )
        self.DeclareVectorOutputPort(
            "diagnostics", 3 * obstacle_count, self._calc_diagnostics, prerequisites_of_calc=depends
        )
        self.DeclareVectorOutputPort(
            "recovery",
            obstacle_count,
            self._calc_recovery,
            prerequisites_of_calc=depends | {self.xd_ticket()},
        )

    @property
    def law(self) -> TubeLaw:
        return self._law

    def center(self, context: Context) -> np.ndarray:
        """The tube centre c(t) in `context` (interpolated within a fixed-rate period)."""
        if self.update_period is None:
            return context.get_continuous_state_vector().CopyToVector()
        return np.array(self._interpolated(context)[:-1])

    def _interpolated(self, context: Context) -> list[float]:
        """[c(t), r(t)] of a fixed-rate tube: linear from the values at the last update to
        those at the end of its period (r is NaN before the first update). Scalar Python
        arithmetic on the n + 1 values: the output port's hot path, cheaper than numpy's
        per-call overhead."""
        size = self._dimension + 1
        values = context.get_discrete_state(self._state_index).value()[: 2 * size + 1].tolist()
        fraction = (context.get_time() - values[-1]) / self.update_period
        fraction = min(max(fraction, 0.0), 1.0)
        start, end = values[:size], values[size:-1]
        return [a + fraction * (b - a) for a, b in zip(start, end, strict=True)]

    def set_center(self, context: Context, center: np.ndarray) -> None:
        """Place the centre at `center` in `context` (held there until the next update in
        fixed-rate mode)."""
        center = np.asarray(center, dtype=float)
        if self.update_period is None:
            context.SetContinuousState(center)
            return
        state = _period_state(center, self._count, context.get_time())
        context.SetDiscreteState(self._state_index, state)

    def _circulation(self, context: Context) -> np.ndarray | None:
        if self._circulation_index is None:
            return None
        axes = context.get_discrete_state(self._circulation_index).CopyToVector()
        return axes.reshape(self._count, 3)

    def _belief(self, context: Context) -> GaussianBelief:
        """The belief port's value in `context`, unpacked."""
        return GaussianBelief.from_vector(self._belief_port.Eval(context), self._dimension)

    def _law_in(self, context: Context) -> TubeLaw:
        """The law with the target in use: ``law.target``, or the `target` input if declared."""
        if self._target_law is None:
            return self._law
        return self._target_law.Eval(context)

    def _calc_target_law(self, context: Context, value: AbstractValue) -> None:
        value.set_value(self._law.with_target(self._target_port.Eval(context)))

    def _calc_evaluation(self, context: Context, value: AbstractValue) -> None:
        law = self._law_in(context)
        center = self.center(context)
        circulation = self._circulation(context)
        if self._full_covariance:
            evaluation = law.evaluate_slots(
                center, self._belief(context), self._task, True, circulation=circulation
            )
        else:
            evaluation = law.evaluate_packed(
                center, self._belief_port.Eval(context), self._task_table, circulation=circulation
            )
        tube = np.empty(self._dimension + 1)  # the `tube` port value, [c, r]
        tube[:-1] = center
        tube[-1] = evaluation.radius
        rate = evaluation.center_rate.tolist()
        if not (all(map(math.isfinite, rate)) and math.isfinite(evaluation.radius)):
            raise RuntimeError(
                f"tube law produced a non-finite value at t = {context.get_time():.6g} s: "
                f"ċ = {evaluation.center_rate}, r = {evaluation.radius} (a recovery needs "
                f"a finite max_center_speed, v_c = {law.max_center_speed})"
            )
        value.set_value((evaluation, tube))

    def evaluation(self, context: Context) -> TubeEvaluation:
        """The cached law evaluation (ċ, r, q_j, d̂_j, θ_j) in `context`."""
        return self._evaluation.Eval(context)[0]

    def _calc_tube(self, context: Context, output: BasicVector) -> None:
        if self.update_period is not None:
            tube = self._interpolated(context)
            if not math.isnan(tube[-1]):  # certified at the update (before it: the law's)
                output.SetFromVector(tube)
                return
        output.SetFromVector(self._evaluation.Eval(context)[1])

    def _calc_diagnostics(self, context: Context, output: BasicVector) -> None:
        evaluation = self.evaluation(context)
        output.SetFromVector(
            np.concatenate(
                [evaluation.avoid_probability, evaluation.quantile_distance, evaluation.theta]
            )
        )

    def _calc_recovery(self, context: Context, output: BasicVector) -> None:
        if self.update_period is not None:
            state = context.get_discrete_state(self._state_index).value()
            output.SetFromVector(state[2 * self._dimension + 3 :])
            return
        epsilon = self._task.epsilon  # an inactive slot reads q = 1 > ε: never recovering
        output.SetFromVector((self.evaluation(context).avoid_probability <= epsilon) * 1.0)

    def DoCalcTimeDerivatives(  # noqa: N802 (Drake API)
        self, context: Context, derivatives: ContinuousState
    ) -> None:
        if self.update_period is None:  # a fixed-rate tube has no continuous state
            derivatives.get_mutable_vector().SetFromVector(self.evaluation(context).center_rate)

    def _carry(
        self,
        context: Context,
        discrete_state: DiscreteValues,
        center: np.ndarray,
        mean: np.ndarray,
        theta: np.ndarray,
    ) -> bool:
        """Write the circulation axes after this step (:func:`carry_circulation`) at
        `center` with θ_j evaluated there; False (nothing written) when no obstacle is
        active and no axis is held."""
        axes = self._circulation(context)
        active = theta > 0.0
        if not np.any(active) and not np.any(axes):
            return False
        target = self._law_in(context).target
        carried = carry_circulation(axes, center, mean, active, target - center)
        discrete_state.set_value(self._circulation_index, carried.ravel())
        return True

    def _carry_circulation(self, context: Context, discrete_state: DiscreteValues) -> EventStatus:
        center, theta = self.center(context), self.evaluation(context).theta
        if self._carry(context, discrete_state, center, self._belief(context).mean, theta):
            return EventStatus.Succeeded()
        return EventStatus.DidNothing()  # nothing active, nothing held: no state change

    def _discrete_update(self, context: Context, discrete_state: DiscreteValues) -> None:
        law = self._law_in(context)
        slots = self._belief(context)
        if not slots.active.all():
            raise RuntimeError(
                f"obstacle_belief: slots {np.flatnonzero(~slots.active).tolist()} inactive at "
                f"t = {context.get_time():.6g} s; the fixed-rate tube's rate bounds need every "
                "slot active (run a tracked belief in continuous time)"
            )
        belief = ObstacleBelief.of(slots, self._task)
        # `discrete_state` holds the current values: update them in place.
        state = discrete_state.get_mutable_value(self._state_index)
        n = self._dimension
        if state[2 * n + 2] == context.get_time() and not math.isnan(state[n]):
            return  # this instant's update is done (initialisation, then the grid at t = 0)
        reached = state[n + 1 : 2 * n + 1].copy()  # the centre now (end of the last period)
        update = law.advance(
            reached,
            belief,
            self.update_period,
            self._rate_bounds,
            self._circulation(context),
            radius=state[2 * n + 1],
        )
        state[:n] = reached
        state[n] = update.start_radius
        state[n + 1 : 2 * n + 1] = update.center
        state[2 * n + 1] = update.end_radius
        state[2 * n + 2] = context.get_time()
        state[2 * n + 3 :] = ~update.certified
        if self._circulation_index is not None:
            self._carry(context, discrete_state, update.center, belief.mean, update.theta)


def _period_state(center: np.ndarray, count: int, time: float = 0.0) -> np.ndarray:
    """A fixed-rate tube's state with the centre held at `center`, no radius yet and
    nothing recovering: [c and r at the update, c and r at the end of the period, the update
    time, one recovery flag per obstacle (1 = not certified)]."""
    held = [*center, math.nan]
    return np.concatenate([held, held, [time], np.zeros(count)])
