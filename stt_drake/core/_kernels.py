"""Compiled (numba) kernels for the hot path: the noncentral chi law (q_j of Eq. (5), d̂_j of
Eq. (8)), one call per controller evaluation, per invariant check and per scripted belief.
The tube law's kernels, which call these, are :mod:`stt_drake.core._tube`.

Why a second implementation exists
----------------------------------
The vectorised numpy/scipy code in :mod:`stt_drake.core.probability`, :mod:`stt_drake.core.tube`,
:mod:`stt_drake.core.control` and :mod:`stt_drake.core.invariants` is the *reference*: short, close
to the paper's equations, and built on scipy's Boost noncentral χ² for n = 2 and for the
quantile. At the problem sizes of a robot (tens of obstacles) it spends almost all its time
in numpy's ~1 µs per-call overhead (a tube step is ~60 small numpy calls), not in
arithmetic (~100 flops per obstacle). This module does the same arithmetic as scalar loops
compiled by numba, so one tube step is one native call.

The two are not twins: the kernels use different algorithms (a Bessel series for the
n = 2 Marcum Q-function instead of Boost's Poisson mixture; a bracketed Halley iteration
from Sankaran's start instead of Boost's quantile search), so the tests comparing the two
paths compare independent implementations, and both are compared with
``scipy.stats.ncx2``. The n = 1, 3 closed forms exist in both because they are what the
numpy path is fastest with too; they are a few lines each.

numba (rather than Cython/C++): it is a pinned dependency already, needs no compiler
toolchain at install time, and with ``cache=True`` compiles once per machine into
a cache folder keyed by the kernels' sources (:func:`stt_drake.core.backend.jit_options`;
a few seconds on first use; importing :mod:`stt_drake` does not import
this module — :func:`stt_drake.core.backend.compiled` loads it on first need).
``STT_DRAKE_PURE_NUMPY=1`` (or :func:`stt_drake.core.backend.pure_numpy`) selects the reference
path instead.

Notation (paper Sec. 3, Proposition 3.1): for Z ~ N(a·e, I_n), a = ‖x − μ_j‖/σ_j, ‖Z‖ is
noncentral chi with n degrees of freedom; ``sf(b) = P(‖Z‖ ≥ b)`` is q_j of Eq. (5)
at b = (r_o + r_min)/σ, and the quantile s with sf(s) = ε gives d̂_j = σ s − r_o
(Eq. (8)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from stt_drake.core.backend import jit_options
from stt_drake.core.constants import (
    CHI_QUANTILE_MAX_ITERATIONS,
    CHI_QUANTILE_RTOL,
    CIRCULATION_MIN_SINE,
    SF_IS_ONE_BELOW,
)

_JIT = jit_options()
#: Fused multiply-adds allowed (LLVM's `contract` flag only, no other fast-math licence):
#: the Bessel recurrence's serial chain v_{k−1} = v_{k+1} + (2k/x)v_k then takes one fused
#: operation a term instead of two, ~20 % of a Marcum Q₁ (each at least as accurate).
_CONTRACT = {**_JIT, "fastmath": {"contract"}}

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
_INV_SQRT_2 = 1.0 / math.sqrt(2.0)
#: Below this offset a = ‖x − μ‖/σ the law is the central one to double precision (the
#: difference is O(a²)); treating it as 0 avoids dividing by a denormal.
_NEGLIGIBLE_OFFSET = 1e-150
#: Below this ab only the first term of each Bessel series is visible in double precision.
_TINY_ARGUMENT = 1e-30
#: Rescaling threshold of the backward Bessel recurrence.
_BIG = 1e200
#: A Halley step's error is judged from its cubic term only for steps below this share of
#: min(s, 1), where the derivatives of sf have not changed (:func:`_halley_error_bound`).
_HALLEY_LOCAL = 1e-3
#: 2⁻⁵³, half the relative spacing of doubles: a quantile error below this share of s is
#: rounding.
_HALF_ULP = 2.0**-53


# --------------------------------------------------------------------------- normal law
@njit(**_JIT)
def ndtr(x: float) -> float:
    """Φ(x), the standard normal CDF (relative accuracy in the lower tail via erfc)."""
    return 0.5 * math.erfc(-x * _INV_SQRT_2)


@njit(**_JIT)
def normal_pdf(x: float) -> float:
    """φ(x) = e^{−x²/2}/√(2π)."""
    return _INV_SQRT_2PI * math.exp(-0.5 * x * x)


@njit(**_JIT)
def ndtri(p: float) -> float:
    """Φ⁻¹(p) by Wichura's algorithm AS 241 (PPND16, relative accuracy ~1e-16)."""
    if not (p > 0.0 and p < 1.0):
        if p == 0.0:
            return -math.inf
        if p == 1.0:
            return math.inf
        return math.nan
    q = p - 0.5
    if abs(q) <= 0.425:
        r = 0.180625 - q * q
        num = (
            (
                (
                    (
                        (
                            (2509.0809287301226727 * r + 33430.575583588128105) * r
                            + 67265.770927008700853
                        )
                        * r
                        + 45921.953931549871457
                    )
                    * r
                    + 13731.693765509461125
                )
                * r
                + 1971.5909503065514427
            )
            * r
            + 133.14166789178437745
        ) * r + 3.387132872796366608
        den = (
            (
                (
                    (
                        (
                            (5226.495278852545925 * r + 28729.085735721942674) * r
                            + 39307.89580009271061
                        )
                        * r
                        + 21213.794301586595867
                    )
                    * r
                    + 5394.1960214247511077
                )
                * r
                + 687.1870074920579083
            )
            * r
            + 42.313330701600911252
        ) * r + 1.0
        return q * num / den
    r = p if q < 0.0 else 1.0 - p
    r = math.sqrt(-math.log(r))
    if r <= 5.0:
        r -= 1.6
        num = (
            (
                (
                    (
                        (
                            (7.7454501427834140764e-4 * r + 0.0227238449892691845833) * r
                            + 0.24178072517745061177
                        )
                        * r
                        + 1.27045825245236838258
                    )
                    * r
                    + 3.64784832476320460504
                )
                * r
                + 5.7694972214606914055
            )
            * r
            + 4.6303378461565452959
        ) * r + 1.42343711074968357734
        den = (
            (
                (
                    (
                        (
                            (1.05075007164441684324e-9 * r + 5.475938084995344946e-4) * r
                            + 0.0151986665636164571966
                        )
                        * r
                        + 0.14810397642748007459
                    )
                    * r
                    + 0.68976733498510000455
                )
                * r
                + 1.6763848301838038494
            )
            * r
            + 2.05319162663775882187
        ) * r + 1.0
    else:
        r -= 5.0
        num = (
            (
                (
                    (
                        (
                            (2.01033439929228813265e-7 * r + 2.71155556874348757815e-5) * r
                            + 0.0012426609473880784386
                        )
                        * r
                        + 0.026532189526576123093
                    )
                    * r
                    + 0.29656057182850489123
                )
                * r
                + 1.7848265399172913358
            )
            * r
            + 5.4637849111641143699
        ) * r + 6.6579046435011037772
        den = (
            (
                (
                    (
                        (
                            (2.04426310338993978564e-15 * r + 1.4215117583164458887e-7) * r
                            + 1.8463183175100546818e-5
                        )
                        * r
                        + 7.868691311456132591e-4
                    )
                    * r
                    + 0.0148753612908506148525
                )
                * r
                + 0.13692988092273580531
            )
            * r
            + 0.59983220655588793769
        ) * r + 1.0
    value = num / den
    return -value if q < 0.0 else value


