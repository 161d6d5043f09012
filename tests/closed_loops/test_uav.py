"""UAV case study (paper Sec. 5.2): a second-order quadrotor among uncertain 3D obstacles.

Closed loops of both UAV scenarios against the paper's guarantees (Theorem 3.2, Theorem 4.1),
model-freeness (a different true mass or drag, same controller), wind rejection, the 3D
choice of v_j ⟂ m_j, the Quadrotor plant against its equations of motion, and the
scenario rules of the UAV config.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario, parse_scenario
from stt_drake.config import Quadrotor as QuadrotorConfig
from stt_drake.config import ScenarioError
from stt_drake.core.circulation import null_space_direction
from stt_drake.core.invariants import INVARIANT_NAMES
from stt_drake.run import RunResult, simulate
from stt_drake.runlog import RunLog
from stt_drake.systems.plants.quadrotor import Quadrotor
from tests.closed_loops.test_closed_loop import (
    test_logged_run_meets_guarantees_by_independent_recomputation as recompute_guarantees,
)
from tests.closed_loops.test_closed_loop import (
    test_tube_stays_in_target_after_reach_time as check_stay,
)

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"
SCENARIOS = ["uav_paper", "uav_cluttered", "uav_authors_field"]


def check_success(result: RunResult) -> None:
    """Every guarantee holds (worst margin ≥ −tolerance), the target is reached and held."""
    metrics = result.metrics
    failed = {k: v for k, v in metrics["invariants"].items() if not v["holds"]}
    assert not failed, f"{metrics['scenario']}: guarantees violated: {failed}"
    assert set(metrics["invariants"]) == set(INVARIANT_NAMES)
    assert metrics["reached"] and metrics["t_tube_in_target"] < metrics["sim_time_s"]
    assert result.log["t"][-1] == pytest.approx(metrics["sim_time_s"])
    assert result.success


def check_independently(result: RunResult) -> None:
    """The closed-loop tests' per-sample recomputation of every guarantee from the raw
    logs, and the stay-in-target check, applied to `result`."""
    recompute_guarantees(lambda _name: result, result.metrics["scenario"])
    check_stay(lambda _name: result, result.metrics["scenario"])


def hover_force(result: RunResult, after: float) -> np.ndarray:
    """Mean commanded force (N) over the samples after time `after`."""
    return result.log["control"][result.log["t"] >= after].mean(axis=0)


# --------------------------------------------------------------------------- closed loops


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS)
def test_every_guarantee_holds_and_target_is_reached(run_scenario, name):
    check_success(run_scenario(name))


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS)
def test_logged_run_meets_guarantees_by_independent_recomputation(run_scenario, name):
    check_independently(run_scenario(name))


@pytest.mark.parametrize("name", SCENARIOS)
def test_uav_hovers_in_the_target_holding_its_weight(run_scenario, name):
    """After reaching the target the UAV hovers: the mean commanded force balances the true
    weight m·g (the wind averages out, drag vanishes at rest) — a controller that never
    reads m or g had to find it from the measured states alone."""
    scenario = load_scenario(DIAGRAMS / f"{name}.yaml")
    result = run_scenario(name)
    plant = scenario.plant
    after = result.metrics["t_tube_in_target"] + 5.0
    assert after < scenario.duration - 10.0
    weight = np.array([0.0, 0.0, plant.mass * plant.gravity])
    np.testing.assert_allclose(hover_force(result, after), weight, atol=0.25)
    speed = np.linalg.norm(np.diff(result.log["output"], axis=0), axis=1) / scenario.log_period
    assert np.all(speed[result.log["t"][1:] >= after] < 0.2)


def test_tube_radius_shrinks_among_the_clutter(run_scenario):
    """uav_cluttered is no decoration: several obstacles act on the tube (θ_j > 0) and the
    radius drops well below r_max somewhere, while staying a soft-min below every d̂_j."""
    scenario = load_scenario(DIAGRAMS / "uav_cluttered.yaml")
    assert len(scenario.obstacles) >= 30 and scenario.dimension == 3
    assert scenario.random_obstacles.region_min == [0.0] * 3
    assert scenario.random_obstacles.region_max == [10.0] * 3
    log = run_scenario("uav_cluttered").log
    assert np.sum(np.any(log["theta"] > 0.0, axis=0)) >= 3
    bound = np.minimum(log["quantile_distance"].min(axis=1), float(log["r_max"]))
    assert np.all(log["radius"] <= bound + 1e-12)
    assert log["radius"].min() < 0.75 * float(log["r_max"])


def test_more_uncertain_obstacle_gets_a_wider_berth(run_scenario):
    """uav_paper's obstacles 0 and 1 are mirror images under x ↔ y (which maps the straight
    start–target diagonal to itself): only their belief differs. Obstacle 0 (large σ, high
    ε) must be passed farther away than obstacle 1 (small σ, low ε)."""
    scenario = load_scenario(DIAGRAMS / "uav_paper.yaml")
    uncertain, certain = scenario.obstacles[0], scenario.obstacles[1]
    swap = [1, 0, 2]
    np.testing.assert_allclose(np.array(uncertain.motion.start)[swap], certain.motion.start)
    np.testing.assert_allclose(np.array(uncertain.motion.velocity)[swap], certain.motion.velocity)
    assert uncertain.radius == certain.radius
    assert np.array_equal(np.array(scenario.start)[swap], scenario.start)
    assert np.array_equal(np.array(scenario.target)[swap], scenario.target)
    assert uncertain.sigma > 3 * certain.sigma and uncertain.epsilon > certain.epsilon

    report = {o["index"]: o for o in run_scenario("uav_paper").metrics["obstacles"]}
    assert report[0]["sigma"] == pytest.approx(uncertain.sigma)
    assert report[1]["epsilon"] == pytest.approx(certain.epsilon)
    assert report[0]["min_distance_to_mean"] > report[1]["min_distance_to_mean"] + 0.15
    # ...and both were close enough to matter: the straight path passes 1.1 m from each.
    assert report[1]["min_distance_to_mean"] < 1.3


# --------------------------------------------------------------------------- model-free


@pytest.mark.slow
@pytest.mark.parametrize(
    ("field", "factor"), [("mass", 0.5), ("drag", 2.0)], ids=["mass-halved", "drag-doubled"]
)
def test_guarantees_hold_with_a_different_true_plant(field, factor):
    """The controller never reads mass or drag: the same gains and funnels must still meet
    every guarantee when the true plant changes (model-free, Theorem 4.1)."""
    scenario = load_scenario(DIAGRAMS / "uav_paper.yaml")
    changed = getattr(scenario.plant, field) * factor
    scenario.plant = dataclasses.replace(scenario.plant, **{field: changed})
    result = simulate(scenario)
    check_success(result)
    check_independently(result)
    # The plant really changed: the hover force follows the true weight.
    after = result.metrics["t_tube_in_target"] + 5.0
    expected = scenario.plant.mass * scenario.plant.gravity
    assert hover_force(result, after)[2] == pytest.approx(expected, abs=0.25)


# --------------------------------------------------------------------------- wind


@pytest.mark.slow
def test_tripled_wind_stays_in_its_bound_and_is_rejected():
    """Three times the scenario's wind: the logged force that entered the plant respects
    |w_i| ≤ 3·A_i at every sample (and uses most of it), every guarantee still holds at
    every integrator step, the target is reached, and while hovering the controller's force
    cancels the gusts it never measures (u ≈ m·g·e_z − w)."""
    scenario = load_scenario(DIAGRAMS / "uav_paper.yaml")
    bound = 3.0 * np.asarray(scenario.plant.wind_amplitude)
    scenario.plant = dataclasses.replace(scenario.plant, wind_amplitude=bound.tolist())
    result = simulate(scenario)
    check_success(result)
    check_independently(result)
    log = result.log
    wind = log["wind"]
    assert wind.shape == (log["t"].size, 3)
    assert np.all(np.abs(wind) <= bound + 1e-12)
    assert np.all(np.abs(wind).max(axis=0) > 0.5 * bound)

    hover = log["t"] >= result.metrics["t_tube_in_target"] + 5.0
    weight = np.array([0.0, 0.0, scenario.plant.mass * scenario.plant.gravity])
    residual = log["control"][hover] - (weight - wind[hover])
    assert np.max(np.abs(residual)) < 0.3 * np.max(bound)
    for axis in range(3):
        gust = wind[hover, axis] - wind[hover, axis].mean()
        response = log["control"][hover, axis] - log["control"][hover, axis].mean()
        assert np.corrcoef(gust, response)[0, 1] < -0.9


def test_nominal_wind_is_logged_within_its_bound(run_scenario):
    """The wind of the shipped scenarios blows (the guarantees above hold with it on) and
    never exceeds |w_i| ≤ A_i."""
    for name in SCENARIOS:
        bound = np.asarray(load_scenario(DIAGRAMS / f"{name}.yaml").plant.wind_amplitude)
        wind = run_scenario(name).log["wind"]
        assert np.all(np.abs(wind) <= bound + 1e-12)
        assert np.all(np.abs(wind).max(axis=0) > 0.5 * bound)


# --------------------------------------------------------------------------- v_j in 3D


def unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def checked_v(m: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """v_j = null_space_direction(m_j, goal_j) row by row, asserting v ⟂ m and |v| = |m|."""
    goal = np.broadcast_to(goal, m.shape)
    v = np.array([null_space_direction(mk[None], gk)[0] for mk, gk in zip(m, goal, strict=True)])
    np.testing.assert_allclose(np.sum(v * m, axis=1) / np.sum(m * m, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), np.linalg.norm(m, axis=1), rtol=1e-12)
    return v


def continuity_bound(m: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per step k → k+1: the change ‖Δv̂‖ and its geometric bound.

    v̂ = normalise(ĝ − (ĝ·m̂)m̂) and ‖ĝ − (ĝ·m̂)m̂‖ = sin∠(m, g), so
    ‖dv̂‖ ≤ (‖dĝ‖ + 2‖dm̂‖)/sin∠(m, g): v is continuous wherever m ∦ g, and a flip
    (‖Δv̂‖ ≈ 2) between close m's breaks the bound.
    """
    goal = np.broadcast_to(goal, m.shape)
    v_hat, m_hat, g_hat = unit(checked_v(m, goal)), unit(m), unit(goal)
    sine = np.linalg.norm(np.cross(m_hat, g_hat), axis=1)
    change = np.linalg.norm(np.diff(v_hat, axis=0), axis=1)
    bound = (
        np.linalg.norm(np.diff(g_hat, axis=0), axis=1)
        + 2.0 * np.linalg.norm(np.diff(m_hat, axis=0), axis=1)
    ) / np.minimum(sine[:-1], sine[1:])
    return change, bound


