"""The 3D null-space direction v_j of Eq. (4) and its circulation axes.

In 3D, v_j ⟂ m_j cannot be a continuous function of m_j alone on the whole sphere (the
hairy-ball theorem), which is why the goal-based choice flipped across the
obstacle–target line. The law therefore takes a circulation axis ω_j per obstacle, chosen
once when obstacle j activates (ω = m̂ × (η − c), so v_j starts along the goal) and carried
along while it stays active (:func:`carry_circulation`): v_j = |m_j|·(ω_j × m̂_j)/|ω_j × m̂_j|.
"""

from __future__ import annotations

import numpy as np

from stt_drake.core import backend
from stt_drake.core.constants import CIRCULATION_MIN_SINE


def null_space_direction(
    m: np.ndarray, goal_direction: np.ndarray, circulation: np.ndarray | None = None
) -> np.ndarray:
    """v_j ⟂ m_j with |v_j| = |m_j| (rows are obstacles).

    n = 2: m rotated by +90°. n = 3 with a circulation axis ω_j (row of `circulation`, zero
    = none chosen): along ω_j × m_j. Otherwise (n ≥ 3): the part of the goal direction
    orthogonal to m, falling back to a fixed axis (e_z, then e_x) where the goal direction
    is parallel to m. n = 1: zero (R¹ has no orthogonal direction).
    """
    count, dimension = m.shape
    if dimension == 1:
        return np.zeros_like(m)
    if dimension == 2:
        return np.column_stack([-m[:, 1], m[:, 0]])
    norm_m = np.linalg.norm(m, axis=1, keepdims=True)
    unit_m = m / np.where(norm_m > 0.0, norm_m, 1.0)
    direction = np.empty_like(m)
    chosen = np.zeros(count, dtype=bool)
    if dimension == 3 and circulation is not None and len(circulation) == count:
        turned = np.cross(circulation, unit_m)
        length = np.linalg.norm(turned, axis=1)
        chosen = length > CIRCULATION_MIN_SINE
        direction[chosen] = turned[chosen] / length[chosen, None]
    candidates = [np.broadcast_to(goal_direction, m.shape)]
    for axis in (dimension - 1, 0):
        candidates.append(np.broadcast_to(np.eye(dimension)[axis], m.shape))
    for candidate in candidates:
        orthogonal = candidate - np.sum(candidate * unit_m, axis=1, keepdims=True) * unit_m
        length = np.linalg.norm(orthogonal, axis=1)
        usable = ~chosen & (length > 1e-6 * np.maximum(np.linalg.norm(candidate, axis=1), 1e-300))
        direction[usable] = orthogonal[usable] / length[usable, None]
        chosen |= usable
    return direction * norm_m


def carry_circulation(
    axes: np.ndarray, center: np.ndarray, mean: np.ndarray, active: np.ndarray, goal: np.ndarray
) -> np.ndarray:
    """The circulation axes ω_j (rows, 3D) after one step: zero where obstacle j is not
    active (θ_j = 0); chosen as m̂_j × (η − c) where it has just activated (falling back to
    m̂ × e_z, then m̂ × e_x, when the goal lies along m̂); otherwise carried along, i.e. made
    orthogonal to the current m̂_j again and renormalised (re-chosen where |ω_j × m̂_j| is
    at most :data:`CIRCULATION_MIN_SINE`: there the law had stopped using ω_j for the goal
    rule). m̂_j = (c − μ_j)/‖c − μ_j‖ has the direction of m_j for an isotropic belief
    (q_j > ε_j while it is active).

    At the centre it is carried at, v_j keeps its direction: a carried axis gives
    ω'_j × m̂_j = (ω_j × m̂_j)/|ω_j − (ω_j·m̂_j)m̂_j|, and a chosen one
    (m̂_j × g) × m̂_j = the part of g orthogonal to m̂_j, the goal rule's direction the law
    took without an axis (g the goal, or the e_z/e_x fallback in the same order). So the
    law's ċ there is the same with the old and the new axes, up to rounding
    (:meth:`stt_drake.systems.tube.SpatiotemporalTube.keep_evaluation` relies on it).

    `mean` may be a belief port's table: only its first 3 columns are read.

    One call of the compiled :func:`stt_drake.core._kernels.carry_circulation` unless the numpy
    path is selected (the code below is its reference)."""
    kernel = backend.compiled("carry_circulation")
    if kernel is not None:
        return kernel(
            np.asarray(axes, dtype=float),
            np.asarray(center, dtype=float),
            np.asarray(mean, dtype=float),
            np.asarray(active, dtype=bool),
            np.asarray(goal, dtype=float),
        )
    offset = np.asarray(center, dtype=float) - np.asarray(mean, dtype=float)[:, :3]
    unit_m = offset / np.maximum(np.linalg.norm(offset, axis=1, keepdims=True), 1e-300)
    carried = axes - np.sum(axes * unit_m, axis=1, keepdims=True) * unit_m
    length = np.linalg.norm(carried, axis=1)
    result = np.zeros_like(axes)
    keep = active & (length > CIRCULATION_MIN_SINE)  # an axis the law still uses
    result[keep] = carried[keep] / length[keep, None]
    fresh = active & ~keep
    for candidate in (goal, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])):
        axis = np.cross(unit_m, np.broadcast_to(candidate, unit_m.shape))
        length = np.linalg.norm(axis, axis=1)
        usable = fresh & (length > 1e-6 * max(float(np.linalg.norm(candidate)), 1e-300))
        result[usable] = axis[usable] / length[usable, None]
        fresh &= ~usable
    return result
