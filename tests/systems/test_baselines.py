"""The comparison baselines: the chance margin κ, the CBF rows and QP, the CC-CBF-QP in a
closed loop, and the potential field."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.solvers import ClarabelSolver, OsqpSolver
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial
from scipy.stats import chi

from stt_drake.core.baselines import (
    GoalSeeking,
    NominalPlant,
    PotentialField,
    chance_margin,
    first_order_cbf_rows,
    second_order_cbf_rows,
)
from stt_drake.core.belief import GaussianBelief, ObstacleTask, largest_sigma
from stt_drake.systems.baselines import (
    CbfQp,
    ChanceConstrainedCbfController,
    PotentialFieldController,
)
from stt_drake.systems.plants.omni import OmniDriveInterface, OmniRobot
from stt_drake.systems.plants.quadrotor import Quadrotor

SOLVERS = [
    name
    for name, solver in (("osqp", OsqpSolver()), ("clarabel", ClarabelSolver()))
    if solver.available()
]


def _avoid_probability(y, mean, covariance, radius, samples, seed):
    """Monte Carlo P(‖y − O‖ ≥ r_o) for O ~ N(mean, covariance), and its standard error."""
    rng = np.random.default_rng(seed)
    centres = rng.multivariate_normal(mean, covariance, size=samples)
    p = float(np.mean(np.linalg.norm(centres - y, axis=1) >= radius))
    return p, np.sqrt(p * (1.0 - p) / samples)


@pytest.mark.parametrize("dimension", [2, 3])
@pytest.mark.parametrize("epsilon", [0.5, 0.9, 0.99])
def test_chance_margin_keeps_the_avoidance_probability(dimension, epsilon):
    sigma, radius, samples = 0.3, 0.5, 200_000
    kappa = float(chance_margin(epsilon, dimension))
    mean = np.zeros(dimension)
    y = np.zeros(dimension)
    y[0] = radius + kappa * sigma
    covariance = sigma**2 * np.eye(dimension)
    p, error = _avoid_probability(y, mean, covariance, radius, samples, seed=dimension)
    assert p - 4.0 * error >= epsilon  # the bound holds, beyond Monte Carlo noise
    # κσ is exactly the ε-ball of the centre: not looser than its definition.
    rng = np.random.default_rng(7)
    inside = np.linalg.norm(rng.normal(0.0, sigma, (samples, dimension)), axis=1) <= kappa * sigma
    assert abs(np.mean(inside) - epsilon) <= 4.0 * np.sqrt(epsilon * (1 - epsilon) / samples)


def test_chance_margin_is_the_chi_quantile():
    epsilon = np.array([0.1, 0.5, 0.9, 0.99, 0.999])
    for dimension in (1, 2, 3, 6):
        np.testing.assert_allclose(
            chance_margin(epsilon, dimension), chi.ppf(epsilon, dimension), rtol=1e-12
        )


def test_largest_sigma_is_conservative_for_a_full_covariance():
    """y on the worst (major) axis at r_o + κ√λ_max: still P ≥ ε."""
    angle = 0.4
    axes = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    covariance = axes @ np.diag([0.4**2, 0.1**2]) @ axes.T
    sigma = float(largest_sigma(covariance))
    assert sigma == pytest.approx(0.4, rel=1e-12)
    epsilon, radius = 0.95, 0.3
    y = axes[:, 0] * (radius + float(chance_margin(epsilon, 2)) * sigma)
    p, error = _avoid_probability(y, np.zeros(2), covariance, radius, 200_000, seed=3)
    assert p - 4.0 * error >= epsilon


def test_second_order_rows_match_finite_differences_of_h():
    """A·u − b = ḧ + 2p ḣ + p² h along a trajectory with ÿ = u/m + f(ẏ), μ̈ = 0: checks
    the exact curvature term."""
    plant = NominalPlant(order=2, mass=1.3, drag=0.4, gravity=9.81)
    y0, v0 = np.array([0.2, -0.1, 1.0]), np.array([0.5, 0.8, -0.3])
    mean0, mean_velocity = np.array([[1.5, 0.7, 0.9]]), np.array([[-0.4, 0.1, 0.2]])
    rho, rate, u = np.array([0.6]), 1.7, np.array([0.3, -2.0, 14.0])
    a, b, h = second_order_cbf_rows(y0, v0, mean0, mean_velocity, rho, np.zeros(1), rate, plant)
    acceleration = u / plant.mass + plant.drift(v0.copy())

    def barrier(t):
        y = y0 + v0 * t + 0.5 * acceleration * t**2
        return np.linalg.norm(y - (mean0[0] + mean_velocity[0] * t)) - rho[0]

    step = 1e-4
    h_dot = (barrier(step) - barrier(-step)) / (2 * step)
    h_ddot = (barrier(step) - 2 * barrier(0.0) + barrier(-step)) / step**2
    assert h[0] == pytest.approx(barrier(0.0), abs=1e-14)
    assert a[0] @ u - b[0] == pytest.approx(h_ddot + 2 * rate * h_dot + rate**2 * h[0], abs=1e-5)


def _projection(a, b, nominal):
    """The one-row QP min ‖u − u_nom‖² s.t. a·u ≥ b in closed form."""
    return nominal + max(0.0, -(a @ nominal - b)) / (a @ a) * a


@pytest.mark.parametrize("solver", SOLVERS)
def test_qp_matches_the_closed_form_projection(solver):
    """Random one-row QPs (box inactive). Tolerance 1e-6: both solvers run at tolerances of
    1e-9 (OSQP, unpolished) and 1e-10 (Clarabel) on a problem of unit scale, so 1e-6 leaves
    three orders of margin and still catches a wrong row or sign."""
    rng = np.random.default_rng(11)
    qp = CbfQp(dimension=2, rows=1, input_limit=np.full(2, 10.0), solver=solver)
    for _ in range(50):
        a = rng.normal(size=2)
        nominal = rng.normal(size=2)
        b = a @ nominal + rng.uniform(-1.0, 1.0)
        step = qp.solve(nominal, a[None, :], np.array([b]))
        assert step.success
        assert step.feasible
        np.testing.assert_allclose(step.command, _projection(a, b, nominal), atol=1e-6)


@pytest.mark.parametrize("solver", SOLVERS)
def test_qp_solves_print_nothing(solver, capfd):
    """A QP whose optimum activates no constraint (OSQP with polishing on prints "Polishing
    not needed ..." from its C code, file descriptor 1) and one with an active row: nothing
    reaches stdout or stderr."""
    qp = CbfQp(dimension=2, rows=1, input_limit=np.full(2, 10.0), solver=solver)
    interior = qp.solve(np.array([0.1, 0.1]), np.array([[1.0, 0.0]]), np.array([-5.0]))
    active = qp.solve(np.array([0.1, 0.1]), np.array([[1.0, 0.0]]), np.array([1.0]))
    assert interior.feasible and active.feasible
    np.testing.assert_allclose(interior.command, [0.1, 0.1], atol=1e-6)
    np.testing.assert_allclose(active.command, [1.0, 0.1], atol=1e-6)
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == ""


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_qp_falls_back(solver):
    """u_nom = (1, 0), row −u_x ≥ 1, |u_i| ≤ 0.2: infeasible; the relaxed QP gives the least
    violation u = (−0.2, 0); without slacks the caller is told to brake."""
    rows = (np.array([1.0, 0.0]), np.array([[-1.0, 0.0]]), np.array([1.0]))
    relaxed = CbfQp(2, 1, np.full(2, 0.2), solver, fallback="slack").solve(*rows)
    assert relaxed.success and not relaxed.feasible
    np.testing.assert_allclose(relaxed.command, [-0.2, 0.0], atol=1e-6)
    braking = CbfQp(2, 1, np.full(2, 0.2), solver, fallback="brake").solve(*rows)
    assert not braking.success and not braking.feasible


def _single_obstacle_task(epsilon=0.9, radius=0.3):
    return ObstacleTask(
        radius=np.array([radius]), epsilon=np.array([epsilon]), p_d=np.array([0.9999])
    )


def _belief(means, sigma, active=None):
    means = np.atleast_2d(means)
    count, n = means.shape
    return GaussianBelief(
        mean=means,
        covariance=np.repeat(sigma**2 * np.eye(n)[None], count, axis=0),
        active=np.ones(count, bool) if active is None else np.asarray(active),
    ).to_vector()


@pytest.mark.parametrize("solver", SOLVERS)
def test_controller_step_is_the_projection_of_the_nominal_command(solver):
    """One update of the system with one active obstacle in the way (and an inactive slot
    far off that would forbid everything if it were read): the projection of u_nom on the
    CBF half-plane (μ̇ = 0 at the first update)."""
    task = ObstacleTask(
        radius=np.array([0.3, 5.0]), epsilon=np.array([0.9, 0.9]), p_d=np.array([0.9999, 0.9999])
    )
    goal = GoalSeeking(goal=np.array([3.0, 0.0]), position_gain=1.0, max_speed=1.0)
    plant = NominalPlant(order=1)
    controller = ChanceConstrainedCbfController(
        task, 2, plant, goal, input_limit=5.0, rate=2.0, solver=solver
    )
    context = controller.CreateDefaultContext()
    y, mean, sigma = np.array([0.0, 0.05]), np.array([0.8, 0.0]), 0.05
    controller.GetInputPort("plant_state").FixValue(context, y)
    controller.GetInputPort("obstacle_belief").FixValue(
        context, _belief([mean, [0.0, 0.0]], sigma, active=[True, False])
    )
    rho = 0.3 + chance_margin(0.9, 2) * sigma
    a, b, _ = first_order_cbf_rows(
        y, mean[None], np.zeros((1, 2)), np.array([rho]), np.zeros(1), 2.0
    )
    nominal = goal.command(plant, y, np.zeros(0))
    assert a[0] @ nominal < b[0]  # the row is active: the test means something
    expected = _projection(a[0], b[0], nominal)
    update = controller.EvalUniquePeriodicDiscreteUpdate(context)
    np.testing.assert_allclose(update.get_vector(0).value(), expected, atol=1e-6)


def _belief_trajectory(start, velocity, sigma, duration):
    """A belief whose mean moves at constant velocity (a first-order hold is exact)."""
    ends = [_belief(start + velocity * t, sigma) for t in (0.0, duration)]
    return PiecewisePolynomial.FirstOrderHold([0.0, duration], np.column_stack(ends))


def _omni_loop(controller, start, velocity, sigma, duration):
    """The CC-CBF-QP driving the repository's omni robot (true = nominal kinematics, no
    disturbance) past one obstacle; returns y (N, 2), the obstacle mean (N, 2) at the
    control steps, and the controller's context."""
    builder = DiagramBuilder()
    robot = builder.AddSystem(OmniRobot(0.05, 0.2, np.zeros(2)))
    drive = builder.AddSystem(OmniDriveInterface(0.05, 0.2, heading_gain=2.0))
    still = builder.AddSystem(ConstantVectorSource(np.zeros(2)))
    belief = builder.AddSystem(
        TrajectorySource(_belief_trajectory(start, velocity, sigma, duration))
    )
    builder.AddSystem(controller)
    builder.Connect(drive.GetOutputPort("wheel_speeds"), robot.GetInputPort("wheel_speeds"))
    builder.Connect(robot.GetOutputPort("pose"), drive.GetInputPort("pose"))
    builder.Connect(still.get_output_port(), robot.GetInputPort("disturbance"))
    builder.Connect(controller.GetOutputPort("control"), drive.GetInputPort("velocity_command"))
    builder.Connect(robot.GetOutputPort("plant_state"), controller.GetInputPort("plant_state"))
    builder.Connect(belief.get_output_port(), controller.GetInputPort("obstacle_belief"))
    log = LogVectorOutput(robot.GetOutputPort("output"), builder, publish_period=0.01)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration)
    root = simulator.get_context()
    data = log.FindLog(root)
    times = data.sample_times()
    return data.data().T, start + np.outer(times, velocity), controller.GetMyContextFromRoot(root)


