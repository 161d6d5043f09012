"""Tests of the compiled kernels (stt_drake.core._kernels, _tube) and of the switch between
them and the numpy reference path (stt_drake.core.backend).

References, none of them the code under test:
* ``scipy.stats.ncx2`` through its public interface (sf, cdf, ppf, isf, pdf), over
  λ ∈ [0, 1e5] and probabilities in [1e-6, 1 − 1e-6], with the issue's 1e-12 absolute
  tolerance on probabilities;
* ``scipy.special`` (ndtri, gammaincc) for the central cases;
* the numpy reference path of every public function (Boost for n = 2 and the quantile: an
  independent algorithm, not a twin of the kernels);
* the unpruned tube step, for the claim that pruning changes no output.
No timing assertions: speed lives in ``stt-drake bench``.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import special
from scipy.stats import ncx2

from stt_drake.bench import obstacle_field
from stt_drake.core import _kernels as kernels
from stt_drake.core import _tube, backend
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.control import BoxFunnel, FunnelController
from stt_drake.core.invariants import evaluate_invariants
from stt_drake.core.probability import (
    PRUNE_HEADROOM_NU,
    noncentral_chi_isf,
    noncentral_chi_sf,
    quantile_distance,
)
from stt_drake.core.tube import TubeLaw
from tests.conftest import DIAGRAMS

DIMENSIONS = (1, 2, 3)
#: Noncentralities λ = a²: exactly 0, tiny, and a log grid up to the issue's 1e5.
LAMBDAS = np.concatenate([[0.0, 1e-300, 1e-24, 1e-12], np.logspace(-6, 5, 56)])
#: Probability levels: both tails down to 1e-6 and the bulk.
LEVELS = np.array([1e-6, 1e-5, 1e-4, 1e-3, 0.01, 0.05, 0.1, 0.3, 0.5, 0.7, 0.9, 0.95, 0.99,
                   0.999, 1 - 1e-4, 1 - 1e-5, 1 - 1e-6])
PROBABILITY_ATOL = 1e-12


def _threshold(probability: float, lam: float, n: int) -> float:
    """b with P(‖Z‖ ≥ b) = probability, from scipy (ppf on the side where it is exact)."""
    if probability > 0.5:
        return float(np.sqrt(ncx2.ppf(1.0 - probability, n, lam)))
    return float(np.sqrt(ncx2.isf(probability, n, lam)))


# --------------------------------------------------------------------------------------
# Survival function and CDF against scipy.stats.ncx2
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", DIMENSIONS)
def test_sf_and_cdf_match_scipy_over_the_issue_ranges(n):
    for lam in LAMBDAS:
        a = np.sqrt(lam)
        for level in LEVELS:
            b = _threshold(level, lam, n)
            sf, cdf, _, _ = kernels.chi_sf_pdf(b, a, n)
            assert abs(sf - ncx2.sf(b * b, n, lam)) <= PROBABILITY_ATOL, (n, lam, level)
            assert abs(cdf - ncx2.cdf(b * b, n, lam)) <= PROBABILITY_ATOL, (n, lam, level)
            assert kernels.chi_sf(b, a, n) == pytest.approx(sf, abs=1e-16)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_the_small_tail_is_computed_directly_not_as_one_minus(n):
    # Survival functions, not 1 − cdf: where a tail is small it keeps relative accuracy.
    for lam in [0.0, 0.5, 4.0, 30.0, 400.0, 1e4]:
        a = np.sqrt(lam)
        for level in [1e-6, 1e-5, 1e-4, 1e-3]:
            b = _threshold(level, lam, n)  # upper tail: sf small
            sf, _, _, _ = kernels.chi_sf_pdf(b, a, n)
            assert sf == pytest.approx(ncx2.sf(b * b, n, lam), rel=1e-8), (n, lam, level)
        for level in [1e-4, 1e-3, 1e-2]:
            b = _threshold(1.0 - level, lam, n)  # lower tail: cdf small
            if b < a:  # the offset is beyond the threshold: the cdf is the direct series
                _, cdf, _, _ = kernels.chi_sf_pdf(b, a, n)
                assert cdf == pytest.approx(ncx2.cdf(b * b, n, lam), rel=1e-8), (n, lam, level)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_sf_is_continuous_at_zero_offset(n):
    # λ → 0: the n = 3 closed form divides by a (expm1 form, limit 2bφ(b)); the n = 2
    # Bessel series has a = 0 as a special case. Both must meet the central law.
    b = np.array([1e-3, 0.1, 0.7, 1.5, 3.0, 6.0])
    central = special.gammaincc(0.5 * n, 0.5 * b * b)
    for a in [0.0, 1e-300, 1e-160, 1e-12, 1e-9]:
        got = np.array([kernels.chi_sf(x, a, n) for x in b])
        np.testing.assert_allclose(got, central, rtol=0, atol=1e-14)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_density_and_its_log_derivative(n):
    # f(b) of ‖Z‖ is 2b·(ncx2 pdf at b²); d ln f/db against a central difference.
    for lam in [0.0, 0.3, 9.0, 200.0, 4e4]:
        a = np.sqrt(lam)
        for level in [1e-4, 0.2, 0.5, 0.8, 1 - 1e-4]:
            b = _threshold(level, lam, n)
            _, _, pdf, dlog = kernels.chi_sf_pdf(b, a, n)
            assert pdf == pytest.approx(2.0 * b * ncx2.pdf(b * b, n, lam), rel=1e-9)
            h = 1e-5 * max(b, 1.0)
            up = kernels.chi_sf_pdf(b + h, a, n)[2]
            down = kernels.chi_sf_pdf(b - h, a, n)[2]
            assert dlog == pytest.approx((np.log(up) - np.log(down)) / (2 * h), rel=1e-5,
                                         abs=1e-6)


def test_marcum_q1_extreme_arguments():
    # Tiny ab (first-term shortcut), huge ab (long Miller recurrence), far tails.
    for a, b in [(1e-20, 1e-15), (316.2, 310.0), (316.2, 322.0), (1e-3, 5.0), (40.0, 1.0),
                 (1.0, 40.0), (3.0, 1e-7)]:
        sf, cdf, _, _ = kernels.chi_sf_pdf(b, a, 2)
        assert sf == pytest.approx(ncx2.sf(b * b, 2, a * a), abs=PROBABILITY_ATOL)
        assert sf + cdf == pytest.approx(1.0, abs=1e-15)
        assert 0.0 <= sf <= 1.0 and 0.0 <= cdf <= 1.0
    # Where Boost overflows (tgamma) the bound P(‖Z‖ ≤ b) ≤ πb²·max density = b²/2 decides.
    for a, b in [(0.5, 1e-170), (300.0, 1e-100), (25.0, 1e-10)]:
        sf, cdf, _, _ = kernels.chi_sf_pdf(b, a, 2)
        assert sf == 1.0
        assert 0.0 <= cdf <= 0.5 * b * b


def test_bessel_recurrence_starts_where_the_tail_is_below_1e_17():
    # Start N(x) = ⌊9√x + 8⌋ (_miller_start): the ratio bound I_k/I_{k−1} <
    # e^{−asinh((k − ½)/x)} holds (against scipy), and its product up to N(x) is < e^{−39.2}
    # for x ≤ 1e7: N grows and the sum falls with x, so N(x_i) at x_{i+1} covers [x_i, x_{i+1}].
    grid = np.logspace(-30, 7, 6000)
    for low, high in itertools.pairwise(grid):
        k = np.arange(1, kernels._miller_start(low) + 1)
        assert np.arcsinh((k - 0.5) / high).sum() >= 39.2, low
    k = np.arange(1, 700)
    for x in np.logspace(-3, 4, 50):
        tail = special.ive(k, x)
        seen = tail > 1e-290
        ratio = tail[seen] / special.ive(k - 1, x)[seen]
        assert np.all(ratio < (x / (k - 0.5 + np.hypot(x, k - 0.5)))[seen]), x
        assert special.ive(kernels._miller_start(x), x) < 1e-17 * special.ive(0, x), x


@pytest.mark.parametrize("n", DIMENSIONS)
def test_sf_special_values(n):
    assert kernels.chi_sf(0.0, 3.0, n) == 1.0
    assert kernels.chi_sf(-1.0, 3.0, n) == 1.0  # P(‖Z‖ ≥ negative) = 1
    assert kernels.chi_sf(2.0, 30.0, n) == 1.0  # 1 − sf < 2⁻⁵⁴: exactly 1
    assert np.isnan(kernels.chi_sf(np.nan, 1.0, n))
    assert np.isnan(kernels.chi_sf(1.0, np.nan, n))


def test_ndtri_matches_scipy():
    p = np.concatenate([np.logspace(-300, -1, 300), np.linspace(0.01, 0.99, 197),
                        1.0 - np.logspace(-16, -1, 200)])
    got = np.array([kernels.ndtri(x) for x in p])
    np.testing.assert_allclose(got, special.ndtri(p), rtol=2e-15, atol=2e-15)
    assert kernels.ndtri(0.0) == -np.inf and kernels.ndtri(1.0) == np.inf
    assert np.isnan(kernels.ndtri(1.5))


# --------------------------------------------------------------------------------------
# Quantile
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", DIMENSIONS)
def test_quantile_matches_scipy_over_the_issue_ranges(n):
    for lam in LAMBDAS:
        a = np.sqrt(lam)
        for level in LEVELS:
            s = kernels.chi_isf(level, a, n)
            expected = _threshold(level, lam, n)
            assert s == pytest.approx(expected, rel=1e-12), (n, lam, level)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_quantile_defining_property(n):
    # sf(s) = ε to rounding: for ε > 1/2 through the cdf, relative to 1 − ε.
    rng = np.random.default_rng(n)
    for _ in range(300):
        a = float(np.exp(rng.uniform(np.log(1e-4), np.log(316.0))))
        level = float(rng.uniform(1e-6, 1 - 1e-6))
        s = kernels.chi_isf(level, a, n)
        if level > 0.5:
            cdf = ncx2.cdf(s * s, n, a * a)
            assert cdf == pytest.approx(1.0 - level, rel=1e-11, abs=1e-15), (a, level)
        else:
            assert ncx2.sf(s * s, n, a * a) == pytest.approx(level, rel=1e-11), (a, level)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_quantile_special_values(n):
    assert kernels.chi_isf(1.0, 2.0, n) == 0.0
    assert kernels.chi_isf(0.0, 2.0, n) == np.inf
    assert np.isnan(kernels.chi_isf(np.nan, 2.0, n))
    assert np.isnan(kernels.chi_isf(0.5, np.nan, n))
    # Far offsets: ‖Z‖ ≈ a + N(0, 1) along e, plus the curvature (n − 1)/(2a).
    a, level = 1e4, 0.9
    assert kernels.chi_isf(level, a, n) == pytest.approx(
        a - special.ndtri(level) + (n - 1) / (2 * a), rel=1e-12
    )


@pytest.mark.parametrize("n", DIMENSIONS)
def test_quantile_bracket_bounds_hold(n):
    # The bracket the iteration starts from must contain the root: a − Φ⁻¹(ε) ≤ s and
    # s ≤ a + sqrt(n + 2 sqrt(n u) + 2u), u = −ln ε.
    for lam in [0.0, 0.01, 1.0, 50.0, 1e4]:
        a = np.sqrt(lam)
        for level in LEVELS:
            s = _threshold(level, lam, n)
            u = -np.log(level)
            assert max(a - special.ndtri(level), 0.0) <= s * (1 + 1e-12) + 1e-300
            assert s <= a + np.sqrt(n + 2 * np.sqrt(n * u) + 2 * u)


@pytest.mark.parametrize("n", DIMENSIONS)
def test_halley_error_bound_holds(n):
    # The quantile returns s + step unevaluated once _halley_error_bound is below half an ulp
    # of s: one Halley step from s near the root s* must land within that bound of s*
    # (up to the rounding of sf and f there), and the bound must be finite near the root.
    rng = np.random.default_rng(20 + n)
    for _ in range(200):
        a = float(np.exp(rng.uniform(np.log(1e-2), np.log(300.0))))
        level = float(rng.uniform(0.05, 0.95))
        root = kernels.chi_isf(level, a, n)
        for offset in [-1e-4, -1e-5, 1e-5, 1e-4]:
            s = root + offset * min(root, 1.0)
            sf, cdf, pdf, dlog = kernels.chi_sf_pdf(s, a, n)
            step = ((1.0 - level) - cdf if level > 0.5 else sf - level) / pdf
            step /= 1.0 + 0.5 * step * dlog
            bound = kernels._halley_error_bound(step, s, a, n, dlog)
            rounding = 8 * np.finfo(float).eps * (root + 1.0 / pdf)
            assert abs(s + step - root) <= bound + rounding, (a, level, offset)
            assert np.isfinite(bound)


# --------------------------------------------------------------------------------------
# Compiled path against the numpy reference path
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", DIMENSIONS)
def test_public_probability_functions_agree_between_paths(n):
    rng = np.random.default_rng(10 + n)
    b = np.abs(rng.normal(2.0, 1.5, 400))
    a = np.abs(rng.normal(2.0, 3.0, 400))
    eps = rng.uniform(1e-4, 1 - 1e-4, 400)
    compiled_sf, compiled_isf = noncentral_chi_sf(b, a, n), noncentral_chi_isf(eps, a, n)
    with backend.pure_numpy():
        reference_sf, reference_isf = noncentral_chi_sf(b, a, n), noncentral_chi_isf(eps, a, n)
    np.testing.assert_allclose(compiled_sf, reference_sf, rtol=0, atol=PROBABILITY_ATOL)
    np.testing.assert_allclose(compiled_isf, reference_isf, rtol=1e-10)
    # Shapes and scalars behave the same on both paths.
    assert np.shape(noncentral_chi_sf(1.0, 2.0, n)) == ()
    assert noncentral_chi_sf(b.reshape(20, 20), a.reshape(20, 20), n).shape == (20, 20)
    with backend.pure_numpy():
        assert np.shape(noncentral_chi_isf(0.9, 2.0, n)) == ()


@pytest.mark.parametrize("n", [2, 3])
def test_quantile_distance_agrees_between_paths(n):
    _, center, belief = obstacle_field(60, n, worst_case=True, seed=3)
    args = (center, belief.mean, belief.sigma, belief.radius, belief.epsilon)
    compiled = quantile_distance(*args)
    with backend.pure_numpy():
        reference = quantile_distance(*args)
    np.testing.assert_allclose(compiled + belief.radius, reference + belief.radius, rtol=1e-10)


def _tube_fields():
    for n in (2, 3):
        for worst in (False, True):
            yield n, worst


@pytest.mark.parametrize(("n", "worst"), list(_tube_fields()))
def test_tube_step_agrees_between_paths(n, worst):
    law, center, belief = obstacle_field(120, n, worst_case=worst, seed=5)
    laws = [
        law,
        TubeLaw(
            target=law.target, k1=law.k1, k2=np.linspace(0.2, 0.6, 120),
            k3=np.linspace(0.0, 0.9, 120), r_min=law.r_min, r_max=law.r_max, nu=law.nu,
            linear_zone=0.05, max_center_speed=law.max_center_speed,
        ),
    ]
    for tube_law in laws:
        compiled = tube_law.evaluate(center, belief)
        port = ObstacleBelief.from_port(belief.to_vector(), n, belief.task)
        packed = tube_law.evaluate(center, port)
        with backend.pure_numpy():
            reference = tube_law.evaluate(center, belief)
        assert np.any(compiled.theta > 0.0) or not worst  # the active branch is exercised
        np.testing.assert_allclose(compiled.avoid_probability, reference.avoid_probability,
                                   rtol=0, atol=PROBABILITY_ATOL)
        np.testing.assert_allclose(compiled.theta, reference.theta, rtol=1e-9, atol=1e-12)
        # ċ: 1/(q − ε) amplifies the 1e-14 differences of q; 1e-9 relative.
        np.testing.assert_allclose(compiled.center_rate, reference.center_rate, rtol=1e-9,
                                   atol=1e-12)
        assert compiled.radius == pytest.approx(reference.radius, rel=1e-12)
        both_exact = compiled.quantile_distance <= tube_law.prune_above
        np.testing.assert_allclose(
            compiled.quantile_distance[both_exact] + belief.radius[both_exact],
            reference.quantile_distance[both_exact] + belief.radius[both_exact],
            rtol=1e-10,
        )
        # The port carries σ² I and the packed kernel reads σ = √λ_max back: one rounding of
        # σ (relative 1e-16), amplified in ċ by 1/(q − ε) as above.
        for field in ("avoid_probability", "quantile_distance", "theta"):
            np.testing.assert_allclose(
                getattr(packed, field), getattr(compiled, field), rtol=1e-12, atol=1e-15
            )
        np.testing.assert_allclose(packed.center_rate, compiled.center_rate, rtol=1e-9, atol=1e-12)
        assert packed.radius == pytest.approx(compiled.radius, rel=1e-12)


def test_tube_step_agrees_between_paths_in_one_dimension():
    belief = ObstacleBelief(
        mean=np.array([[1.2], [-2.0], [9.0]]), sigma=np.array([0.2, 0.5, 0.3]),
        radius=np.array([0.2, 0.3, 0.2]), epsilon=np.array([0.8, 0.9, 0.7]),
        p_d=np.array([0.999, 0.9999, 0.999]),
    )
    law = TubeLaw(np.array([5.0]), 0.5, 0.4, 0.4, 0.1, 0.5, 30.0, max_center_speed=np.inf)
    center = np.array([0.3])
    compiled = law.evaluate(center, belief)
    with backend.pure_numpy():
        reference = law.evaluate(center, belief)
    np.testing.assert_allclose(compiled.center_rate, reference.center_rate, rtol=1e-10)
    assert compiled.radius == pytest.approx(reference.radius, rel=1e-12)


def test_invariant_margins_agree_between_paths():
    for n in (2, 3):
        _, center, belief = obstacle_field(80, n, worst_case=True, seed=7)
        output = center + 0.05
        for radius in [0.25, -0.1]:
            compiled = evaluate_invariants(output, center, radius, belief, 0.1)
            port = ObstacleBelief.from_port(belief.to_vector(), n, belief.task)
            packed = evaluate_invariants(output, center, radius, port, 0.1)
            with backend.pure_numpy():
                reference = evaluate_invariants(output, center, radius, belief, 0.1)
            np.testing.assert_allclose(compiled.margins, reference.margins, rtol=0,
                                       atol=PROBABILITY_ATOL)
            np.testing.assert_allclose(compiled.output_avoid_probability,
                                       reference.output_avoid_probability, rtol=0,
                                       atol=PROBABILITY_ATOL)
            np.testing.assert_allclose(compiled.tube_avoid_probability,
                                       reference.tube_avoid_probability, rtol=0,
                                       atol=PROBABILITY_ATOL)
            # σ read back as √(σ²): one rounding (see the tube step above)
            np.testing.assert_allclose(packed.margins, compiled.margins, rtol=0, atol=1e-13)


def test_invariant_margins_propagate_nan_like_numpy():
    _, center, belief = obstacle_field(5, 2, seed=1)
    compiled = evaluate_invariants(center, center, np.nan, belief, 0.1)
    with backend.pure_numpy():
        reference = evaluate_invariants(center, center, np.nan, belief, 0.1)
    np.testing.assert_array_equal(np.isnan(compiled.margins), np.isnan(reference.margins))


@pytest.mark.parametrize("stages", [1, 2, 3])
def test_controller_agrees_between_paths(stages):
    rng = np.random.default_rng(stages)
    n = 3
    funnels = [BoxFunnel(rng.uniform(1.5, 2.5, n), rng.uniform(0.5, 1.0, n), 0.7)
               for _ in range(stages - 1)]
    controller = FunnelController(kappa=list(rng.uniform(1.0, 4.0, stages)), funnels=funnels)
    for _ in range(50):
        t = float(rng.uniform(0.0, 5.0))
        states = rng.normal(0.0, 0.4, stages * n)
        center, radius = rng.normal(0.0, 0.2, n), float(rng.uniform(0.2, 0.8))
        compiled = controller.evaluate(t, states, center, radius)
        tube_only = controller.control_from_tube(t, states, np.append(center, radius))
        with backend.pure_numpy():
            reference = controller.evaluate(t, states, center, radius)
        np.testing.assert_allclose(compiled.control, reference.control, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(tube_only, compiled.control)
        assert len(compiled.normalized_errors) == stages
        for got, expected in zip(compiled.normalized_errors, reference.normalized_errors,
                                 strict=True):
            np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-15)


def test_controller_rejects_non_finite_input_on_the_compiled_path():
    controller = FunnelController(kappa=[2.0])
    with pytest.raises(ValueError, match="not finite"):
        controller.evaluate(0.0, np.array([np.nan, 0.0]), np.zeros(2), 0.5)
    with pytest.raises(ValueError, match="not finite"):
        controller.control_from_tube(0.0, np.zeros(2), np.array([0.0, 0.0, np.inf]))


def test_packed_controller_kernel_is_the_unpacked_one_or_none():
    """funnel_control_packed: the control of funnel_control on the packed law, None where
    an input is not finite or the lengths do not fit (control_from_tube then falls back)."""
    controller = FunnelController(kappa=[2.0, 3.0], funnels=[BoxFunnel([1.5, 2.0], 0.5, 0.7)])
    law = controller.packed_law(2)
    tube = np.array([0.1, -0.2, 0.6])
    states = np.array([0.3, 0.1, -0.4, 0.2])
    control, _errors, finite = kernels.funnel_control(
        1.2, states, tube[:2], tube[2], *controller.compiled_arguments(2)
    )
    assert finite
    np.testing.assert_array_equal(kernels.funnel_control_packed(1.2, states, tube, law), control)
    for bad_states, bad_tube in ((np.append(states[:3], np.nan), tube), (states, tube * np.inf)):
        assert kernels.funnel_control_packed(1.2, bad_states, bad_tube, law) is None
    assert kernels.funnel_control_packed(np.inf, states, tube, law) is None
    assert kernels.funnel_control_packed(1.2, states[:3], tube, law) is None  # N·n ≠ 3
    assert kernels.funnel_control_packed(1.2, states[:2], tube, law) is None  # law of N = 2


# --------------------------------------------------------------------------------------
# Pruning
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("count", [50, 1000])
def test_pruning_changes_no_output(n, count):
    law, center, belief = obstacle_field(count, n, seed=11)
    pruned = law.evaluate(center, belief)
    exact = law.evaluate(center, belief, prune=False)
    skipped = pruned.quantile_distance != exact.quantile_distance
    assert np.sum(skipped) > count // 2  # the test really exercises pruning
    # ċ, q and θ do not depend on d̂ at all: bit for bit.
    np.testing.assert_array_equal(pruned.center_rate, exact.center_rate)
    np.testing.assert_array_equal(pruned.avoid_probability, exact.avoid_probability)
    np.testing.assert_array_equal(pruned.theta, exact.theta)
    # r: each skipped term weighs < e^{−40} of the r_max term, so r moves by at most
    # n_o·e^{−40}/ν (plus rounding).
    bound = count * np.exp(-PRUNE_HEADROOM_NU) / law.nu + 4 * np.spacing(exact.radius)
    assert abs(pruned.radius - exact.radius) <= bound
    # A skipped d̂ is a true lower bound, still above the threshold.
    assert np.all(pruned.quantile_distance[skipped] > law.prune_above)
    assert np.all(pruned.quantile_distance[skipped] <= exact.quantile_distance[skipped])
    with backend.pure_numpy():
        reference = law.evaluate(center, belief, prune=False)
    assert exact.radius == pytest.approx(reference.radius, rel=1e-12)


# --------------------------------------------------------------------------------------
# The switch
# --------------------------------------------------------------------------------------
def _python(code: str, **env: str) -> str:
    environment = {**os.environ, **env}
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=environment,
        check=True, timeout=300,
    )
    return result.stdout.strip()


def test_importing_the_package_does_not_import_numba():
    code = (
        "import sys\n"
        "import stt_drake.core.tube, stt_drake.core.probability\n"
        "import stt_drake.core.control, stt_drake.core.invariants\n"
        "print('numba' in sys.modules, 'stt_drake.core._kernels' in sys.modules)"
    )
    assert _python(code, STT_DRAKE_PURE_NUMPY="") == "False False"


@pytest.mark.slow
def test_environment_variable_selects_the_numpy_path():
    code = (
        "import sys, numpy as np\n"
        "from stt_drake.core import backend\n"
        "from stt_drake.core.probability import noncentral_chi_sf\n"
        "noncentral_chi_sf(np.ones(3), np.ones(3), 2)\n"
        "print(backend.using_compiled(), 'numba' in sys.modules)"
    )
    assert _python(code, STT_DRAKE_PURE_NUMPY="1") == "False False"
    assert _python(code, STT_DRAKE_PURE_NUMPY="0") == "True True"


def test_pure_numpy_block_restores_the_previous_choice():
    before = backend.using_compiled()
    with backend.pure_numpy():
        assert not backend.using_compiled()
        assert backend.compiled("tube_step", 2) is None
        assert backend.compiled("funnel_control") is None
        with backend.pure_numpy(False):
            assert backend.compiled("tube_step", 2) is _tube.tube_step
            assert backend.compiled("funnel_control") is kernels.funnel_control
    assert backend.using_compiled() == before


def test_every_dispatched_kernel_exists_in_its_module():
    import importlib

    assert set(backend.KERNEL_MODULES) == set(backend.KERNELS)
    for name in backend.KERNELS:
        module = importlib.import_module(f"stt_drake.core.{backend.KERNEL_MODULES[name]}")
        assert callable(getattr(module, name)), name
    with backend.pure_numpy(False):
        for name, module_name in backend.KERNEL_MODULES.items():
            assert backend.compiled(name, 3).__module__ == f"stt_drake.core.{module_name}"


@pytest.mark.parametrize("path", [False, True])
def test_unknown_kernel_name_raises_on_either_path(path):
    # A typo must not silently select the numpy path.
    with backend.pure_numpy(path), pytest.raises(KeyError, match="unknown compiled kernel"):
        backend.compiled("tube_stepp", 2)


def test_dimension_rule():
    with backend.pure_numpy(False):
        for n in backend.COMPILED_DIMENSIONS:
            assert backend.compiled("chi_sf_array", n) is kernels.chi_sf_array
        for n in (0, 4, 7):
            assert backend.compiled("chi_sf_array", n) is None  # the numpy reference
        # Kernels for any n ignore the rule.
        assert backend.compiled("belief_table", 5) is kernels.belief_table
        with pytest.raises(TypeError, match="pass dimension"):
            backend.compiled("invariant_margins")


@pytest.mark.slow
def test_closed_loop_agrees_between_paths():
    # The whole Drake loop (belief source, tube, controller, monitor) on each path.

    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator

    from stt_drake.assembly import load_scenario
    from stt_drake.assembly.diagram import build_diagram
    from stt_drake.core.invariants import InvariantTracker

    scenario = load_scenario(DIAGRAMS / "omni_hardware_case1.yaml")

    def run() -> tuple[np.ndarray, np.ndarray, bool]:
        built = build_diagram(scenario)
        simulator = Simulator(built.diagram)
        ApplySimulatorConfig(scenario.simulator, simulator)
        tracker = InvariantTracker()
        built.monitor.attach(simulator, tracker, False)
        simulator.AdvanceTo(3.0)
        context = simulator.get_context()
        tube = built.loggers["tube"].FindLog(context).data()
        margins = built.loggers["margins"].FindLog(context).data()
        return tube, margins, tracker.holds

    compiled = run()
    with backend.pure_numpy():
        reference = run()
    assert compiled[2] and reference[2]
    assert compiled[0].shape == reference[0].shape
    np.testing.assert_allclose(compiled[0], reference[0], rtol=0, atol=1e-11)
    np.testing.assert_allclose(compiled[1], reference[1], rtol=0, atol=1e-11)


@pytest.mark.parametrize("n", [2, 3])
def test_largest_variance_matches_numpy_eigvalsh(n):
    """The closed-form λ_max of the belief port's covariances (quadratic in 2D, Smith's
    trigonometric cubic in 3D) against LAPACK's eigvalsh, over random SPD matrices with
    condition numbers up to 1e6, repeated eigenvalues and diagonal ones."""
    from stt_drake.core import _kernels

    rng = np.random.default_rng(40 + n)
    matrices = []
    for _ in range(400):
        rotation, _ = np.linalg.qr(rng.normal(size=(n, n)))
        variances = 10.0 ** rng.uniform(-6, 0, n)
        matrices.append((rotation * variances) @ rotation.T)
    matrices.append(np.diag(np.arange(1.0, n + 1.0)))  # diagonal: exact
    matrices.append(0.3 * np.eye(n))  # σ² I: exact
    rotation, _ = np.linalg.qr(rng.normal(size=(n, n)))
    matrices.append((rotation * np.r_[np.full(n - 1, 2.0), 1.0]) @ rotation.T)  # repeated
    for covariance in matrices:
        table = np.concatenate([np.zeros(n), covariance.ravel(), [1.0]])[None, :]
        expected = np.linalg.eigvalsh(covariance)[-1]
        # λ_max's condition is 1 (Weyl): ~10 roundings of the entries' scale ‖Σ‖ = λ_max
        assert _kernels.largest_variance(table, 0, n) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("n", [2, 3])
def test_inactive_slots_never_reach_the_tube_or_the_monitor(n):
    """Masked slots: the packed tube step and invariant margins with some slots inactive
    (their means placed right on the centre, with tiny covariances: they would dominate if
    read) equal the law on the active slots alone, and the inactive slots read q = 1,
    d̂ = +∞, θ = 0 and avoidance probability 1 — compiled and numpy paths alike."""
    from stt_drake.core.belief import GaussianBelief, ObstacleBelief

    law, center, belief = obstacle_field(12, n, worst_case=True, seed=11)
    gaussian = belief.gaussian()
    active = np.ones(12, dtype=bool)
    active[[0, 5, 6, 11]] = False
    mean = gaussian.mean.copy()
    mean[~active] = center
    covariance = gaussian.covariance.copy()
    covariance[~active] = 1e-6 * np.eye(n)
    masked = GaussianBelief(mean, covariance, active)
    subset = ObstacleBelief.of(masked, belief.task)
    output = center + 0.05
    tube = np.append(center, 0.2)
    for numpy_path in (False, True):
        with backend.pure_numpy(numpy_path):
            expected = law.evaluate(center, subset)
            port = ObstacleBelief.from_port(masked.to_vector(), n, belief.task)
            packed = law.evaluate(center, port)
            margins = evaluate_invariants(output, tube[:-1], float(tube[-1]), port, 0.1)
            reference = evaluate_invariants(output, center, 0.2, subset, 0.1)
        np.testing.assert_allclose(packed.center_rate, expected.center_rate, rtol=1e-12)
        assert packed.radius == pytest.approx(expected.radius, rel=1e-14)
        np.testing.assert_array_equal(packed.avoid_probability[active], expected.avoid_probability)
        np.testing.assert_array_equal(packed.avoid_probability[~active], 1.0)
        np.testing.assert_array_equal(packed.quantile_distance[~active], np.inf)
        np.testing.assert_array_equal(packed.theta[~active], 0.0)
        np.testing.assert_allclose(margins.margins, reference.margins, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(margins.output_avoid_probability[~active], 1.0)
