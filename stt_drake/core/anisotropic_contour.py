"""The numpy reference of the saddle-point contour integral and the quantile solver of
:mod:`stt_drake.core.anisotropic` (the method is described there): the same algorithm as
the compiled :mod:`stt_drake.core._anisotropic`, in array form over points (used with
``STT_DRAKE_PURE_NUMPY=1``). :mod:`stt_drake.core.anisotropic` dispatches to it.
"""

from __future__ import annotations

import numpy as np
from scipy import special

from stt_drake.core.constants import (
    ANISOTROPIC_QUANTILE_MAX_ITERATIONS as QUANTILE_MAX_ITERATIONS,
)
from stt_drake.core.constants import ANISOTROPIC_QUANTILE_RTOL as QUANTILE_RTOL
from stt_drake.core.constants import (
    NEWTON_MAX_ITERATIONS,
    PATH_BEND,
    PATH_BEND_SCALE,
    PATH_END,
    PATH_STEP,
    PATH_STRETCH,
    SADDLE_MAX_ITERATIONS,
    STEP_ACCEPT,
)
from stt_drake.core.constants import SERIES_BELOW as _SERIES_BELOW
from stt_drake.core.constants import UNDERFLOW_EXPONENT as _UNDERFLOW

_SERIES_TERMS = 24  # Σ_{k=2}^{25} (k − 1) z^k / k: the next term is < 1e-24 z² for |z| < 0.1


def path_table(
    step: float = PATH_STEP,
    stretch: float = PATH_STRETCH,
    end: float = PATH_END,
    bend: float = PATH_BEND,
    scale: float = PATH_BEND_SCALE,
) -> np.ndarray:
    """The contour at the nodes u_k = (k − ½)·step with τ(u_k)² ≤ end, τ = u + stretch·u³,
    as complex rows [T², dT²/du, d²T²/du², d³T²/du³, T, dT/du, e^{−T²}] (shape (7, nodes))
    for T² = τ² + i·bend·τ² tanh(τ/scale)."""
    count = 1
    while True:
        u_next = (count + 0.5) * step
        if (u_next + stretch * u_next**3) ** 2 > end:
            break
        count += 1
    u = (np.arange(1, count + 1) - 0.5) * step
    tau = u + stretch * u**3
    tau1 = 1.0 + 3.0 * stretch * u * u
    tau2 = 6.0 * stretch * u
    tau3 = 6.0 * stretch
    th = np.tanh(tau / scale)
    se = 1.0 - th * th
    f0 = tau * tau * th
    f1 = 2.0 * tau * th + tau * tau * se / scale
    f2 = 2.0 * th + 4.0 * tau * se / scale - 2.0 * tau * tau * th * se / scale**2
    f3 = (
        6.0 * se / scale
        - 12.0 * tau * th * se / scale**2
        + (4.0 * tau * tau * th * th * se - 2.0 * tau * tau * se * se) / scale**3
    )
    g0 = tau * tau + 1j * bend * f0  # T² and its τ-derivatives
    g1 = 2.0 * tau + 1j * bend * f1
    g2 = 2.0 + 1j * bend * f2
    g3 = 1j * bend * f3
    d1 = g1 * tau1  # ... and its u-derivatives
    d2 = g2 * tau1**2 + g1 * tau2
    d3 = g3 * tau1**3 + 3.0 * g2 * tau1 * tau2 + g1 * tau3
    root = np.sqrt(g0)
    return np.array([g0, d1, d2, d3, root, d1 / (2.0 * root), np.exp(-g0)])


_TABLE = path_table()
_TSQ, _DTSQ, _D2TSQ, _D3TSQ, _T, _TP, _WEIGHT = _TABLE
_POLE_WEIGHT = _WEIGHT * _TP


def _log_gap(z: np.ndarray) -> np.ndarray:
    """G(z) = log(1 − z) + z/(1 − z) for real z < 1 (series Σ (k − 1)z^k/k near 0)."""
    z = np.asarray(z, dtype=float)
    near = np.abs(z) < _SERIES_BELOW
    far = np.where(near, 0.5, z)
    result = np.log1p(-far) + far / (1.0 - far)
    series = np.zeros(z.shape)
    power = z * z
    for k in range(2, 2 + _SERIES_TERMS):
        series += power * ((k - 1.0) / k)
        power = power * z
    return np.where(near, series, result)


