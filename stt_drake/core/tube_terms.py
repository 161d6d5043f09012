"""The terms of the tube law shared by the law (:mod:`stt_drake.core.tube`), its numpy
reference (:mod:`stt_drake.core.tube_reference`) and its fixed-rate update
(:mod:`stt_drake.core.fixed_rate`): the attraction of Eq. (4), the boundary-layer weights,
and the evaluation record with Eqs. (4), (5), (8) and (14) at one instant.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.constants import BOUNDARY_LAYER


def boundary_layer_weights(
    avoid_probability: np.ndarray, epsilon: np.ndarray, p_d: np.ndarray
) -> np.ndarray:
    """w_j = clip(1 − (q_j − ε_j)/δ_j, 0, 1) with δ_j = BOUNDARY_LAYER·(p_d_j − ε_j): 1 at and
    below the ε level set, 0 from δ_j above it, linear in between."""
    width = BOUNDARY_LAYER * (p_d - epsilon)
    return np.clip(1.0 - (avoid_probability - epsilon) / width, 0.0, 1.0)


def signed_cube_root_attraction(
    error: np.ndarray, k1: float, linear_zone: float = 0.0
) -> np.ndarray:
    """k1·sign(e)|e|^{1/3} per component: the finite-time attraction of Eq. (4).

    The cube root is not Lipschitz at e = 0: an error-controlled integrator chatters
    around η with ever smaller steps (measured: 3100 steps/s once c reached η). Within
    |e_i| < `linear_zone` the term is k1·e_i·δ^{-2/3} instead (continuous at δ), i.e. an
    exponential settle with time constant δ^{2/3}/k1. With δ = (k1·h)^{3/2}, h the largest
    integrator step, that time constant is h and δ is the overshoot a step of h would have
    anyway. Finite-time reach then holds to within δ, after which c → η exponentially.
    """
    if linear_zone <= 0.0:
        return k1 * np.cbrt(error)
    linear = error * linear_zone ** (-2.0 / 3.0)
    return k1 * np.where(np.abs(error) < linear_zone, linear, np.cbrt(error))


def linear_zone_for_step(k1: float, max_step: float) -> float:
    """δ = (k1·h)^{3/2}: the attraction's linear zone for an integrator step of at most h."""
    return float((k1 * max_step) ** 1.5)


def attraction_flow(error: np.ndarray, k1: float, duration: float) -> np.ndarray:
    """Exact change of c over `duration` under ċ = k1·cbrt(η − c) alone (Eq. (13)).

    Per component, |e|^{2/3} decreases linearly at rate 2k1/3 until it reaches 0, so the
    flow never overshoots η, whatever the step.
    """
    remaining = np.maximum(np.abs(error) ** (2.0 / 3.0) - (2.0 / 3.0) * k1 * duration, 0.0)
    return error - np.sign(error) * remaining**1.5


def attraction_reach_time(error: np.ndarray, k1: float) -> float:
    """Time for the attraction alone to bring c to η: max_i 3|e_i|^{2/3}/(2 k1)."""
    return float(np.max(3.0 * np.abs(error) ** (2.0 / 3.0) / (2.0 * k1)))


class LawConstants(Protocol):
    """What the numpy reference and the fixed-rate update read of a
    :class:`stt_drake.core.tube.TubeLaw` (a Protocol: the law's module imports them)."""

    target: np.ndarray
    k1: float
    k2: np.ndarray | float
    k3: np.ndarray | float
    r_min: float
    linear_zone: float
    max_center_speed: float

    def radius(self, quantile_distance: np.ndarray) -> float: ...


@dataclass(frozen=True)
class TubeEvaluation:
    """Everything the tube law gives at one instant.

    Attributes:
        center_rate: (n,) ċ of Eq. (4) saturated at max_center_speed and blended with
            the escape velocity in the boundary layer (the recovery velocity at and below
            an ε level set), m/s.
        radius: r of Eq. (14), metres.
        avoid_probability: (m,) q_j(c, t) of Eq. (5) (its period lower bound when the
            law was evaluated with a horizon).
        quantile_distance: (m,) d̂_j of Eq. (8), metres (a lower bound where pruned).
        theta: (m,) switching gains θ_j (at their largest in-law value 1/ε_j − 1/p_d_j
            where q_j ≤ ε_j: the recovery velocity does not use them).
    """

    center_rate: np.ndarray
    radius: float
    avoid_probability: np.ndarray
    quantile_distance: np.ndarray
    theta: np.ndarray

    def in_slots(self, belief: ObstacleBelief) -> TubeEvaluation:
        """This evaluation of `belief`'s obstacles over the port slots it was made from
        (:meth:`ObstacleBelief.in_slots`); an inactive slot reads q = 1, d̂ = +∞, θ = 0 (no
        obstacle there)."""
        q = belief.in_slots(self.avoid_probability, 1.0)
        if q is self.avoid_probability:  # one obstacle per slot
            return self
        return replace(
            self,
            avoid_probability=q,
            quantile_distance=belief.in_slots(self.quantile_distance, np.inf),
            theta=belief.in_slots(self.theta, 0.0),
        )


class _ResultPart:
    """A per-obstacle field of a :class:`_PackedEvaluation`: the view `part` (0: q, 1: d̂,
    2: θ) of the compiled result, made on its first read and then kept in the record's
    ``__dict__``, where later reads find it as a plain attribute (a non-data descriptor)."""

    def __init__(self, part: int) -> None:
        self.part = part

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, record: _PackedEvaluation | None, owner: type) -> object:
        if record is None:
            return self
        out, n = record.__dict__["_result"]
        count = (out.shape[0] - n - 1) // 3
        start = n + 1 + self.part * count
        view = out[start : start + count]
        record.__dict__[self.name] = view
        return view


class _PackedEvaluation(TubeEvaluation):
    """A :class:`TubeEvaluation` over a compiled tube step's result: ċ and r are set when it
    is made; q_j, d̂_j and θ_j, views of the same array, on first read (a loop's derivative
    reads ċ only; three views cost ~0.4 µs of a ~4 µs evaluation)."""

    avoid_probability = _ResultPart(0)
    quantile_distance = _ResultPart(1)
    theta = _ResultPart(2)


def evaluation_of(out: np.ndarray, n: int) -> TubeEvaluation:
    """The :class:`TubeEvaluation` of a compiled tube step's result `out`, laid out as
    [ċ (n), r, q (m), d̂ (m), θ (m)] (:func:`stt_drake.core._tube.step_parts`): its arrays
    are views of `out`, and the record is made without the frozen dataclass's __init__ (one
    object.__setattr__ per field); the same fields."""
    evaluation = object.__new__(_PackedEvaluation)
    made = evaluation.__dict__
    made["_result"] = (out, n)
    made["center_rate"] = out[:n]
    made["radius"] = out.item(n)
    return evaluation


def kernel_extras(
    shape: tuple[int, int],
    circulation: np.ndarray | None,
    inflation: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(reach, spread, circulation) arrays for the compiled kernel: empty where not used."""
    count, dimension = shape
    empty = np.empty(0)
    reach, spread = (empty, empty) if inflation is None else inflation
    axes = (
        np.empty((0, dimension))
        if circulation is None
        else np.ascontiguousarray(circulation, dtype=float).reshape(count, dimension)
    )
    return np.asarray(reach, dtype=float), np.asarray(spread, dtype=float), axes
