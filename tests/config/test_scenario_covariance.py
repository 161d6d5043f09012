"""Full obstacle covariances in the scenario format (issue 13, part 3): the forms
`covariance`, `axes_sigma` + `rotation` and `covariance_schedule`, the belief they give, and
the rules a file with them is checked against.

Expected matrices are built here independently of the code under test: rotations with
pydrake.math.RollPitchYaw and scipy.spatial.transform.Rotation, schedules by hand.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RollPitchYaw
from scipy.spatial.transform import Rotation

from stt_drake.assembly import load_scenario
from stt_drake.config import AssumptionError, Obstacle, ScenarioError, limits, validate
from stt_drake.config.assumptions import target_separation
from stt_drake.core import anisotropic, probability
from stt_drake.core.belief import (
    obstacle_belief,
    obstacle_covariance,
    obstacle_rate_bounds,
    obstacle_sigma,
    obstacle_sigma_bounds,
)
from stt_drake.core.motion import ConstantVelocity, CovarianceSchedule, SigmaSchedule
from stt_drake.core.rules import ISOTROPIC_PERIOD_RULE

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"

UAV_BASE = Path(__file__).resolve().parents[1] / "bad_scenarios" / "base" / "uav.yaml"
OBSTACLE0 = "scenario.obstacles[0]"


# --------------------------------------------------------------------------- helpers


def omni_text(uncertainty: str, more_obstacles: str = "", update_rate_hz: float = 0.0) -> str:
    """A small valid omni scenario; obstacle 0 (static at [2.5, 2.5], r_o 0.2) takes the
    lines `uncertainty` (each indented four spaces) for its centre's uncertainty."""
    return (
        "start: [0.5, 0.5]\n"
        "target: [4.5, 4.5]\n"
        "duration: 10.0\n"
        "tube: {r_min: 0.1, r_max: 0.3, k1: 0.5, k2: 0.4, k3: 0.4, "
        f"update_rate_hz: {update_rate_hz}}}\n"
        "controller: {kappa: [2.0]}\n"
        "plant: {disturbance_amplitude: [0.0, 0.0]}\n"
        "obstacles:\n"
        "  - motion: !ConstantVelocity {start: [2.5, 2.5], velocity: [0.0, 0.0]}\n"
        "    radius: 0.2\n"
        f"{uncertainty}"
        "    epsilon: 0.9\n"
        "    p_d: 0.9999\n"
        f"{more_obstacles}"
    )


def uav_text(uncertainty: str) -> str:
    """The UAV base of the bad-scenario corpus with obstacle 0's sigma replaced."""
    text = UAV_BASE.read_text()
    assert "    sigma: 0.447214\n" in text
    return text.replace("    sigma: 0.447214\n", uncertainty, 1)


def load(text: str, tmp_path: Path, name: str = "scenario"):
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return load_scenario(path)


def assert_names(message: str, path: str, word: str) -> None:
    """`message` names exactly `path` and the rule `word` (outside the "(got ...)" echo)."""
    assert re.search(re.escape(path) + r"(?![\w.\[])", message), (
        f"expected field path {path!r} in: {message}"
    )
    assert word in message.rsplit(" (got ", 1)[0], f"expected rule word {word!r} in: {message}"


def assert_refused(text: str, tmp_path: Path, path: str, word: str) -> str:
    with pytest.raises(ScenarioError) as info:
        load(text, tmp_path)
    message = str(info.value)
    assert_names(message, path, word)
    return message


def rotation_2d(angle: float) -> np.ndarray:
    return Rotation.from_euler("z", angle).as_matrix()[:2, :2]


# --------------------------------------------------------------------------- the forms


