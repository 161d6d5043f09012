"""Tests of stt_drake.core.control (the funnel controller of paper Sec. 4 / Theorem 4.1).

The reference is an independent, deliberately plain implementation of the paper's formulas
(ln((1+e)/(1−e)) rather than atanh, explicit diagonal matrices and a matrix inverse), and a
closed-loop simulation of an uncertain first-order plant that the controller never sees.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stt_drake.core.control import BoxFunnel, FunnelController

HYPOTHESIS = settings(max_examples=80, deadline=None)


# --------------------------------------------------------------------------------------
# Independent reference of the paper's law (valid inside the funnels)
# --------------------------------------------------------------------------------------
def _rho(e):
    return np.log((1.0 + e) / (1.0 - e))


def _reference_law(t, states, center, radius, kappa, funnels):
    """Returns (u, [e_1, e_2, ...]) with funnels given as (p, q, mu) tuples."""
    states = np.asarray(states, dtype=float)
    offset = states[0] - center
    e1 = np.sqrt(np.sum(offset**2)) / radius
    reference = -kappa[0] * _rho(e1) * offset  # r_2
    errors = [e1]
    for k, (p, q, mu) in enumerate(funnels, start=1):
        n = states.shape[1]
        gamma = (np.asarray(p) - np.asarray(q)) * np.exp(-np.asarray(mu) * t) + np.asarray(q)
        gamma = np.broadcast_to(gamma, (n,))
        gamma_matrix = np.diag(gamma)
        e = np.linalg.solve(gamma_matrix, states[k] - reference)
        xi = 4.0 * np.linalg.inv(gamma_matrix) @ np.linalg.inv(np.eye(n) - np.diag(e * e))
        reference = -kappa[k] * xi @ _rho(e)  # r_{k+1}
        errors.append(e)
    return reference, errors


def _controller(kappa, funnels):
    return FunnelController(
        kappa=list(kappa), funnels=[BoxFunnel(start=p, end=q, rate=mu) for p, q, mu in funnels]
    )


def _states_inside(rng, t, center, radius, kappa, funnels, n):
    """Stacked states whose normalised errors are all in (−0.95, 0.95), built stage by stage
    with the reference law's own r_k (only to place the states inside the funnels)."""
    direction = rng.normal(size=n)
    x1 = center + rng.uniform(0.0, 0.95) * radius * direction / np.linalg.norm(direction)
    states = [x1]
    for k in range(1, len(kappa)):
        p, q, mu = funnels[k - 1]
        gamma = np.broadcast_to((np.asarray(p) - q) * np.exp(-np.asarray(mu) * t) + q, (n,))
        reference = _reference_law(
            t, np.array([*states, np.zeros(n)]), center, radius, kappa[:k], funnels[: k - 1]
        )[0]
        states.append(reference + gamma * rng.uniform(-0.95, 0.95, n))
    return np.array(states)


# --------------------------------------------------------------------------------------
# Stage outputs
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 3])
def test_stage_one_output(n):
    rng = np.random.default_rng(n)
    controller = _controller([1.7], [])
    for _ in range(50):
        center = rng.normal(size=n)
        radius = rng.uniform(0.05, 2.0)
        x1 = center + rng.uniform(-1, 1, n) * radius / np.sqrt(n) * 0.99
        e = np.linalg.norm(x1 - center) / radius
        expected = -1.7 * np.log((1.0 + e) / (1.0 - e)) * (x1 - center)
        evaluation = controller.evaluate(0.3, x1[None], center, radius)
        np.testing.assert_allclose(evaluation.control, expected, rtol=1e-12, atol=1e-15)
        assert len(evaluation.normalized_errors) == 1
        assert evaluation.normalized_errors[0] == pytest.approx([e], rel=1e-14)


def test_stage_one_output_is_zero_at_the_tube_centre():
    controller = _controller([2.0], [])
    evaluation = controller.evaluate(0.0, np.array([[0.4, -0.2]]), np.array([0.4, -0.2]), 0.1)
    np.testing.assert_array_equal(evaluation.control, 0.0)


