"""The FR3 description (models/franka_fr3.urdf) against the published parameters.

References are independent of the URDF: the modified-DH table of the Franka documentation
(re-implemented here with numpy) and the numbers of franka_fr3_parameters.md (limits,
masses, the gravity holding torque at the ready pose computed there with pydrake on a
separate model).
"""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.multibody.tree import JacobianWrtVariable

from stt_drake.core.arm import ArmLimits
from stt_drake.systems.plants.franka import FR3_HOME, FR3_TCP, ArmKinematics, make_fr3_plant

# Modified (Craig) DH table of the Franka docs: (a, d, alpha) per joint, then the flange.
DH = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
]
FLANGE_D = 0.107
HAND_YAW = -np.pi / 4
TCP_OFFSET = 0.1034

# FR3 limits of franka_description / the older Franka docs (parameter file, tables 2a-2b).
POSITION_LOWER = [-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159]
POSITION_UPPER = [2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159]
VELOCITY = [2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26]
EFFORT = [87, 87, 87, 87, 12, 12, 12]
# Reflected rotor inertia of the FR3 (parameter file, table 3d), kg·m².
REFLECTED = [0.605721456, 0.605721456, 0.462474144, 0.462474144] + [0.205544064] * 3


def _rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _trans(x: float, y: float, z: float) -> np.ndarray:
    out = np.eye(4)
    out[:3, 3] = (x, y, z)
    return out


def dh_frames(q: np.ndarray) -> list[np.ndarray]:
    """World poses of link frames 1..7, the flange and the hand TCP by modified DH."""
    pose, frames = np.eye(4), []
    for (a, d, alpha), angle in zip(DH, q, strict=True):
        pose = pose @ _rot_x(alpha) @ _trans(a, 0, 0) @ _rot_z(angle) @ _trans(0, 0, d)
        frames.append(pose)
    flange = pose @ _trans(0, 0, FLANGE_D)
    tcp = flange @ _rot_z(HAND_YAW) @ _trans(0, 0, TCP_OFFSET)
    return [*frames, flange, tcp]


@pytest.fixture(scope="module")
def plant():
    return make_fr3_plant()


def _random_configurations(plant, count: int, seed: int = 7) -> np.ndarray:
    limits = ArmLimits.of(plant)
    rng = np.random.default_rng(seed)
    return rng.uniform(limits.position_lower, limits.position_upper, size=(count, 7))


def _drake_frames(plant, context, q: np.ndarray) -> list[np.ndarray]:
    plant.SetPositions(context, q)
    names = [f"fr3_link{i}" for i in range(1, 9)] + [FR3_TCP]
    return [
        plant.CalcRelativeTransform(
            context, plant.world_frame(), plant.GetFrameByName(name)
        ).GetAsMatrix4()
        for name in names
    ]


def test_home_configuration_matches_dh_and_published_pose(plant):
    context = plant.CreateDefaultContext()
    drake = _drake_frames(plant, context, FR3_HOME)
    for expected, actual in zip(dh_frames(FR3_HOME), drake, strict=True):
        np.testing.assert_allclose(actual, expected, atol=1e-9)
    # Published ready-pose numbers (parameter file, section 4): flange and hand TCP.
    np.testing.assert_allclose(drake[7][:3, 3], [0.306891, 0.0, 0.590282], atol=1e-6)
    np.testing.assert_allclose(drake[8][:3, 3], [0.306891, 0.0, 0.486882], atol=1e-6)
    np.testing.assert_allclose(drake[7][:3, 2], [0.0, 0.0, -1.0], atol=1e-9)  # flange down


def test_random_configurations_match_dh(plant):
    context = plant.CreateDefaultContext()
    for q in _random_configurations(plant, 40):
        for expected, actual in zip(dh_frames(q), _drake_frames(plant, context, q), strict=True):
            np.testing.assert_allclose(actual, expected, atol=1e-9)


def test_kinematics_position_and_jacobian_match_dh(plant):
    kinematics = ArmKinematics()
    step = 1e-6
    for q in _random_configurations(plant, 10, seed=3):
        np.testing.assert_allclose(kinematics.position(q), dh_frames(q)[-1][:3, 3], atol=1e-9)
        numeric = np.column_stack(
            [
                (dh_frames(q + step * e)[-1][:3, 3] - dh_frames(q - step * e)[-1][:3, 3])
                / (2 * step)
                for e in np.eye(7)
            ]
        )
        np.testing.assert_allclose(kinematics.jacobian(q), numeric, atol=1e-7)


def test_mass_matrix_positive_definite_over_random_configurations(plant):
    context = plant.CreateDefaultContext()
    smallest_links = np.inf
    for q in np.vstack([FR3_HOME, _random_configurations(plant, 200, seed=11)]):
        plant.SetPositions(context, q)
        mass = plant.CalcMassMatrix(context)
        np.testing.assert_allclose(mass, mass.T, atol=1e-12)
        eigenvalues = np.linalg.eigvalsh(mass)
        # M = M_links + diag(reflected rotor inertia), M_links ⪰ 0: λ_min ≥ min reflected.
        assert eigenvalues[0] >= min(REFLECTED) - 1e-9
        smallest_links = min(smallest_links, np.linalg.eigvalsh(mass - np.diag(REFLECTED))[0])
    assert smallest_links > 0.0


def test_joint_limits_load_from_the_published_fr3_set(plant):
    limits = ArmLimits.of(plant)
    np.testing.assert_allclose(limits.position_lower, POSITION_LOWER)
    np.testing.assert_allclose(limits.position_upper, POSITION_UPPER)
    np.testing.assert_allclose(limits.velocity, VELOCITY)
    np.testing.assert_allclose(limits.effort, EFFORT)
    assert plant.num_actuators() == 7 and plant.num_positions() == 7
    assert np.all(limits.position_lower < FR3_HOME)
    assert np.all(limits.position_upper > FR3_HOME)


def test_reflected_inertia_and_link_masses(plant):
    actuators = [plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices()]
    np.testing.assert_allclose([a.default_reflected_inertia() for a in actuators], REFLECTED)
    links = sum(plant.GetBodyByName(f"fr3_link{i}").default_mass() for i in range(1, 8))
    assert links == pytest.approx(15.495, abs=1e-3)  # parameter file, section 3a
    hand = plant.GetBodyByName("fr3_hand").default_mass()
    assert hand == pytest.approx(0.6544 + 2 * 0.0291, abs=1e-4)


def test_gravity_holding_torque_at_ready_pose_matches_published_values(plant):
    """Parameter file, section 6: FR3 inertials + Franka Hand (0.71 kg) at q_ready."""
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, FR3_HOME)
    holding = -plant.CalcGravityGeneralizedForces(context)
    np.testing.assert_allclose(holding, [0.00, -3.85, -0.58, 22.26, 0.71, 2.20, 0.00], atol=0.015)


def test_translational_jacobian_full_rank_at_ready_pose(plant):
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, FR3_HOME)
    jacobian = plant.CalcJacobianTranslationalVelocity(
        context,
        JacobianWrtVariable.kV,
        plant.GetFrameByName(FR3_TCP),
        np.zeros(3),
        plant.world_frame(),
        plant.world_frame(),
    )
    assert np.linalg.svd(jacobian, compute_uv=False)[-1] > 0.2