# --------------------------------------------------------------------------- n = 2
@njit(**_JIT)
def _miller_start(x: float) -> int:
    """N = ⌊9√x + 8⌋, the start of the backward Bessel recurrence at x = ab, where
    I_N(x)/I_0(x) < e^{−39.2} < 1e-17. Why: I_k/I_{k−1} < x/(k − ½ + √(x² + (k − ½)²))
    = e^{−asinh((k − ½)/x)} (Amos 1974, Math. Comp. 28:239; Segura 2011), so
    ln(I_N/I_0) < −Σ_{k≤N} asinh((k − ½)/x) ≤ −x(u asinh u − √(1 + u²) + 1), u = N/x (a
    midpoint sum of a concave function exceeds its integral): ≈ −N²/2x for N ≪ x, and
    faster decay for N ≳ x (tests/core/test_kernels.py checks the sum for x ≤ 1e7)."""
    return int(9.0 * math.sqrt(x) + 8.0)


@njit(**_CONTRACT)
def _marcum_q1(a: float, b: float) -> tuple[float, float, float, float]:
    """(sf, cdf, pdf, d ln pdf/ds) of ‖Z‖ at b for n = 2: sf is the Marcum Q-function Q₁(a, b).

    Bessel series, both with positive terms only (so no cancellation):

        a < b:  Q₁ = e^{−(a−b)²/2} Σ_{k≥0} (a/b)^k Ĩ_k(ab)           (sf directly)
        a ≥ b:  1 − Q₁ = e^{−(a−b)²/2} Σ_{k≥1} (b/a)^k Ĩ_k(ab)       (cdf directly)

    with Ĩ_k(x) = e^{−x} I_k(x); the other tail is 1 minus that. The Ĩ_k come from
    Miller's backward recurrence I_{k−1} = I_{k+1} + (2k/x) I_k (stable: I_k is the minimal
    solution), normalised by the exact identity Ĩ_0 + 2 Σ_{k≥1} Ĩ_k = 1, so no Bessel
    function is evaluated at all. The recurrence starts at N = ⌊9√x + 8⌋, where
    I_N/I_0 < 1e-17 (:func:`_miller_start`): O(√(ab)) work, ~1.5 ns a term (~48 terms at
    ab = 20, ~2850 at λ = a² = 1e5 with b ≈ a). The same pass gives the density
    f(b) = b e^{−(a−b)²/2} Ĩ_0(ab) and d ln f/ds = 1/b − b + a Ĩ_1/Ĩ_0.
    """
    if b <= 0.0:
        return 1.0, 0.0, 0.0, math.inf
    if a == 0.0:
        g = math.exp(-0.5 * b * b)
        return g, -math.expm1(-0.5 * b * b), b * g, 1.0 / b - b
    x = a * b
    gauss = math.exp(-0.5 * (a - b) * (a - b))
    if x < _TINY_ARGUMENT:  # Ĩ_0 = 1, Ĩ_1 = x/2 and Ĩ_k≥2 = 0 to double precision
        dlog = 1.0 / b - b + 0.5 * a * x
        if a < b:
            return gauss, 1.0 - gauss, b * gauss, dlog
        cdf = 0.5 * gauss * b * b
        return 1.0 - cdf, cdf, b * gauss, dlog
    ratio = a / b if a < b else b / a
    count = _miller_start(x)
    two_over_x = 2.0 / x
    v_next = 0.0  # v_{k+1}
    v = 1.0  # v_k, starting at k = count
    weighted = 0.0  # Σ_{i ≥ k} ratio^{i−k} v_i  (Horner, backward)
    total = 0.0  # Σ_{i ≥ k} v_i
    for k in range(count, 0, -1):
        weighted = weighted * ratio + v
        total += v
        v_prev = v_next + k * two_over_x * v
        v_next, v = v, v_prev
        if v > _BIG:
            v_next /= _BIG
            v /= _BIG
            weighted /= _BIG
            total /= _BIG
    # Now v = v_0, v_next = v_1, weighted = Σ_{k≥1} ratio^{k−1} v_k, total = Σ_{k≥1} v_k.
    norm = v + 2.0 * total
    pdf = b * gauss * (v / norm)
    dlog = 1.0 / b - b + a * (v_next / v)
    if a < b:
        sf = gauss * (v + ratio * weighted) / norm
        return sf, 1.0 - sf, pdf, dlog
    cdf = gauss * (ratio * weighted) / norm
    return 1.0 - cdf, cdf, pdf, dlog