def test_a_covariance_is_loaded_as_given(tmp_path):
    scenario = load(omni_text("    covariance: [[0.02, 0.006], [0.006, 0.01]]\n"), tmp_path)
    expected = np.array([[0.02, 0.006], [0.006, 0.01]])
    np.testing.assert_array_equal(obstacle_covariance(scenario.obstacles[0], 3.0, 2), expected)
    belief = scenario.belief_at(3.0)
    np.testing.assert_array_equal(belief.covariance[0], expected)
    assert belief.sigma[0] == pytest.approx(np.sqrt(np.linalg.eigvalsh(expected)[-1]), rel=1e-14)


def test_axes_sigma_with_a_2d_rotation(tmp_path):
    angle = 0.7
    scenario = load(omni_text(f"    axes_sigma: [0.2, 0.05]\n    rotation: [{angle}]\n"), tmp_path)
    r = rotation_2d(angle)
    expected = r @ np.diag([0.2**2, 0.05**2]) @ r.T
    covariance = obstacle_covariance(scenario.obstacles[0], 0.0, 2)
    np.testing.assert_allclose(covariance, expected, rtol=0, atol=1e-15)
    # The first principal axis is the first column of R, with the larger deviation.
    axis = r[:, 0]
    assert axis @ covariance @ axis == pytest.approx(0.04, rel=1e-12)
    assert scenario.belief_at(0.0).sigma[0] == pytest.approx(0.2, rel=1e-12)


def test_axes_sigma_without_rotation_is_diagonal(tmp_path):
    scenario = load(omni_text("    axes_sigma: [0.1, 0.03]\n"), tmp_path)
    np.testing.assert_allclose(
        obstacle_covariance(scenario.obstacles[0], 0.0, 2), np.diag([0.01, 0.0009]), atol=1e-17
    )


def test_axes_sigma_with_a_3d_roll_pitch_yaw(tmp_path):
    roll, pitch, yaw = 0.3, -0.4, 1.1
    axes = [0.5, 0.2, 0.1]
    scenario = load(
        uav_text(f"    axes_sigma: {axes}\n    rotation: [{roll}, {pitch}, {yaw}]\n"), tmp_path
    )
    r = RollPitchYaw(roll, pitch, yaw).ToRotationMatrix().matrix()
    # The same rotation from scipy: extrinsic x-y-z angles, R = Rz(yaw)·Ry(pitch)·Rx(roll).
    np.testing.assert_allclose(
        Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix(), r, atol=1e-15
    )
    expected = r @ np.diag(np.square(axes)) @ r.T
    covariance = scenario.belief_at(0.0).covariance[0]
    np.testing.assert_allclose(covariance, expected, rtol=0, atol=1e-15)
    # Obstacle 1 keeps its sigma: σ²I in the covariance, σ itself in sigma.
    np.testing.assert_allclose(scenario.belief_at(0.0).covariance[1], 0.070711**2 * np.eye(3))
    assert scenario.belief_at(0.0).sigma.tolist() == pytest.approx([0.5, 0.070711], rel=1e-12)


def test_a_covariance_schedule_interpolates_and_steps(tmp_path):
    c0 = [[0.01, 0.0], [0.0, 0.01]]
    c1 = [[0.03, 0.01], [0.01, 0.02]]
    c2 = [[0.09, 0.0], [0.0, 0.01]]
    schedule = (
        "    covariance_schedule:\n"
        "      times: [1.0, 3.0, 3.0, 6.0]\n"
        f"      covariances: [{c0}, {c1}, {c2}, {c2}]\n"
    )
    scenario = load(omni_text(schedule), tmp_path)
    obstacle = scenario.obstacles[0]
    by_hand = {
        0.0: c0,  # held before the first time
        1.0: c0,
        2.0: [[0.02, 0.005], [0.005, 0.015]],  # halfway from c0 to c1
        2.5: [[0.025, 0.0075], [0.0075, 0.0175]],
        2.999: np.add(np.multiply(0.0005, c0), np.multiply(0.9995, c1)),  # just before the step
        3.001: c2,  # just after it
        5.0: c2,
        9.0: c2,  # held after the last time
    }
    for t, expected in by_hand.items():
        np.testing.assert_allclose(
            obstacle_covariance(obstacle, t, 2), expected, rtol=1e-12, atol=1e-16, err_msg=t
        )
        np.testing.assert_allclose(scenario.belief_at(t).covariance[0], expected, rtol=1e-12)
        largest = np.sqrt(np.linalg.eigvalsh(np.asarray(expected))[-1])
        assert obstacle_sigma(obstacle, t) == pytest.approx(largest, rel=1e-12)