@pytest.mark.parametrize("tilt_deg", [60.0, 90.0, 170.0])
def test_v_is_orthogonal_and_continuous_as_m_rotates_slowly(tilt_deg):
    """m sweeps a full cone of half-angle `tilt` around the goal direction in steps of
    0.2°, growing in length as the gap q − ε closes: v ⟂ m and |v| = |m| at every step,
    and v̂ never moves more than the geometric bound allows — no flip between steps. At
    170° the obstacle is nearly head-on, where v matters most."""
    goal = np.array([0.3, -0.5, 0.8])
    g_hat = goal / np.linalg.norm(goal)
    e1 = unit(np.cross(g_hat, [1.0, 0.0, 0.0]))
    e2 = np.cross(g_hat, e1)
    phi = np.radians(np.arange(0.0, 360.0, 0.2))
    tilt = np.radians(tilt_deg)
    direction = np.cos(tilt) * g_hat + np.sin(tilt) * (
        np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    )
    m = direction * np.linspace(1.0, 40.0, phi.size)[:, None]
    change, bound = continuity_bound(m, goal)
    assert np.all(change <= 1.05 * bound + 1e-12)
    assert change.max() < 0.1


def test_v_is_orthogonal_and_continuous_along_the_uav_run(run_scenario):
    """Along the logged uav_paper run, for every obstacle while it acts (θ_j > 0):
    m_j = (c − μ_j)/(q_j − ε_j) from the logged centre, belief and q_j; v_j ⟂ m_j,
    |v_j| = |m_j|, and v̂_j moves between samples no more than m̂_j and the goal direction
    allow (no flip)."""
    log = run_scenario("uav_paper").log
    theta, q = log["theta"], log["avoid_probability"]
    stretches = 0
    for j in range(theta.shape[1]):
        active = np.flatnonzero(theta[:, j] > 0.0)
        for samples in np.split(active, np.flatnonzero(np.diff(active) > 1) + 1):
            if samples.size < 2:
                continue
            stretches += 1
            beliefs = [RunLog.of(log).belief_at(k) for k in samples]
            mean = np.array([b.mean[j] for b in beliefs])
            gap = q[samples, j] - np.array([b.epsilon[j] for b in beliefs])
            m = (log["center"][samples] - mean) / gap[:, None]
            change, bound = continuity_bound(m, log["target"] - log["center"][samples])
            assert np.all(change <= 1.5 * bound + 1e-9), (j, log["t"][samples])
            assert change.max() < 0.5
    assert stretches >= 2  # obstacles did act on the tube


