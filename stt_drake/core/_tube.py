"""Compiled (numba) tube law: one call per tube-law evaluation (ċ, r, q, d̂, θ; Eqs. (4),
(5), (8), (14)) and per fixed-rate update (:meth:`stt_drake.core.tube.TubeLaw.advance`).

One driver, :func:`tube_step`, runs the law for both beliefs: the attraction, the loop over
the obstacles, the blend with the escape velocity and the soft-min radius are written once;
the per-obstacle terms (q_j, d̂_j and the direction ∇̂q_j) are the part that varies, chosen
when numba compiles by the rank of the uncertainty argument: σ_j (m,) — isotropic,
:func:`isotropic_obstacle` — or Σ_j (m, n, n) — full covariance, the pruning bounds of
:func:`stt_drake.core._anisotropic_tube.anisotropic_bounds`, then, where they do not decide,
:func:`stt_drake.core._anisotropic_tube.anisotropic_obstacle`. Each specialisation holds only
its own terms (the other branch is pruned before typing), so neither pays for the other. The
per-obstacle functions a pruned obstacle reaches take scalars only: a numba call with array
arguments costs reference counting (~10 ns an array), more than such an obstacle's own work.

The numpy reference is :mod:`stt_drake.core.tube` (and :mod:`stt_drake.core.anisotropic_tube`
for the full covariance's per-obstacle terms); the probability kernels are
:mod:`stt_drake.core._kernels`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from stt_drake.core._anisotropic_tube import (
    anisotropic_bounds,
    anisotropic_obstacle,
    projected_sigma,
)
from stt_drake.core._kernels import (
    _distance,
    chi_isf_given,
    chi_sf,
    largest_variance,
    ndtri,
)
from stt_drake.core.backend import jit_options
from stt_drake.core.constants import BOUNDARY_LAYER, CIRCULATION_MIN_SINE, LAYER_STEP

_JIT = jit_options()
#: Small per-obstacle helpers are inlined into the driver's loop (numba IR inlining: no call
#: per obstacle). Inlining keeps the reference counting of array arguments (:data:`_BORROWING`):
#: the isotropic terms take scalars only.
_INLINE = {**_JIT, "inline": "always"}
#: An acting obstacle's share of ċ is compiled without numba's reference counting (its
#: `_nrt` flag): inlined or called, each array argument would cost an atomic increment and
#: decrement (~9 ns an array, measured: ~60 % of the function). Its arrays are the caller's,
#: borrowed for the call; such a function must not allocate or return an array.
_BORROWING = {**_JIT, "_nrt": False}
#: e^{−x} below half an ulp of 1 (2^−53 ≈ 1.1e-16) for x above this: added to a sum ≥ 1, it
#: leaves the sum unchanged (:func:`soft_min_radius`).
_INVISIBLE_EXPONENT = 37.0

#: Layout of the `constants` array of :func:`tube_step`: k1, r_min, r_max, ν, linear zone δ,
#: prune_above, max_center_speed, then the target η (n); decoded by :func:`tube_constants`.
TUBE_CONSTANTS = (
    "k1",
    "r_min",
    "r_max",
    "nu",
    "linear_zone",
    "prune_above",
    "max_center_speed",
)


@njit(**_JIT)
def tube_constants(
    constants: np.ndarray,
) -> tuple[float, float, float, float, float, float, float, np.ndarray]:
    """The `constants` array (:data:`TUBE_CONSTANTS`, then η) as (k1, r_min, r_max, ν,
    linear zone, prune_above, max_center_speed, η)."""
    return (
        constants[0],
        constants[1],
        constants[2],
        constants[3],
        constants[4],
        constants[5],
        constants[6],
        constants[7:],
    )


@njit(**_INLINE)
def isotropic_obstacle(
    distance: float,
    sigma: float,
    radius: float,
    epsilon: float,
    normal_quantile: float,
    r_min: float,
    prune_above: float,
    inflated: bool,
    reach: float,
    spread: float,
    n: int,
) -> tuple[float, float]:
    """Obstacle j's q_j and d̂_j for Σ_j = σ_j² I at distance ‖c − μ_j‖: q_j (Eq. (5); when
    `inflated`, the period lower bound of :func:`period_avoid_probability` for `reach`,
    `spread`) and d̂_j (Eq. (8), always at the exact belief; the quantile is skipped where
    the bound σ(a − Φ⁻¹(ε)) − r_o already exceeds `prune_above`, and that bound is returned;
    NaN where prune_above = −∞). `normal_quantile` is Φ⁻¹(ε) where the caller has it (a
    task table's), else NaN: it is then computed here, only where d̂ is wanted. Scalars
    only: a call costs no reference counting."""
    a = distance / sigma
    if inflated:
        q = period_avoid_probability(distance, sigma, radius + r_min, reach, spread, n)
    else:
        q = chi_sf((radius + r_min) / sigma, a, n)
    if prune_above == -math.inf:  # ċ, q, θ only: d̂ (and so r) not wanted
        return q, math.nan
    if math.isnan(normal_quantile):  # Φ⁻¹(ε), once for the bound and the quantile
        normal_quantile = ndtri(epsilon)
    lower = sigma * max(a - normal_quantile, 0.0) - radius
    if lower > prune_above:
        return q, lower
    return q, sigma * chi_isf_given(epsilon, a, n, normal_quantile) - radius


@njit(**_JIT)
def tube_step(
    center: np.ndarray,
    mean: np.ndarray,
    uncertainty: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    normal_quantile: np.ndarray | None,
    p_d: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    reach: np.ndarray,
    spread: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
    active: np.ndarray,
) -> np.ndarray:
    """One tube-law evaluation (:meth:`stt_drake.core.tube.TubeLaw.evaluate`) in one pass.

    `uncertainty` is σ_j (m,) for isotropic beliefs (:func:`isotropic_obstacle`) or Σ_j
    (m, n, n) for full covariances, n = 2, 3 (:func:`stt_drake.core._anisotropic_tube.
    anisotropic_obstacle`; `reach`, `spread` must then be empty): per obstacle j those give
    q_j (Eq. (5)), d̂_j (Eq. (8)) and ∇̂q_j; then θ_j, m_j, v_j and ċ (Eq. (4)) over the
    obstacles with q_j > ε_j, saturated at max_center_speed, blended with the escape
    velocity by the largest boundary-layer weight w (ċ = (1 − w)·ċ_law + w·ċ_escape;
    ċ_escape = max_center_speed along Σ_j w_j ∇̂q_j, w = 1 at and below an ε level set: the
    recovery); and the soft-min radius (Eq. (14)). `k2`, `k3` hold one gain per obstacle or
    a single one; `circulation` (m, 3) the chosen axes ω_j in 3D (or empty); `constants` is
    laid out as :data:`TUBE_CONSTANTS` followed by η (few arguments: numba's dispatch costs
    per argument).

    The obstacles may be the slots of a belief port read in place (:func:`_port_pass`):
    `mean` then holds μ_j in its first n columns (the port table), and `active` holds one
    flag per slot (empty: every row is an obstacle); an inactive slot stays at q = 1,
    d̂ = +∞, θ = 0, outside ċ and r.

    `normal_quantile` holds Φ⁻¹(ε_j) per obstacle where the caller has them (a task table's
    fourth column: made once per task, not once per obstacle and evaluation), or is None:
    then each is computed where a pruning bound needs it. None, not an empty array: numba
    compiles a specialisation for it with the test removed (an empty array cost the
    obstacles' path 2-3 %, a per-obstacle branch and an array to count references of).

    Returns:
        (ċ, r, q, d̂, θ) in one array (:func:`step_parts`): one array to box on return
        costs less than four.
    """
    k1, r_min, r_max, nu, linear_zone, prune_above, max_speed, target = tube_constants(constants)
    count, n = mean.shape[0], center.shape[0]
    out = np.empty(n + 1 + 3 * count)
    rate, _radius, q, d_hat, theta = step_parts(out, n)
    theta[:] = 0.0
    work = np.empty(6 * n)  # one allocation for the per-call buffers
    goal = work[:n]
    escape = work[n : 2 * n]
    unit = work[2 * n : 3 * n]
    m = work[3 * n : 4 * n]
    offset = work[4 * n : 5 * n]  # the full covariance's
    along = work[5 * n :]
    escape[:] = 0.0
    share = 0.0  # the largest boundary-layer weight (tube.boundary_layer_weights)
    no_axis = work[:0]
    _attraction(center, target, k1, linear_zone, goal, rate)
    inflated = reach.shape[0] == count
    flagged = active.shape[0] == count
    for j in range(count):
        if flagged and not active[j] > 0.5:
            q[j] = 1.0
            d_hat[j] = math.inf
            continue
        # Φ⁻¹(ε_j), or NaN: computed below (the test is pruned when numba compiles)
        quantile = math.nan if normal_quantile is None else normal_quantile[j]
        if uncertainty.ndim == 1:
            distance = _distance(center, mean, j)
            qj, dj = isotropic_obstacle(
                distance,
                uncertainty[j],
                radius[j],
                epsilon[j],
                quantile,
                r_min,
                prune_above,
                inflated,
                reach[j] if inflated else 0.0,
                spread[j] if inflated else 0.0,
                n,
            )
            acts = qj <= p_d[j]
            if acts:  # ∇̂q_j = (c − μ_j)/‖c − μ_j‖ for Σ_j = σ_j² I
                for i in range(n):
                    unit[i] = (center[i] - mean[j, i]) / distance if distance > 0.0 else 0.0
        else:
            distance = 0.0
            for i in range(n):
                offset[i] = center[i] - mean[j, i]
                distance += offset[i] * offset[i]
            distance = math.sqrt(distance)
            sigma_u = projected_sigma(offset, uncertainty, j, distance)
            qj, dj = anisotropic_bounds(
                distance, sigma_u, radius[j], epsilon[j], quantile, r_min, prune_above
            )
            acts = False
            if qj <= p_d[j] or dj <= prune_above:  # a bound does not decide
                qj, dj, acts = anisotropic_obstacle(
                    offset,
                    distance,
                    uncertainty[j],
                    radius[j],
                    epsilon[j],
                    p_d[j],
                    r_min,
                    qj,
                    dj,
                    prune_above,
                    along,
                    unit,
                )
        q[j] = qj
        d_hat[j] = dj
        if acts:
            axis = circulation[j] if circulation.shape[0] == count else no_axis
            theta[j], weight = _obstacle_terms(
                rate,
                escape,
                m,
                unit,
                distance,
                qj,
                epsilon[j],
                p_d[j],
                k2,
                k3,
                j,
                axis,
                goal,
                max_speed,
            )
            share = max(share, weight)
    _finish_rate(rate, share, escape, goal, max_speed)
    out[n] = soft_min_radius(d_hat, r_max, nu)
    return out


@njit(**_JIT)
def step_parts(
    out: np.ndarray, n: int
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """(ċ, r, q, d̂, θ) of a :func:`tube_step` result `out` laid out as [ċ (n), r, q (m),
    d̂ (m), θ (m)] (views; :func:`stt_drake.core.tube_terms.evaluation_of` in Python)."""
    count = (out.shape[0] - n - 1) // 3
    return (
        out[:n],
        out[n],
        out[n + 1 : n + 1 + count],
        out[n + 1 + count : n + 1 + 2 * count],
        out[n + 1 + 2 * count :],
    )


@njit(**_JIT)
def exact_tube_step(
    center: np.ndarray,
    mean: np.ndarray,
    uncertainty: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    p_d: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
) -> np.ndarray:
    """:func:`tube_step` at the belief itself (no period inflation): σ_j (m,) or Σ_j
    (m, n, n), n = 2, 3 (the rules and bounds of :mod:`stt_drake.core.anisotropic_tube`;
    there q_j and d̂_j are the pruning lower bounds where those decided)."""
    no_inflation = np.empty(0)
    return tube_step(
        center,
        mean,
        uncertainty,
        radius,
        epsilon,
        None,
        p_d,
        k2,
        k3,
        no_inflation,
        no_inflation,
        circulation,
        constants,
        no_inflation,  # no activity flags: every obstacle acts
    )


@njit(**_JIT)
def _attraction(
    center: np.ndarray,
    target: np.ndarray,
    k1: float,
    linear_zone: float,
    goal: np.ndarray,
    rate: np.ndarray,
) -> None:
    """goal = η − c and rate = the attraction k1·∛(η − c) of Eq. (4), linear inside the
    zone |e_i| < linear_zone (the tube laws' first term)."""
    for i in range(center.shape[0]):
        e = target[i] - center[i]
        goal[i] = e
        if linear_zone > 0.0 and abs(e) < linear_zone:
            rate[i] = k1 * e * linear_zone ** (-2.0 / 3.0)
        else:
            rate[i] = k1 * np.cbrt(e)


@njit(**_BORROWING)
def _obstacle_terms(
    rate: np.ndarray,
    escape: np.ndarray,
    m: np.ndarray,
    unit: np.ndarray,
    distance: float,
    q: float,
    epsilon: float,
    p_d: float,
    k2: np.ndarray,
    k3: np.ndarray,
    j: int,
    axis: np.ndarray,
    goal: np.ndarray,
    max_speed: float,
) -> tuple[float, float]:
    """Obstacle j's share of ċ where q_j ≤ p_d_j, with `unit` = ∇̂q_j (c − μ_j normalised
    for an isotropic belief; zero where undefined): θ_j = 1/q_j − 1/p_d_j; its
    boundary-layer weight w_j adds w_j·unit to `escape`; above ε_j,
    m_j = ‖c − μ_j‖·unit/(q_j − ε_j) adds k2·θ_j·m_j + k3·θ_j·v_j (v_j ⟂ m_j) to `rate`
    (Eq. (4)). Returns (θ_j, w_j); in recovery θ_j is reported at its largest in-law
    value 1/ε_j − 1/p_d_j."""
    n = rate.shape[0]
    if max_speed < math.inf:
        weight = _layer_weight(q, epsilon, p_d)
    else:  # unbounded: no layer, only the recovery
        weight = 1.0 if q <= epsilon else 0.0
    if weight > 0.0:
        for i in range(n):
            escape[i] += weight * unit[i]
    if q <= epsilon:
        return 1.0 / epsilon - 1.0 / p_d, weight
    th = 1.0 / q - 1.0 / p_d
    scale = distance / (q - epsilon)
    for i in range(n):
        m[i] = scale * unit[i]
    gain2 = k2[j] if k2.shape[0] > 1 else k2[0]
    gain3 = k3[j] if k3.shape[0] > 1 else k3[0]
    for i in range(n):
        rate[i] += gain2 * th * m[i]
    if gain3 != 0.0:
        _add_null_space(rate, m, goal, axis, gain3 * th)
    return th, weight


@njit(**_INLINE)
def _add_null_space(
    rate: np.ndarray, m: np.ndarray, goal: np.ndarray, circulation: np.ndarray, weight: float
) -> None:
    """rate += weight·v, v ⟂ m with |v| = |m|
    (:func:`stt_drake.core.circulation.null_space_direction`): n = 2, m rotated by +90°;
    n ≥ 3, along ω × m for a chosen circulation axis ω (zero: not chosen), else the part of
    the goal direction orthogonal to m, else of e_{n−1}, else of
    e_0 (the first whose orthogonal part is not degenerate)."""
    n = m.shape[0]
    if n == 1:
        return
    if n == 2:
        rate[0] -= weight * m[1]
        rate[1] += weight * m[0]
        return
    norm_m = 0.0
    for i in range(n):
        norm_m += m[i] * m[i]
    norm_m = math.sqrt(norm_m)
    scale = norm_m if norm_m > 0.0 else 1.0
    if n == 3 and circulation.shape[0] == 3:
        cx = circulation[1] * m[2] - circulation[2] * m[1]
        cy = circulation[2] * m[0] - circulation[0] * m[2]
        cz = circulation[0] * m[1] - circulation[1] * m[0]
        length = math.sqrt(cx * cx + cy * cy + cz * cz)
        if length > CIRCULATION_MIN_SINE * scale:
            factor = weight * norm_m / length
            rate[0] += factor * cx
            rate[1] += factor * cy
            rate[2] += factor * cz
            return
    for which in range(3):  # the candidate: goal, e_{n−1}, e_0 (no buffer: no allocation)
        unit_axis = -1 if which == 0 else (n - 1 if which == 1 else 0)
        size = 1.0
        if which == 0:
            size = 0.0
            for i in range(n):
                size += goal[i] * goal[i]
            size = math.sqrt(size)
        dot = 0.0
        for i in range(n):
            dot += _candidate(goal, unit_axis, i) * m[i] / scale
        length = 0.0
        for i in range(n):
            o = _candidate(goal, unit_axis, i) - dot * m[i] / scale
            length += o * o
        length = math.sqrt(length)
        if length > 1e-6 * max(size, 1e-300):
            factor = weight * norm_m / length
            for i in range(n):
                rate[i] += factor * (_candidate(goal, unit_axis, i) - dot * m[i] / scale)
            return


@njit(**_INLINE)
def _candidate(goal: np.ndarray, unit_axis: int, i: int) -> float:
    """Component i of :func:`_add_null_space`'s candidate direction: the goal direction
    (`unit_axis` −1), else the unit vector e_{unit_axis}."""
    if unit_axis < 0:
        return goal[i]
    return 1.0 if i == unit_axis else 0.0


@njit(**_JIT)
def _layer_weight(q: float, epsilon: float, p_d: float) -> float:
    """One obstacle's :func:`stt_drake.core.tube.boundary_layer_weights`."""
    return min(max(1.0 - (q - epsilon) / (BOUNDARY_LAYER * (p_d - epsilon)), 0.0), 1.0)


@njit(**_JIT)
def _finish_rate(
    rate: np.ndarray, share: float, escape: np.ndarray, goal: np.ndarray, max_speed: float
) -> None:
    """Saturate ċ at max_speed, then blend it with the escape velocity by the largest
    boundary-layer weight `share`: ċ = (1 − w)·ċ_law + w·ċ_escape (tube module docstring)."""
    _saturate(rate, max_speed)
    if share > 0.0:
        blended = np.empty(rate.shape[0])
        _recovery_velocity(blended, escape, goal, max_speed)
        if share == 1.0:
            rate[:] = blended
            return
        for i in range(rate.shape[0]):
            rate[i] = (1.0 - share) * rate[i] + share * blended[i]


@njit(**_JIT)
def _saturate(rate: np.ndarray, max_speed: float) -> None:
    """Scale `rate` down to norm `max_speed` if it is faster (|ċ| ≤ max_center_speed)."""
    size = 0.0
    for i in range(rate.shape[0]):
        size += rate[i] * rate[i]
    size = math.sqrt(size)
    if size > max_speed:
        for i in range(rate.shape[0]):
            rate[i] *= max_speed / size


@njit(**_JIT)
def _recovery_velocity(
    rate: np.ndarray, escape: np.ndarray, goal: np.ndarray, max_speed: float
) -> None:
    """rate = max_speed·escape/‖escape‖; when the escape directions cancel (a symmetric
    squeeze, or c on a mean), the goal direction's, else e_0's."""
    n = rate.shape[0]
    for direction in (escape, goal):
        size = 0.0
        for i in range(n):
            size += direction[i] * direction[i]
        size = math.sqrt(size)
        if size > 1e-9:
            for i in range(n):
                rate[i] = max_speed * direction[i] / size
            return
    rate[:] = 0.0
    rate[0] = max_speed


@njit(**_JIT)
def soft_min_radius(d_hat: np.ndarray, r_max: float, nu: float) -> float:
    """r = −(1/ν) ln(e^{−ν r_max} + Σ_j e^{−ν d̂_j}) (Eq. (14)), shifted by the minimum;
    NaN if any d̂_j is NaN.

    The sum starts at the smallest argument's term, e^0 = 1 (the terms reordered), so it
    stays ≥ 1: a term below e^{−37} ≈ 8.5e-17, under half an ulp of 1, cannot change it
    and is skipped, exactly (a pruned d̂_j is always such a term: no exp for it)."""
    smallest = r_max
    nearest = -1  # the index of the smallest d̂_j; −1: r_max is the smallest
    for j in range(d_hat.shape[0]):
        d = d_hat[j]
        if math.isnan(d):
            return math.nan
        if d < smallest:
            smallest = d
            nearest = j
    total = 1.0
    if nearest >= 0:
        exponent = nu * (r_max - smallest)
        if exponent < _INVISIBLE_EXPONENT:
            total += math.exp(-exponent)
    for j in range(d_hat.shape[0]):
        exponent = nu * (d_hat[j] - smallest)
        if exponent < _INVISIBLE_EXPONENT and j != nearest:
            total += math.exp(-exponent)
    return smallest - math.log(total) / nu


@njit(**_JIT)
def period_avoid_probability(
    distance: float, sigma: float, radius: float, reach: float, spread: float, n: int
) -> float:
    """Lower bound of P(‖x − O‖ ≥ radius) over the beliefs reachable within a horizon
    (:func:`stt_drake.core.probability.period_avoid_probability`): the offset shrinks by
    `reach` and the radius grows by spread·(distance + reach + radius)."""
    offset = distance - reach
    if offset < 0.0:
        offset = 0.0
    grown = radius + spread * (distance + reach + radius)
    return chi_sf(grown / sigma, offset / sigma, n)


@njit(**_JIT)
def tube_step_obstacles(
    center: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    p_d: np.ndarray,
    law: np.ndarray,
) -> np.ndarray:
    """:func:`tube_step` for isotropic obstacles given as arrays (one per obstacle), without
    circulation, inflation or slot flags, with the law's k2, k3 and constants
    (:meth:`stt_drake.core.tube.TubeLaw.kernel_arguments`) packed once per law in `law` as
    [len(k2), len(k3), k2, k3, constants]: 7 arguments where :func:`tube_step` takes 14
    (numba's dispatch costs ~50 ns an argument, a tenth of a typical 50-obstacle step)."""
    k2_end = 2 + int(law[0])
    k3_end = k2_end + int(law[1])
    none = sigma[:0]
    return tube_step(
        center,
        mean,
        sigma,
        radius,
        epsilon,
        None,
        p_d,
        law[2:k2_end],
        law[k2_end:k3_end],
        none,
        none,
        mean[:0],
        law[k3_end:],
        none,
    )


# --------------------------------------------------------------------------- belief port
@njit(**_JIT)
def tube_step_packed(
    center: np.ndarray,
    belief: np.ndarray,
    task: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
) -> np.ndarray:
    """:func:`tube_step` on a belief port vector and the task rows ([r_o, ε, p_d, Φ⁻¹(ε)]),
    read in place slot by slot, σ_j = √λ_max(Σ_j); q = 1, d̂ = +∞, θ = 0 in the inactive
    slots (they never reach ċ or r); laid out as :func:`tube_step`'s result."""
    n = center.shape[0]
    table = belief.reshape((-1, n + n * n + 1))
    sigma = _slot_sigmas(table, n)
    return _port_pass(center, table, sigma, task, k2, k3, circulation, constants)


@njit(**_JIT)
def _slot_sigmas(table: np.ndarray, n: int) -> np.ndarray:
    """σ_j = √λ_max(Σ_j) of every active slot of a port `table` (0 in an inactive one,
    whose σ is never read)."""
    sigma = np.zeros(table.shape[0])
    for j in range(table.shape[0]):
        if table[j, n + n * n] > 0.5:
            sigma[j] = math.sqrt(largest_variance(table, j, n))
    return sigma


@njit(**_JIT)
def exact_tube_step_packed(
    center: np.ndarray,
    belief: np.ndarray,
    task: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
) -> np.ndarray:
    """:func:`tube_step_packed` with each active slot's Σ_j exactly (:func:`exact_tube_step`):
    the port vector is read here, so a tube with full covariances pays no unpacking."""
    n = center.shape[0]
    table = belief.reshape((-1, n + n * n + 1))
    covariance = np.empty((table.shape[0], n, n))
    for j in range(table.shape[0]):
        for i in range(n):
            for column in range(n):
                covariance[j, i, column] = table[j, n + i * n + column]
    return _port_pass(center, table, covariance, task, k2, k3, circulation, constants)


@njit(**_JIT)
def _port_pass(
    center: np.ndarray,
    table: np.ndarray,
    uncertainty: np.ndarray,
    task: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
) -> np.ndarray:
    """:func:`tube_step` over the slots of a port `table` (μ in its first n columns, the
    activity flag last) with their σ_j or Σ_j and task rows ([r_o, ε, p_d, Φ⁻¹(ε)]:
    :meth:`stt_drake.core.belief.ObstacleTask.table`): nothing is copied per slot."""
    no_inflation = task[:0, 0]
    return tube_step(
        center,
        table,
        uncertainty,
        task[:, 0],
        task[:, 1],
        task[:, 3],
        task[:, 2],
        k2,
        k3,
        no_inflation,
        no_inflation,
        circulation,
        constants,
        table[:, table.shape[1] - 1],
    )


# --------------------------------------------------------------------------- fixed-rate update
#: The per-obstacle helpers of the update's bounds below are inlined into its loops (as
#: ‖x − μ_j‖ is everywhere): called per obstacle they took ~7 of its 19 µs (50 obstacles).


@njit(**_JIT)
def _inflation(
    sigma: np.ndarray, mean_speed: np.ndarray, sigma_rate: np.ndarray, horizon: float
) -> tuple[np.ndarray, np.ndarray]:
    """(reach, spread) of :meth:`stt_drake.core.fixed_rate.BeliefRateBounds.inflation`."""
    reach = mean_speed * horizon
    spread = np.empty(sigma.shape[0])
    for j in range(sigma.shape[0]):
        low = sigma[j] - sigma_rate[j] * horizon
        spread[j] = sigma[j] / low - 1.0 if low > 0.0 else math.inf
    return reach, spread


@njit(**_INLINE)
def _segment_distances(
    start: np.ndarray, end: np.ndarray, mean: np.ndarray, j: int
) -> tuple[float, float]:
    """:func:`stt_drake.core.probability.segment_distances` for obstacle j."""
    length2 = 0.0
    along = 0.0
    for i in range(start.shape[0]):
        chord = end[i] - start[i]
        length2 += chord * chord
        along += (mean[j, i] - start[i]) * chord
    fraction = along / length2 if length2 > 0.0 else 0.0
    fraction = min(max(fraction, 0.0), 1.0)
    nearest = 0.0
    for i in range(start.shape[0]):
        d = start[i] + fraction * (end[i] - start[i]) - mean[j, i]
        nearest += d * d
    farthest = max(_distance(start, mean, j), _distance(end, mean, j))
    return math.sqrt(nearest), farthest


@njit(**_INLINE)
def _segment_avoid_lower_bound(
    nearest: float,
    farthest: float,
    sigma: float,
    radius: float,
    reach: float,
    spread: float,
    n: int,
) -> float:
    """:func:`stt_drake.core.probability.segment_avoid_lower_bound` for an obstacle at
    `nearest` and `farthest` from the segment (:func:`_segment_distances`)."""
    grown = radius + spread * (farthest + reach + radius)
    offset = nearest - reach
    return chi_sf(grown / sigma, (offset if offset > 0.0 else 0.0) / sigma, n)


@njit(**_INLINE)
def _segment_quantile_lower_bound(
    nearest: float,
    farthest: float,
    sigma: float,
    radius: float,
    epsilon: float,
    normal_quantile: float,
    reach: float,
    spread: float,
    prune_above: float,
    n: int,
) -> float:
    """:func:`stt_drake.core.probability.segment_quantile_lower_bound` for an obstacle at
    `nearest` and `farthest` from the segment (`normal_quantile` = Φ⁻¹(ε)); where the cheap
    bound σ·max(a − Φ⁻¹(ε), 0) already gives more than `prune_above`, that bound."""
    offset = max(nearest - reach, 0.0) / sigma
    penalty = spread * (farthest + reach)
    cheap = (sigma * max(offset - normal_quantile, 0.0) - penalty) / (1.0 + spread) - radius
    if cheap > prune_above:
        return cheap
    quantile = chi_isf_given(epsilon, offset, n, normal_quantile)
    return (sigma * quantile - penalty) / (1.0 + spread) - radius


@njit(**_JIT)
def tube_advance(
    center: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    p_d: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    mean_speed: np.ndarray,
    sigma_rate: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
    prune_above: float,
    duration: float,
    start_radius: float,
    max_attempts: int,
) -> tuple[np.ndarray, np.ndarray, int, float, float, np.ndarray]:
    """:func:`_advance` on the obstacles' arrays, with Φ⁻¹(ε_j) computed here."""
    normal_quantile = np.empty(epsilon.shape[0])
    for j in range(epsilon.shape[0]):
        normal_quantile[j] = ndtri(epsilon[j])
    return _advance(
        center,
        mean,
        sigma,
        radius,
        epsilon,
        normal_quantile,
        p_d,
        k2,
        k3,
        mean_speed,
        sigma_rate,
        circulation,
        constants,
        prune_above,
        duration,
        start_radius,
        max_attempts,
    )


@njit(**_JIT)
def _advance(
    center: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    normal_quantile: np.ndarray,
    p_d: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    mean_speed: np.ndarray,
    sigma_rate: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
    prune_above: float,
    duration: float,
    start_radius: float,
    max_attempts: int,
) -> tuple[np.ndarray, np.ndarray, int, float, float, np.ndarray]:
    """:meth:`stt_drake.core.tube.TubeLaw.advance` in one call (same steps, same rules):
    sub-steps of the law with the look-ahead bound over 2·duration, each keeping every
    positive gap at least half and every boundary-layer weight within LAYER_STEP; then the
    segment certificate over one duration, pulled back (to the earlier sub-steps' ends, then
    halved towards `center`) until it holds and the end radius the segment allows
    (:func:`_end_radius_bound`, from `start_radius`; NaN: the first update) stays ≥ r_min;
    then the radius at both ends of the period. `constants` must skip the
    quantiles of the law (prune_above = −∞); `prune_above` is the law's own (the
    radius bounds use it); `normal_quantile` holds Φ⁻¹(ε_j), which every quantile bound
    reads.

    Returns:
        (c_{k+1}, certified (m,) booleans, accepted sub-steps, r at the start and at the
        end of the period, θ_j at c_{k+1} with the belief itself).
    """
    count, n = mean.shape[0], center.shape[0]  # `mean` may be a port table (μ first)
    k1, r_min, r_max, nu, _zone, _prune, max_speed, target = tube_constants(constants)
    reach2, spread2 = _inflation(sigma, mean_speed, sigma_rate, 2.0 * duration)
    position = center.copy()
    # tube_step's arguments after the point: the look-ahead law, every obstacle acting
    look_ahead = (mean, sigma, radius, epsilon, None, p_d, k2, k3, reach2, spread2)
    look_ahead = (*look_ahead, circulation, constants, reach2[:0])
    step_out = tube_step(position, *look_ahead)
    rate, _r, q, _d, theta = step_parts(step_out, n)
    remaining = duration
    step = duration
    accepted = 0
    candidate = np.empty(n)
    path = np.empty((max_attempts + 1, n))  # the accepted sub-steps' ends, path[0] = c_k
    path[0] = center
    for _attempt in range(max_attempts):
        if remaining <= 1e-12 * duration or step < duration * 2.0**-30:
            break
        step = min(step, remaining)
        acting = False
        for j in range(count):
            if theta[j] > 0.0:
                acting = True
        if acting:
            for i in range(n):
                candidate[i] = position[i] + step * rate[i]
        else:  # the exact attraction flow (Eq. (13)), capped at max_speed·step
            length = 0.0
            for i in range(n):
                e = target[i] - position[i]
                left = abs(e) ** (2.0 / 3.0) - (2.0 / 3.0) * k1 * step
                move = e - math.copysign(max(left, 0.0) ** 1.5, e)
                candidate[i] = move
                length += move * move
            length = math.sqrt(length)
            scale = max_speed * step / length if length > max_speed * step else 1.0
            for i in range(n):
                candidate[i] = position[i] + scale * candidate[i]
        candidate_out = tube_step(candidate, *look_ahead)
        rate_c, _r, q_c, _d, theta_c = step_parts(candidate_out, n)
        keeps = True
        for j in range(count):
            gap = q[j] - epsilon[j]
            if gap > 0.0 and q_c[j] - epsilon[j] < 0.5 * gap:
                keeps = False
            if max_speed < math.inf:  # resolve the boundary layer (tube.LAYER_STEP)
                change = _layer_weight(q_c[j], epsilon[j], p_d[j]) - _layer_weight(
                    q[j], epsilon[j], p_d[j]
                )
                if abs(change) > LAYER_STEP:
                    keeps = False
        if keeps:
            position = candidate.copy()
            rate, q, theta = rate_c, q_c, theta_c
            remaining -= step
            accepted += 1
            path[accepted] = position
            step *= 2.0
        else:
            step *= 0.5
    reach1, spread1 = _inflation(sigma, mean_speed, sigma_rate, duration)
    must_hold = np.empty(count, dtype=np.bool_)
    for j in range(count):
        start_q = period_avoid_probability(
            _distance(center, mean, j), sigma[j], radius[j] + r_min, reach1[j], spread1[j], n
        )
        must_hold[j] = start_q - epsilon[j] > 0.0
    at_start = _point_quantile_lower_bounds(
        center, mean, sigma, radius, epsilon, normal_quantile, reach1, spread1, prune_above
    )
    smallest = math.inf  # min over the obstacles (none: inf, as the reference's initial)
    for j in range(count):
        smallest = min(smallest, at_start[j])
    if not start_radius <= smallest:  # the first update (NaN), or a belief jump
        start_radius = soft_min_radius(at_start, r_max, nu)
    certified = np.empty(count, dtype=np.bool_)
    allowed = np.empty(count)
    holds = False
    back = accepted  # the segment ends at path[back] until that is the first sub-step
    for _pull in range(accepted + 60):
        holds = True
        length = 0.0
        for i in range(n):
            length += (position[i] - center[i]) ** 2
        length = math.sqrt(length)
        for j in range(count):
            nearest, farthest = _segment_distances(center, position, mean, j)
            lower = _segment_avoid_lower_bound(
                nearest, farthest, sigma[j], radius[j] + r_min, reach1[j], spread1[j], n
            )
            certified[j] = lower - epsilon[j] > 0.0
            on_segment = _segment_quantile_lower_bound(
                nearest,
                farthest,
                sigma[j],
                radius[j],
                epsilon[j],
                normal_quantile[j],
                reach1[j],
                spread1[j],
                prune_above,
                n,
            )
            allowed[j] = _end_radius_bound(start_radius, at_start[j], on_segment, length)
            if must_hold[j] and not (certified[j] and allowed[j] >= r_min):
                holds = False
        if holds:
            break
        if back > 1:  # an earlier sub-step's end: the path's chords cut less inward
            back -= 1
            position = path[back].copy()
        else:
            for i in range(n):
                position[i] = center[i] + 0.5 * (position[i] - center[i])
    if not holds:
        position = center.copy()
        certified[:] = must_hold
        allowed[:] = at_start
    ahead = np.minimum(
        _point_quantile_lower_bounds(
            position, mean, sigma, radius, epsilon, normal_quantile, reach2, spread2, prune_above
        ),
        allowed,
    )
    end_radius = soft_min_radius(ahead, r_max, nu)
    theta_end = step_parts(
        exact_tube_step(
            position, mean, sigma, radius, epsilon, p_d, k2, k3, circulation, constants
        ),
        n,
    )[4]
    return position, certified, accepted, start_radius, end_radius, theta_end


@njit(**_JIT)
def tube_advance_packed(
    center: np.ndarray,
    belief: np.ndarray,
    task: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    mean_speed: np.ndarray,
    sigma_rate: np.ndarray,
    circulation: np.ndarray,
    constants: np.ndarray,
    prune_above: float,
    duration: float,
    start_radius: float,
    max_attempts: int,
) -> tuple[np.ndarray, np.ndarray, int, float, float, np.ndarray]:
    """:func:`tube_advance` on a belief port vector whose slots are all active and the task
    rows (:meth:`stt_drake.core.belief.ObstacleTask.table`, Φ⁻¹(ε_j) included), read in
    place as :func:`tube_step_packed` reads them: a fixed-rate update copies nothing."""
    n = center.shape[0]
    table = belief.reshape((-1, n + n * n + 1))
    return _advance(
        center,
        table,
        _slot_sigmas(table, n),
        task[:, 0],
        task[:, 1],
        task[:, 3],
        task[:, 2],
        k2,
        k3,
        mean_speed,
        sigma_rate,
        circulation,
        constants,
        prune_above,
        duration,
        start_radius,
        max_attempts,
    )


@njit(**_JIT)
def _point_quantile_lower_bounds(
    point: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    radius: np.ndarray,
    epsilon: np.ndarray,
    normal_quantile: np.ndarray,
    reach: np.ndarray,
    spread: np.ndarray,
    prune_above: float,
) -> np.ndarray:
    """Per obstacle, the lower bound of d̂_j at `point` over the horizon of (reach, spread):
    :func:`_segment_quantile_lower_bound` of the segment [point, point]."""
    bounds = np.empty(mean.shape[0])
    for j in range(mean.shape[0]):
        distance = _distance(point, mean, j)  # both ends of [point, point]
        bounds[j] = _segment_quantile_lower_bound(
            distance,
            distance,
            sigma[j],
            radius[j],
            epsilon[j],
            normal_quantile[j],
            reach[j],
            spread[j],
            prune_above,
            point.shape[0],
        )
    return bounds


@njit(**_JIT)
def _end_radius_bound(
    start_radius: float, at_start: float, on_segment: float, length: float
) -> float:
    """:func:`stt_drake.core.fixed_rate.end_radius_bound` for one obstacle."""
    lipschitz = at_start - length
    if lipschitz >= on_segment:
        return lipschitz
    if start_radius <= on_segment:
        return on_segment
    return start_radius - (start_radius - on_segment) * length / (at_start - on_segment)