# --------------------------------------------------------------------------- the belief


#: Two more obstacles: one with a constant full covariance, one with a σ schedule.
MORE_OBSTACLES = (
    "  - motion: !ConstantVelocity {start: [3.5, 1.5], velocity: [0.0, 0.02]}\n"
    "    radius: 0.15\n"
    "    covariance: [[0.04, -0.01], [-0.01, 0.02]]\n"
    "    epsilon: 0.8\n"
    "    p_d: 0.999\n"
    "  - motion: !ConstantVelocity {start: [1.5, 3.5], velocity: [0.0, 0.0]}\n"
    "    radius: 0.15\n"
    "    sigma_schedule: {times: [0.0, 4.0], values: [0.05, 0.15]}\n"
    "    epsilon: 0.85\n"
    "    p_d: 0.999\n"
)
MIXED = omni_text("    sigma: 0.1\n", more_obstacles=MORE_OBSTACLES)


def test_a_mixed_field_carries_every_covariance(tmp_path):
    scenario = load(MIXED, tmp_path)
    full = np.array([[0.04, -0.01], [-0.01, 0.02]])
    for t in (0.0, 2.0, 7.0):
        belief = scenario.belief_at(t)
        assert belief.covariance.shape == (3, 2, 2)
        scheduled = float(np.interp(t, [0.0, 4.0], [0.05, 0.15]))
        np.testing.assert_array_equal(belief.covariance[0], 0.1**2 * np.eye(2))
        np.testing.assert_array_equal(belief.covariance[1], full)
        # rtol 1e-15 ≈ 4.5 ulp, here and for the mean below: a few roundings (interpolate and
        # square; multiply and add) that another order of the same operations may differ by.
        np.testing.assert_allclose(belief.covariance[2], scheduled**2 * np.eye(2), rtol=1e-15)
        # sigma: σ of the isotropic obstacles, √λ_max of the full one (λ = 0.03 ± √0.0002).
        largest = np.sqrt(0.03 + np.sqrt(0.0002))
        np.testing.assert_allclose(belief.sigma, [0.1, largest, scheduled], rtol=1e-14)
        np.testing.assert_allclose(belief.mean[1], [3.5, 1.5 + 0.02 * t], rtol=1e-15)
        np.testing.assert_array_equal(belief.radius, [0.2, 0.15, 0.15])
        np.testing.assert_array_equal(belief.epsilon, [0.9, 0.8, 0.85])


def test_an_isotropic_scenario_has_no_covariance(tmp_path):
    text = MIXED.replace("    covariance: [[0.04, -0.01], [-0.01, 0.02]]\n", "    sigma: 0.12\n")
    scenario = load(text, tmp_path)
    belief = scenario.belief_at(2.0)
    assert belief.covariance is None
    np.testing.assert_array_equal(belief.sigma, [0.1, 0.12, np.interp(2.0, [0, 4], [0.05, 0.15])])
    assert all(obstacle_covariance(o, 2.0, 2) is None for o in scenario.obstacles)


def test_models_without_the_covariance_fields_stay_isotropic():
    """An obstacle model written before full covariances (no such attributes)."""

    class OldModel:
        motion = ConstantVelocity(start=[1.0, 2.0], velocity=[0.0, 0.0])
        radius, sigma, sigma_schedule, epsilon, p_d = 0.2, 0.3, None, 0.9, 0.99

    belief = obstacle_belief([OldModel()], 2, 1.0)
    assert belief.covariance is None and belief.sigma.tolist() == [0.3]
    assert obstacle_rate_bounds([OldModel()])[1].tolist() == [0.0]