# --------------------------------------------------------------------------- the plant


@pytest.mark.parametrize("mass", [0.5, 1.3])
def test_quadrotor_follows_its_equations_of_motion(mass):
    """m·v̇ = u − m·g·e_z − c_d·v + w and ṗ = v, checked against the formula; outputs
    y = p and plant_state = state = [p, v]."""
    drag, gravity = 0.3, 9.81
    position, velocity = np.array([1.0, -2.0, 3.0]), np.array([0.4, 0.1, -0.7])
    force, wind = np.array([1.0, -2.0, 15.0]), np.array([0.3, 0.2, -0.1])
    plant = Quadrotor(mass, drag, gravity, position, velocity)
    context = plant.CreateDefaultContext()
    plant.GetInputPort("control").FixValue(context, force)
    plant.GetInputPort("disturbance").FixValue(context, wind)
    derivatives = plant.EvalTimeDerivatives(context).CopyToVector()
    np.testing.assert_allclose(derivatives[:3], velocity)
    acceleration = (force + wind - drag * velocity) / mass - np.array([0.0, 0.0, gravity])
    np.testing.assert_allclose(derivatives[3:], acceleration, rtol=1e-14)
    np.testing.assert_array_equal(plant.GetOutputPort("output").Eval(context), position)
    for port in ("plant_state", "state"):
        np.testing.assert_array_equal(
            plant.GetOutputPort(port).Eval(context), np.concatenate([position, velocity])
        )