@pytest.mark.parametrize("solver", SOLVERS)
def test_closed_loop_keeps_the_constraint(solver):
    """A moving obstacle crossing the robot's path: h = ‖y − μ‖ − ρ ≥ 0 at every control
    step, the constraint comes close to active, and no step is infeasible."""
    sigma, epsilon = 0.05, 0.9
    controller = ChanceConstrainedCbfController(
        _single_obstacle_task(epsilon),
        2,
        NominalPlant(order=1),
        GoalSeeking(goal=np.array([5.0, 0.0]), max_speed=1.0),
        input_limit=1.0,
        period=0.01,
        rate=2.0,
        solver=solver,
    )
    y, mean, context = _omni_loop(
        controller, np.array([4.0, 0.1]), np.array([-0.5, 0.0]), sigma, duration=6.0
    )
    h = np.linalg.norm(y - mean, axis=1) - (0.3 + chance_margin(epsilon, 2) * sigma)
    assert h.min() >= 0.0
    assert h.min() < 0.1
    assert controller.infeasible_count(context) == 0
    assert controller.update_count(context) == 600
    assert np.linalg.norm(y[-1] - [5.0, 0.0]) < 0.5  # and it gets past


@pytest.mark.parametrize("fallback", ["slack", "brake"])
def test_infeasible_steps_use_the_fallback_and_are_counted(fallback):
    """An obstacle rushing at 2 m/s at a robot allowed 0.2 m/s per axis: no input can keep
    h ≥ 0; the run finishes and the infeasible steps are counted."""
    controller = ChanceConstrainedCbfController(
        _single_obstacle_task(),
        2,
        NominalPlant(order=1),
        GoalSeeking(goal=np.array([5.0, 0.0])),
        input_limit=0.2,
        fallback=fallback,
    )
    _, _, context = _omni_loop(
        controller, np.array([4.0, 0.1]), np.array([-2.0, 0.0]), 0.05, duration=3.0
    )
    assert 0 < controller.infeasible_count(context) < controller.update_count(context)


