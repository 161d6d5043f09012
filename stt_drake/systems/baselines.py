"""The baselines as Drake systems: a chance-constrained CBF-QP (discrete, zero-order hold)
and an artificial potential field (continuous). Their math is in
:mod:`stt_drake.core.baselines`.

Both read the same ports as the STT loop: `plant_state` (order 1: [y]; order 2: [y, ẏ])
and `obstacle_belief` (:class:`stt_drake.core.belief.GaussianBelief` layout; inactive slots
are ignored), and write `control` (n). The task numbers r_o, ε of each slot are a
constructor parameter (:class:`stt_drake.core.belief.ObstacleTask`; p_d is not used).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pydrake.solvers import ClarabelSolver, MathematicalProgram, OsqpSolver, SolverOptions
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from stt_drake.core.baselines import (
    GoalSeeking,
    NominalPlant,
    PotentialField,
    chance_margin,
    first_order_cbf_rows,
    saturate_norm,
    second_order_cbf_rows,
)
from stt_drake.core.belief import GaussianBelief, ObstacleTask, belief_size, largest_sigma

#: Solver options for tight tolerances (the QP is tiny, so tight costs little). OSQP's
#: solution polishing is off (`polishing`, OSQP ≥ 1.0's name; Drake rejects the older
#: `polish`): Drake turns it on by default, and OSQP's C code then prints "Polishing not
#: needed - no active set detected at optimal point" to stdout whenever no constraint is
#: active — whatever `verbose` says. At eps = 1e-9 the unpolished ADMM solution is accurate
#: enough for a command.
_SOLVER_OPTIONS = {
    "osqp": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 20000, "polishing": 0},
    "clarabel": {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10},
}


@dataclass(frozen=True)
class QpStep:
    """One step of :class:`CbfQp`: the command u (n,); `feasible`, whether the hard QP
    (every CBF row) was solved; `success`, whether any QP was solved (if not, `command` is
    meaningless and the caller brakes)."""

    command: np.ndarray
    feasible: bool
    success: bool


class _Program:
    """min ‖u − u_nom‖² (+ w Σ_j s_j + Σ_j s_j² when `slack_penalty` is given) s.t.
    A_j·u (+ s_j) ≥ b_j, −u_max ≤ u ≤ u_max (, s ≥ 0), with updatable u_nom, A, b."""

    def __init__(
        self, dimension: int, rows: int, input_limit: np.ndarray, slack_penalty: float | None
    ) -> None:
        self.prog = MathematicalProgram()
        self.u = self.prog.NewContinuousVariables(dimension, "u")
        self._hessian = 2.0 * np.eye(dimension)
        self._cost = self.prog.AddQuadraticCost(
            self._hessian, np.zeros(dimension), self.u
        ).evaluator()
        self.prog.AddBoundingBoxConstraint(-input_limit, input_limit, self.u)
        variables = self.u
        self._matrix = np.zeros((rows, dimension))
        if slack_penalty is not None:
            slack = self.prog.NewContinuousVariables(rows, "s")
            self.prog.AddQuadraticCost(2.0 * np.eye(rows), np.full(rows, slack_penalty), slack)
            self.prog.AddBoundingBoxConstraint(0.0, np.inf, slack)
            variables = np.concatenate([self.u, slack])
            self._matrix = np.hstack([self._matrix, np.eye(rows)])
        self._dimension = dimension
        self._upper = np.full(rows, np.inf)
        self._constraint = self.prog.AddLinearConstraint(
            self._matrix, np.full(rows, -np.inf), self._upper, variables
        ).evaluator()

    def update(self, nominal: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
        self._cost.UpdateCoefficients(self._hessian, -2.0 * nominal)
        self._matrix[:, : self._dimension] = a
        self._constraint.UpdateCoefficients(self._matrix, b, self._upper)


class CbfQp:
    """The CBF-QP of one control step, built once as Drake `MathematicalProgram`s whose
    coefficients each step updates (`UpdateCoefficients`; rebuilding measured 1.5-2× slower):

        hard:     min_u ‖u − u_nom‖²  s.t. A_j·u ≥ b_j (one row per obstacle slot),
                                           −u_max ≤ u ≤ u_max;
        relaxed:  min_{u,s} ‖u − u_nom‖² + w Σ_j s_j + Σ_j s_j²
                  s.t. A_j·u + s_j ≥ b_j, −u_max ≤ u ≤ u_max, s ≥ 0.

    An unused row is 0·u ≥ −∞. Each step solves the hard QP; only when the solver reports
    it infeasible (or fails) does `fallback="slack"` solve the relaxed one, the least
    violation weighted by w (its linear part; the unit quadratic part makes the Hessian
    positive definite, which OSQP's ADMM needs to converge, and the solution unique);
    `fallback="brake"` returns success = False and the caller brakes.

    Why two stages rather than always the relaxed QP (the same solution when the hard QP
    is feasible, the penalty being exact while every multiplier is below w): measured with
    Drake's OSQP, the relaxed QP with 50 rows took 1.4-22 ms and failed on up to 20 % of
    problems (w = 1e2..1e6; the large linear cost drowns the u-cost in OSQP's cost scaling),
    while the hard QP took 0.1 ms and agreed with Clarabel on every feasibility verdict.
    Clarabel handles both forms (0.1-0.5 ms).

    Args:
        dimension: n.
        rows: the number of CBF rows (obstacle slots).
        input_limit: u_max (n,) (plant input unit), > 0.
        solver: "osqp" or "clarabel" (Drake's `OsqpSolver` / `ClarabelSolver`).
        fallback: "slack" or "brake".
        slack_penalty: w (u's unit² per row unit).
    """

    def __init__(
        self,
        dimension: int,
        rows: int,
        input_limit: np.ndarray,
        solver: str = "osqp",
        fallback: str = "slack",
        slack_penalty: float = 1e4,
    ) -> None:
        solvers = {"osqp": OsqpSolver, "clarabel": ClarabelSolver}
        if solver not in solvers:
            raise ValueError(f"CbfQp: solver must be 'osqp' or 'clarabel', got {solver!r}")
        if fallback not in ("slack", "brake"):
            raise ValueError(f"CbfQp: fallback must be 'slack' or 'brake', got {fallback!r}")
        self._solver = solvers[solver]()
        if not self._solver.available():
            raise RuntimeError(f"CbfQp: Drake's {solver} solver is not available in this build")
        self._options = SolverOptions()
        for name, value in _SOLVER_OPTIONS[solver].items():
            self._options.SetOption(self._solver.solver_id(), name, value)
        self._hard = _Program(dimension, rows, input_limit, None)
        self._relaxed = (
            _Program(dimension, rows, input_limit, slack_penalty) if fallback == "slack" else None
        )
        self._dimension = dimension

    def solve(self, nominal: np.ndarray, a: np.ndarray, b: np.ndarray) -> QpStep:
        """Solve for u_nom = `nominal` (n,) and rows A = `a` (rows, n), b (rows,) (b_j = −∞
        for an unused row)."""
        for program in (self._hard, self._relaxed):
            if program is None:
                break
            program.update(nominal, a, b)
            result = self._solver.Solve(program.prog, None, self._options)
            if result.is_success():
                return QpStep(result.GetSolution(program.u), program is self._hard, True)
        return QpStep(np.zeros(self._dimension), False, False)


def _chance_margins(task: ObstacleTask, dimension: int) -> np.ndarray:
    """κ_j of every slot; ε_j = 1 has no finite margin (a Gaussian centre is unbounded)."""
    kappa = chance_margin(task.epsilon, dimension)
    if not np.all(np.isfinite(kappa)):
        raise ValueError(
            f"baseline: every epsilon must lie in (0, 1) for a finite chance margin, got "
            f"{np.asarray(task.epsilon).tolist()}"
        )
    return kappa


@dataclass(frozen=True)
class _Inputs:
    """What a baseline reads at one instant: the output y (n,), its velocity ẏ (n,; empty
    for order 1), the belief, and its active slots' indices, means (k, n) and inflated
    radii ρ_j = r_o_j + κ_j √λ_max(Σ_j) (k,)."""

    y: np.ndarray
    velocity: np.ndarray
    belief: GaussianBelief
    index: np.ndarray
    mean: np.ndarray
    rho: np.ndarray


class _BaselineController(LeafSystem):
    """The inputs both baselines share: `plant_state` (order·n) and `obstacle_belief`
    (GaussianBelief layout, task.count slots), the input limit and the chance margins."""

    def __init__(
        self,
        task: ObstacleTask,
        dimension: int,
        plant: NominalPlant,
        input_limit: float | np.ndarray,
    ) -> None:
        super().__init__()
        self._dimension = dimension
        self._plant = plant
        self._limit = np.broadcast_to(np.asarray(input_limit, dtype=float), (dimension,)).copy()
        self._radius = np.asarray(task.radius, dtype=float)
        self._kappa = _chance_margins(task, dimension)
        self._state_port = self.DeclareVectorInputPort("plant_state", plant.order * dimension)
        self._belief_port = self.DeclareVectorInputPort(
            "obstacle_belief", belief_size(task.count, dimension)
        )

    def _inputs(self, context: Context) -> _Inputs:
        n = self._dimension
        stacked = self._state_port.Eval(context)
        belief = GaussianBelief.from_vector(self._belief_port.Eval(context), n)
        index = np.flatnonzero(belief.active)
        rho = self._radius[index] + self._kappa[index] * largest_sigma(belief.covariance[index])
        return _Inputs(stacked[:n], stacked[n:], belief, index, belief.mean[index], rho)


class ChanceConstrainedCbfController(_BaselineController):
    """Chance-constrained CBF-QP baseline, updated every `period` seconds and held between
    updates (zero-order hold, as on hardware).

    Each update: u_nom from `goal_seeking` through the nominal plant, then :class:`CbfQp`
    with the rows of :func:`stt_drake.core.baselines.first_order_cbf_rows` (order 1) or
    :func:`stt_drake.core.baselines.second_order_cbf_rows` (order 2) for every active
    slot, for the inflated radius ρ_j = r_o_j + κ_j σ_j (κ_j = χ_n quantile at ε_j,
    σ_j = √λ_max(Σ_j)). The belief's rates are backward differences over one period,
    μ̇_j = (μ_j(t) − μ_j(t − T))/T and ρ̇_j likewise, held in the discrete state; they are 0
    at the first update and at the first update after a slot becomes active.

    When the hard QP is infeasible (or its solve fails) the step counts as infeasible
    (:meth:`infeasible_count`) and the fallback acts: with `fallback="slack"` the relaxed
    QP's u (least weighted violation), with `fallback="brake"` — or when the relaxed solve
    fails too — braking: order 1, u = 0; order 2, the nominal command for ÿ = −k_v ẏ,
    clipped to the input limit.

    Ports: inputs `plant_state` (order·n), `obstacle_belief` (GaussianBelief layout,
    task.count slots); output `control` (n), the held command.

    Args:
        task: r_o and ε of every slot.
        dimension: n.
        plant: the nominal plant model.
        goal_seeking: the nominal controller.
        input_limit: u_max, |u_i| ≤ u_max_i (scalar or (n,), plant input unit).
        period: control period T, s.
        rate: CBF rate, 1/s: α for order 1, the double pole p (k1 = 2p, k0 = p²) for order 2.
        solver: "osqp" or "clarabel".
        fallback: "slack" or "brake" (see :class:`CbfQp`).
        slack_penalty: w of :class:`CbfQp`.
    """

    def __init__(
        self,
        task: ObstacleTask,
        dimension: int,
        plant: NominalPlant,
        goal_seeking: GoalSeeking,
        input_limit: float | np.ndarray,
        period: float = 0.01,
        rate: float = 2.0,
        solver: str = "osqp",
        fallback: str = "slack",
        slack_penalty: float = 1e4,
    ) -> None:
        super().__init__(task, dimension, plant, input_limit)
        n, m = dimension, task.count
        self._count = m
        self._goal_seeking = goal_seeking
        self._period = period
        self._rate = rate
        self._qp = CbfQp(n, m, self._limit, solver, fallback, slack_penalty)
        #: Wall time of every update (µs): a diagnostic outside the Context, never read by
        #: the control law.
        self._step_times_us: list[float] = []

        self._control = self.DeclareDiscreteState(n)
        # The previous update's belief: means (m·n), inflated radii (m), active flags (m).
        self._previous = self.DeclareDiscreteState(m * n + 2 * m)
        # [updates, infeasible updates].
        self._counters = self.DeclareDiscreteState(2)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("control", self._control)

    def infeasible_count(self, context: Context) -> int:
        """Updates so far where the CBF rows could not all be met (fallback used)."""
        return int(context.get_discrete_state(self._counters).GetAtIndex(1))

    def update_count(self, context: Context) -> int:
        """Updates (QP solves) so far."""
        return int(context.get_discrete_state(self._counters).GetAtIndex(0))

    def median_step_time_us(self) -> float:
        """Median wall time of one update (belief unpacking, rows, QP update and solve) in
        µs over every update this system ran, in any context; NaN before the first."""
        return float(np.median(self._step_times_us)) if self._step_times_us else float("nan")

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        start = time.perf_counter()
        n, m = self._dimension, self._count
        inputs = self._inputs(context)
        y, velocity, belief = inputs.y, inputs.velocity, inputs.belief
        index, mean, rho = inputs.index, inputs.mean, inputs.rho

        previous = context.get_discrete_state(self._previous).value()
        previous_mean = previous[: m * n].reshape(m, n)[index]
        previous_rho = previous[m * n : m * n + m][index]
        seen = previous[m * n + m :][index] > 0.5
        mean_velocity = np.where(seen[:, None], (mean - previous_mean) / self._period, 0.0)
        rho_rate = np.where(seen, (rho - previous_rho) / self._period, 0.0)

        if self._plant.order == 1:
            a, b, _ = first_order_cbf_rows(y, mean, mean_velocity, rho, rho_rate, self._rate)
        else:
            a, b, _ = second_order_cbf_rows(
                y, velocity, mean, mean_velocity, rho, rho_rate, self._rate, self._plant
            )
        rows = np.zeros((m, n))
        rows[index] = a
        bounds = np.full(m, -np.inf)
        bounds[index] = b
        step = self._qp.solve(self._goal_seeking.command(self._plant, y, velocity), rows, bounds)
        command = step.command if step.success else self._brake(velocity)

        stored = np.zeros(m * n + 2 * m)
        stored[: m * n] = belief.mean.reshape(-1)
        stored[m * n : m * n + m][index] = rho
        stored[m * n + m :] = belief.active
        counters = context.get_discrete_state(self._counters).value()
        discrete_state.set_value(self._control, command)
        discrete_state.set_value(self._previous, stored)
        discrete_state.set_value(
            self._counters, counters + np.array([1.0, float(not step.feasible)])
        )
        self._step_times_us.append(1e6 * (time.perf_counter() - start))

    def _brake(self, velocity: np.ndarray) -> np.ndarray:
        """Order 1: stop (u = 0). Order 2: the command for ÿ = −k_v ẏ, clipped."""
        if self._plant.order == 1:
            return np.zeros(self._dimension)
        command = self._plant.command_for_velocity(
            np.zeros(self._dimension), velocity, self._goal_seeking.velocity_gain
        )
        return np.clip(command, -self._limit, self._limit)


class PotentialFieldController(_BaselineController):
    """Artificial potential field baseline: continuous, no state, direct feedthrough.

    F = −∇U(y) of :class:`stt_drake.core.baselines.PotentialField` over the active slots'
    inflated balls (ρ_j as in :class:`ChanceConstrainedCbfController`) is read as a desired
    velocity. Order 1: u = F. Order 2 (a PD on the field's velocity): v_d = sat_{v_max}(F),
    a = k_v (v_d − ẏ) (damping on the velocity error), u = m (a − f(ẏ)) in the nominal
    plant (:meth:`stt_drake.core.baselines.NominalPlant.command_for_velocity`). Then u is
    clipped to |u_i| ≤ u_max_i (the projection onto the input box).

    Ports: inputs `plant_state` (order·n), `obstacle_belief` (GaussianBelief layout,
    task.count slots); output `control` (n).

    Args:
        task: r_o and ε of every slot.
        dimension: n.
        plant: the nominal plant model.
        field: the potential field (goal and gains).
        input_limit: u_max (scalar or (n,), plant input unit).
        max_speed: v_max (m/s), order 2.
        velocity_gain: k_v (1/s), order 2.
    """

    def __init__(
        self,
        task: ObstacleTask,
        dimension: int,
        plant: NominalPlant,
        field: PotentialField,
        input_limit: float | np.ndarray,
        max_speed: float = 1.0,
        velocity_gain: float = 4.0,
    ) -> None:
        super().__init__(task, dimension, plant, input_limit)
        self._field = field
        self._max_speed = max_speed
        self._velocity_gain = velocity_gain
        self.DeclareVectorOutputPort("control", dimension, self._calc_control)

    def _calc_control(self, context: Context, output: BasicVector) -> None:
        inputs = self._inputs(context)
        command = self._field.field(inputs.y, inputs.mean, inputs.rho)
        if self._plant.order == 2:
            command = self._plant.command_for_velocity(
                saturate_norm(command, self._max_speed), inputs.velocity, self._velocity_gain
            )
        output.SetFromVector(np.clip(command, -self._limit, self._limit))