# --------------------------------------------------------------------------- dispatch
@njit(**_JIT)
def chi_sf_pdf(b: float, a: float, n: int) -> tuple[float, float, float, float]:
    """(sf, cdf, pdf, d ln pdf/ds) of ‖Z‖ at b, Z ~ N(a e, I_n), n ∈ {1, 2, 3}.

    sf = P(‖Z‖ ≥ b) and cdf = P(‖Z‖ < b) are each computed directly where that tail is the
    small one and cancellation-free (the other is 1 minus it):

    n = 1: sf = Φ(a−b) + Φ(−a−b), cdf = Φ(b−a) − Φ(−b−a); f = φ(b−a) + φ(b+a).
    n = 3: sf = Φ(a−b) + Φ(−a−b) + φ(b−a)(1 − e^{−2ab})/a, cdf = Φ(b−a) − Φ(−b−a) −
           φ(b−a)(1 − e^{−2ab})/a, f = (b/a)φ(b−a)(1 − e^{−2ab}); 1 − e^{−2ab} as
           −expm1(−2ab) where e^{−2ab} ≥ ½, so a → 0 is continuous (limits 2bφ(b) and
           2b²φ(b)).
    n = 2: :func:`_marcum_q1`.
    d ln f/ds = (n − 1)/s − s + a I_{n/2}(as)/I_{n/2−1}(as): −b + a tanh(ab) (n = 1),
    1/b − b + a coth(ab) (n = 3).
    """
    if math.isnan(a) or math.isnan(b):
        return math.nan, math.nan, math.nan, math.nan
    if a < _NEGLIGIBLE_OFFSET:
        a = 0.0
    if n == 2:
        return _marcum_q1(a, b)
    if b <= 0.0:
        if n == 1:
            return 1.0, 0.0, 2.0 * normal_pdf(a), 0.0
        return 1.0, 0.0, 0.0, math.inf
    e = math.exp(-2.0 * a * b)  # φ(b + a) = φ(b − a)·e
    phi = normal_pdf(b - a)
    direct_cdf = a > b  # the lower tail is the small one
    if direct_cdf:
        cdf = ndtr(b - a) - ndtr(-b - a)
    else:
        sf = ndtr(a - b) + ndtr(-a - b)
    if n == 1:
        pdf = phi * (1.0 + e)
        dlog = -b + a * (1.0 - e) / (1.0 + e)
    else:
        # 1 − e is within 1.5 ulp where e < ½ (1 − e ≥ ½) and costs no expm1 (~8 ns)
        one_minus_e = 1.0 - e if e < 0.5 else -math.expm1(-2.0 * a * b)
        if a > 0.0:
            shell = phi * one_minus_e / a
            pdf = (b / a) * phi * one_minus_e
            dlog = 1.0 / b - b + (a * (1.0 + e) / one_minus_e if one_minus_e > 0.0 else 1.0 / b)
        else:
            shell = 2.0 * b * normal_pdf(b)
            pdf = 2.0 * b * b * normal_pdf(b)
            dlog = 2.0 / b - b
        if direct_cdf:
            cdf -= shell
        else:
            sf += shell
    if direct_cdf:
        return 1.0 - cdf, cdf, pdf, dlog
    return sf, 1.0 - sf, pdf, dlog


@njit(**_JIT)
def chi_cdf_series(b: float, a: float, n: int) -> float:
    """P(‖Z‖ ≤ b) with relative accuracy in the lower tail (small a and b), any n.

    χ'²_n(λ) is a Poisson(λ/2) mixture of χ²_{n+2k}; with y = b²/2 and the lower
    incomplete gamma written as P(ν, y) = Σ_{i≥0} t_{ν+i}, t_ν = e^{−y} y^ν/Γ(ν + 1),
    regrouping gives  cdf = Σ_{m≥0} t_{n/2+m} · W_m,  W_m = Σ_{k≤m} e^{−λ/2}(λ/2)^k/k!,
    a sum of positive terms (1 − sf would cancel here). Meant for a ≲ 8 (e^{−λ/2} must not
    underflow) and b of a few units; about 2y + 20 terms.
    """
    if b <= 0.0:
        return 0.0
    y = 0.5 * b * b
    half_lambda = 0.5 * a * a
    order = 0.5 * n
    t = math.exp(-y + order * math.log(y) - math.lgamma(order + 1.0))
    w = math.exp(-half_lambda)
    weight = w
    total = t * weight
    for m in range(1, 100_000):
        t *= y / (order + m)
        w *= half_lambda / m
        weight += w
        term = t * weight
        total += term
        if m > 2.0 * y + 5.0 and term <= 1e-17 * total:
            break
    return total


