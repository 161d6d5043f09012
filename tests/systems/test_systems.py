"""Tests of the Drake systems in stt_drake.systems and of stt_drake.assembly.diagram.

Drake's own style: build a small system or diagram, FixValue its inputs on a context,
evaluate output ports or time derivatives (or advance a short time with a Simulator), and
compare with tolerances against independent computations: the paper's formulas
evaluated here by hand (with scipy.stats.ncx2 for the noncentral chi-square quantile), the
pure-numpy core the systems wrap, or closed forms (e.g. the Rayleigh tail
P(‖Z‖ ≥ R) = exp(−R²/2σ²) of a 2D Gaussian centred on the point).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import pytest
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import DiagramBuilder, EventStatus
from pydrake.systems.primitives import ConstantVectorSource, Integrator
from scipy.stats import ncx2

from stt_drake.assembly import parse_scenario
from stt_drake.assembly.diagram import build_diagram
from stt_drake.config import Obstacle
from stt_drake.core.belief import GaussianBelief, ObstacleBelief, ObstacleTask, belief_size
from stt_drake.core.control import BoxFunnel, FunnelController
from stt_drake.core.fixed_rate import BeliefRateBounds
from stt_drake.core.invariants import INVARIANT_NAMES, InvariantTracker, evaluate_invariants
from stt_drake.core.motion import ConstantVelocity, Oscillation, SigmaSchedule, Waypoints
from stt_drake.core.probability import avoid_probability
from stt_drake.core.tube import TubeLaw, linear_zone_for_step
from stt_drake.systems.belief_source import ObstacleBeliefSource
from stt_drake.systems.controller import STTController
from stt_drake.systems.monitor import InvariantMonitor
from stt_drake.systems.plants.omni import OmniDriveInterface, OmniRobot, wheel_matrix
from stt_drake.systems.tube import SpatiotemporalTube

MARGIN = {name: i for i, name in enumerate(INVARIANT_NAMES)}


def make_belief(mean, sigma, radius, epsilon, p_d) -> ObstacleBelief:
    return ObstacleBelief(
        mean=np.atleast_2d(np.asarray(mean, dtype=float)),
        sigma=np.atleast_1d(np.asarray(sigma, dtype=float)),
        radius=np.atleast_1d(np.asarray(radius, dtype=float)),
        epsilon=np.atleast_1d(np.asarray(epsilon, dtype=float)),
        p_d=np.atleast_1d(np.asarray(p_d, dtype=float)),
    )


# --------------------------------------------------------------------------------------
# 1. ObstacleBeliefSource
# --------------------------------------------------------------------------------------
def belief_source_obstacles() -> list[Obstacle]:
    return [
        Obstacle(
            motion=ConstantVelocity(start=[1.0, -2.0], velocity=[0.5, 0.25]),
            radius=0.2,
            sigma=0.1,
            epsilon=0.9,
            p_d=0.999,
        ),
        Obstacle(
            motion=Oscillation(
                center=[0.0, 1.0], amplitude=[0.3, 0.6], frequency_hz=0.25, phase=[0.0, 0.5]
            ),
            radius=0.3,
            sigma=0.2,
            sigma_schedule=SigmaSchedule(times=[0.0, 2.0, 4.0], values=[0.05, 0.25, 0.15]),
            epsilon=0.8,
            p_d=0.99,
        ),
        Obstacle(
            motion=Waypoints(times=[0.0, 1.0, 3.0], positions=[[0.0, 0.0], [1.0, 2.0], [3.0, 2.0]]),
            radius=0.15,
            sigma=0.07,
            epsilon=0.95,
            p_d=0.9999,
        ),
    ]


def belief_by_hand(t: float) -> np.ndarray:
    """The port vector of `belief_source_obstacles()` at t, laid out by hand."""
    mean0 = np.array([1.0 + 0.5 * t, -2.0 + 0.25 * t])
    angle = 2.0 * np.pi * 0.25 * t
    mean1 = np.array([0.3 * np.sin(angle), 1.0 + 0.6 * np.sin(angle + 0.5)])
    sigma1 = 0.05 + 0.1 * t if t <= 2.0 else (0.25 - 0.05 * (t - 2.0) if t <= 4.0 else 0.15)
    if t <= 1.0:
        mean2 = np.array([t, 2.0 * t])
    elif t <= 3.0:
        mean2 = np.array([1.0 + (t - 1.0), 2.0])
    else:
        mean2 = np.array([3.0, 2.0])
    # [mean, covariance σ² I (row-major), active] per slot
    return np.concatenate(
        [
            [*mean0, 0.1**2, 0.0, 0.0, 0.1**2, 1.0],
            [*mean1, sigma1**2, 0.0, 0.0, sigma1**2, 1.0],
            [*mean2, 0.07**2, 0.0, 0.0, 0.07**2, 1.0],
        ]
    )


@pytest.mark.parametrize("t", [0.0, 0.4, 1.0, 2.5, 3.7, 6.0])
def test_belief_source_output_matches_motion_models(t):
    source = ObstacleBeliefSource(belief_source_obstacles(), dimension=2)
    context = source.CreateDefaultContext()
    context.SetTime(t)
    port = source.GetOutputPort("obstacle_belief")
    assert port.size() == 3 * (2 + 4 + 1) == belief_size(3, 2)
    assert source.obstacle_count == 3
    value = port.Eval(context)
    expected = belief_by_hand(t)
    np.testing.assert_allclose(value, expected, rtol=0.0, atol=1e-12)
    # The same through the dataclass: to_vector is the layout above.
    table = expected.reshape(3, 7)
    belief = GaussianBelief(
        mean=table[:, :2], covariance=table[:, 2:6].reshape(3, 2, 2), active=table[:, 6] > 0.5
    )
    np.testing.assert_allclose(value, belief.to_vector(), rtol=0.0, atol=1e-12)


def test_belief_source_output_follows_context_time():
    """The output is recomputed when only the time changes (time is its prerequisite)."""
    source = ObstacleBeliefSource(belief_source_obstacles(), dimension=2)
    context = source.CreateDefaultContext()
    port = source.GetOutputPort("obstacle_belief")
    np.testing.assert_allclose(port.Eval(context), belief_by_hand(0.0), atol=1e-12)
    context.SetTime(1.5)
    np.testing.assert_allclose(port.Eval(context), belief_by_hand(1.5), atol=1e-12)


def test_belief_source_three_dimensional():
    obstacle = Obstacle(
        motion=ConstantVelocity(start=[1.0, 2.0, 3.0], velocity=[-1.0, 0.0, 0.5]),
        radius=0.4,
        sigma=0.3,
        epsilon=0.7,
        p_d=0.95,
    )
    source = ObstacleBeliefSource([obstacle], dimension=3)
    context = source.CreateDefaultContext()
    context.SetTime(2.0)
    port = source.GetOutputPort("obstacle_belief")
    assert port.size() == 3 + 9 + 1
    variance = 0.3**2
    np.testing.assert_allclose(
        port.Eval(context),
        [-1.0, 2.0, 4.0, variance, 0, 0, 0, variance, 0, 0, 0, variance, 1.0],
        rtol=0.0,
        atol=1e-12,
    )


def test_belief_vector_round_trip_and_wrong_length():
    vector = belief_by_hand(1.3)
    belief = GaussianBelief.from_vector(vector, dimension=2)
    assert belief.count == 3 and belief.dimension == 2
    np.testing.assert_array_equal(belief.mean, vector.reshape(3, 7)[:, :2])
    np.testing.assert_array_equal(belief.covariance[:, 1, 1], vector.reshape(3, 7)[:, 5])
    assert belief.active.all()
    np.testing.assert_array_equal(belief.to_vector(), vector)
    with pytest.raises(ValueError, match="length 20"):
        GaussianBelief.from_vector(vector[:-1], dimension=2)
    with pytest.raises(ValueError, match="dimension 3"):
        GaussianBelief.from_vector(vector, dimension=3)  # 21 is not a multiple of 13


# --------------------------------------------------------------------------------------
# 2. SpatiotemporalTube
# --------------------------------------------------------------------------------------
TARGET = np.array([3.0, 0.5])
# Obstacle 0 sits close to the test centres, so q_0 < p_d and its avoidance term is active;
# obstacle 1 is far away (q_1 = 1 > p_d, θ_1 = 0).
TUBE_BELIEF = make_belief(
    mean=[[1.0, 0.3], [-4.0, 5.0]],
    sigma=[0.1, 0.2],
    radius=[0.15, 0.2],
    epsilon=[0.9, 0.8],
    p_d=[0.9999, 0.999],
)


def make_law(linear_zone: float = 0.0) -> TubeLaw:
    return TubeLaw(
        target=TARGET,
        k1=0.7,
        k2=np.array([0.4, 0.5]),
        k3=0.3,
        r_min=0.1,
        r_max=0.3,
        nu=40.0,
        linear_zone=linear_zone,
        max_center_speed=np.inf,  # the paper's law
    )


def reference_tube(center: np.ndarray, belief: ObstacleBelief, law: TubeLaw):
    """ċ, r, q, d̂, θ from the paper's formulas (n = 2), with scipy.stats.ncx2."""
    n = belief.dimension
    offset = center - belief.mean
    lam = np.sum(offset**2, axis=1) / belief.sigma**2
    q = ncx2.sf(((belief.radius + law.r_min) / belief.sigma) ** 2, n, lam)
    theta = np.where(q <= belief.p_d, 1.0 / q - 1.0 / belief.p_d, 0.0)
    m = offset / (q - belief.epsilon)[:, None]
    v = np.column_stack([-m[:, 1], m[:, 0]])  # rotated by +90°
    k2 = np.broadcast_to(law.k2, q.shape)
    k3 = np.broadcast_to(law.k3, q.shape)
    rate = law.k1 * np.cbrt(law.target - center) + np.sum(
        (k2[:, None] * m + k3[:, None] * v) * theta[:, None], axis=0
    )
    d_hat = belief.sigma * np.sqrt(ncx2.ppf(1.0 - belief.epsilon, n, lam)) - belief.radius
    radius = -np.log(np.exp(-law.nu * law.r_max) + np.sum(np.exp(-law.nu * d_hat))) / law.nu
    return rate, radius, q, d_hat, theta


