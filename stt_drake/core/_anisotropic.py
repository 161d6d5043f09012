"""Compiled (numba) kernels of :mod:`stt_drake.core.anisotropic`: the ball probabilities, their
gradient and the quantile radius of a Gaussian obstacle O ~ N(μ, Σ), for n = 2 and 3.

The method (saddle-point contour integration of the Laplace inversion integral) and its
derivation are in :mod:`stt_drake.core.anisotropic`; this module is the same arithmetic as
scalar loops, one native call per point. Its constants are those of
:mod:`stt_drake.core.constants`, shared with the numpy reference.

Inputs: the caller decomposes Σ = V diag(variances) Vᵀ once per obstacle and passes

* ``variances``: the eigenvalues λ_i of Σ (> 0), shape (n,);
* ``offset``: the point relative to the mean in the eigenbasis, Vᵀ(point − μ), shape (n,)
  (for the ``*_array`` kernels, (k, n): one row per point);
* ``radius``: the collision distance R (> 0).

With Y = ‖point − O‖² = Σ_i (offset_i + √λ_i z_i)², z ~ N(0, I), the kernels work in units
of the threshold: κ_i = λ_i/R², ν_i = offset_i²/R², so that the collision event is Y/R² < 1.
Gradients are returned in the eigenbasis (∂/∂offset_i); the caller rotates them with V.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from stt_drake.core._kernels import ndtri
from stt_drake.core.anisotropic_contour import path_table
from stt_drake.core.backend import jit_options
from stt_drake.core.constants import (
    ANISOTROPIC_QUANTILE_MAX_ITERATIONS,
    ANISOTROPIC_QUANTILE_RTOL,
    NEWTON_MAX_ITERATIONS,
    PATH_STEP,
    SADDLE_MAX_ITERATIONS,
    SERIES_BELOW,
    STEP_ACCEPT,
    UNDERFLOW_EXPONENT,
)

_JIT = jit_options()
_INV_SQRT_2 = 1.0 / math.sqrt(2.0)
#: The small helpers of the contour loop are inlined into it (~15 % of its time).
_INLINE = {**_JIT, "inline": "always"}

#: The saddle iteration stops once |log K'(ŝ)| is at this rounding level of K' itself (its
#: Newton steps would then be rounding noise, which can cycle between two neighbouring x).
_SADDLE_RESIDUAL = 1e-15
#: The quantile iteration returns the root of its fifth-order model once the model's
#: estimated truncation error (relative, in R²) is below this (see :func:`quantile_radius`).
_QUANTILE_REMAINDER = 1e-15
#: The start's Newton iteration on √J (:func:`_solve_gap`) stops after a step below this
#: share of 1 + |x|: its error is then ~1e-6 (quadratic convergence), far below the ~1e-3 of
#: the Lugannani–Rice start it serves, and any x is consistent (R² is computed from it).
_GAP_STEP = 1e-3


_TABLE = path_table()
PATH_NODES = _TABLE.shape[1]
_TSQ = _TABLE[0].copy()
_DTSQ = _TABLE[1].copy()
_D2TSQ = _TABLE[2].copy()
_D3TSQ = _TABLE[3].copy()
_T = _TABLE[4].copy()
_TP = _TABLE[5].copy()
_WEIGHT = _TABLE[6].copy()
_POLE_WEIGHT = _WEIGHT * _TP


# --------------------------------------------------------------------------- saddle point
@njit(**_JIT)
def log_gap(z: float) -> float:
    """G(z) = log(1 − z) + z/(1 − z) ≥ 0 for real z < 1, without cancellation near 0
    (series Σ_{k≥2} (k − 1) z^k / k)."""
    if abs(z) < SERIES_BELOW:
        total = 0.0
        power = z * z
        k = 2.0
        while True:
            term = power * (k - 1.0) / k
            total += term
            if abs(term) <= 1e-17 * total:
                return total
            power *= z
            k += 1.0
    return math.log1p(-z) + z / (1.0 - z)


@njit(**_JIT)
def _slope_terms(kappa: np.ndarray, nu: np.ndarray, x: float) -> tuple[float, float]:
    """(K'(s), K''(s)) at s = (1 − e^x)/(2κ_max), K the cumulant generating function of
    Y/R² (κ_max the largest κ)."""
    kmax = np.max(kappa)
    grow = math.expm1(x)
    first = 0.0
    second = 0.0
    for i in range(kappa.shape[0]):
        t = 1.0 + (kappa[i] / kmax) * grow
        first += kappa[i] / t + nu[i] / (t * t)
        second += 2.0 * kappa[i] * kappa[i] / (t * t) + 4.0 * kappa[i] * nu[i] / (t * t * t)
    return first, second


@njit(**_JIT)
def saddle_log_t(kappa: np.ndarray, nu: np.ndarray) -> float:
    """x = log(1 − 2κ_max ŝ) at the saddle point K'(ŝ) = 1.

    Newton's iteration on log K' (nearly linear in x in both tails), kept inside a bracket
    valid from the start: K' ≥ κ_max/t_max, so K' ≥ 1 at t_max = κ_max; and
    K' ≤ nκ_max/t_max + κ_max² Σν_i/κ_i² / t_max², so K' ≤ 1 at the larger of twice each
    term's root. x = 0 (ŝ = 0) separates the two cases by the sign of E[Y/R²] − 1.
    """
    n = kappa.shape[0]
    kmax = np.max(kappa)
    mean = 0.0
    tail = 0.0
    for i in range(n):
        mean += kappa[i] + nu[i]
        tail += nu[i] * (kmax / kappa[i]) ** 2
    if mean >= 1.0:
        lo = 0.0
        hi = math.log(max(2.0 * n * kmax, math.sqrt(2.0 * tail), 1.0))
    else:
        lo = math.log(kmax)
        hi = 0.0
    x = 0.5 * (lo + hi)
    for _ in range(SADDLE_MAX_ITERATIONS):
        first, second = _slope_terms(kappa, nu, x)
        g = math.log(first)
        if abs(g) <= _SADDLE_RESIDUAL:
            return x
        if g > 0.0:
            lo = x
        else:
            hi = x
        slope = -second / first * math.exp(x) / (2.0 * kmax)
        new = x - g / slope
        if not (lo <= new <= hi):
            new = 0.5 * (lo + hi)
        if abs(new - x) <= 4e-16 * (1.0 + abs(x)) or hi - lo <= 4e-16 * (1.0 + abs(x)):
            return new
        x = new
    return x


# --------------------------------------------------------------------------- the contour
@njit(**_INLINE)
def _norm2(c: complex) -> float:
    """|c|²."""
    return c.real * c.real + c.imag * c.imag


@njit(**_INLINE)
def _reciprocal(c: complex) -> complex:
    """1/c as c̄/|c|² (numba's complex division handles overflow this code cannot meet, at
    several times the cost)."""
    return c.conjugate() * (1.0 / _norm2(c))


@njit(**_INLINE)
def _sum_log(delta: complex, rho: np.ndarray) -> complex:
    """Σ_i log(1 − ρ_iδ) for Im δ > 0, with one logarithm and one arctangent per pair.

    Each q_i = 1 − ρ_iδ is in the lower half-plane, arg q_i ∈ (−π, 0), so a pair's
    arg q_i q_j ∈ (−2π, 0) is the principal argument of the product, less 2π if that is
    positive. (Re log is ½ log Π|q_i|², whose absolute error ~1e-16 is all ψ needs.)
    """
    n = rho.shape[0]
    modulus = 1.0
    angle = 0.0
    i = 0
    while i < n:
        qr = 1.0 - rho[i] * delta.real
        qi = -rho[i] * delta.imag
        modulus *= qr * qr + qi * qi
        if i + 1 < n:
            pr = 1.0 - rho[i + 1] * delta.real
            pi = -rho[i + 1] * delta.imag
            modulus *= pr * pr + pi * pi
            pair = math.atan2(qr * pi + qi * pr, qr * pr - qi * pi)
            angle += pair - 2.0 * math.pi if pair > 0.0 else pair
        else:
            angle += math.atan2(qi, qr)
        i += 2
    return complex(0.5 * math.log(modulus), angle)


@njit(**_INLINE)
def _psi(
    delta: complex, rho: np.ndarray, a: np.ndarray, a_over_rho: np.ndarray
) -> tuple[complex, complex, complex, complex]:
    """(ψ, ψ′, ψ″, ψ‴) at δ (Im δ > 0), where ψ(δ) = Φ(ŝ + δ) − Φ(ŝ) without its linear
    term (zero at the saddle): Σ_i −½[log(1 − z_i) + z_i] + (a_i/ρ_i) z_i²/(1 − z_i),
    z_i = ρ_iδ."""
    p0 = -0.5 * _sum_log(delta, rho)
    p1 = 0j
    p2 = 0j
    p3 = 0j
    for i in range(rho.shape[0]):
        r = rho[i]
        z = r * delta
        w = _reciprocal(1.0 - z)
        w2 = w * w
        zw = z * w
        p0 += -0.5 * z + a_over_rho[i] * z * zw
        p1 += 0.5 * r * zw + a[i] * zw * (2.0 - z) * w
        p2 += r * (0.5 * r + 2.0 * a[i] * w) * w2
        p3 += r * r * w2 * w * (r + 6.0 * a[i] * w)
    return p0, p1, p2, p3


@njit(**_INLINE)
def _solve_node(
    delta: complex, k: int, rho: np.ndarray, a: np.ndarray, a_over_rho: np.ndarray
) -> tuple[complex, complex, complex, complex]:
    """The δ with ψ(δ) = −T_k², from a predicted δ, and (ψ′, ψ″, ψ‴) there.

    Each step is the third-order series reversion of ψ(δ − Δ) + T_k² = 0,
    Δ = u + c₂u² + (2c₂² − c₃)u³ with u = (ψ + T_k²)/ψ′, c₂ = ψ″/2ψ′, c₃ = ψ‴/6ψ′ (error
    O(u⁴)); a Newton step instead while u is above 10 % of |δ|. Stops after a step with
    |u| ≤ :data:`STEP_ACCEPT`·|δ|. The derivatives returned are those of the last evaluation
    carried over its correction by Taylor's formula (error O(Δ³) in ψ′, below 1e-15).
    """
    p1 = p2 = p3 = correction = 0j
    for _ in range(NEWTON_MAX_ITERATIONS):
        p0, p1, p2, p3 = _psi(delta, rho, a, a_over_rho)
        inverse = _reciprocal(p1)
        u = (p0 + _TSQ[k]) * inverse
        size = _norm2(u)
        scale = _norm2(delta)
        if size > 1e-2 * scale:
            correction = u
        else:
            c2 = 0.5 * p2 * inverse
            c3 = p3 * inverse / 6.0
            correction = u * (1.0 + u * (c2 + u * (2.0 * c2 * c2 - c3)))
        delta -= correction
        if size <= STEP_ACCEPT**2 * scale:
            break
    return delta, p1 - correction * (p2 - 0.5 * correction * p3), p2 - correction * p3, p3


@njit(**_JIT)
def small_tail(
    kappa: np.ndarray, nu: np.ndarray, gradient: np.ndarray
) -> tuple[float, bool, float, float]:
    """The smaller tail of Y/R² at 1, Y = Σ κ_i (z_i + b_i)², ν_i = κ_i b_i².

    Returns (tail, upper, density, slope): tail = P(Y/R² ≥ 1) if upper else P(Y/R² < 1);
    density and slope are the density of Y/R² at 1 and its derivative. If `gradient` has
    n entries it receives D_i = the density at 1 of Y/R² + κ_i·χ²₂ (∂P(Y/R² < 1)/∂ν_i =
    −D_i); pass an empty array to skip it.
    """
    tail, upper, density, slope, _, _, _ = _tail_at(kappa, nu, gradient, saddle_log_t(kappa, nu))
    return tail, upper, density, slope


@njit(**_JIT)
def _tail_at(
    kappa: np.ndarray, nu: np.ndarray, gradient: np.ndarray, x: float
) -> tuple[float, bool, float, float, float, float, float]:
    """:func:`small_tail` at a given saddle x = log(1 − 2κ_max ŝ) (:func:`saddle_log_t`), with
    the density's next three derivatives: (tail, upper, f, f′, f″, f‴, f⁗) for the density f
    of Y/R² at 1.

    The density is the inversion integral (1/2πi)∫ e^{K(s) − st} ds at t = 1, so its k-th
    t-derivative is the same integral with (−s)^k: one more product per node on the same
    contour (Daniels 1987, the saddle-point inversion's derivatives). The Gaussian weight
    e^{−τ²} dominates s^k for the few k used, so the trapezoid sum keeps its accuracy; the
    quantile uses f″..f⁗ only in terms of third to fifth order in its step.
    """
    n = kappa.shape[0]
    want_gradient = gradient.shape[0] == n
    if want_gradient:
        gradient[:] = 0.0
    kmax = np.max(kappa)
    grow = math.expm1(x)
    s_hat = -grow / (2.0 * kmax)
    t_hat = np.empty(n)
    rho = np.empty(n)
    a = np.empty(n)
    a_over_rho = np.empty(n)
    k2 = 0.0
    k3 = 0.0
    phi_hat = 0.0
    for i in range(n):
        z = -(kappa[i] / kmax) * grow  # 2κ_i ŝ
        t_hat[i] = 1.0 - z
        rho[i] = 2.0 * kappa[i] / t_hat[i]
        a[i] = nu[i] / (t_hat[i] * t_hat[i])
        a_over_rho[i] = a[i] / rho[i]
        k2 += 0.5 * rho[i] * rho[i] + 2.0 * a[i] * rho[i]
        k3 += rho[i] ** 3 + 6.0 * rho[i] * rho[i] * a[i]
        phi_hat -= 0.5 * log_gap(z) + 0.5 * nu[i] * z * z / (kappa[i] * t_hat[i] * t_hat[i])
    upper = s_hat > 0.0
    if phi_hat < UNDERFLOW_EXPONENT:
        return 0.0, upper, 0.0, 0.0, 0.0, 0.0, 0.0
    w = math.sqrt(-phi_hat)
    pole = complex(0.0, w if upper else -w)
    # Start: δ = a₁T + a₂T² + O(T³) at the first node, a Taylor step (with δ⁗ by a difference)
    # from the previous node at the others.
    a1 = complex(0.0, math.sqrt(2.0 / k2))
    a2 = k3 / (3.0 * k2 * k2)
    delta = d1 = d2 = d3 = d4 = 0j
    tail = 0.0
    density = 0.0
    slope = 0.0
    third = 0.0
    fourth = 0.0
    fifth = 0.0
    for k in range(PATH_NODES):
        if k == 0:
            delta = _T[0] * (a1 + a2 * _T[0])
        else:
            h = PATH_STEP
            delta += h * (d1 + h * (0.5 * d2 + h * (d3 + 0.25 * h * d4) / 6.0))
        delta, p1, p2, p3 = _solve_node(delta, k, rho, a, a_over_rho)
        inverse = -_reciprocal(p1)
        d1 = _DTSQ[k] * inverse
        d2 = (_D2TSQ[k] + p2 * d1 * d1) * inverse
        d4 = d3  # the fourth derivative, by a difference of the third
        d3 = (_D3TSQ[k] + 3.0 * p2 * d1 * d2 + p3 * d1 * d1 * d1) * inverse
        d4 = (d3 - d4) / PATH_STEP if k > 0 else 0j
        s = s_hat + delta
        weighted = _WEIGHT[k] * d1
        tail += (weighted * _reciprocal(s) - _POLE_WEIGHT[k] * _reciprocal(_T[k] - pole)).imag
        density += weighted.imag
        ws = weighted * s
        slope -= ws.imag
        ws = ws * s
        third += ws.imag
        ws = ws * s
        fourth -= ws.imag
        fifth += (ws * s).imag
        if want_gradient:
            for i in range(n):
                gradient[i] += (weighted * _reciprocal(1.0 - rho[i] * delta)).imag / t_hat[i]
    scale = math.exp(phi_hat) * PATH_STEP / math.pi
    if want_gradient:
        for i in range(n):
            gradient[i] *= scale
    sign = 1.0 if upper else -1.0
    value = 0.5 * math.erfc(w) + sign * scale * tail
    return (
        min(max(value, 0.0), 1.0),
        upper,
        scale * density,
        scale * slope,
        scale * third,
        scale * fourth,
        scale * fifth,
    )


# --------------------------------------------------------------------------- probabilities
@njit(**_JIT)
def _is_finite(variances: np.ndarray, offset: np.ndarray) -> bool:
    """Whether every variance and offset is finite."""
    for i in range(variances.shape[0]):
        if not (math.isfinite(variances[i]) and math.isfinite(offset[i])):
            return False
    return True


@njit(**_JIT)
def _scaled(
    variances: np.ndarray, offset: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """(κ, ν) = (λ/R², offset²/R²)."""
    threshold = radius * radius
    return variances / threshold, offset * offset / threshold


@njit(**_JIT)
def ball_probabilities(
    variances: np.ndarray, offset: np.ndarray, radius: float
) -> tuple[float, float]:
    """(P(‖point − O‖ < R), P(‖point − O‖ ≥ R)); the smaller one is computed directly."""
    if math.isnan(radius) or not _is_finite(variances, offset):
        return math.nan, math.nan
    if radius <= 0.0 or radius == math.inf:
        return (0.0, 1.0) if radius <= 0.0 else (1.0, 0.0)
    kappa, nu = _scaled(variances, offset, radius)
    tail, upper, _, _ = small_tail(kappa, nu, np.empty(0))
    if upper:
        return 1.0 - tail, tail
    return tail, 1.0 - tail


@njit(**_JIT)
def avoid_gradient(
    variances: np.ndarray, offset: np.ndarray, radius: float
) -> tuple[float, np.ndarray]:
    """(P(‖point − O‖ ≥ R), its gradient with respect to offset).

    ∂P(Y < R²)/∂offset_i = −2 offset_i D_i / R² with D_i from :func:`small_tail` (the
    density of a quadratic form of the same kind), so ∂avoid/∂offset_i = 2 offset_i D_i/R².
    """
    n = variances.shape[0]
    gradient = np.zeros(n)
    if math.isnan(radius) or not _is_finite(variances, offset):
        return math.nan, gradient + math.nan
    if radius <= 0.0 or radius == math.inf:
        return (1.0 if radius <= 0.0 else 0.0), gradient
    kappa, nu = _scaled(variances, offset, radius)
    tail, upper, _, _ = small_tail(kappa, nu, gradient)
    threshold = radius * radius
    for i in range(n):
        gradient[i] *= 2.0 * offset[i] / threshold
    return (tail if upper else 1.0 - tail), gradient


# --------------------------------------------------------------------------- quantile
@njit(**_JIT)
def _gap_and_slope(ratio: np.ndarray, b2: np.ndarray, x: float) -> tuple[float, float]:
    """(J, dJ/dx) with J = ŝK'(ŝ) − K(ŝ) = −Φ̂ ≥ 0 at s = (1 − e^x)/(2λ_max), for
    ratio_i = λ_i/λ_max and b2_i = offset_i²/λ_i (J does not depend on the threshold)."""
    grow = math.expm1(x)
    gap = 0.0
    slope = 0.0
    for i in range(ratio.shape[0]):
        z = -ratio[i] * grow
        t = 1.0 - z
        gap += 0.5 * log_gap(z) + 0.5 * b2[i] * z * z / (t * t)
        slope += z * ratio[i] / (t * t) + 2.0 * z * ratio[i] * b2[i] / (t * t * t)
    return gap, -0.5 * math.exp(x) * slope


@njit(**_JIT)
def _solve_gap(
    ratio: np.ndarray, b2: np.ndarray, goal: float, direction: float, start: float
) -> float:
    """The x on the side `direction` (−1: ŝ > 0, +1: ŝ < 0) with √J(x) = goal ≥ 0.

    Newton's iteration on √J from `start` if that is on the side (else from the middle of
    the bracket), inside a bracket [0, x] found by doubling (√J grows with |x| on each
    side); stops after a step below :data:`_GAP_STEP`·(1 + |x|) (error ~1e-6: the start
    needs no more; a tighter stop cost ~5 more J evaluations per quantile, ~4 % of it).
    """
    if goal <= 0.0:
        return 0.0
    warm = start * direction > 0.0
    lo = 0.0
    hi = start if warm else direction
    while math.sqrt(_gap_and_slope(ratio, b2, hi)[0]) < goal and abs(hi) < 512.0:
        lo = hi
        hi *= 2.0
    x = start if warm and abs(lo) <= abs(start) <= abs(hi) else 0.5 * (lo + hi)
    for _ in range(SADDLE_MAX_ITERATIONS):
        gap, slope = _gap_and_slope(ratio, b2, x)
        root = math.sqrt(gap)
        if root < goal:
            lo = x
        else:
            hi = x
        new = x - (root - goal) * 2.0 * root / slope if slope != 0.0 else 0.5 * (lo + hi)
        if not (min(lo, hi) <= new <= max(lo, hi)):
            new = 0.5 * (lo + hi)
        if abs(new - x) <= _GAP_STEP * (1.0 + abs(x)):
            return new
        x = new
    return x


@njit(**_JIT)
def _start(variances: np.ndarray, offset: np.ndarray, epsilon: float) -> tuple[float, float]:
    """A first R² for the quantile: where the Lugannani–Rice approximation of the tail,
    ½erfc(√J) ± φ(ŵ)(1/û − 1/ŵ) (ŵ = ±√(2J), û = ŝ√K″, J = ŝK′ − K), equals ε.

    Its leading term is inverted for x = log(1 − 2λ_maxŝ) (:func:`_solve_gap`) with the
    correction term held at its last value, three times; the result is typically within
    1e-3 of R² (relative). Returns (R², x): x is the exact saddle of that threshold (R² is
    computed from x as K′), which saves the quantile's first saddle iteration.
    """
    lmax = np.max(variances)
    ratio = variances / lmax
    b2 = offset * offset / variances
    small = min(epsilon, 1.0 - epsilon)
    sign = 1.0 if epsilon < 0.5 else -1.0  # the upper tail (ŝ > 0, x < 0) is the small one
    target = small
    x = 0.0
    for attempt in range(3):
        goal = -ndtri(target) * _INV_SQRT_2  # the w with ½erfc(w) = target
        x = _solve_gap(ratio, b2, goal, -sign, x)
        gap = _gap_and_slope(ratio, b2, x)[0]
        if attempt == 2 or gap < 1e-3:  # near ŝ = 0 the correction cancels; skip it
            break
        grow = math.expm1(x)
        curvature = 0.0
        for i in range(ratio.shape[0]):
            t = 1.0 + ratio[i] * grow
            curvature += 2.0 * ratio[i] ** 2 / (t * t) * (1.0 + 2.0 * b2[i] / t)
        u_hat = -0.5 * grow * math.sqrt(curvature)
        w_hat = sign * math.sqrt(2.0 * gap)
        correction = math.exp(-gap) / math.sqrt(2.0 * math.pi) * (1.0 / u_hat - 1.0 / w_hat)
        target = min(max(small - sign * correction, 0.1 * small), 0.5)
    grow = math.expm1(x)
    first = 0.0
    for i in range(variances.shape[0]):
        t = 1.0 + ratio[i] * grow
        first += variances[i] / t + offset[i] * offset[i] / (t * t)
    return first, x


@njit(**_JIT)
def saddlepoint_start(variances: np.ndarray, offset: np.ndarray, epsilon: float) -> float:
    """The Lugannani–Rice first R² of the quantile (:func:`_start`, without its saddle)."""
    return _start(variances, offset, epsilon)[0]


@njit(**_JIT)
def quantile_radius(variances: np.ndarray, offset: np.ndarray, epsilon: float) -> float:
    """The radius r with P(‖point − O‖ ≥ r) = ε (ε ∈ (0, 1)).

    A fifth-order iteration on g(y) = log P(Y ≥ y) − log ε (ε ≤ ½; log P(Y < y) − log(1 − ε)
    above, for that tail's accuracy), y = r², started at :func:`saddlepoint_start` and kept
    inside a bracket valid from the start (e the unit offset, a = ‖offset‖):

    * lower: ‖w‖ ≥ |e·w| gives P(‖w‖ ≥ r) ≥ Φ((a − r)/σ_e) and, about the main axis,
      ≥ 2Φ(−r/σ_max); so r = max(a − σ_e Φ⁻¹(ε), −σ_max Φ⁻¹(ε/2), 0) has P ≥ ε;
    * upper: ‖w‖ ≤ a + σ_max‖z‖ and Laurent–Massart's P(‖z‖² ≥ n + 2√(nu) + 2u) ≤ e^{−u},
      u = −ln ε.

    Each contour evaluation at y gives P and the density's derivatives f..f⁗ (:func:`_tail_at`),
    hence g's Taylor coefficients g₁..g₅ in h = y′/y − 1 (the cumulant formulas of log P).
    The step solves the quintic Taylor model g(y(1 + h)) = 0 by Newton from Halley's step
    (Householder's methods of order p use g′..g⁽ᵖ⁻¹⁾; the model's root has error O(h⁶)). The
    root is returned without another evaluation when the model's truncation error,
    estimated as max(t₅, t₄ρ)·ρ from its terms t_k = |g_k h^k/(k! g₁)| and their largest
    ratio ρ, is below 1e-15 (taking t₄ρ² covers a t₅ that is small by cancellation), or,
    as before, once a step is below ANISOTROPIC_QUANTILE_RTOL (error ~1e-25 then). From the
    ~1e-3 start that is one evaluation for most points and two for nearly all the rest, where
    Halley's iteration needed two or three.
    """
    if not (epsilon > 0.0 and epsilon < 1.0):
        if epsilon >= 1.0:
            return 0.0
        if epsilon <= 0.0:
            return math.inf
        return math.nan
    n = variances.shape[0]
    if not _is_finite(variances, offset):
        return math.nan
    norm2 = 0.0
    along = 0.0
    for i in range(n):
        norm2 += offset[i] * offset[i]
        along += variances[i] * offset[i] * offset[i]
    distance = math.sqrt(norm2)
    sigma_max = math.sqrt(np.max(variances))
    z_eps = ndtri(epsilon)
    z_half = ndtri(0.5 * epsilon)
    lower = max(-sigma_max * z_half, 0.0)
    if distance > 0.0:
        lower = max(lower, distance - math.sqrt(along / norm2) * z_eps)
    u = -math.log(epsilon)
    upper = distance + sigma_max * math.sqrt(n + 2.0 * math.sqrt(n * u) + 2.0 * u)
    y_lo = lower * lower
    y_hi = upper * upper
    upper_tail = epsilon <= 0.5
    target = math.log(epsilon) if upper_tail else math.log1p(-epsilon)
    y_start, x_start = _start(variances, offset, epsilon)
    y = min(max(y_start, y_lo), y_hi)
    if not y > 0.0:
        y = 0.5 * (y_lo + y_hi)
    sign = -1.0 if upper_tail else 1.0  # d prob/dt = sign·density
    for iteration in range(ANISOTROPIC_QUANTILE_MAX_ITERATIONS):
        kappa = variances / y
        nu = offset * offset / y
        x = x_start if iteration == 0 and y == y_start else saddle_log_t(kappa, nu)
        tail, upper_side, d1, d2, d3, d4, d5 = _tail_at(kappa, nu, np.empty(0), x)
        prob = tail if upper_side == upper_tail else 1.0 - tail
        if prob > 0.0:
            if (math.log(prob) > target) == upper_tail:
                y_lo = y
            else:
                y_hi = y
        else:
            if upper_tail:
                y_hi = y
            else:
                y_lo = y
        accept = False
        if not (prob > 0.0 and d1 > 0.0):
            new = 0.5 * (y_lo + y_hi)
        else:
            g0 = math.log(prob) - target
            p1 = sign * d1 / prob
            p2 = sign * d2 / prob
            p3 = sign * d3 / prob
            p4 = sign * d4 / prob
            p5 = sign * d5 / prob
            g1 = p1
            g2 = p2 - p1 * p1
            g3 = p3 - 3.0 * p1 * p2 + 2.0 * p1**3
            g4 = p4 - 4.0 * p1 * p3 - 3.0 * p2 * p2 + 12.0 * p1 * p1 * p2 - 6.0 * p1**4
            g5 = (
                p5
                - 5.0 * p4 * p1
                - 10.0 * p3 * p2
                + 20.0 * p3 * p1 * p1
                + 30.0 * p2 * p2 * p1
                - 60.0 * p2 * p1**3
                + 24.0 * p1**5
            )
            c2 = 0.5 * g2
            c3 = g3 / 6.0
            c4 = g4 / 24.0
            c5 = g5 / 120.0
            halley = -2.0 * g0 * g1 / (2.0 * g1 * g1 - g0 * g2)
            h = halley
            for _ in range(4):
                value = g0 + h * (g1 + h * (c2 + h * (c3 + h * (c4 + h * c5))))
                deriv = g1 + h * (2.0 * c2 + h * (3.0 * c3 + h * (4.0 * c4 + h * 5.0 * c5)))
                h -= value / deriv
            if math.isfinite(h) and abs(h - halley) <= 0.1 * abs(halley):
                t1 = abs(h)
                t2 = abs(c2 / g1) * t1 * t1
                t3 = abs(c3 / g1) * t1**3
                t4 = abs(c4 / g1) * t1**4
                t5 = abs(c5 / g1) * t1**5
                ratio = max(t2 / t1, t3 / t2, t4 / t3, t5 / t4) if t1 * t2 * t3 * t4 > 0.0 else 1.0
                accept = h == 0.0 or max(t5, t4 * ratio) * ratio <= _QUANTILE_REMAINDER
            else:
                h = halley
            new = y * (1.0 + h)
        if not (y_lo <= new <= y_hi):
            new = 0.5 * (y_lo + y_hi)
            accept = False
        if accept or abs(new - y) <= ANISOTROPIC_QUANTILE_RTOL * y:
            return math.sqrt(new)
        if y_hi - y_lo <= 1e-15 * y_hi:
            return math.sqrt(0.5 * (y_lo + y_hi))
        y = new
    return math.sqrt(y)


# --------------------------------------------------------------------------- many points
@njit(**_JIT)
def ball_probabilities_array(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> np.ndarray:
    """:func:`ball_probabilities` for each row of `offsets` (k, n): (k, 2) [collision, avoid]."""
    out = np.empty((offsets.shape[0], 2))
    for j in range(offsets.shape[0]):
        out[j, 0], out[j, 1] = ball_probabilities(variances, offsets[j], radius)
    return out


@njit(**_JIT)
def avoid_gradient_array(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`avoid_gradient` for each row of `offsets`: ((k,) avoid, (k, n) gradients)."""
    count = offsets.shape[0]
    avoid = np.empty(count)
    gradients = np.empty(offsets.shape)
    for j in range(count):
        avoid[j], gradients[j] = avoid_gradient(variances, offsets[j], radius)
    return avoid, gradients


@njit(**_JIT)
def quantile_radius_array(variances: np.ndarray, offsets: np.ndarray, epsilon: float) -> np.ndarray:
    """:func:`quantile_radius` for each row of `offsets` (k, n)."""
    out = np.empty(offsets.shape[0])
    for j in range(offsets.shape[0]):
        out[j] = quantile_radius(variances, offsets[j], epsilon)
    return out
