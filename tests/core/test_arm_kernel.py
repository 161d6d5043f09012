"""The compiled arm law (stt_drake.core._arm.arm_control) against the numpy reference
(:meth:`stt_drake.core.arm.ArmFunnelLaw.evaluate` under ``backend.pure_numpy``).

Both paths evaluate the same formulas; they differ in rounding only: each SVD of the (3, 7)
Jacobian is LAPACK's gesdd (numpy's build and the one numba calls), backward stable, so where
J is well conditioned (singular values in [0.1, 1], gaps ≥ 0.05) U, s and V agree to a few
ε‖J‖/gap ≈ 1e-14 and q̇_ref to a few ε of its scale. The torque is −κ₂ ξ(e₂) ρ(e₂) with
e₂ = (q̇ − q̇_ref)/γ: inside the funnel (|e₂| ≤ 0.9) its derivative in e₂ is at most ~10³ times
its scale, so it agrees to ~1e-12 relative (and, for a joint with e₂ ≈ 0 where the torque
itself is ≈ 0, to ~1e-12 of the largest torque); beyond the boundary e₂ is saturated and
the torque depends on γ only. A near-singular J leaves the singular vector of its smallest
singular value defined only to ~ε/s₃ (any SVD), so there the tests compare what the law
promises: the damped inverse (continuous in J for λ > 0) and the task-space motion J q̇_ref.
"""

from __future__ import annotations

import numpy as np
import pytest

from stt_drake.core import backend
from stt_drake.core.arm import ArmControlEvaluation, ArmFunnelLaw, JointSpaceMapping
from stt_drake.core.control import BoxFunnel, FunnelController

HOME = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
LOWER = np.array([-2.74, -1.78, -2.90, -3.04, -2.81, 0.54, -3.02])
UPPER = np.array([2.74, 1.78, 2.90, -0.15, 2.81, 4.52, 3.02])
KAPPA = (5.0, 1.5)
START, END, RATE = np.linspace(1.0, 1.6, 7), np.full(7, 0.4), 0.8
RADIUS = 0.05


def make_law(posture_gain: float = 1.0) -> ArmFunnelLaw:
    funnel = BoxFunnel(start=START, end=END, rate=RATE)
    mapping = JointSpaceMapping(
        damping=0.02,
        posture=HOME,
        posture_gain=posture_gain,
        position_lower=LOWER,
        position_upper=UPPER,
        limit_margin=0.25,
        limit_gain=1.0,
    )
    return ArmFunnelLaw(FunnelController(kappa=KAPPA, funnels=[funnel]), mapping)