@njit(**_JIT)
def chi_sf(b: float, a: float, n: int) -> float:
    """P(‖Z‖ ≥ b), Z ~ N(a e, I_n): 1 without any work where that is exact in double."""
    if b - a <= SF_IS_ONE_BELOW:
        return 1.0
    return chi_sf_pdf(b, a, n)[0]


@njit(**_JIT)
def _sankaran_start(eps: float, a: float, n: int, normal_quantile: float) -> float:
    """Starting s for sf(s) = ε: Sankaran's (1959) normal approximation of χ'²_n(λ = a²)
    inverted, which stays usable in both tails (where Patnaik's and Wilson–Hilferty's
    degrade); where its base goes negative (lower tail of small n + λ), the small-s law
    P(‖Z‖ ≤ s) ≈ e^{−a²/2} s^n / (2^{n/2} Γ(n/2 + 1)) is inverted instead.
    `normal_quantile` is Φ⁻¹(ε)."""
    lam = a * a
    k = float(n)
    h = 1.0 - (2.0 / 3.0) * (k + lam) * (k + 3.0 * lam) / ((k + 2.0 * lam) ** 2)
    p = (k + 2.0 * lam) / ((k + lam) ** 2)
    m = (h - 1.0) * (1.0 - 3.0 * h)
    z = -normal_quantile  # Φ⁻¹(1 − ε) without forming 1 − ε
    base = (
        1.0
        + h * p * (h - 1.0 - 0.5 * (2.0 - h) * m * p)
        + z * h * math.sqrt(2.0 * p) * (1.0 + 0.5 * m * p)
    )
    if base > 0.0:
        return math.sqrt((k + lam) * base ** (1.0 / h))
    log_cdf = math.log1p(-eps) + 0.5 * lam + 0.5 * k * math.log(2.0) + math.lgamma(0.5 * k + 1.0)
    return math.exp(log_cdf / k)


@njit(**_JIT)
def _halley_error_bound(step: float, s: float, a: float, n: int, dlog: float) -> float:
    """A bound on |s + step − s*| after a Halley step from s towards the root s* of
    g(s) = sf(s) − ε (+∞ unless |step| ≤ _HALLEY_LOCAL·min(s, 1)).

    Halley's error is e' = C e³ + O(e⁴) with C = g''²/(4g'²) − g'''/(6g') = L²/12 − L'/6,
    since g' = −f, g'' = −fL, g''' = −f(L' + L²) with L = d ln f/ds = (n − 1)/s − s + aR,
    R = I_{n/2}(as)/I_{n/2−1}(as). R' = 1 − R² − (n − 1)R/(as) (the ratio's Riccati
    equation) gives L' = a² − t² − (n − 1)(t/s + 1/s²) − 1 with t = aR, and |e| = |step|
    to O(e³). f, L and so C vary on a scale ≥ min(s, 1) in s (1/s, the Gaussian factor,
    R(as)), so within the local zone C and the e⁴ term change the bound by < 1 %:
    2(L²/12 + |L'|/6)|step|³ bounds the error with room to spare."""
    if not (abs(step) <= _HALLEY_LOCAL * min(s, 1.0)):
        return math.inf
    inverse = 1.0 / s
    t = dlog - (n - 1) * inverse + s  # aR
    slope = (a - t) * (a + t) - (n - 1) * inverse * (t + inverse) - 1.0  # L'
    return 2.0 * (dlog * dlog / 12.0 + abs(slope) / 6.0) * abs(step) ** 3


@njit(**_JIT)
def chi_isf(eps: float, a: float, n: int) -> float:
    """The s ≥ 0 with P(‖Z‖ ≥ s) = ε for Z ~ N(a e, I_n), n ∈ {1, 2, 3} (Eq. (8)):
    :func:`chi_isf_given` with Φ⁻¹(ε)."""
    return chi_isf_given(eps, a, n, ndtri(eps))