@pytest.mark.parametrize(
    "kappa, funnels",
    [
        ([1.3, 0.8], [(2.0, 0.2, 1.5)]),
        ([0.5, 2.0], [(np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.3, 0.5]), 0.7)]),
        ([1.0, 0.6, 1.4], [(1.5, 0.2, 1.0), (4.0, 0.5, np.array([0.5, 1.0, 2.0]))]),
        ([2.0, 1.0, 0.3], [(np.array([1.0, 1.5, 2.0]), 0.05, 3.0), (10.0, 1.0, 0.0)]),
    ],
)
def test_multi_stage_output_matches_reference(kappa, funnels):
    n = 3
    rng = np.random.default_rng(len(kappa) * 10 + len(funnels))
    controller = _controller(kappa, funnels)
    assert controller.stages == len(kappa)
    for _ in range(40):
        t = rng.uniform(0.0, 5.0)
        center = rng.normal(size=n)
        radius = rng.uniform(0.05, 1.0)
        states = _states_inside(rng, t, center, radius, kappa, funnels, n)
        expected, expected_errors = _reference_law(t, states, center, radius, kappa, funnels)
        evaluation = controller.evaluate(t, states.ravel(), center, radius)
        # Products of ~6 rounded factors per stage, amplified by 1/(1 − e²) ≤ 10.3 at
        # |e| ≤ 0.95 and by the next stage's ρ: 1e-10 relative is ample and still ~1e5
        # times tighter than any formula slip would be.
        np.testing.assert_allclose(evaluation.control, expected, rtol=1e-10, atol=1e-12)
        assert len(evaluation.normalized_errors) == len(kappa)
        assert evaluation.normalized_errors[0][0] == pytest.approx(expected_errors[0], rel=1e-13)
        for got, want in zip(evaluation.normalized_errors[1:], expected_errors[1:], strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
            assert np.all(np.abs(got) < 1.0)


def test_states_accept_stacked_or_flat_layout():
    controller = _controller([1.0, 1.0], [(1.0, 0.1, 1.0)])
    states = np.array([[0.1, 0.0], [0.2, -0.1]])
    center = np.zeros(2)
    flat = controller.evaluate(0.5, states.ravel(), center, 0.5).control
    stacked = controller.evaluate(0.5, states, center, 0.5).control
    np.testing.assert_array_equal(flat, stacked)


# --------------------------------------------------------------------------------------
# Saturation: always finite, pointing the right way
# --------------------------------------------------------------------------------------
big = st.floats(-1e6, 1e6)
radii = st.sampled_from([0.0, 1e-300, 1e-12, 1e-3, 0.5, -0.2])


@HYPOTHESIS
@given(
    stages=st.integers(1, 3),
    values=st.lists(big, min_size=9, max_size=9),
    center=st.lists(big, min_size=3, max_size=3),
    radius=radii,
    t=st.floats(0.0, 1e3),
)
def test_output_is_always_finite(stages, values, center, radius, t):
    kappa = [1.0, 2.0, 0.5][:stages]
    funnels = [(1.0, 1e-3, 2.0), (0.5, 0.01, 1.0)][: stages - 1]
    controller = _controller(kappa, funnels)
    states = np.array(values[: 3 * stages]).reshape(stages, 3)
    evaluation = controller.evaluate(t, states, np.array(center), radius)
    assert evaluation.control.shape == (3,)
    assert np.all(np.isfinite(evaluation.control))


@HYPOTHESIS
@given(
    offset=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2).map(np.array),
    radius=st.sampled_from([0.0, 1e-9, 0.1, 1.0, 1e3]),
    kappa=st.floats(0.01, 100.0),
)
def test_stage_one_points_back_to_the_tube_centre(offset, radius, kappa):
    center = np.array([0.7, -0.3])
    x1 = center + offset
    offset = x1 - center  # what the controller sees (tiny offsets round away)
    if np.linalg.norm(offset) == 0.0:
        x1 = center + np.array([1e-3, 0.0])
        offset = x1 - center
    u = _controller([kappa], []).evaluate(0.0, x1[None], center, radius).control
    assert np.all(np.isfinite(u))
    assert np.dot(u, x1 - center) < 0.0
    # And along the offset: u = −κ ρ (x1 − c) with 0 < ρ ≤ 2 atanh(1 − 1e-9) ≈ 21.4.
    cross = u[0] * offset[1] - u[1] * offset[0]
    assert abs(cross) <= 1e-12 * np.linalg.norm(u) * np.linalg.norm(offset)
    assert np.linalg.norm(u) <= kappa * 2.0 * np.arctanh(1.0 - 1e-9) * np.linalg.norm(offset) * (
        1 + 1e-12
    )


def test_saturated_output_beyond_the_funnel_is_the_boundary_value():
    # Outside the ball (e1 ≥ 1) the law uses e1 = 1 − 1e-9: ρ = ln((2 − 1e-9)/1e-9).
    controller = _controller([1.5], [])
    center = np.zeros(2)
    x1 = np.array([[3.0, 4.0]])
    rho_max = np.log((2.0 - 1e-9) / 1e-9)
    for radius in [0.0, 1.0, 5.0]:
        evaluation = controller.evaluate(0.0, x1, center, radius)
        np.testing.assert_allclose(evaluation.control, -1.5 * rho_max * x1[0], rtol=1e-6)
        assert evaluation.normalized_errors[0][0] >= 1.0  # reported unsaturated