def _saddle_log_t(kappa: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Per row, x = log(1 − 2κ_max ŝ) at K′(ŝ) = 1 (as the kernel's ``saddle_log_t``)."""
    n = kappa.shape[1]
    kmax = kappa.max(axis=1)
    ratio = kappa / kmax[:, None]
    mean = (kappa + nu).sum(axis=1)
    tail = (nu / ratio**2).sum(axis=1)
    above = mean >= 1.0
    top = np.log(np.maximum(np.maximum(2.0 * n * kmax, np.sqrt(2.0 * tail)), 1.0))
    lo = np.where(above, 0.0, np.log(np.where(above, 1.0, kmax)))
    hi = np.where(above, top, 0.0)
    x = 0.5 * (lo + hi)
    active = np.ones(x.shape, dtype=bool)
    for _ in range(SADDLE_MAX_ITERATIONS):
        grow = np.expm1(x)[:, None]
        t = 1.0 + ratio * grow
        first = (kappa / t + nu / (t * t)).sum(axis=1)
        second = (2.0 * kappa * kappa / (t * t) + 4.0 * kappa * nu / (t * t * t)).sum(axis=1)
        g = np.log(first)
        lo = np.where(active & (g > 0.0), x, lo)
        hi = np.where(active & ~(g > 0.0), x, hi)
        new = x + g / (second / first * np.exp(x) / (2.0 * kmax))
        new = np.where((lo <= new) & (new <= hi), new, 0.5 * (lo + hi))
        tolerance = 4e-16 * (1.0 + np.abs(x))
        done = (np.abs(new - x) <= tolerance) | (hi - lo <= tolerance)
        x = np.where(active, new, x)
        active &= ~done
        if not active.any():
            break
    return x


def _sum_log(delta: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Σ_i log(1 − ρ_iδ) per row for Im δ > 0 (as the kernel: one arctangent per pair)."""
    q = 1.0 - rho * delta[:, None]
    modulus = np.prod(q.real**2 + q.imag**2, axis=1)
    angle = np.zeros(delta.shape)
    for i in range(0, rho.shape[1], 2):
        if i + 1 < rho.shape[1]:
            pair = np.angle(q[:, i] * q[:, i + 1])
            angle += np.where(pair > 0.0, pair - 2.0 * np.pi, pair)
        else:
            angle += np.angle(q[:, i])
    return 0.5 * np.log(modulus) + 1j * angle


def _psi(delta: np.ndarray, rho: np.ndarray, a: np.ndarray) -> tuple:
    """(ψ, ψ′, ψ″, ψ‴) per row at δ (see the kernel's ``_psi``)."""
    z = rho * delta[:, None]
    w = 1.0 / (1.0 - z)
    w2 = w * w
    zw = z * w
    p0 = -0.5 * _sum_log(delta, rho) + (-0.5 * z + (a / rho) * z * zw).sum(axis=1)
    p1 = (0.5 * rho * zw + a * zw * (2.0 - z) * w).sum(axis=1)
    p2 = (rho * (0.5 * rho + 2.0 * a * w) * w2).sum(axis=1)
    p3 = (rho * rho * w2 * w * (rho + 6.0 * a * w)).sum(axis=1)
    return p0, p1, p2, p3


def _solve_node(delta: np.ndarray, k: int, rho: np.ndarray, a: np.ndarray) -> tuple:
    """Per row, δ with ψ(δ) = −T_k² and (ψ′, ψ″, ψ‴) there (see the kernel's ``_solve_node``)."""
    delta = delta.copy()
    p1, p2, p3, correction = (np.zeros(delta.shape, dtype=complex) for _ in range(4))
    active = np.arange(delta.shape[0])
    for _ in range(NEWTON_MAX_ITERATIONS):
        q0, q1, q2, q3 = _psi(delta[active], rho[active], a[active])
        inverse = 1.0 / q1
        u = (q0 + _TSQ[k]) * inverse
        size = np.abs(u) ** 2
        scale = np.abs(delta[active]) ** 2
        c2 = 0.5 * q2 * inverse
        c3 = q3 * inverse / 6.0
        step = np.where(size > 1e-2 * scale, u, u * (1.0 + u * (c2 + u * (2.0 * c2 * c2 - c3))))
        delta[active] -= step
        p1[active], p2[active], p3[active], correction[active] = q1, q2, q3, step
        active = active[size > STEP_ACCEPT**2 * scale]
        if active.size == 0:
            break
    return (
        delta,
        p1 - correction * (p2 - 0.5 * correction * p3),
        p2 - correction * p3,
        p3,
    )


def _small_tail(kappa: np.ndarray, nu: np.ndarray, gradient: bool) -> tuple:
    """Per row of (κ, ν) (k, n): (tail, upper, density, slope, D (k, n) or None), as the
    kernel's ``small_tail``."""
    count, n = kappa.shape
    tail = np.zeros(count)
    density = np.zeros(count)
    slope = np.zeros(count)
    terms = np.zeros((count, n)) if gradient else None
    x = _saddle_log_t(kappa, nu)
    kmax = kappa.max(axis=1)
    grow = np.expm1(x)
    s_hat = -grow / (2.0 * kmax)
    z = -(kappa / kmax[:, None]) * grow[:, None]
    t_hat = 1.0 - z
    rho = 2.0 * kappa / t_hat
    a = nu / (t_hat * t_hat)
    k2 = (0.5 * rho * rho + 2.0 * a * rho).sum(axis=1)
    k3 = (rho**3 + 6.0 * rho * rho * a).sum(axis=1)
    phi_hat = -(0.5 * _log_gap(z) + 0.5 * nu * z * z / (kappa * t_hat * t_hat)).sum(axis=1)
    upper = s_hat > 0.0
    live = np.flatnonzero(phi_hat >= _UNDERFLOW)
    if live.size == 0:
        return tail, upper, density, slope, terms
    rho, a, t_hat, s_hat = rho[live], a[live], t_hat[live], s_hat[live]
    w = np.sqrt(-phi_hat[live])
    pole = 1j * np.where(upper[live], w, -w)
    a1 = 1j * np.sqrt(2.0 / k2[live])
    a2 = k3[live] / (3.0 * k2[live] ** 2)
    h = PATH_STEP
    delta = d1 = d2 = d3 = d4 = np.zeros(live.size, dtype=complex)
    sums = np.zeros((3, live.size))
    grad = np.zeros((live.size, n))
    for k in range(_TSQ.shape[0]):
        if k == 0:
            delta = _T[0] * (a1 + a2 * _T[0])
        else:
            delta = delta + h * (d1 + h * (0.5 * d2 + h * (d3 + 0.25 * h * d4) / 6.0))
        delta, p1, p2, p3 = _solve_node(delta, k, rho, a)
        inverse = -1.0 / p1
        d1 = _DTSQ[k] * inverse
        d2 = (_D2TSQ[k] + p2 * d1 * d1) * inverse
        previous = d3
        d3 = (_D3TSQ[k] + 3.0 * p2 * d1 * d2 + p3 * d1**3) * inverse
        d4 = (d3 - previous) / h if k > 0 else np.zeros(live.size, dtype=complex)
        s = s_hat + delta
        weighted = _WEIGHT[k] * d1
        sums[0] += (weighted / s - _POLE_WEIGHT[k] / (_T[k] - pole)).imag
        sums[1] += weighted.imag
        sums[2] -= (weighted * s).imag
        if gradient:
            grad += (weighted[:, None] / (1.0 - rho * delta[:, None])).imag / t_hat
    scale = np.exp(phi_hat[live]) * h / np.pi
    sign = np.where(upper[live], 1.0, -1.0)
    tail[live] = np.clip(0.5 * special.erfc(w) + sign * scale * sums[0], 0.0, 1.0)
    density[live] = scale * sums[1]
    slope[live] = scale * sums[2]
    if gradient:
        terms[live] = scale[:, None] * grad
    return tail, upper, density, slope, terms


def _scaled(variances: np.ndarray, offsets: np.ndarray, radius: float) -> tuple:
    """(κ, ν) = (λ/R², offset²/R²) as (k, n) arrays."""
    offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
    threshold = float(radius) ** 2
    kappa = np.broadcast_to(np.asarray(variances, dtype=float) / threshold, offsets.shape)
    return np.array(kappa), offsets * offsets / threshold


def ball_probabilities(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Reference path of :func:`stt_drake.core.anisotropic.ball_probabilities`."""
    tail, upper, _, _, _ = _small_tail(*_scaled(variances, offsets, radius), False)
    collision = np.where(upper, 1.0 - tail, tail)
    return collision, np.where(upper, tail, 1.0 - tail)


def avoid_gradient(
    variances: np.ndarray, offsets: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Reference path of :func:`stt_drake.core.anisotropic.avoid_gradient`:
    ∂avoid/∂offset_i = 2 offset_i D_i/R²."""
    offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
    tail, upper, _, _, terms = _small_tail(*_scaled(variances, offsets, radius), True)
    return np.where(upper, tail, 1.0 - tail), 2.0 * offsets * terms / float(radius) ** 2


def _gap_and_slope(ratio: np.ndarray, b2: np.ndarray, x: np.ndarray) -> tuple:
    """Per row, (J, dJ/dx) with J = ŝK′ − K at s = (1 − e^x)/(2λ_max) (as the kernel)."""
    grow = np.expm1(x)[:, None]
    z = -ratio * grow
    t = 1.0 - z
    gap = (0.5 * _log_gap(z) + 0.5 * b2 * z * z / (t * t)).sum(axis=1)
    slope = (z * ratio / (t * t) + 2.0 * z * ratio * b2 / (t * t * t)).sum(axis=1)
    return gap, -0.5 * np.exp(x) * slope


def _solve_gap(ratio: np.ndarray, b2: np.ndarray, goal: np.ndarray, direction: float) -> np.ndarray:
    """Per row, x on the side `direction` with √J(x) = goal (as the kernel's ``_solve_gap``)."""
    count = b2.shape[0]
    lo = np.zeros(count)
    hi = np.full(count, direction)
    growing = goal > 0.0
    while True:
        short = growing & (np.sqrt(_gap_and_slope(ratio, b2, hi)[0]) < goal) & (np.abs(hi) < 512)
        if not short.any():
            break
        lo = np.where(short, hi, lo)
        hi = np.where(short, 2.0 * hi, hi)
    x = np.where(growing, 0.5 * (lo + hi), 0.0)
    active = growing.copy()
    for _ in range(SADDLE_MAX_ITERATIONS):
        if not active.any():
            break
        gap, slope = _gap_and_slope(ratio, b2, x)
        root = np.sqrt(gap)
        below = root < goal
        lo = np.where(active & below, x, lo)
        hi = np.where(active & ~below, x, hi)
        safe = np.where(slope != 0.0, slope, 1.0)
        new = np.where(slope != 0.0, x - (root - goal) * 2.0 * root / safe, lo)
        inside = (np.minimum(lo, hi) <= new) & (new <= np.maximum(lo, hi))
        new = np.where(inside, new, 0.5 * (lo + hi))
        done = np.abs(new - x) <= 1e-12 * (1.0 + np.abs(x))
        x = np.where(active, new, x)
        active &= ~done
    return x


def _saddlepoint_start(variances: np.ndarray, offsets: np.ndarray, epsilon: float) -> np.ndarray:
    """Per row, the kernel's ``saddlepoint_start``: R² where the Lugannani–Rice tail is ε."""
    ratio = variances / variances.max()
    b2 = offsets * offsets / variances
    small = min(epsilon, 1.0 - epsilon)
    sign = 1.0 if epsilon < 0.5 else -1.0
    target = np.full(offsets.shape[0], small)
    x = np.zeros(offsets.shape[0])
    correcting = np.ones(offsets.shape[0], dtype=bool)
    for attempt in range(3):
        goal = special.erfcinv(2.0 * target)
        x = np.where(correcting, _solve_gap(ratio, b2, goal, -sign), x)
        gap = _gap_and_slope(ratio, b2, x)[0]
        correcting &= gap >= 1e-3
        if attempt == 2 or not correcting.any():
            break
        grow = np.expm1(x)[:, None]
        t = 1.0 + ratio * grow
        curvature = (2.0 * ratio**2 / (t * t) * (1.0 + 2.0 * b2 / t)).sum(axis=1)
        u_hat = -0.5 * grow[:, 0] * np.sqrt(curvature)
        w_hat = sign * np.sqrt(2.0 * gap)
        with np.errstate(divide="ignore", invalid="ignore"):
            correction = np.exp(-gap) / np.sqrt(2.0 * np.pi) * (1.0 / u_hat - 1.0 / w_hat)
        corrected = np.clip(small - sign * correction, 0.1 * small, 0.5)
        target = np.where(correcting, corrected, target)
    t = 1.0 + ratio * np.expm1(x)[:, None]
    return (variances / t + offsets * offsets / (t * t)).sum(axis=1)


def quantile_radius(variances: np.ndarray, offsets: np.ndarray, epsilon: float) -> np.ndarray:
    """Reference path of :func:`stt_drake.core.anisotropic.quantile_radius` (the kernel's
    iteration, row-wise)."""
    variances = np.asarray(variances, dtype=float)
    offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
    count, n = offsets.shape
    norm2 = (offsets * offsets).sum(axis=1)
    along = (variances * offsets * offsets).sum(axis=1)
    distance = np.sqrt(norm2)
    sigma_max = np.sqrt(variances.max())
    lower = np.full(count, max(-sigma_max * special.ndtri(0.5 * epsilon), 0.0))
    aligned = distance - np.sqrt(along / np.where(norm2 > 0.0, norm2, 1.0)) * special.ndtri(epsilon)
    lower = np.where(norm2 > 0.0, np.maximum(lower, aligned), lower)
    u = -np.log(epsilon)
    upper = distance + sigma_max * np.sqrt(n + 2.0 * np.sqrt(n * u) + 2.0 * u)
    y_lo, y_hi = lower * lower, upper * upper
    upper_tail = epsilon <= 0.5
    target = np.log(epsilon) if upper_tail else np.log1p(-epsilon)
    sign = -1.0 if upper_tail else 1.0
    y = np.clip(_saddlepoint_start(variances, offsets, epsilon), y_lo, y_hi)
    y = np.where(y > 0.0, y, 0.5 * (y_lo + y_hi))
    radius = np.full(count, np.nan)
    active = np.arange(count)
    for _ in range(QUANTILE_MAX_ITERATIONS):
        ya = y[active]
        tail, side, density, slope, _ = _small_tail(
            np.array(np.broadcast_to(variances, (active.size, n))) / ya[:, None],
            offsets[active] ** 2 / ya[:, None],
            False,
        )
        prob = np.where(side == upper_tail, tail, 1.0 - tail)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_prob = np.log(prob)
            above = np.where(prob > 0.0, (log_prob > target) == upper_tail, not upper_tail)
            y_lo[active] = np.where(above, ya, y_lo[active])
            y_hi[active] = np.where(above, y_hi[active], ya)
            f = density / ya
            f_slope = slope / (ya * ya)
            g = log_prob - target
            g1 = sign * f / prob
            g2 = sign * f_slope / prob - g1 * g1
            halley = ya - 2.0 * g * g1 / (2.0 * g1 * g1 - g * g2)
        lo, hi = y_lo[active], y_hi[active]
        new = np.where((prob > 0.0) & (f > 0.0), halley, 0.5 * (lo + hi))
        new = np.where((lo <= new) & (new <= hi), new, 0.5 * (lo + hi))
        converged = np.abs(new - ya) <= QUANTILE_RTOL * ya
        narrow = hi - lo <= 1e-15 * hi
        radius[active] = np.where(converged, np.sqrt(new), np.sqrt(0.5 * (lo + hi)))
        y[active] = new
        active = active[~(converged | narrow)]
        if active.size == 0:
            break
    radius[active] = np.sqrt(y[active])
    return radius