@njit(**_JIT)
def chi_isf_given(eps: float, a: float, n: int, normal_quantile: float) -> float:
    """:func:`chi_isf` for a caller that has `normal_quantile` = Φ⁻¹(ε) already (the tube
    law's pruning bound needs it too): the s ≥ 0 with P(‖Z‖ ≥ s) = ε for Z ~ N(a e, I_n),
    n ∈ {1, 2, 3} (Eq. (8)).

    Halley's iteration on g(s) = sf(s) − ε (g' = −f, g'' = −f·d ln f/ds), started from
    :func:`_sankaran_start` and kept inside a bracket that is valid from the start:

    * lower: ‖Z‖ ≥ Z·e gives sf(s) ≥ Φ(a − s), so sf(a − Φ⁻¹(ε)) ≥ ε;
    * upper: ‖Z‖ ≤ a + ‖W‖ with ‖W‖² ~ χ²_n and Laurent–Massart's
      P(‖W‖² ≥ n + 2√(nu) + 2u) ≤ e^{−u}, u = −ln ε.

    For ε > 1/2 the residual is (1 − ε) − cdf(s), for the lower tail's relative accuracy.
    Every evaluation shrinks the bracket; a step that leaves it is replaced by that bracket
    end (once) or by bisection, so the iteration cannot diverge. Converged when a step is
    below CHI_QUANTILE_RTOL·s, or when a Halley step's error bound is below half an ulp of s
    (:func:`_halley_error_bound`): then s + step is s* to rounding, without the evaluation
    that would only confirm it.
    """
    if math.isnan(eps) or math.isnan(a):
        return math.nan
    if eps >= 1.0:
        return 0.0
    if eps <= 0.0:
        return math.inf
    # For ε > 1/2 solve cdf(s) = 1 − ε instead: near ε = 1 an ulp of sf would move s by
    # ~1e-16/(n(1 − ε)) relative. The cdf is direct (see chi_sf_pdf) where a > s, and from
    # the lower-tail series where a is small and the tail thin.
    delta = 1.0 - eps  # exact for ε ≥ 1/2
    use_cdf = eps > 0.5
    series = delta < 1e-3 and a < 8.0
    lo = max(a - normal_quantile, 0.0)
    u = -math.log(eps)
    hi = a + math.sqrt(n + 2.0 * math.sqrt(n * u) + 2.0 * u)
    s = _sankaran_start(eps, a, n, normal_quantile)
    if not (s > lo and s < hi):
        s = 0.5 * (lo + hi)
    tried_lo = tried_hi = False
    for _ in range(CHI_QUANTILE_MAX_ITERATIONS):
        sf, cdf, pdf, dlog = chi_sf_pdf(s, a, n)
        if series:
            g = delta - chi_cdf_series(s, a, n)
        elif use_cdf:
            g = delta - cdf
        else:
            g = sf - eps
        if g > 0.0:
            lo = s
        elif g < 0.0:
            hi = s
        else:
            return s
        new = math.nan
        if pdf > 0.0:
            step = g / pdf  # Newton: s + (sf − ε)/f
            denominator = 1.0 + 0.5 * step * dlog
            if denominator > 0.5:
                step /= denominator  # Halley
                if _halley_error_bound(step, s, a, n, dlog) <= _HALF_ULP * s:
                    return s + step  # s* to rounding: no confirming evaluation
            if abs(step) <= CHI_QUANTILE_RTOL * s:
                return s + step
            new = s + step
        if not (new > lo and new < hi):
            # A step past a bracket end lands on that end once (the root can sit within
            # rounding of the bound, e.g. n = 1 at large a), else bisection.
            if new <= lo and not tried_lo:
                new, tried_lo = lo, True
            elif new >= hi and not tried_hi:
                new, tried_hi = hi, True
            else:
                new = 0.5 * (lo + hi)
                if not (hi - lo > 4e-16 * hi):
                    return new
        s = new
    return s


# --------------------------------------------------------------------------- arrays
@njit(**_JIT)
def chi_sf_array(b: np.ndarray, a: np.ndarray, n: int) -> np.ndarray:
    """:func:`chi_sf` over equal-length 1D arrays."""
    out = np.empty(b.shape[0])
    for i in range(b.shape[0]):
        out[i] = chi_sf(b[i], a[i], n)
    return out


@njit(**_JIT)
def chi_isf_array(eps: np.ndarray, a: np.ndarray, n: int) -> np.ndarray:
    """:func:`chi_isf` over equal-length 1D arrays."""
    out = np.empty(eps.shape[0])
    for i in range(eps.shape[0]):
        out[i] = chi_isf(eps[i], a[i], n)
    return out


@njit(**_JIT)
def level_set_offset(threshold: float, level: float, n: int) -> float:
    """The a ≥ 0 with P(‖Z‖ ≥ `threshold`) = `level` for Z ~ N(a e, I_n), n ∈ {1, 2, 3}: the
    level-set distance of :func:`stt_drake.core.probability.level_set_radius` for σ = 1;
    0 where a = 0 already gives at least `level`, +inf where no a reaches it.

    The tail grows with a: by the divergence theorem ∂P(‖Z‖ ≥ b)/∂a = f(b)·R with f the
    density of ‖Z‖ at b and R = I_{n/2}(ab)/I_{n/2−1}(ab) ≥ 0, the mean of the cosine on the
    sphere of radius b, which :func:`chi_sf_pdf`'s d ln f/ds = (n − 1)/b − b + aR gives.
    Newton's iteration from a = b + Φ⁻¹(level) (the root where the tail is Φ(a − b)), inside
    the numpy function's bracket [0, upper] and shrinking it, bisecting a step that leaves
    it; for level > ½ the residual is (1 − level) − cdf, for that tail's relative accuracy.
    """
    if math.isnan(threshold) or math.isnan(level):
        return math.nan
    if chi_sf(threshold, 0.0, n) >= level:
        return 0.0
    upper = threshold + math.sqrt(n) + 10.0
    for _ in range(60):
        if chi_sf(threshold, upper, n) >= level:
            break
        upper *= 2.0
    else:
        return math.inf
    lo, hi = 0.0, upper
    a = threshold + ndtri(level)
    if not (a > lo and a < hi):
        a = 0.5 * (lo + hi)
    use_cdf = level > 0.5
    for _ in range(CHI_QUANTILE_MAX_ITERATIONS):
        sf, cdf, pdf, dlog = chi_sf_pdf(threshold, a, n)
        g = (1.0 - level) - cdf if use_cdf else sf - level
        if g > 0.0:
            hi = a
        elif g < 0.0:
            lo = a
        else:
            return a
        slope = pdf * (dlog - (n - 1) / threshold + threshold) / a  # threshold > 0 here
        new = a - g / slope if slope > 0.0 else math.nan
        if not (new > lo and new < hi):
            new = 0.5 * (lo + hi)
        if abs(new - a) <= CHI_QUANTILE_RTOL * (1.0 + a) or not hi - lo > 4e-16 * hi:
            return new
        a = new
    return a


@njit(**_JIT)
def level_set_offsets(thresholds: np.ndarray, level: float, n: int) -> np.ndarray:
    """:func:`level_set_offset` for each of `thresholds` at one `level` (the guide's table of
    level-set radii over β = r_s/σ, :class:`stt_drake.core.guide.LevelSetRadii`)."""
    out = np.empty(thresholds.shape[0])
    for i in range(thresholds.shape[0]):
        out[i] = level_set_offset(thresholds[i], level, n)
    return out