def test_quadrotor_is_made_of_compiled_drake_systems():
    """No Python callback per derivative evaluation: every subsystem is a pydrake primitive,
    and the default state is the given initial position and velocity."""
    plant = Quadrotor(1.0, 0.2, 9.81, np.array([1.0, 2.0, 3.0]), np.array([0.5, 0.0, -0.5]))
    kinds = {type(system).__module__ for system in plant.GetSystems()}
    assert kinds == {"pydrake.systems.primitives"}, kinds
    context = plant.CreateDefaultContext()
    np.testing.assert_array_equal(
        context.get_continuous_state_vector().CopyToVector(), [1.0, 2.0, 3.0, 0.5, 0.0, -0.5]
    )


def test_quadrotor_outputs_do_not_feed_through_inputs():
    """The loop plant_state → controller → control must not be an algebraic loop."""
    plant = Quadrotor(1.0, 0.2, 9.81, np.zeros(3), np.zeros(3))
    for port in ("output", "plant_state", "state"):
        for i in range(plant.num_input_ports()):
            assert not plant.HasDirectFeedthrough(i, plant.GetOutputPort(port).get_index())


# --------------------------------------------------------------------------- scenario rules


PAPER = (DIAGRAMS / "uav_paper.yaml").read_text()


def paper_with(**replacements: str) -> str:
    text = PAPER
    for old, new in replacements.items():
        assert old in text, old
        text = text.replace(old, new)
    return text


def rejected(text: str, path: str, word: str) -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text)
    message = str(info.value)
    assert message.startswith(path + ":"), message
    assert word in message, message
    return message


def test_uav_files_load_as_quadrotor_with_two_stages():
    for name in SCENARIOS:
        scenario = load_scenario(DIAGRAMS / f"{name}.yaml")
        assert isinstance(scenario.plant, QuadrotorConfig)
        assert scenario.dimension == 3
        assert len(scenario.controller.kappa) == 2 and len(scenario.controller.funnels) == 1
        assert scenario.tube.r_min == 0.3 and scenario.tube.r_max == 0.9
        assert min(scenario.initial_set_radius, scenario.target_set_radius) >= 0.9
        # the funnel contains the initial velocity error, r_2(0) = 0 as y(0) = s
        assert np.all(
            np.abs(scenario.plant.initial_velocity) < scenario.controller.funnels[0].start
        )
    paper = load_scenario(DIAGRAMS / "uav_paper.yaml")
    assert (paper.tube.k1, paper.tube.k2, paper.tube.k3) == (0.31, 0.03, 0.03)
    assert len(paper.obstacles) == 4


