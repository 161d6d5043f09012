"""SpatiotemporalTube: the STT centre as Drake state, radius and diagnostics as outputs.

One system; how it moves its centre is chosen when it is built (`update_period`):

* :class:`ContinuousCentre`: c is continuous state, ċ from Eq. (4) integrated by the
  Simulator; recovery is q_j(c) ≤ ε_j.
* :class:`FixedRateCentre`: c and r are discrete state (slots named by
  :class:`PeriodLayout`), updated every h seconds by :meth:`stt_drake.core.tube.TubeLaw.advance`
  and interpolated linearly in between; recovery is "period not certified for obstacle j".

Each mode declares its state and events on the system and answers what differs: the centre,
the `tube` output, the `recovery` output and ċ. The rest — the ports, the belief prepared
once from the input, the law's evaluation, the diagnostics, the 3D circulation axes — is the
system's, shared by both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

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

from stt_drake.core.belief import (
    ObstacleBelief,
    ObstacleTask,
    PortBelief,
    belief_size,
    slot_active,
)
from stt_drake.core.circulation import carry_circulation
from stt_drake.core.fixed_rate import BeliefRateBounds, advance_port
from stt_drake.core.rules import (
    NU_HINT,
    check_continuous_for_covariance,
    check_nu_for_count,
    checked_by,
)
from stt_drake.core.tube import TubeEvaluation, TubeLaw
from stt_drake.systems.memo import LastResult

# The carry's statuses, made once (each EventStatus made is a call into Drake; at every step)
_NOTHING_CARRIED, _CARRIED = EventStatus.DidNothing(), EventStatus.Succeeded()


class SpatiotemporalTube(LeafSystem):
    """The tube Γ(t) = B(c(t), r(t)) of Sec. 3, driven online by the obstacle belief.

    Input `obstacle_belief` (mean, covariance and active flag per slot:
    :class:`stt_drake.core.belief.GaussianBelief`); `task` gives each slot's r_o, ε, p_d.
    The input is prepared once per change (:meth:`ObstacleBelief.from_port`, :meth:`belief`).
    With ``full_covariance=True`` the law uses each Σ_j exactly
    (:mod:`stt_drake.core.anisotropic_tube`; continuous mode only,
    :func:`stt_drake.core.rules.check_continuous_for_covariance`), else σ_j² = λ_max(Σ_j)
    (exact for Σ_j = σ_j² I; :func:`stt_drake.core.belief.largest_sigma`). Only active slots
    reach ċ and r; an inactive slot's diagnostics read q = 1, d̂ = +∞, θ = 0. Outputs `tube`
    = [c, r] (n + 1), `diagnostics` = [q_j (m), d̂_j (m), θ_j (m)] and `recovery` (m): 1
    while the tube is recovering from obstacle j (its belief left the bounds the guarantee
    relies on; see :mod:`stt_drake.core.tube`), else 0.

    Modes (module docstring): continuous (``update_period=None``, :class:`ContinuousCentre`)
    or fixed rate (``update_period=h``, :class:`FixedRateCentre`; `rate_bounds` required:
    the guarantee needs to know how fast each belief may move). In continuous time the
    radius is evaluated at the current centre and belief, so r ≤ min_j d̂_j at every instant;
    at a fixed rate it is a certified lower bound of that. `diagnostics` always holds the law
    at the current centre and belief.

    In 3D the null-space directions follow circulation axes held in the Context (chosen
    when an obstacle activates, carried while it stays active; :func:`carry_circulation`),
    updated at every Simulator step (continuous) or update (fixed rate).

    The law's ν must exceed ln(n_o + 1)/r_min for the task's n_o slots (Theorem 3.2 (iii),
    :func:`stt_drake.core.rules.check_nu_for_count`), else ValueError at construction.

    With ``target_input=True`` the target η is read from an extra input port `target` (n)
    instead of ``law.target`` — a task sequencer switches it (e.g. a pick-and-place).
    """

    def __new__(
        cls,
        law: TubeLaw,
        initial_center: np.ndarray,
        task: ObstacleTask,
        *args: object,
        **kwargs: object,
    ) -> SpatiotemporalTube:
        # A fixed-rate tube has no continuous state: made as _FixedRateTube, which keeps
        # Drake's own DoCalcTimeDerivatives, no derivative evaluation calls into Python.
        update_period = args[0] if args else kwargs.get("update_period")
        fixed_rate = cls is SpatiotemporalTube and update_period is not None
        return super().__new__(_FixedRateTube if fixed_rate else cls)

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
        with checked_by("SpatiotemporalTube", hint="use update_period=None with covariances"):
            check_continuous_for_covariance(
                full_covariance, update_period is not None, "update_period", update_period, "None"
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
        self.task = task
        self._full_covariance = full_covariance
        obstacle_count = task.count
        self._belief_port = self.DeclareVectorInputPort(
            "obstacle_belief", belief_size(obstacle_count, self._dimension)
        )
        self._target_port = (
            self.DeclareVectorInputPort("target", self._dimension) if target_input else None
        )
        initial_center = np.asarray(initial_center, dtype=float)
        #: Whether circulation axes are held (3D with obstacles).
        self.circulates = self._dimension == 3 and obstacle_count > 0
        self._circulation_index = (
            self.DeclareDiscreteState(np.zeros(3 * obstacle_count)) if self.circulates else None
        )
        self._mode: ContinuousCentre | FixedRateCentre = (
            ContinuousCentre()
            if update_period is None
            else FixedRateCentre(update_period, rate_bounds)
        )
        tickets = self._mode.declare(self, initial_center)
        # The axes are the only discrete state (continuous time): read as the whole vector
        self._circulation_alone = self.circulates and self.num_discrete_state_groups() == 1
        # The law with the target in use: rebuilt only when the `target` input changes.
        self._target_law = (
            self._declare_cache(
                "tube law for the current target",
                self._calc_target_law,
                {self.input_port_ticket(self._target_port.get_index())},
            )
            if target_input
            else None
        )
        self._belief = self._declare_cache(
            "obstacle belief prepared for the law",
            self._calc_belief,
            {self.input_port_ticket(self._belief_port.get_index())},
        )
        # (TubeEvaluation, [c, r] with the law's exact radius); the last one memoised
        # (stt_drake.systems.memo: a step's first stage repeats the monitor's evaluation).
        self._last_evaluation = LastResult()
        self._last_target_law = LastResult()
        self._evaluation = self._declare_cache(
            "tube law evaluation",
            self._calc_evaluation,
            tickets | {self.all_input_ports_ticket()},
        )
        depends = {self._evaluation.ticket()}
        self.DeclareVectorOutputPort(
            "tube",
            self._dimension + 1,
            self._mode.calc_tube,
            prerequisites_of_calc=tickets | {self.all_input_ports_ticket()},
        )
        self.DeclareVectorOutputPort(
            "diagnostics", 3 * obstacle_count, self._calc_diagnostics, prerequisites_of_calc=depends
        )
        self.DeclareVectorOutputPort(
            "recovery",
            obstacle_count,
            lambda context, output: output.SetFromVector(self._mode.recovery(context)),
            prerequisites_of_calc=depends | {self.xd_ticket()},
        )

    def _declare_cache(self, description: str, calc: object, prerequisites: set) -> object:
        """A cache entry holding any Python object, computed by `calc`."""
        return self.DeclareCacheEntry(
            description=description,
            value_producer=ValueProducer(allocate=AbstractValue.Make(object()).Clone, calc=calc),
            prerequisites_of_calc=prerequisites,
        )

    @property
    def law(self) -> TubeLaw:
        return self._law

    @property
    def update_period(self) -> float | None:
        """h of the fixed-rate tube (s); None in continuous time."""
        return self._mode.update_period

    def center(self, context: Context) -> np.ndarray:
        """The tube centre c(t) in `context` (interpolated within a fixed-rate period)."""
        return self._mode.center(context)

    def set_center(self, context: Context, center: np.ndarray) -> None:
        """Place the centre at `center` in `context` (held there until the next update in
        fixed-rate mode)."""
        self._mode.set_center(context, np.asarray(center, dtype=float))

    def belief(self, context: Context) -> PortBelief:
        """The `obstacle_belief` input with the task numbers, as the law reads it (made
        once per input change)."""
        return self._belief.Eval(context)

    def _calc_belief(self, context: Context, value: AbstractValue) -> None:
        value.set_value(
            ObstacleBelief.from_port(
                self._belief_port.Eval(context), self._dimension, self.task, self._full_covariance
            )
        )

    def circulation(self, context: Context) -> np.ndarray | None:
        """The circulation axes (slots, 3) held in `context` (None: not 3D)."""
        if self._circulation_index is None:
            return None
        axes = (  # the whole-vector read costs a quarter less than the group's
            context.get_discrete_state_vector()
            if self._circulation_alone
            else context.get_discrete_state(self._circulation_index)
        ).CopyToVector()
        return axes.reshape(self.task.count, 3)

    def law_in(self, context: Context) -> TubeLaw:
        """The law with the target in use: ``law.target``, or the `target` input if declared."""
        if self._target_law is None:
            return self._law
        return self._target_law.Eval(context)

    def _calc_target_law(self, context: Context, value: AbstractValue) -> None:
        # The same target gives the same law object (with its looked-up kernel, gains and
        # constants): this entry is recomputed at every step, the target rarely changes.
        target = self._target_port.Eval(context)
        key, law = self._last_target_law.lookup(target)
        if law is None:
            law = self._last_target_law.store(key, self._law.with_target(target))
        value.set_value(law)

    def _calc_evaluation(self, context: Context, value: AbstractValue) -> None:
        # The hot path: the port vector is the memo key, and the law reads it as it is (no
        # belief is made: the `belief` cache entry is for the readers that need one).
        center = self.center(context)
        vector, circulation = self._belief_port.Eval(context), self.circulation(context)
        target = None if self._target_law is None else self._target_port.Eval(context)
        key, result = self._last_evaluation.lookup(center, vector, circulation, target)
        if result is not None:  # the same inputs as the last evaluation: its result
            value.set_value(result)
            return
        law = self.law_in(context)
        evaluation = law.evaluate_port(
            center, vector, self.task, self._full_covariance, circulation
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
        value.set_value(self._last_evaluation.store(key, (evaluation, tube)))

    def evaluated(self, context: Context) -> tuple[TubeEvaluation, np.ndarray]:
        """The cached (law evaluation, [c, r] with the law's exact radius) in `context`."""
        return self._evaluation.Eval(context)

    def evaluation(self, context: Context) -> TubeEvaluation:
        """The cached law evaluation (ċ, r, q_j, d̂_j, θ_j) in `context`."""
        return self._evaluation.Eval(context)[0]

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
        self._mode.derivatives(context, derivatives)

    @staticmethod
    def carries(theta: np.ndarray, axes: np.ndarray) -> bool:
        """Whether the axes need carrying (:meth:`carry`): some obstacle is active (θ_j > 0)
        or some axis is held."""
        # θ_j ≥ 0: none active, none held (count_nonzero costs a third of any())
        return bool(np.count_nonzero(theta) or np.count_nonzero(axes))

    def carry(
        self,
        context: Context,
        discrete_state: DiscreteValues,
        center: np.ndarray,
        theta: np.ndarray,
        axes: np.ndarray,
        keep: bool = False,
    ) -> None:
        """Write the circulation axes after this step (:func:`carry_circulation`) at
        `center` with θ_j evaluated there, from the `axes` held in `context`
        (:meth:`circulation`). With `keep` (`center` is the
        centre in `context`), the memoised evaluation there stands for the carried axes too
        (:meth:`keep_evaluation`)."""
        vector = self._belief_port.Eval(context)
        # The port table as it is: μ_j in its first 3 columns (no copy of the means).
        table = vector.reshape(self.task.count, -1)
        goal = self.law_in(context).target - center
        carried = carry_circulation(axes, center, table, theta > 0.0, goal)
        discrete_state.set_value(self._circulation_index, carried.ravel())
        if keep:
            self.keep_evaluation(context, center, vector, axes, carried)

    def keep_evaluation(
        self,
        context: Context,
        center: np.ndarray,
        vector: np.ndarray,
        held: np.ndarray,
        carried: np.ndarray,
    ) -> None:
        """After the axes `held` were carried to `carried` at `center` (the centre in
        `context`, `vector` its belief port value), the memoised evaluation there stands for
        the new axes too: v_j keeps its direction when its axis is carried at the centre it
        is carried at (:func:`carry_circulation`), so ċ is the same up to rounding and the
        step's first stage need not run the law again. Not with full covariances (there
        ∇̂q_j is not along c − μ_j)."""
        if self._full_covariance:
            return
        target = None if self._target_law is None else self._target_port.Eval(context)
        key = self._last_evaluation.key
        held_key = key(center, vector, held, target)  # the order of _calc_evaluation's lookup
        # The same key but for the axes (the other parts' bytes made once)
        self._last_evaluation.rekey(held_key, (*held_key[:2], *key(carried), *held_key[3:]))


class _FixedRateTube(SpatiotemporalTube):
    """A :class:`SpatiotemporalTube` with ``update_period=h`` (made by its constructor): no
    continuous state, so Drake's own (empty) time derivatives instead of a Python call per
    derivative evaluation (a few per cent of a fixed-rate closed loop)."""

    DoCalcTimeDerivatives = LeafSystem.DoCalcTimeDerivatives


class ContinuousCentre:
    """The continuous-time tube: c is continuous state, ċ = the law's centre rate (Eq. (4),
    |ċ| ≤ max_center_speed, recovery where q_j ≤ ε_j), integrated by the Simulator with error
    control and a bounded max step (the scenarios' default SimulatorConfig). The radius is
    evaluated at the current centre and belief, so r ≤ min_j d̂_j at every instant. 3D
    circulation axes are carried at every Simulator step."""

    update_period = None

    def declare(self, tube: SpatiotemporalTube, initial_center: np.ndarray) -> set:
        """Declare c on `tube`; the tickets of what the centre depends on."""
        self._tube = tube
        tube.DeclareContinuousState(BasicVector(initial_center))
        if tube.circulates:
            tube.DeclarePerStepDiscreteUpdateEvent(self._carry_circulation)
        return {tube.xc_ticket(), tube.xd_ticket()}

    def center(self, context: Context) -> np.ndarray:
        return context.get_continuous_state_vector().CopyToVector()

    def set_center(self, context: Context, center: np.ndarray) -> None:
        context.SetContinuousState(center)

    def calc_tube(self, context: Context, output: BasicVector) -> None:
        """The `tube` output [c, r]: the law's exact radius at the current centre."""
        output.SetFromVector(self._tube.evaluated(context)[1])

    def recovery(self, context: Context) -> np.ndarray:
        """1.0 where q_j(c) ≤ ε_j (an inactive slot reads q = 1 > ε: never recovering)."""
        q = self._tube.evaluation(context).avoid_probability
        return (q <= self._tube.task.epsilon) * 1.0

    def derivatives(self, context: Context, derivatives: ContinuousState) -> None:
        derivatives.SetFromVector(self._tube.evaluation(context).center_rate)

    def _carry_circulation(self, context: Context, discrete_state: DiscreteValues) -> EventStatus:
        tube = self._tube
        theta, held = tube.evaluation(context).theta, tube.circulation(context)
        if not tube.carries(theta, held):
            return _NOTHING_CARRIED  # nothing active, nothing held: no state change
        tube.carry(context, discrete_state, self.center(context), theta, held, keep=True)
        return _CARRIED


@dataclass(frozen=True)
class PeriodLayout:
    """The slots of a fixed-rate tube's discrete state vector, for dimension n and
    `count` obstacle slots: c and r at the last update, c and r at the end of its period,
    the update time, and one recovery flag per obstacle (1 = not certified)."""

    dimension: int
    count: int

    @cached_property  # read at every update and output: computed once
    def start_center(self) -> slice:
        return slice(0, self.dimension)

    @cached_property
    def start_radius(self) -> int:
        return self.dimension

    @cached_property
    def end_center(self) -> slice:
        return slice(self.dimension + 1, 2 * self.dimension + 1)

    @cached_property
    def end_radius(self) -> int:
        return 2 * self.dimension + 1

    @cached_property
    def time(self) -> int:
        return 2 * self.dimension + 2

    @cached_property
    def recovery(self) -> slice:
        return slice(2 * self.dimension + 3, None)

    def held(self, center: np.ndarray, time: float = 0.0) -> np.ndarray:
        """The state with the centre held at `center`, no radius yet and nothing
        recovering."""
        held = [*center, math.nan]
        return np.concatenate([held, held, [time], np.zeros(self.count)])


class FixedRateCentre:
    """The fixed-rate tube (update period h): at initialisation and then every h seconds
    :meth:`TubeLaw.advance` (:func:`stt_drake.core.fixed_rate.advance_port`: on the port
    vector, no belief made) computes the next centre and radius from the belief sampled at
    the update, the way it runs on a robot; the output moves linearly from the values at the
    update to those at the end of the period, and q_j(c(t), t) > ε_j and
    r(t) ≤ d̂_j(c(t), t) are certified for the whole period from `rate_bounds`. Between
    updates the output costs an interpolation, no probability. Every slot must be active
    (the rate bounds are per obstacle)."""

    def __init__(self, update_period: float, rate_bounds: BeliefRateBounds) -> None:
        self.update_period = update_period
        self._rate_bounds = rate_bounds

    def declare(self, tube: SpatiotemporalTube, initial_center: np.ndarray) -> set:
        """Declare the period state and the update events on `tube`; the tickets of what
        the centre depends on."""
        self._tube = tube
        self._layout = PeriodLayout(len(initial_center), tube.task.count)
        self._state_index = tube.DeclareDiscreteState(self._layout.held(initial_center))
        # The first update at initialisation, then every period on the grid k·h with
        # offset 0 (the grid Drake puts a logger's samples on: fewer update and log times
        # one rounding apart, each of which costs the integrator a ~1e-15 s step); the
        # periodic event at t = 0 finds that update done and leaves it.
        tube.DeclareInitializationDiscreteUpdateEvent(self._update)
        tube.DeclarePeriodicDiscreteUpdateEvent(self.update_period, 0.0, self._update)
        # The period read off the state once per change, not at every output (_interpolated).
        self._period = tube._declare_cache(
            "fixed-rate period", self._calc_period, {tube.discrete_state_ticket(self._state_index)}
        )
        return {tube.xd_ticket(), tube.time_ticket()}

    def _calc_period(self, context: Context, value: AbstractValue) -> None:
        """([c_k, r_k], [c_{k+1} − c_k, r_{k+1} − r_k], t_k) of the state, as Python floats."""
        size, time = self._layout.dimension + 1, self._layout.time  # [c, r] twice, then t_k
        values = context.get_discrete_state(self._state_index).value()[: time + 1].tolist()
        start = values[:size]
        value.set_value((start, [values[size + i] - start[i] for i in range(size)], values[time]))

    def _interpolated(self, context: Context) -> list[float]:
        """[c(t), r(t)]: linear from the values at the last update to those at the end of
        its period (r is NaN before the first update). Scalar Python arithmetic on the
        n + 1 values: the output port's hot path, cheaper than numpy's per-call overhead."""
        start, change, start_time = self._period.Eval(context)
        fraction = (context.get_time() - start_time) / self.update_period
        # clamped to [0, 1] by comparisons: min(max(...)) costs two builtin calls more
        fraction = 0.0 if fraction < 0.0 else 1.0 if fraction > 1.0 else fraction
        return [a + fraction * d for a, d in zip(start, change, strict=True)]

    def center(self, context: Context) -> np.ndarray:
        return np.array(self._interpolated(context)[:-1])

    def set_center(self, context: Context, center: np.ndarray) -> None:
        """Hold the centre at `center` until the next update."""
        context.SetDiscreteState(self._state_index, self._layout.held(center, context.get_time()))

    def calc_tube(self, context: Context, output: BasicVector) -> None:
        """The `tube` output: the certified interpolation (before the first update: the
        law's)."""
        tube = self._interpolated(context)
        output.SetFromVector(self._tube.evaluated(context)[1] if math.isnan(tube[-1]) else tube)

    def recovery(self, context: Context) -> np.ndarray:
        """The flags of the last update: 1.0 where the period was not certified."""
        return context.get_discrete_state(self._state_index).value()[self._layout.recovery]

    def derivatives(self, context: Context, derivatives: ContinuousState) -> None:
        """No continuous state."""

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        tube, layout, now = self._tube, self._layout, context.get_time()
        # The law reads the port vector itself (advance_port: no belief is made).
        vector = tube._belief_port.Eval(context)
        active = slot_active(vector, layout.dimension)
        if np.count_nonzero(active) < active.size:  # not all active (a third of all()'s cost)
            raise RuntimeError(
                f"obstacle_belief: slots {np.flatnonzero(~active).tolist()} "
                f"inactive at t = {now:.6g} s; the fixed-rate tube's rate "
                "bounds need every slot active (run a tracked belief in continuous time)"
            )
        # `discrete_state` holds the current values: update them in place.
        state = discrete_state.get_mutable_value(self._state_index)
        if state[layout.time] == now and not math.isnan(state[layout.start_radius]):
            return  # this instant's update is done (initialisation, then the grid at t = 0)
        reached = state[layout.end_center].copy()  # the centre now (end of the last period)
        circulation = tube.circulation(context)
        update = advance_port(
            tube.law_in(context),
            reached,
            vector,
            tube.task,
            self.update_period,
            self._rate_bounds,
            circulation,
            radius=state[layout.end_radius],
        )
        # [c, r] at both ends of the period, then t_k (PeriodLayout), in one write
        state[: layout.time + 1] = [
            *reached.tolist(),
            update.start_radius,
            *update.center.tolist(),
            update.end_radius,
            now,
        ]
        state[layout.recovery] = ~update.certified
        if circulation is not None and tube.carries(update.theta, circulation):
            tube.carry(context, discrete_state, update.center, update.theta, circulation)
