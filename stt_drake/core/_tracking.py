"""Compiled (numba) kernel of :func:`stt_drake.core.tracking.update`: the predict and
correct steps of one constant-velocity Kalman filter per obstacle slot, as scalar loops.

The numpy reference in :mod:`stt_drake.core.tracking` does the same arithmetic with batched
matrix products (a few µs of numpy call overhead each); these loops exploit the structure
instead (F = [[I, Δt I], [0, I]], H = [I 0]), so a predict + correct of 50 tracks is one
native call. The dimension n is made a compile-time constant (``numba.literally``, one
specialisation per n in 1, 2, 3) so the tiny loops unroll: that halves the time of the
runtime-n version. A test compares it with the numpy reference.

Arrays, for m slots in dimension n: ``state`` (m, 2n) = [p, v] per slot (m, m/s),
``covariance`` (m, 2n, 2n), ``dt`` (m,) seconds, ``z`` (m, n) measured positions (m),
``density`` the white-acceleration spectral density q (m²/s³), ``noise_covariance`` R
(n, n; m²). The correction is the Joseph form; its upper triangle is mirrored, so the
covariance is symmetric exactly.
"""

from __future__ import annotations

import numpy as np
from numba import literally, njit

from stt_drake.core.backend import jit_options

_JIT = jit_options()


@njit(**_JIT)
def _predict_slot(x: np.ndarray, p: np.ndarray, dt: float, density: float, n: int) -> None:
    """x ← F x, P ← F P Fᵀ + Q(dt) for one slot, in place, block by block."""
    literally(n)
    for i in range(n):
        x[i] += dt * x[n + i]
    for i in range(n):
        for k in range(n):
            vv = p[n + i, n + k]
            p[i, k] += dt * (p[i, n + k] + p[n + i, k]) + dt * dt * vv
            p[i, n + k] += dt * vv
            p[n + i, k] += dt * vv
    q_pp = density * dt * dt * dt / 3.0
    q_pv = density * dt * dt / 2.0
    for i in range(n):
        p[i, i] += q_pp
        p[i, n + i] += q_pv
        p[n + i, i] += q_pv
        p[n + i, n + i] += density * dt


@njit(**_JIT)
def _correct_slot(
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    r: np.ndarray,
    chol: np.ndarray,
    gain_t: np.ndarray,
    w: np.ndarray,
    m: np.ndarray,
    n: int,
) -> None:
    """Measurement update of one slot in place: Joseph form, symmetric by construction.
    `chol`, `gain_t`, `w`, `m` are scratch arrays of shapes (n, n), (n, 2n), (2n, 2n), (2n, n).

    The inner loops run along rows (independent outputs, contiguous memory) so they
    vectorise instead of waiting on one running sum."""
    literally(n)
    d = 2 * n
    # Cholesky factor L of the innovation covariance S = P_pp + R.
    for i in range(n):
        for k in range(i + 1):
            s = p[i, k] + r[i, k]
            for t in range(k):
                s -= chol[i, t] * chol[k, t]
            chol[i, k] = np.sqrt(s) if i == k else s / chol[k, k]
    # Kᵀ = S⁻¹ P[:n, :] (n, 2n), row by row: L Y = P[:n, :], then Lᵀ Kᵀ = Y.
    for i in range(n):
        for c in range(d):
            gain_t[i, c] = p[i, c]
        for t in range(i):
            for c in range(d):
                gain_t[i, c] -= chol[i, t] * gain_t[t, c]
        for c in range(d):
            gain_t[i, c] /= chol[i, i]
    for i in range(n - 1, -1, -1):
        for t in range(i + 1, n):
            for c in range(d):
                gain_t[i, c] -= chol[t, i] * gain_t[t, c]
        for c in range(d):
            gain_t[i, c] /= chol[i, i]
    # x ← x + K (z − p); the innovation z − p sits in m[:n, 0] meanwhile.
    for i in range(n):
        m[i, 0] = z[i] - x[i]
    for i in range(n):
        for a in range(d):
            x[a] += gain_t[i, a] * m[i, 0]
    # W = (I − K H) P = P − K P[:n, :].
    for a in range(d):
        for b in range(d):
            w[a, b] = p[a, b]
        for i in range(n):
            for b in range(d):
                w[a, b] -= gain_t[i, a] * p[i, b]
    # Joseph: P ← W (I − K H)ᵀ + K R Kᵀ = W + M Kᵀ with M = K R − W[:, :n] (2n, n).
    for a in range(d):
        for i in range(n):
            s = -w[a, i]
            for t in range(n):
                s += gain_t[t, a] * r[t, i]
            m[a, i] = s
    # Only the upper triangle, mirrored: the result is symmetric exactly.
    for a in range(d):
        for b in range(a, d):
            p[a, b] = w[a, b]
        for i in range(n):
            for b in range(a, d):
                p[a, b] += m[a, i] * gain_t[i, b]
        for b in range(a):
            p[a, b] = p[b, a]