def test_sigma_bounds_of_every_form():
    def obstacle(**fields) -> Obstacle:
        return Obstacle(motion=ConstantVelocity(start=[0.0, 0.0], velocity=[0.0, 0.0]), **fields)

    assert obstacle_sigma_bounds(obstacle(sigma=0.2)) == (0.2, 0.2)
    schedule = SigmaSchedule(times=[0.0, 1.0], values=[0.3, 0.1])
    assert obstacle_sigma_bounds(obstacle(sigma_schedule=schedule)) == (0.1, 0.3)
    low, high = obstacle_sigma_bounds(obstacle(axes_sigma=[0.1, 0.4], rotation=[0.2]))
    assert low == pytest.approx(0.4) and high == pytest.approx(0.4)
    turning = CovarianceSchedule(
        times=[0.0, 1.0], covariances=[[[1.0, 0.0], [0.0, 0.01]], [[0.01, 0.0], [0.0, 1.0]]]
    )
    low, high = obstacle_sigma_bounds(obstacle(covariance_schedule=turning))
    assert high == pytest.approx(1.0)
    sampled = [
        np.sqrt(np.linalg.eigvalsh(turning.covariance(t))[-1]) for t in np.linspace(0, 1, 101)
    ]
    assert low <= min(sampled) + 1e-15 and min(sampled) == pytest.approx(np.sqrt(0.505))


# --------------------------------------------------------------------------- rate bounds


def _sampled_sigma_rate(schedule: CovarianceSchedule, times: np.ndarray) -> float:
    sigma = [np.sqrt(np.linalg.eigvalsh(schedule.covariance(t))[-1]) for t in times]
    return float(np.max(np.abs(np.diff(sigma)) / np.diff(times)))


def test_covariance_schedule_rate_bound_is_exact_for_a_scaled_identity():
    # Σ(t) = σ(t)²I with σ² linear from 0.01 to 0.09 over 2 s: σ̇ = 0.04/(2σ), largest at
    # σ = 0.1: 0.2 m/s (the segment slope |Δσ|/Δt is only 0.1).
    schedule = CovarianceSchedule(
        times=[0.0, 2.0], covariances=[(0.01 * np.eye(2)).tolist(), (0.09 * np.eye(2)).tolist()]
    )
    assert schedule.sigma_rate_bound() == pytest.approx(0.2, rel=1e-12)
    sampled = _sampled_sigma_rate(schedule, np.linspace(0.0, 2.0, 20001))
    assert sampled <= schedule.sigma_rate_bound() and sampled == pytest.approx(0.2, rel=1e-3)


def test_covariance_schedule_rate_bound_covers_a_turning_covariance():
    # σ_max is 1 at both samples (a zero segment slope) but dips to √0.505 halfway.
    schedule = CovarianceSchedule(
        times=[0.0, 1.0], covariances=[[[1.0, 0.0], [0.0, 0.01]], [[0.01, 0.0], [0.0, 1.0]]]
    )
    sampled = _sampled_sigma_rate(schedule, np.linspace(0.0, 1.0, 20001))
    assert sampled > 0.5
    assert sampled <= schedule.sigma_rate_bound()


def test_rate_bounds_of_a_scenario_skip_steps(tmp_path):
    schedule = (
        "    covariance_schedule:\n"
        "      times: [0.0, 2.0, 2.0, 4.0]\n"
        "      covariances: [[[0.01, 0.0], [0.0, 0.01]], [[0.04, 0.0], [0.0, 0.01]],\n"
        "                    [[0.25, 0.0], [0.0, 0.25]], [[0.25, 0.0], [0.0, 0.25]]]\n"
    )
    scenario = load(omni_text(schedule, more_obstacles=MORE_OBSTACLES), tmp_path)
    mean_speed, sigma_rate = obstacle_rate_bounds(scenario.obstacles)
    # Segment 0 → 2 s: ‖ΔΣ‖₂ = 0.03, min trace/n = 0.01: 0.03/(2·2·0.1) = 0.075 m/s; the step
    # at 2 s is no segment; the last segment is constant.
    assert sigma_rate[0] == pytest.approx(0.075, rel=1e-12)
    assert sigma_rate[1] == 0.0  # a constant covariance
    assert sigma_rate[2] == pytest.approx(0.1 / 4.0)  # the σ schedule, as before
    assert mean_speed.tolist() == pytest.approx([0.0, 0.02, 0.0])