def _random_field_case(rng):
    field = PotentialField(
        goal=np.array([2.0, 1.0, 0.5]),
        attraction_gain=0.8,
        attraction_distance=1.5,
        repulsion_gain=0.05,
        influence_distance=0.8,
    )
    mean = rng.uniform(-1.0, 1.0, size=(4, 3))
    rho = np.full(4, 0.3)
    while True:
        y = rng.uniform(-1.5, 1.5, size=3)
        if np.all(np.linalg.norm(y - mean, axis=1) - rho > 0.05):
            return field, y, mean, rho


def test_potential_field_is_minus_the_gradient_of_u():
    rng = np.random.default_rng(5)
    step, repelled = 1e-6, 0
    for _ in range(40):
        field, y, mean, rho = _random_field_case(rng)
        numeric = np.array(
            [
                (field.potential(y + e, mean, rho) - field.potential(y - e, mean, rho)) / (2 * step)
                for e in step * np.eye(3)
            ]
        )
        np.testing.assert_allclose(field.field(y, mean, rho), -numeric, rtol=1e-5, atol=1e-6)
        repelled += np.any(np.linalg.norm(y - mean, axis=1) - rho < field.influence_distance)
    assert repelled > 10  # the repulsive terms were exercised


@pytest.mark.parametrize("order", [1, 2])
def test_potential_field_controller_respects_the_input_limit(order):
    """Close to an obstacle the field is huge; the command stays in |u_i| ≤ u_max and is
    the core field (order 1, inside the limit far from obstacles)."""
    limit = np.array([0.7, 0.7, 15.0])
    plant = NominalPlant(order=order, mass=1.0, drag=0.2, gravity=9.81 if order == 2 else 0.0)
    field = PotentialField(goal=np.array([3.0, 0.0, 1.0]), attraction_distance=0.5)
    task = ObstacleTask(radius=np.array([0.3]), epsilon=np.array([0.9]), p_d=np.array([0.9999]))
    controller = PotentialFieldController(task, 3, plant, field, input_limit=limit)
    context = controller.CreateDefaultContext()
    sigma = 0.05
    rho = 0.3 + chance_margin(0.9, 3) * sigma
    for mean, expect_saturation in (([0.4, 0.0, 1.0], True), ([50.0, 0.0, 1.0], False)):
        y = np.array([0.0, 0.0, 1.0])
        controller.GetInputPort("plant_state").FixValue(
            context, np.r_[y, np.zeros((order - 1) * 3)]
        )
        controller.GetInputPort("obstacle_belief").FixValue(context, _belief([mean], sigma))
        command = controller.GetOutputPort("control").Eval(context)
        assert np.all(np.abs(command) <= limit + 1e-12)
        if expect_saturation:
            assert np.any(np.isclose(np.abs(command), limit))
        elif order == 1:
            np.testing.assert_allclose(command, field.field(y, np.array([mean]), np.array([rho])))