def jacobian_with(singular: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A (3, 7) Jacobian U diag(singular) Vᵀ with random orthonormal U, V, column-major as
    Drake returns it."""
    u, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    v, _ = np.linalg.qr(rng.normal(size=(7, 3)))
    return np.asfortranarray(u @ np.diag(singular) @ v.T)


def both_paths(law: ArmFunnelLaw, *arguments) -> tuple[ArmControlEvaluation, ...]:
    compiled = law.evaluate(*arguments)
    with backend.pure_numpy():
        reference = law.evaluate(*arguments)
    return compiled, reference


def random_case(rng: np.random.Generator, e1: float, e2: np.ndarray, singular: np.ndarray):
    """Arguments of evaluate with the stage-1 error e1 and stage-2 errors e2 (made so by
    choosing y and q̇ from the reference's own q̇_ref), q within ±0.5 rad of home or in a
    limit band."""
    jacobian = jacobian_with(singular, rng)
    t = rng.uniform(0.0, 6.0)
    center = rng.normal(size=3)
    direction = rng.normal(size=3)
    position = center + e1 * RADIUS * direction / np.linalg.norm(direction)
    in_band = rng.random(7) < 0.3
    q = np.where(in_band, UPPER - rng.uniform(-0.05, 0.3, 7), HOME + rng.uniform(-0.5, 0.5, 7))
    with backend.pure_numpy():
        zero = np.zeros(7)
        reference = make_law().evaluate(t, position, q, zero, jacobian, center, RADIUS)
    gamma = (START - END) * np.exp(-RATE * t) + END
    v = reference.joint_velocity + gamma * e2
    return t, position, q, v, jacobian, center, RADIUS


def assert_close(compiled: ArmControlEvaluation, reference: ArmControlEvaluation) -> None:
    for name in ("task_velocity", "joint_velocity", "normalized_errors"):
        expected = getattr(reference, name)
        scale = np.max(np.abs(expected[np.isfinite(expected)]))  # e₁ = ∞ when r = 0
        atol = 1e-13 * scale
        np.testing.assert_allclose(getattr(compiled, name), expected, rtol=1e-12, atol=atol)
    scale = np.max(np.abs(reference.torque))
    np.testing.assert_allclose(compiled.torque, reference.torque, rtol=1e-12, atol=1e-12 * scale)


def test_kernel_is_selected_and_accepts_realistic_arguments():
    rng = np.random.default_rng(0)
    law = make_law()
    arguments = random_case(rng, 0.5, rng.uniform(-0.5, 0.5, 7), np.array([1.0, 0.6, 0.3]))
    assert backend.using_compiled()
    kernel = backend.compiled("arm_control")
    t, position, q, v, jacobian, center, radius = arguments
    *_, valid = kernel(t, position, q, v, jacobian, center, radius, *law._kernel_arguments)
    assert valid  # the compiled path is not a silent fall-back to numpy


@pytest.mark.parametrize("posture_gain", [0.0, 1.0])
def test_compiled_law_matches_numpy_inside_the_funnels(posture_gain):
    rng = np.random.default_rng(1)
    law = make_law(posture_gain)
    for _ in range(200):
        singular = np.sort(rng.uniform(0.1, 1.0, 3))[::-1] + np.array([0.1, 0.05, 0.0])
        e2 = rng.uniform(-0.9, 0.9, 7)
        arguments = random_case(rng, rng.uniform(0.0, 0.95), e2, singular)
        assert_close(*both_paths(law, *arguments))


def test_compiled_law_matches_numpy_at_and_beyond_the_funnel_boundaries():
    """Saturated errors: e₁ ∈ {1} ∪ [1, 3] (position on or outside the ball), r = 0
    (e₁ = ∞), |e₂| ∈ {1} ∪ [1, 4]."""
    rng = np.random.default_rng(2)
    law = make_law()
    for k in range(200):
        e1 = 1.0 if k % 4 == 0 else rng.uniform(1.0, 3.0)
        e2 = rng.choice([-1.0, 1.0], 7) * np.where(rng.random(7) < 0.3, 1.0, rng.uniform(1, 4, 7))
        arguments = list(random_case(rng, e1, e2, np.array([1.0, 0.5, 0.2])))
        if k % 10 == 0:
            arguments[-1] = 0.0
        compiled, reference = both_paths(law, *arguments)
        assert_close(compiled, reference)
        assert np.all(np.abs(reference.normalized_errors) >= 1.0 - 1e-12)


@pytest.mark.parametrize("smallest", [1e-4, 1e-9, 0.0])
def test_compiled_law_matches_numpy_near_singular_jacobians(smallest):
    rng = np.random.default_rng(3)
    for _ in range(100):
        singular = np.array([1.0, rng.uniform(0.2, 0.8), smallest])
        arguments = random_case(rng, rng.uniform(0.0, 0.95), rng.uniform(-0.9, 0.9, 7), singular)
        jacobian = arguments[4]
        # Without a null-space term q̇_ref = J⁺_λ v_ref (well conditioned for λ > 0): all
        # of the law agrees.
        assert_close(*both_paths(make_law(posture_gain=0.0), *arguments[:2], HOME, *arguments[3:]))
        # With it, the null-space direction of s₃ is arbitrary to ~ε/s₃ in any SVD: the
        # task-space motion J q̇_ref agrees, and both null-space terms leave it unmoved.
        compiled, reference = both_paths(make_law(), *arguments)
        motion = jacobian @ reference.joint_velocity
        np.testing.assert_allclose(
            jacobian @ compiled.joint_velocity, motion, rtol=1e-12, atol=1e-12
        )
        np.testing.assert_allclose(compiled.task_velocity, reference.task_velocity, rtol=1e-12)


def test_non_finite_or_misshaped_inputs_take_the_reference_path():
    rng = np.random.default_rng(4)
    law = make_law()
    arguments = random_case(rng, 0.5, rng.uniform(-0.5, 0.5, 7), np.array([1.0, 0.6, 0.3]))
    t, position, q, v, jacobian, center, radius = arguments
    for selected in (False, True):
        with backend.pure_numpy(selected):
            with pytest.raises(ValueError, match="not finite"):
                law.evaluate(t, np.full(3, np.nan), q, v, jacobian, center, radius)
            with pytest.raises(ValueError):
                law.evaluate(t, position, q, v, jacobian[:, :6], center, radius)
    bad_q = q.copy()
    bad_q[2] = np.nan
    compiled, reference = both_paths(law, t, position, bad_q, v, jacobian, center, radius)
    np.testing.assert_array_equal(compiled.torque, reference.torque)
    assert np.isnan(compiled.torque).any()