# --------------------------------------------------------------------------- exact checks


def test_the_initial_condition_uses_the_exact_anisotropic_probability(tmp_path):
    # An obstacle 0.7 m from the start along x, long along y: with its largest σ as an
    # isotropic σ the start would not be clear with ε = 0.95; with Σ it is.
    start = np.array([0.5, 0.5])
    mean = np.array([1.2, 0.5])
    narrow_along_x = np.diag([0.01, 0.25])
    radius = 0.2 + 0.1
    exact = anisotropic.avoid_probability(start, mean, narrow_along_x, radius)
    isotropic = probability.avoid_probability(
        start, mean[None], np.array([0.5]), np.array([radius])
    )
    assert float(isotropic[0]) < 0.95 < exact

    def text(covariance: np.ndarray) -> str:
        return (
            omni_text(f"    covariance: {covariance.tolist()}\n")
            .replace("start: [2.5, 2.5]", "start: [1.2, 0.5]")
            .replace("    epsilon: 0.9\n", "    epsilon: 0.95\n")
        )

    assert load(text(narrow_along_x), tmp_path).obstacles[0].covariance is not None
    # Turned by 90°, long along x: the exact probability fails the condition.
    long_along_x = np.diag([0.25, 0.01])
    assert anisotropic.avoid_probability(start, mean, long_along_x, radius) < 0.95
    with pytest.raises(AssumptionError) as info:
        load(text(long_along_x), tmp_path)
    assert_names(str(info.value), "scenario.start", "initial avoidance condition")


def test_target_separation_uses_the_exact_anisotropic_probability(tmp_path):
    schedule = (
        "    covariance_schedule:\n"
        "      times: [0.0, 5.0]\n"
        "      covariances: [[[0.04, 0.01], [0.01, 0.02]], [[0.3, -0.1], [-0.1, 0.5]]]\n"
    )
    scenario = load(omni_text(schedule, more_obstacles=MORE_OBSTACLES), tmp_path)
    separation = target_separation(scenario, checkpoints=6)
    target = np.asarray(scenario.target)
    for k, t in enumerate(separation.times):
        belief = scenario.belief_at(float(t))
        for j in range(3):
            radius = belief.radius[j] + scenario.tube.r_min
            if j == 2:  # isotropic: the σ formula, unchanged
                expected = probability.avoid_probability(
                    target, belief.mean[j : j + 1], belief.sigma[j : j + 1], np.array([radius])
                )[0]
            else:
                expected = anisotropic.avoid_probability(
                    target, belief.mean[j], belief.covariance[j], radius
                )
            assert separation.q[k, j] == pytest.approx(expected, rel=1e-12, abs=1e-15), (t, j)


def test_an_obstacle_with_a_covariance_sitting_on_the_target_is_refused_when_strict(tmp_path):
    text = omni_text("    covariance: [[0.04, 0.0], [0.0, 0.01]]\n").replace(
        "start: [2.5, 2.5]", "start: [4.5, 4.4]"
    )
    assert len(load(text, tmp_path).obstacles) == 1  # runs; the breach is recorded
    with pytest.raises(AssumptionError) as info:
        load("strict: true\n" + text, tmp_path)
    assert_names(str(info.value), OBSTACLE0, "Assumption 3")


# --------------------------------------------------------------------------- the rules