def assert_diagnostics(diagnostics, q, d_hat, theta, law: TubeLaw):
    """[q, d̂, θ] against the formulas. Where d̂ exceeds r_max + 40/ν the tube may report a
    cheaper lower bound instead (documented pruning; its soft-min weight is < e^-40), so
    there only the bound is checked: threshold < reported ≤ exact."""
    m = len(q)
    np.testing.assert_allclose(diagnostics[:m], q, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(diagnostics[2 * m :], theta, rtol=1e-8, atol=1e-12)
    reported = diagnostics[m : 2 * m]
    threshold = law.r_max + 40.0 / law.nu
    exact = d_hat <= threshold
    np.testing.assert_allclose(reported[exact], d_hat[exact], rtol=1e-8, atol=1e-12)
    assert np.all(reported[~exact] > threshold)
    assert np.all(reported[~exact] <= d_hat[~exact] + 1e-9)


def tube_context(tube: SpatiotemporalTube, center: np.ndarray, belief: ObstacleBelief):
    context = tube.CreateDefaultContext()
    tube.GetInputPort("obstacle_belief").FixValue(context, belief.to_vector())
    tube.set_center(context, center)
    return context


@pytest.mark.parametrize("center", [[0.5, 0.0], [0.6, 0.35], [2.0, -1.0]])
def test_tube_continuous_outputs_and_derivatives(center):
    center = np.array(center)
    law = make_law()
    tube = SpatiotemporalTube(law, np.zeros(2), TUBE_BELIEF.task)
    context = tube_context(tube, center, TUBE_BELIEF)
    assert tube.GetOutputPort("tube").size() == 3
    assert tube.GetOutputPort("diagnostics").size() == 6

    rate, radius, q, d_hat, theta = reference_tube(center, TUBE_BELIEF, law)
    if center[1] != -1.0:
        assert theta[0] > 0.0, "test setup: obstacle 0 must be active near these centres"
    assert theta[1] == 0.0

    np.testing.assert_allclose(
        tube.GetOutputPort("tube").Eval(context), [*center, radius], rtol=1e-9, atol=1e-12
    )
    assert_diagnostics(tube.GetOutputPort("diagnostics").Eval(context), q, d_hat, theta, law)
    derivatives = tube.EvalTimeDerivatives(context).CopyToVector()
    np.testing.assert_allclose(derivatives, rate, rtol=1e-8, atol=1e-12)

    # ... and the same as the numpy core on the same centre and belief.
    evaluation = law.evaluate(center, TUBE_BELIEF)
    np.testing.assert_allclose(derivatives, evaluation.center_rate, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(
        tube.GetOutputPort("diagnostics").Eval(context),
        np.concatenate(
            [evaluation.avoid_probability, evaluation.quantile_distance, evaluation.theta]
        ),
        rtol=1e-12,
        atol=1e-15,
    )
    np.testing.assert_allclose(tube.center(context), center, rtol=0.0, atol=0.0)


def test_tube_outputs_track_state_and_belief_changes():
    """The cached law evaluation is invalidated by the state and by the belief input, and
    by nothing else: changing the time leaves the outputs unchanged."""
    law = make_law()
    tube = SpatiotemporalTube(law, np.zeros(2), TUBE_BELIEF.task)
    context = tube_context(tube, np.array([0.5, 0.0]), TUBE_BELIEF)
    tube_port = tube.GetOutputPort("tube")
    first = tube_port.Eval(context).copy()

    context.SetTime(5.0)
    np.testing.assert_array_equal(tube_port.Eval(context), first)

    moved = np.array([0.55, 0.2])
    context.SetContinuousState(moved)
    rate, radius, *_ = reference_tube(moved, TUBE_BELIEF, law)
    np.testing.assert_allclose(tube_port.Eval(context), [*moved, radius], rtol=1e-9)
    np.testing.assert_allclose(tube.EvalTimeDerivatives(context).CopyToVector(), rate, rtol=1e-8)

    shifted = make_belief(
        mean=[[0.8, 0.5], [-4.0, 5.0]],
        sigma=[0.12, 0.2],
        radius=[0.15, 0.2],
        epsilon=[0.9, 0.8],
        p_d=[0.9999, 0.999],
    )
    tube.GetInputPort("obstacle_belief").FixValue(context, shifted.to_vector())
    rate, radius, q, d_hat, theta = reference_tube(moved, shifted, law)
    np.testing.assert_allclose(tube_port.Eval(context), [*moved, radius], rtol=1e-9)
    assert_diagnostics(tube.GetOutputPort("diagnostics").Eval(context), q, d_hat, theta, law)
    np.testing.assert_allclose(tube.EvalTimeDerivatives(context).CopyToVector(), rate, rtol=1e-8)


def test_tube_in_feedback_loop_has_no_algebraic_loop():
    """Belief source → tube → controller → drive → robot → controller builds, and the
    tube's outputs feed through from the belief input only."""
    law = make_law()
    builder = DiagramBuilder()
    obstacles = [
        Obstacle(motion=ConstantVelocity(start=[1.0, 0.3], velocity=[0.0, 0.0]), sigma=0.1),
        Obstacle(motion=ConstantVelocity(start=[-4.0, 5.0], velocity=[0.1, 0.0]), sigma=0.2),
    ]
    source = builder.AddSystem(ObstacleBeliefSource(obstacles, 2))
    tube = builder.AddSystem(SpatiotemporalTube(law, np.zeros(2), ObstacleTask.of(obstacles)))
    controller = builder.AddSystem(STTController(FunnelController(kappa=[2.0]), 2))
    drive = builder.AddSystem(OmniDriveInterface(0.05, 0.2, heading_gain=2.0))
    robot = builder.AddSystem(OmniRobot(0.05, 0.2, np.zeros(2)))
    builder.Connect(source.get_output_port(), tube.GetInputPort("obstacle_belief"))
    builder.Connect(tube.GetOutputPort("tube"), controller.GetInputPort("tube"))
    builder.Connect(robot.GetOutputPort("plant_state"), controller.GetInputPort("plant_state"))
    builder.Connect(controller.GetOutputPort("control"), drive.GetInputPort("velocity_command"))
    builder.Connect(robot.GetOutputPort("pose"), drive.GetInputPort("pose"))
    builder.Connect(drive.GetOutputPort("wheel_speeds"), robot.GetInputPort("wheel_speeds"))
    builder.ExportInput(robot.GetInputPort("disturbance"), "disturbance")
    diagram = builder.Build()  # raises on an algebraic loop

    belief_in = tube.GetInputPort("obstacle_belief").get_index()
    for name in ("tube", "diagnostics"):
        assert tube.HasDirectFeedthrough(belief_in, tube.GetOutputPort(name).get_index())
    for name in ("output", "plant_state", "pose"):
        out = robot.GetOutputPort(name).get_index()
        for port in ("wheel_speeds", "disturbance"):
            assert not robot.HasDirectFeedthrough(robot.GetInputPort(port).get_index(), out)

    context = diagram.CreateDefaultContext()
    diagram.GetInputPort("disturbance").FixValue(context, np.zeros(2))
    simulator = Simulator(diagram, context)
    simulator.AdvanceTo(0.2)
    tube_value = tube.GetOutputPort("tube").Eval(tube.GetMyContextFromRoot(context))
    position = robot.GetOutputPort("output").Eval(robot.GetMyContextFromRoot(context))
    assert np.linalg.norm(position - tube_value[:2]) < tube_value[2]
    assert tube_value[0] > 0.0  # the centre moved towards the target


def test_tube_rejects_non_finite_rate():
    """A non-finite ċ (here from a NaN obstacle mean) is a named RuntimeError, not a silent
    NaN state."""
    tube = SpatiotemporalTube(make_law(), np.zeros(2), TUBE_BELIEF.task)
    broken = make_belief(
        mean=[[np.nan, 0.3], [-4.0, 5.0]],
        sigma=[0.1, 0.2],
        radius=[0.15, 0.2],
        epsilon=[0.9, 0.8],
        p_d=[0.9999, 0.999],
    )
    context = tube_context(tube, np.array([0.5, 0.0]), broken)
    context.SetTime(1.25)
    with pytest.raises(RuntimeError, match=r"non-finite value at t = 1\.25 s"):
        tube.EvalTimeDerivatives(context)


def test_tube_fixed_rate_in_diagram_with_continuous_state():
    """A fixed-rate tube next to any continuous-state system (every plant): the Diagram
    asks each subsystem for its time derivatives, and the tube, which has no continuous
    state in this mode, must write none. build_diagram with update_rate_hz > 0 needs this."""
    law = make_law()
    builder = DiagramBuilder()
    tube = builder.AddSystem(SpatiotemporalTube(
            law, np.zeros(2), TUBE_BELIEF.task, update_period=0.01,
            rate_bounds=BeliefRateBounds.still(2),
        )
    )
    belief = builder.AddSystem(ConstantVectorSource(TUBE_BELIEF.to_vector()))
    integrator = builder.AddSystem(Integrator(3))
    builder.Connect(belief.get_output_port(), tube.GetInputPort("obstacle_belief"))
    builder.Connect(tube.GetOutputPort("tube"), integrator.get_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    derivatives = diagram.EvalTimeDerivatives(context).CopyToVector()
    _, radius, *_ = reference_tube(np.zeros(2), TUBE_BELIEF, law)
    np.testing.assert_allclose(derivatives, [0.0, 0.0, radius], rtol=1e-9)


def test_tube_fixed_rate_five_updates():
    law = make_law()
    start = np.array([0.4, -0.1])
    tube = SpatiotemporalTube(
        law, start, TUBE_BELIEF.task, update_period=0.01, rate_bounds=BeliefRateBounds.still(2)
    )
    assert tube.update_period == 0.01
    context = tube_context(tube, start, TUBE_BELIEF)
    simulator = Simulator(tube, context)
    centers = [start.copy()]
    for _ in range(5):  # updates at t = 0, 0.01, ..., 0.04
        centers.append(law.advance(centers[-1], TUBE_BELIEF, 0.01).center)
    # Between updates the output moves linearly from the centre reached at the update to
    # the next one: halfway through the last period it is their midpoint.
    simulator.AdvanceTo(0.045)
    np.testing.assert_allclose(
        tube.center(simulator.get_context()), 0.5 * (centers[4] + centers[5]), rtol=0, atol=1e-12
    )
    simulator.AdvanceTo(0.05)
    expected = centers[5]
    # The fraction (t − t_k)/h is 1 up to a rounding of t: 1e-12 m, not bitwise.
    np.testing.assert_allclose(tube.center(simulator.get_context()), expected, rtol=0.0, atol=1e-12)
    assert np.linalg.norm(expected - start) > 1e-3  # the update really moved the centre

    _, radius, *_ = reference_tube(expected, TUBE_BELIEF, law)
    np.testing.assert_allclose(
        tube.GetOutputPort("tube").Eval(simulator.get_context()), [*expected, radius], rtol=1e-9
    )


def test_fixed_rate_tube_refuses_an_inactive_slot_by_name():
    """The fixed-rate rate bounds are per obstacle: an update that reads an inactive slot
    stops the run and names the slot and the time (the flags are read off the port
    vector; every active slot passes)."""
    law = make_law()
    start = np.array([0.4, -0.1])
    tube = SpatiotemporalTube(
        law, start, TUBE_BELIEF.task, update_period=0.01, rate_bounds=BeliefRateBounds.still(2)
    )
    gaussian = TUBE_BELIEF.gaussian()
    for active, inactive in (([True, True], None), ([True, False], 1), ([False, True], 0)):
        vector = GaussianBelief(gaussian.mean, gaussian.covariance, np.array(active)).to_vector()
        context = tube.CreateDefaultContext()
        tube.GetInputPort("obstacle_belief").FixValue(context, vector)
        tube.set_center(context, start)
        assert tube.belief(context).all_active == (inactive is None)
        simulator = Simulator(tube, context)
        if inactive is None:
            simulator.Initialize()
            continue
        with pytest.raises(RuntimeError, match=rf"slots \[{inactive}\] inactive at t = 0 s"):
            simulator.Initialize()


def test_fixed_rate_state_slots_are_named_by_the_period_layout():
    """The fixed-rate tube's discrete state, read by slot name (PeriodLayout): after the
    update at t = 0 it holds c at the update (the start), c at the end of the period (the
    law's advance), r at both ends, the update time and no recovery flag."""
    from stt_drake.systems.tube import PeriodLayout

    law = make_law()
    start = np.array([0.4, -0.1])
    tube = SpatiotemporalTube(
        law, start, TUBE_BELIEF.task, update_period=0.01, rate_bounds=BeliefRateBounds.still(2)
    )
    layout = PeriodLayout(dimension=2, count=2)
    held = layout.held(start, time=0.5)
    assert held.size == 2 * 3 + 1 + 2 and held[layout.time] == 0.5
    assert np.isnan(held[layout.start_radius]) and np.isnan(held[layout.end_radius])
    context = tube_context(tube, start, TUBE_BELIEF)
    simulator = Simulator(tube, context)
    simulator.Initialize()
    state = simulator.get_context().get_discrete_state(0).value()
    update = law.advance(start, TUBE_BELIEF, 0.01)
    np.testing.assert_array_equal(state[layout.start_center], start)
    np.testing.assert_array_equal(state[layout.end_center], update.center)
    assert state[layout.start_radius] == update.start_radius
    assert state[layout.end_radius] == update.end_radius
    assert state[layout.time] == 0.0
    np.testing.assert_array_equal(state[layout.recovery], 0.0)


# --- the thin-layer trap (issue requirement) ---------------------------------------------
THIN_EPSILON = 0.99
THIN_BELIEF = make_belief(
    mean=[[2.0, 0.02]], sigma=[np.sqrt(0.001)], radius=[0.15], epsilon=[THIN_EPSILON], p_d=[0.9999]
)
THIN_TARGET = np.array([4.0, 0.0])
THIN_R_MIN = 0.21


def thin_layer_law(linear_zone: float, law_class: type[TubeLaw] = TubeLaw) -> TubeLaw:
    return law_class(
        target=THIN_TARGET,
        k1=0.7,
        k2=0.4,
        k3=0.4,
        r_min=THIN_R_MIN,
        r_max=0.27,
        nu=20.0,
        linear_zone=linear_zone,
        max_center_speed=np.inf,  # the paper's law
    )


def thin_q_gap(center: np.ndarray) -> float:
    """q − ε for the thin-layer obstacle, from the probability kernel (not the tube)."""
    q = avoid_probability(
        center, THIN_BELIEF.mean, THIN_BELIEF.sigma, THIN_BELIEF.radius + THIN_R_MIN
    )
    return float(q[0] - THIN_EPSILON)


def run_thin_layer(law, update_period, config: SimulatorConfig | None, duration: float = 15.0):
    """Simulate the tube alone against the fixed thin-layer belief; record at every step
    (every update in fixed-rate mode) the time, centre, q − ε and the diagnostics' q."""
    tube = SpatiotemporalTube(
        law,
        np.zeros(2),
        THIN_BELIEF.task,
        update_period=update_period,
        rate_bounds=BeliefRateBounds.still(1),
    )
    context = tube.CreateDefaultContext()
    tube.GetInputPort("obstacle_belief").FixValue(context, THIN_BELIEF.to_vector())
    simulator = Simulator(tube, context)
    if config is not None:
        ApplySimulatorConfig(config, simulator)
    records = []

    def monitor(root_context):
        center = tube.center(root_context)
        q_port = tube.GetOutputPort("diagnostics").Eval(root_context)[0]
        records.append((root_context.get_time(), *center, thin_q_gap(center), q_port))
        return EventStatus.DidNothing()

    simulator.set_monitor(monitor)
    simulator.AdvanceTo(duration)
    return tube, simulator, np.array(records)


def assert_thin_layer_safe_and_reached(records: np.ndarray):
    t, center, gap, q_port = records[:, 0], records[:, 1:3], records[:, 3], records[:, 4]
    assert np.all(np.isfinite(records))
    assert np.all(gap > 0.0), f"q − ε = {gap.min():.3g} at t = {t[np.argmin(gap)]:.4g}"
    np.testing.assert_allclose(q_port - THIN_EPSILON, gap, rtol=0.0, atol=1e-12)
    # The layer was really entered: q fell below p_d (θ > 0, the avoidance term acted),
    # so this is not a run that never met the obstacle.
    assert gap.min() < 0.9999 - THIN_EPSILON
    assert np.linalg.norm(center[-1] - THIN_TARGET) < 1e-3
    assert t[-1] == pytest.approx(15.0)


def test_thin_layer_continuous_error_controlled():
    config = SimulatorConfig(
        integration_scheme="runge_kutta3",
        max_step_size=0.01,
        accuracy=1e-6,
        use_error_control=True,
    )
    law = thin_layer_law(linear_zone_for_step(0.7, 0.01), RecordingLaw)
    _, _, records = run_thin_layer(law, None, config)
    assert_thin_layer_safe_and_reached(records)
    # Error control keeps even the stage points (rejected trial steps included) out of
    # q ≤ ε — the contrast with the fixed-step trap below.
    assert min(law.gaps) > 0.0


def test_thin_layer_fixed_rate_100hz():
    _, _, records = run_thin_layer(thin_layer_law(0.0), 0.01, None)
    # One monitor call per update (plus the initial one): every update is checked.
    assert len(records) == 1501
    np.testing.assert_allclose(np.diff(records[:, 0]), 0.01, atol=1e-9)
    assert_thin_layer_safe_and_reached(records)


@dataclass(frozen=True)
class RecordingLaw(TubeLaw):
    """A TubeLaw that records q − ε (from the probability kernel) at every centre the
    integrator evaluates it at, stage points included — the step-end monitor only sees
    accepted steps."""

    gaps: list[float] = field(default_factory=list)

    def evaluate_port(self, center, *args, **kwargs):  # the tube system's entry
        self.gaps.append(thin_q_gap(center))
        return super().evaluate_port(center, *args, **kwargs)


def test_thin_layer_trap_is_real_for_fixed_step_explicit_integration():
    config = SimulatorConfig(
        integration_scheme="runge_kutta2", max_step_size=0.01, use_error_control=False
    )
    law = thin_layer_law(linear_zone_for_step(0.7, 0.01), RecordingLaw)
    raised = None
    records = np.empty((0, 5))
    try:
        _, _, records = run_thin_layer(law, None, config)
    except RuntimeError as error:  # a non-finite rate
        raised = error
    crossed = len(law.gaps) > 0 and min(law.gaps) < 0.0
    crossed_at_step_end = records.size > 0 and records[:, 3].min() < 0.0
    assert raised is not None or crossed or crossed_at_step_end, (
        "fixed 10 ms RK2 steps neither crossed q = ε nor produced a non-finite value"
    )
    if raised is not None:
        assert "non-finite" in str(raised)
    else:  # and the run is ruined: the centre never settles at the target
        assert np.linalg.norm(records[-1, 1:3] - THIN_TARGET) > 1.0


# --------------------------------------------------------------------------------------
# 3. STTController
# --------------------------------------------------------------------------------------
def test_controller_single_stage_dimension_2():
    kappa = 1.7
    controller = STTController(FunnelController(kappa=[kappa]), dimension=2)
    context = controller.CreateDefaultContext()
    context.SetTime(0.8)
    center, radius = np.array([1.0, -0.5]), 0.4
    x1 = np.array([1.2, -0.35])
    controller.GetInputPort("tube").FixValue(context, [*center, radius])
    controller.GetInputPort("plant_state").FixValue(context, x1)
    u = controller.GetOutputPort("control").Eval(context)

    e1 = np.linalg.norm(x1 - center) / radius  # 0.625
    rho = np.log((1.0 + e1) / (1.0 - e1))
    np.testing.assert_allclose(u, -kappa * rho * (x1 - center), rtol=1e-12)
    core = FunnelController(kappa=[kappa]).evaluate(0.8, x1, center, radius)
    np.testing.assert_allclose(u, core.control, rtol=1e-14)


def test_controller_two_stages_dimension_3():
    funnel = BoxFunnel(
        start=np.array([2.0, 1.5, 3.0]),
        end=np.array([0.2, 0.1, 0.3]),
        rate=np.array([1.0, 0.5, 2.0]),
    )
    core = FunnelController(kappa=[1.5, 0.8], funnels=[funnel])
    controller = STTController(core, dimension=3)
    assert controller.GetInputPort("plant_state").size() == 6
    assert controller.GetInputPort("tube").size() == 4
    assert controller.GetOutputPort("control").size() == 3
    t = 0.6
    context = controller.CreateDefaultContext()
    context.SetTime(t)
    center, radius = np.array([0.5, 0.2, -0.3]), 0.5
    x1 = np.array([0.6, 0.1, -0.1])
    x2 = np.array([-0.3, 0.4, 0.2])
    controller.GetInputPort("tube").FixValue(context, [*center, radius])
    controller.GetInputPort("plant_state").FixValue(context, np.concatenate([x1, x2]))
    u = controller.GetOutputPort("control").Eval(context)

    # By hand from the paper's formulas: stage 1, then the box funnel of stage 2.
    e1 = np.linalg.norm(x1 - center) / radius
    r2 = -1.5 * np.log((1.0 + e1) / (1.0 - e1)) * (x1 - center)
    gamma = (np.array([2.0, 1.5, 3.0]) - [0.2, 0.1, 0.3]) * np.exp(-np.array([1.0, 0.5, 2.0]) * t)
    gamma += [0.2, 0.1, 0.3]
    e2 = (x2 - r2) / gamma
    assert np.all(np.abs(e2) < 1.0), "test setup: x2 must start inside its funnel"
    xi = 4.0 / (gamma * (1.0 - e2**2))
    expected = -0.8 * xi * np.log((1.0 + e2) / (1.0 - e2))
    np.testing.assert_allclose(u, expected, rtol=1e-12)
    np.testing.assert_allclose(u, core.evaluate(t, np.stack([x1, x2]), center, radius).control)

    # The funnel is time-varying: the system reads the context time.
    context.SetTime(0.0)
    np.testing.assert_allclose(
        controller.GetOutputPort("control").Eval(context),
        core.evaluate(0.0, np.stack([x1, x2]), center, radius).control,
        rtol=1e-14,
    )
    assert not np.allclose(controller.GetOutputPort("control").Eval(context), u)


def test_controller_direct_feedthrough():
    controller = STTController(FunnelController(kappa=[1.0]), dimension=2)
    out = controller.GetOutputPort("control").get_index()
    for name in ("tube", "plant_state"):
        assert controller.HasDirectFeedthrough(controller.GetInputPort(name).get_index(), out)


# --------------------------------------------------------------------------------------
# 4. InvariantMonitor
# --------------------------------------------------------------------------------------
MONITOR_CENTER = np.array([1.0, 2.0])
MONITOR_RADIUS = 0.3


def monitor_context(output, belief: ObstacleBelief, center=MONITOR_CENTER, radius=MONITOR_RADIUS):
    monitor = InvariantMonitor(dimension=2, task=belief.task, r_min=0.1)
    context = monitor.CreateDefaultContext()
    monitor.GetInputPort("tube").FixValue(context, [*center, radius])
    monitor.GetInputPort("obstacle_belief").FixValue(context, belief.to_vector())
    monitor.GetInputPort("output").FixValue(context, np.asarray(output, dtype=float))
    return monitor, context


FAR_BELIEF = make_belief(
    mean=[[40.0, -30.0], [-50.0, 60.0]],
    sigma=[0.2, 0.5],
    radius=[0.3, 0.2],
    epsilon=[0.95, 0.7],
    p_d=[0.9999, 0.99],
)


def test_monitor_output_at_tube_center_far_obstacles():
    monitor, context = monitor_context(MONITOR_CENTER, FAR_BELIEF)
    margins = monitor.GetOutputPort("margins").Eval(context)
    assert monitor.GetOutputPort("margins").size() == len(INVARIANT_NAMES) == 5
    assert margins[MARGIN["output_in_tube"]] == pytest.approx(MONITOR_RADIUS, abs=1e-15)
    assert margins[MARGIN["radius_positive"]] == pytest.approx(MONITOR_RADIUS, abs=1e-15)
    # Every obstacle is ~50 σ away: every probability is 1, the margin is min_j (1 − ε_j).
    for name in ("center_avoid_probability", "tube_avoid_probability", "output_avoid_probability"):
        assert margins[MARGIN[name]] == pytest.approx(1.0 - 0.95, abs=1e-12)
    np.testing.assert_allclose(
        monitor.GetOutputPort("output_avoid_probability").Eval(context), [1.0, 1.0], atol=1e-12
    )
    np.testing.assert_allclose(
        monitor.GetOutputPort("tube_avoid_probability").Eval(context), [1.0, 1.0], atol=1e-12
    )


def test_monitor_output_outside_tube_is_negative():
    y = MONITOR_CENTER + np.array([0.3, 0.4])  # 0.5 m from the centre
    monitor, context = monitor_context(y, FAR_BELIEF)
    margins = monitor.GetOutputPort("margins").Eval(context)
    assert margins[MARGIN["output_in_tube"]] == pytest.approx(MONITOR_RADIUS - 0.5, abs=1e-14)
    assert margins[MARGIN["output_in_tube"]] < 0.0


def test_monitor_probabilities_closed_form_and_kernel():
    """Obstacle 0 is centred on y and obstacle 1 on c: a 2D Gaussian centred on the point
    gives P(‖x − O‖ ≥ R) = exp(−R²/(2σ²)) (Rayleigh tail)."""
    y = np.array([1.1, 2.05])
    belief = make_belief(
        mean=[y, MONITOR_CENTER],
        sigma=[0.2, 0.25],
        radius=[0.1, 0.05],
        epsilon=[0.3, 0.2],
        p_d=[0.99, 0.99],
    )
    monitor, context = monitor_context(y, belief)
    output_avoid = monitor.GetOutputPort("output_avoid_probability").Eval(context)
    tube_avoid = monitor.GetOutputPort("tube_avoid_probability").Eval(context)
    margins = monitor.GetOutputPort("margins").Eval(context)

    rayleigh_y0 = np.exp(-(0.1**2) / (2 * 0.2**2))
    assert output_avoid[0] == pytest.approx(rayleigh_y0, rel=1e-12)
    rayleigh_c1 = np.exp(-((0.05 + MONITOR_RADIUS) ** 2) / (2 * 0.25**2))
    assert tube_avoid[1] == pytest.approx(rayleigh_c1, rel=1e-12)
    center_q1 = np.exp(-((0.05 + 0.1) ** 2) / (2 * 0.25**2))  # r_o + r_min

    np.testing.assert_allclose(
        output_avoid,
        avoid_probability(y, belief.mean, belief.sigma, belief.radius),
        rtol=1e-14,
    )
    np.testing.assert_allclose(
        tube_avoid,
        avoid_probability(
            MONITOR_CENTER, belief.mean, belief.sigma, belief.radius + MONITOR_RADIUS
        ),
        rtol=1e-14,
    )
    assert margins[MARGIN["output_avoid_probability"]] == pytest.approx(
        min(output_avoid - belief.epsilon), rel=1e-14
    )
    assert margins[MARGIN["tube_avoid_probability"]] == pytest.approx(
        min(tube_avoid[0] - 0.3, rayleigh_c1 - 0.2), rel=1e-12
    )
    center_q = avoid_probability(MONITOR_CENTER, belief.mean, belief.sigma, belief.radius + 0.1)
    assert center_q[1] == pytest.approx(center_q1, rel=1e-12)
    assert margins[MARGIN["center_avoid_probability"]] == pytest.approx(
        min(center_q - belief.epsilon), rel=1e-14
    )
    assert margins[MARGIN["output_in_tube"]] == pytest.approx(
        MONITOR_RADIUS - np.hypot(0.1, 0.05), abs=1e-14
    )
    sample = evaluate_invariants(y, MONITOR_CENTER, MONITOR_RADIUS, belief, 0.1)
    np.testing.assert_allclose(margins, sample.margins, rtol=1e-14)


def test_monitor_follows_input_changes():
    """Its cache is invalidated by each input: a new y gives a new output_in_tube margin."""
    monitor, context = monitor_context(MONITOR_CENTER, FAR_BELIEF)
    port = monitor.GetOutputPort("margins")
    assert port.Eval(context)[0] == pytest.approx(MONITOR_RADIUS)
    monitor.GetInputPort("output").FixValue(context, MONITOR_CENTER + np.array([0.0, 0.1]))
    assert port.Eval(context)[0] == pytest.approx(MONITOR_RADIUS - 0.1)
    monitor.GetInputPort("tube").FixValue(context, [*MONITOR_CENTER, 0.5])
    assert port.Eval(context)[0] == pytest.approx(0.5 - 0.1)
    assert port.Eval(context)[MARGIN["radius_positive"]] == pytest.approx(0.5)


def test_monitor_with_covariances_reads_its_port_and_names_a_broken_one():
    """With full covariances the monitor hands its port vector straight to the compiled
    margins: the same margins and probabilities as evaluate_tube_invariants of the belief
    it reads (one obstacle near enough for a contour integral), and a Σ_j that breaks a
    rule is still named by its obstacle (the belief's path)."""
    from stt_drake.core.invariants import evaluate_tube_invariants

    y, tube = np.array([1.1, 2.05]), np.array([*MONITOR_CENTER, MONITOR_RADIUS])
    mean = np.array([[1.2, 2.6], [40.0, -30.0]])
    covariance = np.array([[[0.02, 0.005], [0.005, 0.01]], [[0.04, 0.0], [0.0, 0.09]]])
    monitor = InvariantMonitor(2, FAR_BELIEF.task, r_min=0.1, full_covariance=True)
    context = monitor.CreateDefaultContext()
    monitor.GetInputPort("tube").FixValue(context, tube)
    monitor.GetInputPort("output").FixValue(context, y)
    belief_port = monitor.GetInputPort("obstacle_belief")
    vector = GaussianBelief(mean, covariance, np.ones(2, dtype=bool)).to_vector()
    belief_port.FixValue(context, vector)
    belief = ObstacleBelief.from_port(vector, 2, FAR_BELIEF.task, full_covariance=True)
    expected = evaluate_tube_invariants(y, tube, belief, 0.1)
    np.testing.assert_array_equal(monitor.GetOutputPort("margins").Eval(context), expected.margins)
    for name in ("output_avoid_probability", "tube_avoid_probability"):
        values = monitor.GetOutputPort(name).Eval(context)
        np.testing.assert_array_equal(values, getattr(expected, name))
        assert 0.0 < values[0] < 1.0 and values[1] == 1.0
    covariance[1] = -covariance[1]
    belief_port.FixValue(
        context, GaussianBelief(mean, covariance, np.ones(2, dtype=bool)).to_vector()
    )
    with pytest.raises(ValueError, match=r"^obstacle 1: covariance must be positive definite"):
        monitor.GetOutputPort("margins").Eval(context)


def monitor_diagram(y0: np.ndarray, velocity: np.ndarray):
    """Monitor fed by ConstantVectorSources (tube, belief) and y(t) = y0 + velocity·t."""
    builder = DiagramBuilder()
    monitor = builder.AddSystem(InvariantMonitor(2, FAR_BELIEF.task, r_min=0.1))
    tube = builder.AddSystem(ConstantVectorSource([*MONITOR_CENTER, MONITOR_RADIUS]))
    belief = builder.AddSystem(ConstantVectorSource(FAR_BELIEF.to_vector()))
    speed = builder.AddSystem(ConstantVectorSource(velocity))
    position = builder.AddSystem(Integrator(2))
    builder.Connect(tube.get_output_port(), monitor.GetInputPort("tube"))
    builder.Connect(belief.get_output_port(), monitor.GetInputPort("obstacle_belief"))
    builder.Connect(speed.get_output_port(), position.get_input_port())
    builder.Connect(position.get_output_port(), monitor.GetInputPort("output"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    position.set_integral_value(position.GetMyContextFromRoot(simulator.get_mutable_context()), y0)
    return monitor, simulator


def test_monitor_strict_stops_run_outside_tube():
    y0 = MONITOR_CENTER + np.array([0.5, 0.0])  # 0.2 m outside the tube
    monitor, simulator = monitor_diagram(y0, np.zeros(2))
    tracker = InvariantTracker()
    monitor.attach(simulator, tracker, strict=True)
    with pytest.raises(RuntimeError, match=r"output_in_tube.*t = [-+0-9.e]+ s") as info:
        simulator.AdvanceTo(0.5)
    assert "-0.2" in str(info.value)  # the margin r − ‖y − c‖
    assert tracker.first_violation is not None and "output_in_tube" in tracker.first_violation


def test_monitor_non_strict_records_violation():
    y0 = MONITOR_CENTER + np.array([0.5, 0.0])
    monitor, simulator = monitor_diagram(y0, np.zeros(2))
    tracker = InvariantTracker()
    monitor.attach(simulator, tracker, strict=False)
    simulator.AdvanceTo(0.5)
    assert simulator.get_context().get_time() == 0.5
    record = tracker.records["output_in_tube"]
    assert not record.holds and not tracker.holds
    assert record.worst_margin == pytest.approx(MONITOR_RADIUS - 0.5, abs=1e-12)
    assert record.t_worst == 0.0  # constant inputs: the first sample is (one of) the worst
    assert tracker.records["radius_positive"].holds
    assert tracker.records["output_avoid_probability"].worst_margin == pytest.approx(0.05)


def test_monitor_strict_and_non_strict_with_moving_output():
    """y leaves the tube at t* = r/|v| = 0.6 s: strict mode stops at the first step after t*,
    non-strict mode runs on and records the worst margin r − |v|T at T."""
    velocity = np.array([0.3, -0.4])  # |v| = 0.5 m/s
    monitor, simulator = monitor_diagram(MONITOR_CENTER.copy(), velocity)
    tracker = InvariantTracker()
    monitor.attach(simulator, tracker, strict=True)
    with pytest.raises(RuntimeError, match="output_in_tube") as info:
        simulator.AdvanceTo(2.0)
    match = re.search(r"t = ([-+0-9.e]+) s: margin ([-+0-9.e]+)", str(info.value))
    assert match is not None, str(info.value)
    t_stop, margin = float(match.group(1)), float(match.group(2))
    assert 0.6 < t_stop <= 2.0
    assert margin == pytest.approx(MONITOR_RADIUS - 0.5 * t_stop, rel=1e-4, abs=1e-6)

    monitor, simulator = monitor_diagram(MONITOR_CENTER.copy(), velocity)
    tracker = InvariantTracker()
    monitor.attach(simulator, tracker, strict=False)
    simulator.AdvanceTo(2.0)
    record = tracker.records["output_in_tube"]
    assert not record.holds
    assert record.worst_margin == pytest.approx(MONITOR_RADIUS - 0.5 * 2.0, abs=1e-9)
    assert record.t_worst == pytest.approx(2.0)
    assert "output_in_tube" in tracker.first_violation


# --------------------------------------------------------------------------------------
# 5. OmniRobot + OmniDriveInterface
# --------------------------------------------------------------------------------------
NOMINAL_WHEEL, NOMINAL_BASE, HEADING_GAIN = 0.05, 0.2, 2.0


def omni_derivatives(true_wheel, true_base, pose, command, disturbance=(0.0, 0.0)):
    """ẋ, ẏ, ψ̇ of the robot with its wheel speeds computed by the nominal drive."""
    drive = OmniDriveInterface(NOMINAL_WHEEL, NOMINAL_BASE, HEADING_GAIN)
    drive_context = drive.CreateDefaultContext()
    drive.GetInputPort("velocity_command").FixValue(drive_context, np.asarray(command))
    drive.GetInputPort("pose").FixValue(drive_context, np.asarray(pose))
    wheel_speeds = drive.GetOutputPort("wheel_speeds").Eval(drive_context)

    robot = OmniRobot(true_wheel, true_base, np.zeros(2))
    context = robot.CreateDefaultContext()
    context.SetContinuousState(pose)
    robot.GetInputPort("wheel_speeds").FixValue(context, wheel_speeds)
    robot.GetInputPort("disturbance").FixValue(context, np.asarray(disturbance, dtype=float))
    return robot.EvalTimeDerivatives(context).CopyToVector(), robot, context


def test_omni_nominal_kinematics_follow_command():
    pose = np.array([0.3, -0.2, 0.7])
    command = np.array([0.4, -0.25])
    derivatives, robot, context = omni_derivatives(NOMINAL_WHEEL, NOMINAL_BASE, pose, command)
    np.testing.assert_allclose(derivatives[:2], command, rtol=1e-12, atol=1e-14)
    assert derivatives[2] == pytest.approx(-HEADING_GAIN * 0.7, rel=1e-12)
    np.testing.assert_array_equal(robot.GetOutputPort("output").Eval(context), pose[:2])
    np.testing.assert_array_equal(robot.GetOutputPort("plant_state").Eval(context), pose[:2])
    np.testing.assert_array_equal(robot.GetOutputPort("pose").Eval(context), pose)


def test_omni_heading_error_is_wrapped():
    pose = np.array([0.0, 0.0, 3.5])  # wrap(3.5) = 3.5 − 2π
    derivatives, *_ = omni_derivatives(NOMINAL_WHEEL, NOMINAL_BASE, pose, [0.1, 0.2])
    np.testing.assert_allclose(derivatives[:2], [0.1, 0.2], rtol=1e-12)
    assert derivatives[2] == pytest.approx(-HEADING_GAIN * (3.5 - 2.0 * np.pi), rel=1e-12)


def test_omni_true_wheel_radius_scales_velocity():
    pose = np.array([1.0, 2.0, 0.7])
    command = np.array([0.4, -0.25])
    derivatives, *_ = omni_derivatives(1.1 * NOMINAL_WHEEL, NOMINAL_BASE, pose, command)
    np.testing.assert_allclose(derivatives[:2], 1.1 * command, rtol=1e-12)
    assert derivatives[2] == pytest.approx(1.1 * -HEADING_GAIN * 0.7, rel=1e-12)


def test_omni_disturbance_adds_to_velocity():
    pose = np.array([0.0, 0.0, 0.7])
    command = np.array([0.4, -0.25])
    disturbance = np.array([0.05, -0.02])
    derivatives, *_ = omni_derivatives(NOMINAL_WHEEL, NOMINAL_BASE, pose, command, disturbance)
    np.testing.assert_allclose(derivatives[:2], command + disturbance, rtol=1e-12)
    assert derivatives[2] == pytest.approx(-HEADING_GAIN * 0.7, rel=1e-12)


def test_omni_outputs_do_not_feed_through():
    robot = OmniRobot(NOMINAL_WHEEL, NOMINAL_BASE, np.array([0.5, -0.5]), initial_heading=0.3)
    context = robot.CreateDefaultContext()
    np.testing.assert_array_equal(robot.GetOutputPort("pose").Eval(context), [0.5, -0.5, 0.3])
    for out in ("output", "plant_state", "pose"):
        for port in ("wheel_speeds", "disturbance"):
            assert not robot.HasDirectFeedthrough(
                robot.GetInputPort(port).get_index(), robot.GetOutputPort(out).get_index()
            )


def test_omni_base_and_drive_call_no_python():
    """The base and its drive are Drake primitives (evaluated in C++): no derivative
    evaluation or output of theirs calls Python."""
    robot = OmniRobot(NOMINAL_WHEEL, NOMINAL_BASE, np.array([0.5, -0.5]), initial_heading=0.3)
    drive = OmniDriveInterface(NOMINAL_WHEEL, NOMINAL_BASE, HEADING_GAIN)
    for diagram, names in (
        (robot, {"inputs", "kinematics", "position"}),
        (drive, {"inputs", "wheels"}),
    ):
        kinds = {system.get_name(): type(system).__module__ for system in diagram.GetSystems()}
        assert set(kinds) == names
        assert set(kinds.values()) == {"pydrake.systems.primitives"}


def test_omni_state_is_the_displacement_from_the_initial_pose():
    """The base's state is the displacement from its initial pose (its output adds the pose
    back): its derivative at pose p is the one at p from a zero start. The drive's one
    state (a SymbolicVectorSystem needs one in a continuous Diagram) never changes."""
    start = np.array([2.0, -1.0, 2.5])
    pose = np.array([0.3, -0.2, 0.7])
    command = np.array([0.4, -0.25])
    expected, *_ = omni_derivatives(NOMINAL_WHEEL, NOMINAL_BASE, pose, command)
    robot = OmniRobot(NOMINAL_WHEEL, NOMINAL_BASE, start[:2], initial_heading=start[2])
    context = robot.CreateDefaultContext()
    np.testing.assert_array_equal(robot.GetOutputPort("pose").Eval(context), start)
    context.SetContinuousState(pose - start)
    np.testing.assert_allclose(robot.GetOutputPort("pose").Eval(context), pose, atol=1e-15)
    drive = OmniDriveInterface(NOMINAL_WHEEL, NOMINAL_BASE, HEADING_GAIN)
    drive_context = drive.CreateDefaultContext()
    drive.GetInputPort("velocity_command").FixValue(drive_context, command)
    drive.GetInputPort("pose").FixValue(drive_context, robot.GetOutputPort("pose").Eval(context))
    wheel_speeds = drive.GetOutputPort("wheel_speeds").Eval(drive_context)
    robot.GetInputPort("wheel_speeds").FixValue(context, wheel_speeds)
    robot.GetInputPort("disturbance").FixValue(context, np.zeros(2))
    derivatives = robot.EvalTimeDerivatives(context).CopyToVector()
    np.testing.assert_allclose(derivatives, expected, rtol=1e-14, atol=1e-15)
    assert drive.EvalTimeDerivatives(drive_context).CopyToVector().tolist() == [0.0]


def test_wheel_matrix_rows():
    wheel, base = 0.06, 0.25
    matrix = wheel_matrix(wheel, base)
    angles = [0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0]
    for row, alpha in zip(matrix, angles, strict=True):
        np.testing.assert_allclose(row, np.array([-np.sin(alpha), np.cos(alpha), base]) / wheel)
    # A pure rotation turns every wheel at L·ψ̇/r_w.
    np.testing.assert_allclose(matrix @ [0.0, 0.0, 1.5], np.full(3, base * 1.5 / wheel))
    # A pure body-x translation: wheel 0 (at α = 0) rolls sideways, the others ∓√3/2·v/r_w.
    s = np.sqrt(3.0) / 2.0
    np.testing.assert_allclose(
        matrix @ [0.2, 0.0, 0.0], [0.0, -s * 0.2 / wheel, s * 0.2 / wheel], atol=1e-12
    )


# --------------------------------------------------------------------------------------
# 6. build_diagram
# --------------------------------------------------------------------------------------
SCENARIO_YAML = """
name: tiny
start: [0.0, 0.0]
target: [2.0, 0.0]
duration: 2.0
log_period: 0.05
tube: {{r_min: 0.1, r_max: 0.3, k1: 0.7, k2: 0.4, k3: 0.4, update_rate_hz: {rate}}}
controller: {{kappa: [3.0]}}
plant:
  wheel_radius: 0.052
  base_radius: 0.21
  nominal_wheel_radius: 0.05
  nominal_base_radius: 0.2
  disturbance_amplitude: [0.02, 0.02]
  disturbance_frequency_hz: 0.5
obstacles:
  - motion: !ConstantVelocity {{start: [1.0, 0.9], velocity: [0.0, -0.1]}}
    radius: 0.15
    sigma: 0.1
    epsilon: 0.9
    p_d: 0.9999
  - motion: !Oscillation {{center: [1.5, -1.0], amplitude: [0.0, 0.2], frequency_hz: 0.25}}
    radius: 0.2
    sigma: 0.15
    epsilon: 0.8
    p_d: 0.999
"""

SYSTEM_NAMES = (
    "obstacle_belief_source",
    "spatiotemporal_tube",
    "stt_controller",
    "invariant_monitor",
    "omni_robot",
)
LOGGER_NAMES = (
    "output",
    "tube",
    "belief",
    "diagnostics",
    "recovery",
    "control",
    "margins",
    "output_avoid_probability",
    "tube_avoid_probability",
)


def scenario_belief_by_hand(t: float) -> np.ndarray:
    mean0 = [1.0, 0.9 - 0.1 * t]
    mean1 = [1.5, -1.0 + 0.2 * np.sin(2.0 * np.pi * 0.25 * t)]
    # [mean, σ² I row-major, active] per slot; r_o, ε, p_d are the tube's, not the port's
    return np.array([*mean0, 0.01, 0, 0, 0.01, 1.0, *mean1, 0.0225, 0, 0, 0.0225, 1.0])


@pytest.mark.parametrize("rate", [0.0, 100.0])
def test_build_diagram_structure_and_logs(rate):
    scenario = parse_scenario(SCENARIO_YAML.format(rate=rate))
    assert len(scenario.obstacles) == 2
    built = build_diagram(scenario)
    diagram = built.diagram
    for name in SYSTEM_NAMES:
        diagram.GetSubsystemByName(name)  # raises if absent
    assert built.belief_source.get_name() == "obstacle_belief_source"
    assert built.tube.get_name() == "spatiotemporal_tube"
    assert built.controller.get_name() == "stt_controller"
    assert built.monitor.get_name() == "invariant_monitor"
    assert built.plant.get_name() == "omni_robot"
    assert built.tube.update_period == (None if rate == 0.0 else 0.01)
    assert set(built.loggers) == set(LOGGER_NAMES)

    assert built.belief_source.HasOutputPort("obstacle_belief")
    assert built.tube.HasInputPort("obstacle_belief")
    assert built.monitor.HasInputPort("obstacle_belief")
    assert built.tube.HasOutputPort("tube") and built.tube.HasOutputPort("diagnostics")
    assert built.controller.HasInputPort("tube") and built.controller.HasInputPort("plant_state")
    assert built.controller.HasOutputPort("control")
    assert built.monitor.HasInputPort("tube") and built.monitor.HasOutputPort("margins")
    assert built.plant.HasOutputPort("plant_state")

    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator, simulator)
    simulator.AdvanceTo(2.0)
    root = simulator.get_context()
    logs = {name: sink.FindLog(root) for name, sink in built.loggers.items()}
    expected_times = np.arange(41) * 0.05  # every log_period from 0 to 2 s
    sizes = {"output": 2, "tube": 3, "belief": 14, "diagnostics": 6, "control": 2, "margins": 5}
    sizes |= {"recovery": 2}
    sizes |= {"output_avoid_probability": 2, "tube_avoid_probability": 2}
    for name, log in logs.items():
        np.testing.assert_allclose(log.sample_times(), expected_times, atol=1e-9, err_msg=name)
        assert log.data().shape == (sizes[name], 41), name

    # Wiring: the belief log is the obstacles' motion; the tube starts at `start` and the
    # robot's output starts there too (y(0) = start).
    for k in (0, 13, 40):
        np.testing.assert_allclose(
            logs["belief"].data()[:, k], scenario_belief_by_hand(expected_times[k]), atol=1e-12
        )
    np.testing.assert_allclose(logs["tube"].data()[:2, 0], [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(logs["output"].data()[:, 0], [0.0, 0.0], atol=1e-12)
    # The closed loop works: the centre moved towards the target, y stayed in the tube,
    # and the monitor's margin is r − ‖y − c‖ of the logged signals.
    center, radius = logs["tube"].data()[:2], logs["tube"].data()[2]
    assert center[0, -1] > 0.5
    distance = np.linalg.norm(logs["output"].data() - center, axis=0)
    assert np.all(distance < radius)
    np.testing.assert_allclose(logs["margins"].data()[0], radius - distance, atol=1e-12)