# --------------------------------------------------------------------------------------
# Box funnel and constructor checks
# --------------------------------------------------------------------------------------
def test_box_funnel_width():
    funnel = BoxFunnel(
        start=np.array([2.0, 1.0]), end=np.array([0.2, 0.5]), rate=np.array([1.0, 3.0])
    )
    # γ(t) = (p − q)e^{−μt} + q: at t = 0, e^{−0} = 1 exactly; at t = 50, e^{−50} ≈ 2e-22 and
    # e^{−150} lie below half an ulp of q, so both ends round to p and q on any libm.
    np.testing.assert_allclose(funnel.width(0.0), [2.0, 1.0], rtol=1e-15)
    np.testing.assert_allclose(funnel.width(50.0), [0.2, 0.5], rtol=1e-15)
    times = np.linspace(0.0, 5.0, 51)
    widths = np.array([funnel.width(t) for t in times])
    assert np.all(np.diff(widths, axis=0) < 0.0)  # shrinking
    assert times[10] == pytest.approx(1.0)
    np.testing.assert_allclose(widths[10], [0.2 + 1.8 * np.exp(-1.0), 0.5 + 0.5 * np.exp(-3.0)])
    scalar = BoxFunnel(start=1.0, end=0.1, rate=0.0)  # μ = 0: constant p
    assert scalar.width(7.0) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "kappa, funnel_count",
    [([], 0), ([1.0], 1), ([1.0, 1.0], 0), ([1.0, 1.0], 2), ([1.0, 1.0, 1.0], 1)],
)
def test_constructor_rejects_wrong_numbers_of_funnels(kappa, funnel_count):
    with pytest.raises(ValueError):
        FunnelController(kappa=kappa, funnels=[BoxFunnel(1.0, 0.1, 1.0)] * funnel_count)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_inputs_raise(bad):
    controller = _controller([1.0, 1.0], [(1.0, 0.1, 1.0)])
    states = np.array([[0.1, 0.0], [0.0, 0.0]])
    center = np.zeros(2)
    bad_states = states.copy()
    bad_states[1, 0] = bad
    with pytest.raises(ValueError):
        controller.evaluate(0.0, bad_states, center, 0.5)
    with pytest.raises(ValueError):
        controller.evaluate(0.0, states, np.array([0.0, bad]), 0.5)
    with pytest.raises(ValueError):
        controller.evaluate(0.0, states, center, bad)
    with pytest.raises(ValueError):
        controller.evaluate(bad, states, center, 0.5)


# --------------------------------------------------------------------------------------
# Closed loop (Theorem 4.1) without Drake
# --------------------------------------------------------------------------------------
def _plant_gain(x):
    """Unknown, state-dependent, non-symmetric g(x) whose symmetric part is the constant
    S = [[1, 0.3], [0.3, 0.8]] (λ_min ≈ 0.58 > 0): the skew part varies with x."""
    skew = 1.5 * np.sin(x[0] + 2.0 * x[1])
    return np.array([[1.0, 0.3 + skew], [0.3 - skew, 0.8]])


def _disturbance(t):
    return 0.4 * np.array([np.sin(3.0 * t), np.cos(5.0 * t + 0.3)])  # |w| ≤ 0.57


def _tube_center(t):
    return np.array([1.5 * np.cos(0.8 * t), np.sin(1.2 * t)])  # |ċ| ≤ 1.7


def _simulate(controller, radius, duration, dt, use_control=True):
    x = _tube_center(0.0) + np.array([0.15, 0.1])  # e1(0) = 0.90
    worst = 0.0
    for step in range(round(duration / dt)):
        t = step * dt
        center = _tube_center(t)
        evaluation = controller.evaluate(t, x[None], center, radius)
        worst = max(worst, float(evaluation.normalized_errors[0][0]))
        u = evaluation.control if use_control else np.zeros(2)
        x = x + dt * (_plant_gain(x) @ u + _disturbance(t))
    return worst


def test_closed_loop_first_order_plant_stays_in_the_tube():
    # ẋ = g(x)u + w with g unknown to the controller, a bounded w and a moving tube. The
    # steady bound (κ ρ(e) λ_min r e ≥ |ċ| + |w|) puts e near 0.85 in the worst alignment,
    # so the funnel is really exercised; 1 ms Euler steps: κ ρ ‖g‖ dt ≲ 0.1 (not stiff).
    controller = _controller([10.0], [])
    radius = 0.2
    assert np.linalg.eigvalsh(np.array([[1.0, 0.3], [0.3, 0.8]])).min() > 0.5
    worst = _simulate(controller, radius, duration=8.0, dt=1e-3)
    assert worst < 1.0
    # Without control the same output leaves the same tube: the test is not vacuous.
    assert _simulate(controller, radius, duration=8.0, dt=1e-3, use_control=False) > 1.0