COVARIANCE_CASES = [
    pytest.param("[[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]]", "2x2", id="3x3-in-2d"),
    pytest.param("[[0.01, 0.0], [0.0]]", "2x2", id="ragged"),
    pytest.param("[[0.01, 0.0]]", "2x2", id="one-row"),
    pytest.param("[[0.01, 0.004], [0.003, 0.02]]", "symmetric", id="asymmetric"),
    pytest.param(
        "[[0.01, 0.02], [0.02, 0.01]]",
        "symmetric positive definite: smallest eigenvalue -0.01",
        id="indefinite",
    ),
    pytest.param("[[0.0, 0.0], [0.0, 0.0]]", "positive definite", id="zero"),
    pytest.param("[[100.0, 0.0], [0.0, 1.0e-12]]", "well conditioned", id="singular"),
    pytest.param("[[0.01, 0.0], [0.0, 1.0e-8]]", "≥ 0.001", id="thinner-than-1mm"),
]


@pytest.mark.parametrize("matrix, word", COVARIANCE_CASES)
def test_covariance_rules(matrix, word, tmp_path):
    assert_refused(
        omni_text(f"    covariance: {matrix}\n"), tmp_path, f"{OBSTACLE0}.covariance", word
    )


def test_a_nan_in_a_covariance_is_refused_by_the_number_limits(tmp_path):
    text = omni_text("    covariance: [[0.01, .nan], [.nan, 0.01]]\n")
    assert_refused(text, tmp_path, f"{OBSTACLE0}.covariance[0][1]", "finite")


def test_a_covariance_of_wrong_type_is_refused_with_its_path(tmp_path):
    text = omni_text("    covariance: [0.01, 0.02]\n")
    assert_refused(text, tmp_path, f"{OBSTACLE0}.covariance[0]", "list")


def test_a_3d_covariance_must_be_3x3(tmp_path):
    text = uav_text("    covariance: [[0.04, 0.0], [0.0, 0.04]]\n")
    assert_refused(text, tmp_path, f"{OBSTACLE0}.covariance", "3x3")


AXES_CASES = [
    pytest.param("    axes_sigma: [0.1, 0.0]\n", f"{OBSTACLE0}.axes_sigma[1]", "> 0", id="zero"),
    pytest.param("    axes_sigma: [-0.1, 0.2]\n", f"{OBSTACLE0}.axes_sigma[0]", "> 0", id="neg"),
    pytest.param(
        "    axes_sigma: [0.1, 1.0e-5]\n", f"{OBSTACLE0}.axes_sigma[1]", "≥ 0.001", id="tiny"
    ),
    pytest.param("    axes_sigma: [0.1]\n", f"{OBSTACLE0}.axes_sigma", "2 entries", id="short"),
    pytest.param(
        "    axes_sigma: [0.1, 0.2]\n    rotation: [0.1, 0.2, 0.3]\n",
        f"{OBSTACLE0}.rotation",
        "1 entry in 2D",
        id="rotation-3-in-2d",
    ),
    pytest.param(
        "    axes_sigma: [0.1, 0.2]\n    rotation: []\n",
        f"{OBSTACLE0}.rotation",
        "1 entry in 2D",
        id="rotation-empty",
    ),
    pytest.param(
        "    axes_sigma: [0.1, 0.2]\n    rotation: [.inf]\n",
        f"{OBSTACLE0}.rotation[0]",
        "finite",
        id="rotation-inf",
    ),
    pytest.param(
        "    sigma: 0.1\n    rotation: [0.3]\n",
        f"{OBSTACLE0}.rotation",
        "with axes_sigma only",
        id="rotation-without-axes",
    ),
    pytest.param(
        "    axes_sigma: [1000.0, 0.0005]\n", f"{OBSTACLE0}.axes_sigma[1]", "≥ 0.001", id="thin"
    ),
    pytest.param(
        "    axes_sigma: [2000.0, 0.001]\n",
        f"{OBSTACLE0}.axes_sigma",
        "well conditioned",
        id="ratio",
    ),
]