@pytest.mark.parametrize(
    ("old", "new", "path", "word"),
    [
        ("mass: 1.0 ", "mass: 0.0 ", "scenario.plant.mass", "> 0"),
        ("drag: 0.2 ", "drag: -0.1 ", "scenario.plant.drag", "≥ 0"),
        ("gravity: 9.81", "gravity: -9.81", "scenario.plant.gravity", "≥ 0"),
        (
            "initial_velocity: [0.3, -0.2, 0.1]",
            "initial_velocity: [0.3, -0.2]",
            "scenario.plant.initial_velocity",
            "3 entries",
        ),
        (
            "wind_amplitude: [0.5, 0.5, 0.3]",
            "wind_amplitude: [0.5, -0.5, 0.3]",
            "scenario.plant.wind_amplitude",
            "≥ 0",
        ),
        (
            "wind_frequencies_hz: [0.07, 0.19, 0.43]",
            "wind_frequencies_hz: []",
            "scenario.plant.wind_frequencies_hz",
            "at least one",
        ),
        ("body_radius: 0.25", "body_radius: 0.0", "scenario.plant.body_radius", "> 0"),
        ("kappa: [3.0, 4.0]", "kappa: [3.0]", "scenario.controller.kappa", "2 stage"),
        (
            "body_radius: 0.25",
            "body_radius: 0.25\n  rotor_count: 4",
            "scenario.plant.rotor_count",
            "unknown field",
        ),
        ("start: [1.0, 1.0, 1.0]", "start: [1.0, 1.0]", "scenario.start", "3 dimensions"),
    ],
)
def test_bad_quadrotor_field_is_rejected_with_its_path(old, new, path, word):
    rejected(paper_with(**{old: new}), path, word)


def test_funnel_that_misses_the_initial_velocity_is_rejected():
    """p_2 must exceed |v(0) − r_2(0)| = |v(0)| per axis (y(0) = s): v_x(0) = 0.3."""
    funnel = "start: [2.0, 2.0, 2.0], end: [1.0, 1.0, 1.0]"
    message = rejected(
        paper_with(**{funnel: "start: [0.25, 2.0, 2.0], end: [0.1, 1.0, 1.0]"}),
        "scenario.controller.funnels[0].start",
        "initial error",
    )
    assert "0.3" in message
    parse_scenario(paper_with(**{funnel: "start: [0.35, 0.25, 0.15], end: [0.1, 0.1, 0.1]"}))


def test_funnel_start_accounts_for_the_stage_one_reference():
    """With y(0) ≠ s the stage-1 law already asks for a velocity at t = 0:
    r_2(0) = −κ_1 ρ_1 (y(0) − s), ρ_1 = 2 atanh(e_1), e_1 = ‖y(0) − s‖/r(0). The UAV starts
    at rest 0.25 m from s along x, κ_1 = 3, and r(0) ∈ [r_max − ln(n_o + 1)/ν, r_max], so
    |r_2,x(0)| ∈ [0.42, 0.53] m/s: p_x = 0.3 > |v_x(0)| = 0 must still be rejected, 0.6
    accepted."""
    scenario = load_scenario(DIAGRAMS / "uav_paper.yaml")
    nu = scenario.nu
    offset = 0.25
    low_r, high_r = 0.9 - math.log(len(scenario.obstacles) + 1) / nu, 0.9
    reference = [3.0 * 2.0 * math.atanh(offset / r) * offset for r in (high_r, low_r)]
    assert 0.3 < reference[0] <= reference[1] < 0.6
    moved = {
        "initial_velocity: [0.3, -0.2, 0.1]": "initial_velocity: [0.0, 0.0, 0.0]\n"
        "  initial_position: [1.25, 1.0, 1.0]",
    }
    funnel = "start: [2.0, 2.0, 2.0], end: [1.0, 1.0, 1.0]"
    rejected(
        paper_with(**moved, **{funnel: "start: [0.3, 2.0, 2.0], end: [0.2, 1.0, 1.0]"}),
        "scenario.controller.funnels[0].start",
        "initial error",
    )
    parse_scenario(paper_with(**moved, **{funnel: "start: [0.6, 2.0, 2.0], end: [0.2, 1.0, 1.0]"}))


def test_untagged_plant_is_still_the_omni_robot():
    """Quadrotor joined the Plant union after OmniRobot: an untagged `plant:` mapping keeps
    meaning OmniRobot, so every omni file loads unchanged."""
    scenario = load_scenario(DIAGRAMS / "omni_hardware_case1.yaml")
    assert type(scenario.plant).__name__ == "OmniRobot"
    assert "!Quadrotor" in PAPER