# --------------------------------------------------------------------------- geometry
@njit(**{**_JIT, "inline": "always"})  # per obstacle in the loops: no call
def _distance(point: np.ndarray, mean: np.ndarray, j: int) -> float:
    """‖point − μ_j‖ for μ_j in the first n columns of row j of `mean`, n = len(point)."""
    total = 0.0
    for i in range(point.shape[0]):
        d = point[i] - mean[j, i]
        total += d * d
    return math.sqrt(total)


@njit(**_JIT)
def _cross_unit(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> float:
    """out = a × b normalised (3D); returns |a × b| before normalising (out untouched if 0)."""
    x = a[1] * b[2] - a[2] * b[1]
    y = a[2] * b[0] - a[0] * b[2]
    z = a[0] * b[1] - a[1] * b[0]
    length = math.sqrt(x * x + y * y + z * z)
    if length > 0.0:
        out[0] = x / length
        out[1] = y / length
        out[2] = z / length
    return length


@njit(**_JIT)
def carry_circulation(
    axes: np.ndarray, center: np.ndarray, mean: np.ndarray, active: np.ndarray, goal: np.ndarray
) -> np.ndarray:
    """:func:`stt_drake.core.circulation.carry_circulation` (3D), one loop over the obstacles."""
    count = mean.shape[0]
    result = np.zeros((count, 3))
    unit_m = np.empty(3)
    fallback = np.zeros((3, 3))
    fallback[0, :] = goal
    fallback[1, 2] = 1.0
    fallback[2, 0] = 1.0
    sizes = np.array([math.sqrt(goal[0] ** 2 + goal[1] ** 2 + goal[2] ** 2), 1.0, 1.0])
    for j in range(count):
        if not active[j]:
            continue
        distance = _distance(center, mean, j)
        scale = distance if distance > 1e-300 else 1e-300
        for i in range(3):
            unit_m[i] = (center[i] - mean[j, i]) / scale
        dot = axes[j, 0] * unit_m[0] + axes[j, 1] * unit_m[1] + axes[j, 2] * unit_m[2]
        length = 0.0
        for i in range(3):
            result[j, i] = axes[j, i] - dot * unit_m[i]
            length += result[j, i] ** 2
        length = math.sqrt(length)
        if length > CIRCULATION_MIN_SINE:
            for i in range(3):
                result[j, i] /= length
            continue
        result[j, :] = 0.0
        for k in range(3):
            if _cross_unit(unit_m, fallback[k], result[j]) > 1e-6 * max(sizes[k], 1e-300):
                break
            result[j, :] = 0.0
    return result


# --------------------------------------------------------------------------- belief port
@njit(**_JIT)
def largest_variance(table: np.ndarray, j: int, n: int) -> float:
    """λ_max of the covariance in row j of a belief port table ([μ (n), Σ (n², row-major),
    active] per slot; :mod:`stt_drake.core.belief`), in closed form: n = 2 from the
    characteristic quadratic; n = 3 by the trigonometric solution of the characteristic
    cubic of a symmetric matrix (Smith 1961, Comm. ACM 4(4):168), exact for a diagonal Σ."""
    if n == 1:
        return table[j, 1]
    if n == 2:
        a = table[j, 2]
        b = 0.5 * (table[j, 3] + table[j, 4])
        d = table[j, 5]
        return 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)
    a00, a11, a22 = table[j, 3], table[j, 7], table[j, 11]
    a01 = 0.5 * (table[j, 4] + table[j, 6])
    a02 = 0.5 * (table[j, 5] + table[j, 9])
    a12 = 0.5 * (table[j, 8] + table[j, 10])
    off = a01 * a01 + a02 * a02 + a12 * a12
    if off == 0.0:
        return max(a00, max(a11, a22))
    mean = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - mean, a11 - mean, a22 - mean
    scale = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0)
    det = (
        b00 * (b11 * b22 - a12 * a12)
        - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02)
    )
    half_det = min(max(0.5 * det / scale**3, -1.0), 1.0)
    return mean + 2.0 * scale * math.cos(math.acos(half_det) / 3.0)