@pytest.mark.parametrize("lines, path, word", AXES_CASES)
def test_axes_sigma_and_rotation_rules(lines, path, word, tmp_path):
    assert_refused(omni_text(lines), tmp_path, path, word)


def test_a_3d_rotation_needs_roll_pitch_yaw(tmp_path):
    text = uav_text("    axes_sigma: [0.4, 0.2, 0.1]\n    rotation: [0.5]\n")
    assert_refused(text, tmp_path, f"{OBSTACLE0}.rotation", "3 entries in 3D: [roll, pitch, yaw]")


SCHEDULE_CASES = [
    pytest.param(
        "{times: [0.0, 5.0, 8.0], covariances: [[[0.01, 0.0], [0.0, 0.01]]]}",
        f"{OBSTACLE0}.covariance_schedule",
        "as many covariances as times",
        id="length",
    ),
    pytest.param(
        "{times: [], covariances: []}",
        f"{OBSTACLE0}.covariance_schedule",
        "≥ 1",
        id="empty",
    ),
    pytest.param(
        "{times: [0.0, 5.0, 2.0], covariances: [[[0.01, 0.0], [0.0, 0.01]],"
        " [[0.01, 0.0], [0.0, 0.01]], [[0.01, 0.0], [0.0, 0.01]]]}",
        f"{OBSTACLE0}.covariance_schedule.times",
        "increase",
        id="times-decreasing",
    ),
    pytest.param(
        "{times: [1.0, 1.0, 1.0], covariances: [[[0.01, 0.0], [0.0, 0.01]],"
        " [[0.01, 0.0], [0.0, 0.01]], [[0.01, 0.0], [0.0, 0.01]]]}",
        f"{OBSTACLE0}.covariance_schedule.times",
        "repeated once",
        id="time-thrice",
    ),
    pytest.param(
        "{times: [0.0, 5.0], covariances: [[[0.01, 0.0], [0.0, 0.01]],"
        " [[0.01, 0.0], [0.0, -0.01]]]}",
        f"{OBSTACLE0}.covariance_schedule.covariances[1]",
        "positive definite",
        id="bad-matrix",
    ),
    pytest.param(
        "{times: [0.0, 5.0], covariances: [[[0.01, 0.0], [0.0, 0.01]],"
        " [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]]]}",
        f"{OBSTACLE0}.covariance_schedule.covariances[1]",
        "2x2",
        id="bad-shape",
    ),
]


@pytest.mark.parametrize("schedule, path, word", SCHEDULE_CASES)
def test_covariance_schedule_rules(schedule, path, word, tmp_path):
    assert_refused(omni_text(f"    covariance_schedule: {schedule}\n"), tmp_path, path, word)


PAIRS = {
    "sigma": "    sigma: 0.1\n",
    "sigma_schedule": "    sigma_schedule: {times: [0.0, 5.0], values: [0.1, 0.2]}\n",
    "covariance": "    covariance: [[0.01, 0.0], [0.0, 0.02]]\n",
    "axes_sigma": "    axes_sigma: [0.1, 0.2]\n",
    "covariance_schedule": (
        "    covariance_schedule: {times: [0.0], covariances: [[[0.01, 0.0], [0.0, 0.01]]]}\n"
    ),
}


@pytest.mark.parametrize(
    "first, second",
    [
        (a, b)
        for i, a in enumerate(PAIRS)
        for b in list(PAIRS)[i + 1 :]
        if {a, b} != {"sigma", "sigma_schedule"}
    ],
)
def test_two_uncertainty_forms_are_refused_naming_both(first, second, tmp_path):
    message = assert_refused(
        omni_text(PAIRS[first] + PAIRS[second]), tmp_path, f"{OBSTACLE0}.{second}", "both given"
    )
    assert f"{first} and {second}" in message


def test_two_forms_are_refused_in_code_built_obstacles_too(tmp_path):
    scenario = load(omni_text(PAIRS["covariance"]), tmp_path)
    scenario.obstacles[0].axes_sigma = [0.1, 0.2]
    with pytest.raises(ScenarioError) as info:
        validate(scenario)
    assert_names(str(info.value), f"{OBSTACLE0}.axes_sigma", "both given")


