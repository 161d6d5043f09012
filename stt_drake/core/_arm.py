"""Compiled (numba) kernel of the arm's funnel law
(:meth:`stt_drake.core.arm.ArmFunnelLaw.evaluate`).

The numpy reference in :mod:`stt_drake.core.arm` runs stage 1, the damped least-squares
mapping and stage 2 as some forty small numpy calls (~50 µs per evaluation, almost all of
it call overhead); this is the same arithmetic, in the same order, as one native call. The
SVD of the (3, 7) Jacobian is LAPACK's, as in numpy (``np.linalg.svd``, gesdd), so the two
paths differ by rounding only; a test compares them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from stt_drake.core._kernels import _rho, funnel_control
from stt_drake.core.backend import jit_options

_JIT = jit_options()


@njit(**_JIT)
def arm_control(
    t: float,
    position: np.ndarray,
    q: np.ndarray,
    v: np.ndarray,
    jacobian: np.ndarray,
    center: np.ndarray,
    radius: float,
    kappa: np.ndarray,
    funnel_start: np.ndarray,
    funnel_end: np.ndarray,
    funnel_rate: np.ndarray,
    saturation: float,
    damping: float,
    posture: np.ndarray,
    posture_gain: float,
    position_lower: np.ndarray,
    position_upper: np.ndarray,
    limit_margin: float,
    limit_gain: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """Stage 1, the mapping and stage 2 of the arm law (:mod:`stt_drake.core.arm`).

    Stage 1: e₁ = ‖y − c‖/r, v_ref = −κ₁ ρ(e₁)(y − c). Mapping: J = U diag(s) Vᵀ,
    q̇_ref = V diag(s/(s² + λ²)) Uᵀ v_ref + z − V Vᵀ z with the null-space velocity
    z = −k_p (q − posture) + k_l (clip((m − (q − q_lo))/m, 0, 1) − clip((m − (q_hi − q))/m, 0, 1)).
    Stage 2: γ = (p − q_γ)e^{−μt} + q_γ, e₂ = (q̇ − q̇_ref)/γ, τ = −κ₂ ξ ρ(e₂) with
    ξ = 4/(γ(1 − e₂²)) (e₂ saturated at ±`saturation` in ξ and ρ). The funnel arrays are
    the (m,) per-joint p, q_γ, μ.

    Returns:
        (τ (m,), v_ref (n,), q̇_ref (m,), normalised errors [e₁, e₂ (m)] before saturation,
        whether the inputs are finite and their shapes agree; when not, the other values
        are meaningless and the caller runs the numpy reference, which reports the problem).
    """
    n = position.shape[0]
    m = q.shape[0]
    torque = np.empty(m)
    joint = np.empty(m)
    errors = np.empty(1 + m)
    shapes = (
        center.shape[0] == n
        and jacobian.shape[0] == n
        and jacobian.shape[1] == m
        and v.shape[0] == m
        and posture.shape[0] == m
        and position_lower.shape[0] == m
        and position_upper.shape[0] == m
        and funnel_start.shape[0] == m
        and funnel_end.shape[0] == m
        and funnel_rate.shape[0] == m
    )
    if not shapes:
        return torque, np.empty(n), joint, errors, False
    # stage 1: the one-stage funnel law (it also checks that t, r, y and c are finite)
    no_funnel = np.empty((0, n))
    task, stage_one, finite = funnel_control(
        t, position, center, radius, kappa[:1], no_funnel, no_funnel, no_funnel, saturation
    )
    errors[0] = stage_one[0]
    for values in (q, v):
        finite = finite and np.all(np.isfinite(values))
    if not (finite and np.all(np.isfinite(jacobian))):
        return torque, task, joint, errors, False
    # mapping
    u, s, vt = np.linalg.svd(jacobian, full_matrices=False)
    z = np.empty(m)
    for j in range(m):
        below = min(max((limit_margin - (q[j] - position_lower[j])) / limit_margin, 0.0), 1.0)
        above = min(max((limit_margin - (position_upper[j] - q[j])) / limit_margin, 0.0), 1.0)
        z[j] = -posture_gain * (q[j] - posture[j]) + limit_gain * (below - above)
    # Uᵀ v_ref and Vᵀ z as loops: BLAS calls cost more than the arithmetic at this size.
    weights = np.zeros(s.shape[0])
    along = np.zeros(s.shape[0])
    for k in range(s.shape[0]):
        for i in range(n):
            weights[k] += u[i, k] * task[i]
        weights[k] *= s[k] / (s[k] * s[k] + damping**2)
        for j in range(m):
            along[k] += vt[k, j] * z[j]
    for j in range(m):
        mapped = 0.0
        projected = 0.0
        for k in range(s.shape[0]):
            mapped += vt[k, j] * weights[k]
            projected += vt[k, j] * along[k]
        joint[j] = mapped + z[j] - projected
    # stage 2
    for j in range(m):
        gamma = (funnel_start[j] - funnel_end[j]) * math.exp(-funnel_rate[j] * t) + funnel_end[j]
        e = (v[j] - joint[j]) / gamma
        errors[1 + j] = e
        clipped = min(max(e, -saturation), saturation)
        xi = 4.0 / (gamma * (1.0 - clipped * clipped))
        torque[j] = -kappa[1] * xi * _rho(e, saturation)
    return torque, task, joint, errors, True