def test_second_order_closed_loop_keeps_the_constraint():
    """The exponential CBF on the repository's quadrotor (nominal = true mass, drag and
    gravity; no wind) with an obstacle drifting across its path at flight height."""
    sigma, epsilon, duration = 0.05, 0.9, 8.0
    start, velocity = np.array([3.0, 0.05, 1.0]), np.array([-0.3, 0.0, 0.0])
    task = ObstacleTask(radius=np.array([0.4]), epsilon=np.array([epsilon]), p_d=np.array([0.9999]))
    controller = ChanceConstrainedCbfController(
        task,
        3,
        NominalPlant(order=2, mass=1.0, drag=0.2, gravity=9.81),
        GoalSeeking(goal=np.array([5.0, 0.0, 1.0]), max_speed=1.0, velocity_gain=3.0),
        input_limit=np.array([5.0, 5.0, 20.0]),
        rate=2.0,
    )
    builder = DiagramBuilder()
    uav = builder.AddSystem(Quadrotor(1.0, 0.2, 9.81, np.array([0.0, 0.0, 1.0]), np.zeros(3)))
    wind = builder.AddSystem(ConstantVectorSource(np.zeros(3)))
    belief = builder.AddSystem(
        TrajectorySource(
            PiecewisePolynomial.FirstOrderHold(
                [0.0, duration],
                np.column_stack([_belief(start + velocity * t, sigma) for t in (0.0, duration)]),
            )
        )
    )
    builder.AddSystem(controller)
    builder.Connect(wind.get_output_port(), uav.GetInputPort("disturbance"))
    builder.Connect(controller.GetOutputPort("control"), uav.GetInputPort("control"))
    builder.Connect(uav.GetOutputPort("plant_state"), controller.GetInputPort("plant_state"))
    builder.Connect(belief.get_output_port(), controller.GetInputPort("obstacle_belief"))
    log = LogVectorOutput(uav.GetOutputPort("output"), builder, publish_period=0.01)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(duration)
    data = log.FindLog(simulator.get_context())
    mean = start + np.outer(data.sample_times(), velocity)
    h = np.linalg.norm(data.data().T - mean, axis=1) - (0.4 + chance_margin(epsilon, 3) * sigma)
    assert 0.0 <= h.min() < 0.1
    context = controller.GetMyContextFromRoot(simulator.get_context())
    assert controller.infeasible_count(context) == 0