def test_sigma_with_a_sigma_schedule_is_still_one_form(tmp_path):
    scenario = load(omni_text(PAIRS["sigma"] + PAIRS["sigma_schedule"]), tmp_path)
    assert scenario.belief_at(5.0).sigma[0] == pytest.approx(0.2)
    assert scenario.belief_at(5.0).covariance is None


@pytest.mark.parametrize("form", ["covariance", "axes_sigma", "covariance_schedule"])
def test_each_covariance_form_stands_in_for_sigma(form, tmp_path):
    scenario = load(omni_text(PAIRS[form]), tmp_path)
    assert scenario.belief_at(0.0).covariance is not None


def test_no_uncertainty_at_all_is_required(tmp_path):
    message = assert_refused(omni_text(""), tmp_path, f"{OBSTACLE0}.sigma", "required")
    assert "covariance" in message and "axes_sigma" in message


# --------------------------------------------------------------------------- fixed rate


@pytest.mark.parametrize("form", ["covariance", "axes_sigma", "covariance_schedule"])
def test_a_full_covariance_refuses_the_fixed_rate_tube(form, tmp_path):
    isotropic = (
        "  - motion: !ConstantVelocity {start: [3.5, 1.0], velocity: [0.0, 0.0]}\n"
        "    radius: 0.15\n    sigma: 0.1\n    epsilon: 0.9\n    p_d: 0.9999\n"
    )
    text = omni_text(PAIRS[form], more_obstacles=isotropic, update_rate_hz=50.0)
    message = assert_refused(text, tmp_path, "scenario.tube.update_rate_hz", "isotropic")
    assert "use 0 (continuous)" in message and "obstacle 0" in message
    assert ISOTROPIC_PERIOD_RULE in message  # the rule the law and the Drake system ask
    # The same obstacles in continuous time load.
    continuous = omni_text(PAIRS[form], more_obstacles=isotropic, update_rate_hz=0.0)
    assert load(continuous, tmp_path).belief_at(0.0).covariance is not None


def test_an_isotropic_field_may_use_the_fixed_rate_tube(tmp_path):
    scenario = load(omni_text(PAIRS["sigma"], update_rate_hz=50.0), tmp_path)
    assert scenario.tube.update_rate_hz == 50.0


# --------------------------------------------------------------------------- memory


@pytest.mark.parametrize("scenario", ["omni_hardware_case1", "omni_anisotropic", "uav_paper"])
def test_the_memory_estimate_counts_what_the_loggers_record(scenario):
    """Per obstacle and sample, the estimate counts exactly the values the built diagram's
    loggers record (Σ_j is on the belief port, isotropic or not): measured as the logged
    width with one obstacle more."""
    from pydrake.systems.primitives import VectorLogSink

    from stt_drake.assembly.diagram import build_diagram

    def width(count: int) -> int:
        loaded = load_scenario(DIAGRAMS / f"{scenario}.yaml")
        loaded.obstacles = loaded.obstacles[:count]
        sinks = [
            s for s in build_diagram(loaded).diagram.GetSystems() if isinstance(s, VectorLogSink)
        ]
        return sum(sink.get_input_port(0).size() for sink in sinks)

    dimension = load_scenario(DIAGRAMS / f"{scenario}.yaml").dimension
    assert limits.obstacle_values_per_sample(dimension) == width(3) - width(2)


def test_the_memory_estimate_names_its_terms(tmp_path, monkeypatch):
    monkeypatch.setenv(limits.MEMORY_BUDGET_ENV, "0.001")
    text = omni_text(PAIRS["covariance"]).replace("duration: 10.0", "duration: 60.0")
    message = assert_refused(text, tmp_path, "scenario.log_period", "memory budget")
    assert f"(n + n² + {limits.OBSTACLE_VALUES_PER_SAMPLE} values per obstacle" in message