@njit(**_JIT)
def _update_slots(
    x: np.ndarray,
    p: np.ndarray,
    dt: np.ndarray,
    z: np.ndarray,
    density: float,
    noise_covariance: np.ndarray,
    n: int,
) -> None:
    """Every slot of x, p predicted by dt[j], then corrected by z[j], in place."""
    literally(n)
    chol, gain_t = np.empty((n, n)), np.empty((n, 2 * n))
    w, m = np.empty((2 * n, 2 * n)), np.empty((2 * n, n))
    for j in range(x.shape[0]):
        _predict_slot(x[j], p[j], dt[j], density, n)
        _correct_slot(x[j], p[j], z[j], noise_covariance, chol, gain_t, w, m, n)


@njit(**_JIT)
def track_update(
    state: np.ndarray,
    covariance: np.ndarray,
    dt: np.ndarray,
    z: np.ndarray,
    density: float,
    noise_covariance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Every slot predicted by dt[j], then corrected by z[j] (new arrays), for n = 1, 2, 3.

    Raises:
        ValueError: another n (:mod:`stt_drake.core.backend` never asks for one).
    """
    x = state.copy()
    p = covariance.copy()
    n = z.shape[1]
    if n == 1:
        _update_slots(x, p, dt, z, density, noise_covariance, 1)
    elif n == 2:
        _update_slots(x, p, dt, z, density, noise_covariance, 2)
    elif n == 3:
        _update_slots(x, p, dt, z, density, noise_covariance, 3)
    else:
        raise ValueError("track_update is compiled for n = 1, 2, 3 only")
    return x, p


# The monitored update (NIS and adaptive process noise, :mod:`stt_drake.core.consistency`).


@njit(**_JIT)
def _nis_slot(
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    r: np.ndarray,
    chol: np.ndarray,
    y: np.ndarray,
    n: int,
) -> float:
    """ν = yᵀ S⁻¹ y of one predicted slot, y = z − p, S = P_pp + R (Cholesky, forward
    substitution: ν = ‖L⁻¹ y‖²)."""
    literally(n)
    for i in range(n):
        for k in range(i + 1):
            s = p[i, k] + r[i, k]
            for t in range(k):
                s -= chol[i, t] * chol[k, t]
            chol[i, k] = np.sqrt(s) if i == k else s / chol[k, k]
    nis = 0.0
    for i in range(n):
        s = z[i] - x[i]
        for t in range(i):
            s -= chol[i, t] * y[t]
        y[i] = s / chol[i, i]
        nis += y[i] * y[i]
    return nis


@njit(**_JIT)
def _monitored_slots(
    buffers: tuple,
    dt: np.ndarray,
    z: np.ndarray,
    base: float,
    noise_covariance: np.ndarray,
    rule: tuple,
    n: int,
) -> None:
    """Every slot predicted with density base·scale[j], its NIS ν taken, the window test
    run, the scale adapted (gain > 0) and the prediction topped up with the extra process
    noise, then corrected; all in place. `buffers` = (x, p, scale, ring, count, nis, test),
    written; `rule` = (lower, upper, gain, step_cap, relax, max_scale)."""
    x, p, scale, ring, count, nis, test = buffers
    lower, upper, gain, step_cap, relax, max_scale = rule
    literally(n)
    chol, gain_t = np.empty((n, n)), np.empty((n, 2 * n))
    w, m = np.empty((2 * n, 2 * n)), np.empty((2 * n, n))
    y = np.empty(n)
    window = ring.shape[1]
    for j in range(x.shape[0]):
        h = dt[j]
        old = scale[j]
        _predict_slot(x[j], p[j], h, base * old, n)
        value = _nis_slot(x[j], p[j], z[j], noise_covariance, chol, y, n)
        nis[j] = value
        k = int(count[j])
        ring[j, k % window] = value
        k += 1
        count[j] = k
        used = min(k, window)
        total = 0.0
        for i in range(used):
            total += ring[j, i]
        if total > upper[used - 1]:
            test[j] = 1.0
        elif total < lower[used - 1]:
            test[j] = -1.0
        else:
            test[j] = 0.0
        if gain > 0.0:
            step = min(value / n - 1.0, step_cap)
            if step < 0.0:
                step *= relax
            new = min(max(old * np.exp(gain * step), 1.0), max_scale)
            scale[j] = new
            extra = base * (new - old)
            if extra != 0.0:
                for i in range(n):
                    p[j, i, i] += extra * h * h * h / 3.0
                    p[j, i, n + i] += extra * h * h / 2.0
                    p[j, n + i, i] += extra * h * h / 2.0
                    p[j, n + i, n + i] += extra * h
        _correct_slot(x[j], p[j], z[j], noise_covariance, chol, gain_t, w, m, n)


@njit(**_JIT)
def track_update_monitored(
    state: np.ndarray,
    covariance: np.ndarray,
    dt: np.ndarray,
    z: np.ndarray,
    base: float,
    noise_covariance: np.ndarray,
    scale: np.ndarray,
    ring: np.ndarray,
    count: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    gain: float,
    step_cap: float,
    relax: float,
    max_scale: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`stt_drake.core.tracking.monitored_update` (new arrays), for n = 1, 2, 3:
    (state, covariance, scale, ring, count, nis, test).

    Raises:
        ValueError: another n.
    """
    x, p = state.copy(), covariance.copy()
    s, r, c = scale.copy(), ring.copy(), count.copy()
    nis, test = np.empty(x.shape[0]), np.empty(x.shape[0])
    n = z.shape[1]
    buffers = (x, p, s, r, c, nis, test)
    rule = (lower, upper, gain, step_cap, relax, max_scale)
    if n == 1:
        _monitored_slots(buffers, dt, z, base, noise_covariance, rule, 1)
    elif n == 2:
        _monitored_slots(buffers, dt, z, base, noise_covariance, rule, 2)
    elif n == 3:
        _monitored_slots(buffers, dt, z, base, noise_covariance, rule, 3)
    else:
        raise ValueError("track_update_monitored is compiled for n = 1, 2, 3 only")
    return x, p, s, r, c, nis, test


# The published belief (:meth:`stt_drake.core.tracking.KalmanTracker.belief_vector`).


@njit(**_JIT)
def _predicted_slot(
    record: np.ndarray, t: float, density: float, out: np.ndarray, n: int
) -> None:
    """One slot's belief record [mean (n), covariance (n²), active] at time t (s) from its
    track record [state (2n), covariance ((2n)²), detection time, active, ...]: the
    position block of F P Fᵀ + Q(dt), dt = t − detection time
    (:func:`stt_drake.core.tracking.predicted_position`); mean 0, covariance I inactive."""
    d = 2 * n
    base = d + d * d
    if record[base + 1] <= 0.5:
        out[:] = 0.0
        for i in range(n):
            out[n + i * n + i] = 1.0
        return
    dt = t - record[base]
    for i in range(n):
        out[i] = record[i] + dt * record[n + i]
    noise = density * dt**3 / 3.0
    for i in range(n):
        for k in range(n):
            cross = record[d + i * d + n + k] + record[d + k * d + n + i]
            value = record[d + i * d + k] + dt * cross + dt**2 * record[d + (n + i) * d + n + k]
            out[n + i * n + k] = value + noise if i == k else value
    out[n + n * n] = 1.0


@njit(**_JIT)
def track_belief(
    table: np.ndarray,
    previous: np.ndarray,
    t: float,
    weight: float,
    density: float,
    scale_column: int,
    n: int,
) -> np.ndarray:
    """The `obstacle_belief` port vector at time t (s) from the track records `table`
    (m, record), blended with the belief of `previous` (m, record) by `weight` in [0, 1)
    (1: no blend; :func:`stt_drake.core.tracking.blend_beliefs`). Each slot predicts with
    `density` (m²/s³), times its record's column `scale_column` when ≥ 0 (the adaptive
    noise scale)."""
    count = table.shape[0]
    size = n + n * n + 1
    out = np.empty(count * size)
    old = np.empty(size)
    for j in range(count):
        slot = out[j * size : (j + 1) * size]
        q = density * table[j, scale_column] if scale_column >= 0 else density
        _predicted_slot(table[j], t, q, slot, n)
        if weight >= 1.0 or slot[size - 1] <= 0.5:
            continue
        q = density * previous[j, scale_column] if scale_column >= 0 else density
        _predicted_slot(previous[j], t, q, old, n)
        if old[size - 1] <= 0.5:
            continue
        w = weight
        for i in range(n):
            for k in range(n):
                index = n + i * n + k
                jump = w * (1.0 - w) * (slot[i] - old[i]) * (slot[k] - old[k])
                slot[index] = (1.0 - w) * old[index] + w * slot[index] + jump
        for i in range(n):
            slot[i] = (1.0 - w) * old[i] + w * slot[i]
    return out