@njit(**_JIT)
def active_slots(
    belief: np.ndarray, task: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The active slots of a belief port vector with their task rows ([r_o, ε, p_d, …] per
    slot): (slot indices, μ (k, n), σ = √λ_max(Σ) (k,), task rows [r_o, ε, p_d] (k, 3))."""
    table = belief.reshape((-1, n + n * n + 1))
    count = table.shape[0]
    active = 0
    for j in range(count):
        if table[j, n + n * n] > 0.5:
            active += 1
    slots = np.empty(active, dtype=np.int64)
    mean = np.empty((active, n))
    sigma = np.empty(active)
    rows = np.empty((active, 3))
    k = 0
    for j in range(count):
        if table[j, n + n * n] > 0.5:
            slots[k] = j
            for i in range(n):
                mean[k, i] = table[j, i]
            sigma[k] = math.sqrt(largest_variance(table, j, n))
            for i in range(3):
                rows[k, i] = task[j, i]
            k += 1
    return slots, mean, sigma, rows


@njit(**_JIT)
def active_covariances(
    belief: np.ndarray, task: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The active slots of a belief port vector with their task rows: (slot indices,
    μ (k, n), Σ (k, n, n), task rows (k, 3))."""
    table = belief.reshape((-1, n + n * n + 1))
    slots = np.nonzero(table[:, n + n * n] > 0.5)[0]
    mean = np.empty((slots.shape[0], n))
    covariance = np.empty((slots.shape[0], n, n))
    rows = np.empty((slots.shape[0], 3))
    for k in range(slots.shape[0]):
        j = slots[k]
        for i in range(n):
            mean[k, i] = table[j, i]
            for column in range(n):
                covariance[k, i, column] = table[j, n + i * n + column]
        for i in range(3):
            rows[k, i] = task[j, i]
    return slots, mean, covariance, rows


# --------------------------------------------------------------------------- invariants
@njit(**_JIT)
def invariant_margins(
    output: np.ndarray,
    center: np.ndarray,
    tube_radius: float,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    r_min: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The margins of :func:`stt_drake.core.invariants.evaluate_invariants` in one pass.

    Returns:
        (margins (5,), P(‖y − O_j‖ ≥ r_o_j) (m,), P(‖c − O_j‖ ≥ r_o_j + r) (m,)).
    """
    count, n = mean.shape
    output_q = np.empty(count)
    tube_q = np.empty(count)
    grown = 0.0 if tube_radius < 0.0 else tube_radius  # max(r, 0), NaN stays NaN
    margins = np.empty(5)
    offset = 0.0
    for i in range(n):
        offset += (output[i] - center[i]) ** 2
    margins[0] = tube_radius - math.sqrt(offset)
    worst_center = 1.0
    worst_tube = 1.0
    worst_output = 1.0
    for j in range(count):
        s = sigma[j]
        eps = epsilon[j]
        a_center = _distance(center, mean, j) / s
        center_gap = chi_sf((radius[j] + r_min) / s, a_center, n) - eps
        tq = chi_sf((radius[j] + grown) / s, a_center, n)
        oq = chi_sf(radius[j] / s, _distance(output, mean, j) / s, n)
        tube_q[j] = tq
        output_q[j] = oq
        worst_center = _nan_min(worst_center, center_gap)
        worst_tube = _nan_min(worst_tube, tq - eps)
        worst_output = _nan_min(worst_output, oq - eps)
    margins[1] = worst_center
    margins[2] = worst_tube
    margins[3] = worst_output
    margins[4] = tube_radius
    return margins, output_q, tube_q


@njit(**_JIT)
def invariant_margins_packed(
    output: np.ndarray, tube: np.ndarray, belief: np.ndarray, task: np.ndarray, r_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`invariant_margins` on port vectors: tube = [c, r], the belief port vector and
    the task rows as in :func:`tube_step_packed`; the active slots only (the inactive ones:
    probability 1)."""
    n = output.shape[0]
    slots, mean, sigma, rows = active_slots(belief, task, n)
    margins, output_active, tube_active = invariant_margins(
        output, tube[:n], tube[n], mean, sigma, rows[:, 0], rows[:, 1], r_min
    )
    output_q = np.ones(task.shape[0])
    tube_q = np.ones(task.shape[0])
    for k in range(slots.shape[0]):
        output_q[slots[k]] = output_active[k]
        tube_q[slots[k]] = tube_active[k]
    return margins, output_q, tube_q


@njit(**_JIT)
def _nan_min(x: float, y: float) -> float:
    """min like numpy's: NaN wins."""
    if math.isnan(x) or math.isnan(y):
        return math.nan
    return y if y < x else x


# --------------------------------------------------------------------------- belief
@njit(**_JIT)
def _cut(array: np.ndarray, offset: int, count: int) -> tuple[np.ndarray, int]:
    """The view array[offset : offset + count] and the offset after it (how the packed
    kernels below read their arguments in place)."""
    return array[offset : offset + count], offset + count


@njit(**_JIT)
def _cut_rows(array: np.ndarray, offset: int, rows: int, width: int) -> tuple[np.ndarray, int]:
    """The next rows·width entries of `array` from `offset` as a (rows, width) view, and the
    offset after them."""
    view, after = _cut(array, offset, rows * width)
    return view.reshape((rows, width)), after


@njit(**_JIT)
def belief_table(
    template: np.ndarray, t: float, values: np.ndarray, layout: np.ndarray
) -> np.ndarray:
    """The belief port vector at time t (:class:`stt_drake.systems.belief_source.
    ObstacleBeliefSource`): a copy of the (m, n + n² + 1) `template`, with the means of the
    `oscillating` rows set to center + amplitude·sin(ω t + phase), those of the `moving`
    rows to start + t·velocity, and those of the `sampled` rows (piecewise-linear tracks:
    track k is rows first[k]..last[k] of `sample_times`, `sample_positions`) interpolated
    in the segment found by bisection, held outside the span, the later sample at a
    repeated time (the arithmetic of :mod:`stt_drake.core.motion`); a `bounded` track's
    row is active (1.0) inside its span only.

    These arrays come packed in `layout` and `values`, two arguments instead of fourteen (a
    compiled call's cost grows with its argument count); their order is
    :attr:`stt_drake.core.motion.MotionTable.kernel_layout`'s, and the views are read in place."""
    n, oscillating_count, moving_count, sampled_count, sample_count = layout[:5]
    oscillating, at = _cut(layout, 5, oscillating_count)
    moving, at = _cut(layout, at, moving_count)
    sampled, at = _cut(layout, at, sampled_count)
    first, at = _cut(layout, at, sampled_count)
    last, at = _cut(layout, at, sampled_count)
    bounded, _ = _cut(layout, at, sampled_count)
    center, at = _cut_rows(values, 0, oscillating_count, n)
    amplitude, at = _cut_rows(values, at, oscillating_count, n)
    angular_frequency, at = _cut(values, at, oscillating_count)
    phase, at = _cut_rows(values, at, oscillating_count, n)
    start, at = _cut_rows(values, at, moving_count, n)
    velocity, at = _cut_rows(values, at, moving_count, n)
    sample_times, at = _cut(values, at, sample_count)
    sample_positions, _ = _cut_rows(values, at, sample_count, n)
    table = template.copy()
    for k in range(oscillating.shape[0]):
        j = oscillating[k]
        for i in range(n):
            angle = angular_frequency[k] * t + phase[k, i]
            table[j, i] = center[k, i] + amplitude[k, i] * math.sin(angle)
    for k in range(moving.shape[0]):
        j = moving[k]
        for i in range(n):
            table[j, i] = start[k, i] + t * velocity[k, i]
    for k in range(sampled.shape[0]):
        j = sampled[k]
        low, high = first[k], last[k] - 1  # the segment starts of track k
        index, a, b = low, low, high
        while a <= b:  # the largest segment start at or before t (low if none)
            middle = (a + b) // 2
            if sample_times[middle] <= t:
                index, a = middle, middle + 1
            else:
                b = middle - 1
        elapsed = t - sample_times[index]
        step = sample_times[index + 1] - sample_times[index]
        if step > 0.0:
            fraction = min(max(elapsed / step, 0.0), 1.0)
        else:  # a step: the later sample from its time on
            fraction = 1.0 if elapsed >= 0.0 else 0.0
        for i in range(n):
            before = sample_positions[index, i]
            table[j, i] = before + fraction * (sample_positions[index + 1, i] - before)
        if bounded[k]:
            inside = sample_times[first[k]] <= t <= sample_times[last[k]]
            table[j, table.shape[1] - 1] = 1.0 if inside else 0.0
    return table.reshape(-1)


# --------------------------------------------------------------------------- controller
@njit(**_JIT)
def _rho(e: float, saturation: float) -> float:
    """ρ = ln((1 + e)/(1 − e)) = 2 atanh(e), e clipped to ±saturation."""
    return 2.0 * math.atanh(min(max(e, -saturation), saturation))


@njit(**_JIT)
def funnel_control(
    t: float,
    states: np.ndarray,
    center: np.ndarray,
    radius: float,
    kappa: np.ndarray,
    funnel_start: np.ndarray,
    funnel_end: np.ndarray,
    funnel_rate: np.ndarray,
    saturation: float,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The funnel law of Sec. 4 (:meth:`stt_drake.core.control.FunnelController.evaluate`).

    Stage 1: e₁ = ‖x₁ − c‖/r, r₂ = −κ₁ ρ(e₁)(x₁ − c) (Eq. (20a)). Stage k ≥ 2:
    γ = (p − q)e^{−μt} + q, e_k = (x_k − r_k)/γ, ξ = 4/(γ(1 − e_k²)), r_{k+1} = −κ_k ξ ρ(e_k)
    (Eqs. (19a)–(19c)). `states` is [x_1; …; x_N] flat; the funnel arrays are (N − 1, n).

    Returns:
        (u = r_{N+1} (n,), normalised errors [e₁, e₂ (n), …, e_N (n)] before saturation,
        whether t, r, every state and the centre are finite).
    """
    n = center.shape[0]
    finite = math.isfinite(t) and math.isfinite(radius)
    for i in range(states.shape[0]):
        finite = finite and math.isfinite(states[i])
    for i in range(n):
        finite = finite and math.isfinite(center[i])
    stages = kappa.shape[0]
    errors = np.empty(1 + (stages - 1) * n)
    reference = np.empty(n)
    distance = 0.0
    for i in range(n):
        distance += (states[i] - center[i]) ** 2
    distance = math.sqrt(distance)
    e1 = distance / radius if radius > 0.0 else math.inf
    errors[0] = e1
    gain = -kappa[0] * _rho(e1, saturation)
    for i in range(n):
        reference[i] = gain * (states[i] - center[i])
    for k in range(1, stages):
        for i in range(n):
            start = funnel_start[k - 1, i]
            end = funnel_end[k - 1, i]
            gamma = (start - end) * math.exp(-funnel_rate[k - 1, i] * t) + end
            e = (states[k * n + i] - reference[i]) / gamma
            errors[1 + (k - 1) * n + i] = e
            clipped = min(max(e, -saturation), saturation)
            xi = 4.0 / (gamma * (1.0 - clipped * clipped))
            reference[i] = -kappa[k] * xi * _rho(e, saturation)
    return reference, errors, finite


@njit(**_JIT)
def funnel_control_packed(
    t: float, states: np.ndarray, tube: np.ndarray, law: np.ndarray
) -> np.ndarray | None:
    """:func:`funnel_control`'s control u with the tube as its port vector [c, r] and the
    law's constants packed in one array (few arguments and one returned array: a compiled
    call's cost grows with both), `law` = [saturation, κ (N,), p, q, μ ((N − 1)·n each)]
    (:meth:`stt_drake.core.control.FunnelController.packed_law`); N = len(states)/n.

    Returns:
        u (n,), or None if an input is not finite or the lengths do not fit.
    """
    n = tube.shape[0] - 1
    stages = states.shape[0] // n if n > 0 else 0
    fits = stages > 0 and states.shape[0] == stages * n
    if not (fits and law.shape[0] == 1 + stages + 3 * (stages - 1) * n):
        return None
    kappa, at = _cut(law, 1, stages)
    funnel_start, at = _cut_rows(law, at, stages - 1, n)
    funnel_end, at = _cut_rows(law, at, stages - 1, n)
    funnel_rate, _ = _cut_rows(law, at, stages - 1, n)
    control, _errors, finite = funnel_control(
        t, states, tube[:n], tube[n], kappa, funnel_start, funnel_end, funnel_rate, law[0]
    )
    return control if finite else None
