"""The spatiotemporal tube law (paper Sec. 3): centre velocity, radius and diagnostics.

One call of :meth:`TubeLaw.evaluate` gives, for the tube centre c and the belief of all
obstacles, the centre velocity ċ of Eq. (4), the radius r of Eq. (14) and
per-obstacle diagnostics (q_j, d̂_j, θ_j).

Fixes to the printed paper (docs/design.md, "Where the paper is silent or is read
differently"):
* the attraction term is the signed cube root per component, k1·sign(η − c)|η − c|^{1/3};
* the radius is the log-sum-exp soft-min r = −(1/ν) ln(e^{−ν r_max} + Σ_j e^{−ν d̂_j}),
  which is always ≤ min(r_max, min_j d̂_j); it stays > 0 only if ν > ln(n_o + 1)/r_min.

Bounded centre, boundary layer and recovery
-------------------------------------------
|ċ| ≤ v_c = ``max_center_speed`` always: the law's ċ is scaled down to v_c when faster.
In the paper's law the term k2·θ_j·m_j only dominates very close to q_j = ε_j (with the
authors' k2 = 0.03 and θ_j ≈ 0.05 it outweighs a 1 m/s attraction only below q_j − ε_j ≈
2e-3), so the centre rides a stiff 1/(q_j − ε_j) field a hair above the level set, and
two level sets closing on it (a *pinch*: the escape from one drives it into the other,
Theorem 3.2 (ii) treats one unbounded term at a time) pushed it across (the authors' 3D
field with k1 = 0.31: −3e-6 at 8.78 s), after which law and recovery alternated at the
boundary and the integrator chattered to a stop. So the law has a *boundary layer*
of width δ_j = BOUNDARY_LAYER·(p_d_j − ε_j) above each ε level set, with weight
w_j = clip(1 − (q_j − ε_j)/δ_j, 0, 1) (:func:`boundary_layer_weights`):

    ċ = (1 − w)·sat_{v_c}(ċ_law) + w·v_c·u/‖u‖,  w = max_j w_j,  u = Σ_j w_j (c − μ_j)/‖c − μ_j‖,

ċ_law being Eq. (4) over the obstacles with q_j > ε_j. Outside every layer (w = 0) this is
the paper's law. At and below an ε level set (w_j = 1) it is the *recovery*: v_c along u,
the direction in which the violated q_j increase fastest (∇_c q_j is along c − μ_j for
isotropic beliefs), turned away from the obstacles whose layer the centre is in, until
every q_j > ε_j again. ċ is continuous in c and in the beliefs (w and u are; at w = 1 the
law's share is 0) except where u = 0 (then the goal direction is used), so no mode
switch can chatter, and nothing is floored: the centre never
jumps, and the invariant monitor reports violated margins honestly.

Why the guarantee survives: on the ε level set of obstacle j (w_j = 1),
∇_c q_j·ċ ∝ ‖u‖⁻¹(1 + Σ_{k≠j} w_k cos∠(c − μ_j, c − μ_k)) v_c, so the centre leaves
the level set at speed v_c·(that) — the paper's single-obstacle argument (the saturated
ċ along c − μ_j) is the case of no other layer. Theorem 3.2 (ii) then holds while
the level set approaches slower than that speed; two level sets meeting head on (cos = −1)
cannot be escaped by any law that only moves the centre, and the run reports it.

The 3D null-space direction v_j follows a circulation axis per obstacle
(:mod:`stt_drake.core.circulation`). The fixed-rate (real-time) tube and its discrete-time
guarantee are derived in :mod:`stt_drake.core.fixed_rate`, with the update it describes
(:meth:`TubeLaw.advance`).

Where things are: the law's terms (attraction, boundary layer, the evaluation record) in
:mod:`stt_drake.core.tube_terms`; the numpy reference of one evaluation in
:mod:`stt_drake.core.tube_reference`; here the law, its constants and the one dispatch to
the compiled kernels or that reference (:meth:`TubeLaw.evaluate`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import Any

import numpy as np

from stt_drake.core import backend
from stt_drake.core.belief import ObstacleBelief, ObstacleTask, PortBelief
from stt_drake.core.fixed_rate import BeliefRateBounds, FixedRateUpdate
from stt_drake.core.fixed_rate import advance as fixed_rate_advance
from stt_drake.core.probability import PRUNE_HEADROOM_NU
from stt_drake.core.rules import (
    check_continuous_for_covariance,
    check_tube_law,
    checked_by,
    minimum_nu,
)
from stt_drake.core.tube_reference import evaluate_reference
from stt_drake.core.tube_terms import (
    TubeEvaluation,
    attraction_flow,
    attraction_reach_time,
    boundary_layer_weights,
    evaluation_of,
    kernel_extras,
    linear_zone_for_step,
    signed_cube_root_attraction,
)

#: The law's public names, with those of :mod:`stt_drake.core.tube_terms`,
#: :mod:`stt_drake.core.fixed_rate` and :mod:`stt_drake.core.rules` callers import from here.
__all__ = [
    "ANISOTROPIC_PRUNE_HEADROOM_NU",
    "BeliefRateBounds",
    "FixedRateUpdate",
    "TubeEvaluation",
    "TubeLaw",
    "attraction_flow",
    "attraction_reach_time",
    "boundary_layer_weights",
    "default_nu",
    "linear_zone_for_step",
    "minimum_nu",
    "signed_cube_root_attraction",
]


def default_nu(obstacle_count: int, r_min: float) -> float:
    """Twice :func:`minimum_nu`: guarantees r ≥ r_min/2 whenever every q_j > ε_j.

    Without obstacles the soft-min has the one argument r_max (r = r_max whatever ν) and
    :func:`minimum_nu` is 0; ν is then derived as for one obstacle, 2 ln 2/r_min, so it
    stays a positive, finite number for everything that divides by it (the pruning
    headroom 40/ν, the level-set speeds)."""
    return 2.0 * minimum_nu(max(obstacle_count, 1), r_min)


#: Pruning headroom (× 1/ν) of the quantiles of beliefs with full covariances
#: (:attr:`TubeLaw.anisotropic_prune_above`): e^{−25} ≈ 1.4e-11, the quantile method's own
#: accuracy is ~1e-13; the isotropic law keeps PRUNE_HEADROOM_NU = 40.
ANISOTROPIC_PRUNE_HEADROOM_NU = 25.0

#: The compiled kernel's empty argument: no period inflation (reach, spread), no activity
#: flags (every row of the obstacles' arrays is an obstacle).
_EMPTY = np.empty(0)


def _kernel_mode(full_covariance: bool, mode: str) -> str:
    """The kernel constants' key: full covariances prune with their own bound."""
    return "pruned_anisotropic" if full_covariance and mode == "pruned" else mode


@dataclass(frozen=True)
class TubeLaw:
    """Centre and radius law of the STT (Eqs. (4), (5), (8) and (14)).

    Attributes:
        target: (n,) η, the point the centre is pulled to.
        k1: attraction gain (> 0).
        k2: avoidance gain along m_j (> 0), scalar or one per obstacle.
        k3: gain along v_j ⟂ m_j (≥ 0), scalar or one per obstacle.
        r_min: buffer added to each obstacle radius in q_j (> 0).
        r_max: largest tube radius (> r_min).
        nu: soft-min sharpness; must exceed ln(n_o + 1)/r_min for Theorem 3.2 (iii).
        linear_zone: δ of :func:`signed_cube_root_attraction` (metres; 0 = exact cube root).
        max_center_speed: v_c, the bound on |ċ| and the recovery speed (m/s). A required
            keyword, as in a scenario file: a finite v_c is what lets the tube recover
            after a belief jump ("Bounded centre, boundary layer and recovery" above), so
            it is never switched off silently. ``math.inf`` must be given explicitly: it
            means unbounded, no boundary layer (the paper's law above every ε level set),
            and a recovery has no finite speed, so its ċ is not finite (the Drake system
            stops the run and says so).

    Checked when made (:func:`stt_drake.core.rules.check_tube_law`, a scenario file's rules);
    ν against the obstacle count where that is known (SpatiotemporalTube, AddStt).
    """

    target: np.ndarray
    k1: float
    k2: np.ndarray | float
    k3: np.ndarray | float
    r_min: float
    r_max: float
    nu: float
    linear_zone: float = 0.0
    max_center_speed: float = field(kw_only=True)

    def __post_init__(self) -> None:
        with checked_by("TubeLaw"):
            check_tube_law(*(getattr(self, f.name) for f in fields(TubeLaw)))  # in order

    def __getstate__(self) -> dict[str, object]:
        """The law for pickle and copy: its fields and constants, without the process's
        table of compiled kernels (:meth:`_kernel_call`; rebuilt on first use)."""
        state = dict(self.__dict__)
        state.pop("_kernel_calls", None)
        return state

    def radius(self, quantile_distance: np.ndarray) -> float:
        """Soft-min radius r = −(1/ν) ln(e^{−ν r_max} + Σ e^{−ν d̂_j}) (Eq. (14)).

        Shifted by the hard minimum before exponentiating, so nothing under/overflows.
        """
        values = np.append(quantile_distance, self.r_max)
        smallest = np.min(values)
        return float(smallest - np.log(np.sum(np.exp(-self.nu * (values - smallest)))) / self.nu)

    @property
    def prune_above(self) -> float:
        """d̂_j provably above r_max + PRUNE_HEADROOM_NU/ν is not computed exactly: its
        soft-min weight e^{−ν d̂_j} is below e^{−40} of the r_max term, so r moves by less
        than n_o·e^{−40}/ν (≈ 4e-18·n_o/ν m), and ċ, q_j, θ_j do not depend on d̂_j at all."""
        return self.r_max + PRUNE_HEADROOM_NU / self.nu

    @property
    def anisotropic_prune_above(self) -> float:
        """:attr:`prune_above` for beliefs with full covariances, whose quantile costs a
        contour integral (~15 µs) instead of ~0.1 µs: r_max + ANISOTROPIC_PRUNE_HEADROOM_NU/ν.
        A pruned d̂_j enters the soft-min as its lower bound (≤ d̂_j: r only gets smaller, so
        r ≤ min_j d̂_j still holds), which moves r by less than n_o·e^{−25}/ν
        (≈ 1.4e-11·n_o/ν m) from the all-exact law."""
        return self.r_max + ANISOTROPIC_PRUNE_HEADROOM_NU / self.nu

    @cached_property
    def _kernel_constants(self) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """(k2, k3, constants by pruning mode) as float arrays for the compiled kernel
        (layout: :data:`stt_drake.core._tube.TUBE_CONSTANTS`, then η); once per law. Modes:
        "pruned", "exact" (every quantile) and "rate" (ċ, q, θ only; the compiled kernel
        then returns NaN for d̂ and r)."""
        target = np.asarray(self.target, dtype=float).ravel()

        def constants(prune_above: float) -> np.ndarray:
            head = [self.k1, self.r_min, self.r_max, self.nu, self.linear_zone]
            return np.array([*head, prune_above, self.max_center_speed, *target], dtype=float)

        return (
            np.atleast_1d(np.array(self.k2, dtype=float)).ravel(),
            np.atleast_1d(np.array(self.k3, dtype=float)).ravel(),
            {
                "pruned": constants(self.prune_above),
                "pruned_anisotropic": constants(self.anisotropic_prune_above),
                "exact": constants(np.inf),
                "rate": constants(-np.inf),
            },
        )

    def with_target(self, target: np.ndarray) -> TubeLaw:
        """This law attracted to `target` (n,), its kernel constants reused with only η
        replaced: a guide or a task sequencer moves η as often as every step."""
        target = np.array(target, dtype=float).ravel()
        k2, k3, constants = self._kernel_constants
        n = target.size
        moved = {}
        for mode, values in constants.items():
            moved[mode] = values.copy()
            moved[mode][-n:] = target
        # A field-for-field copy (dataclasses.replace re-runs __init__: 5× slower); the
        # constants go where cached_property keeps them.
        law = object.__new__(TubeLaw)
        law.__dict__.update(self.__dict__)
        law.__dict__["target"] = target
        law.__dict__["_kernel_constants"] = (k2, k3, moved)
        law.__dict__["_kernel_calls"] = {}  # they hold the constants of the old η
        return law

    def kernel_arguments(self, count: int, mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(k2, k3, constants) of the compiled kernels for `count` obstacles in pruning
        `mode` (a key of :attr:`_kernel_constants`); ValueError unless k2 and k3 are one
        gain or one per obstacle."""
        k2, k3, constants = self._kernel_constants
        if k2.size not in (1, count) or k3.size not in (1, count):
            raise ValueError(
                f"k2/k3: need one gain or one per obstacle ({count}), got {k2.size} and {k3.size}"
            )
        return k2, k3, constants[mode]

    def _kernel_call(self, name: str, n: int, count: int, mode: str) -> tuple[Any, ...] | None:
        """(compiled kernel `name`, k2, k3, constants, empty circulation (0, n)) for `count`
        obstacles in pruning `mode` (full covariances, the "exact_" kernels, prune with
        their own bound: :func:`_kernel_mode`), or None where the numpy reference runs
        (:func:`stt_drake.core.backend.compiled`); for "tube_step_obstacles", (kernel,
        [len(k2), len(k3), k2, k3, constants]). Looked up once per law and key, not per
        evaluation: the lookup, the gains' checks and the arrays cost more than the kernel's
        pruned obstacles (:meth:`with_target` starts the law's table afresh)."""
        if not backend.using_compiled():  # checked every call: tests switch per block
            return None
        calls = self.__dict__.setdefault("_kernel_calls", {})
        key = (name, n, count, mode)
        call = calls.get(key)
        if call is None:
            kernel = backend.compiled(name, n)
            if kernel is None:
                return None
            constants_mode = _kernel_mode(name.startswith("exact"), mode)
            k2, k3, constants = self.kernel_arguments(count, constants_mode)
            if name == "tube_step_obstacles":  # the gains and constants in one array
                call = (kernel, np.concatenate([[k2.size, k3.size], k2, k3, constants]))
            else:
                call = (kernel, k2, k3, constants, np.empty((0, n)))
            calls[key] = call
        return call

    def evaluate(
        self,
        center: np.ndarray,
        belief: ObstacleBelief,
        prune: bool = True,
        circulation: np.ndarray | None = None,
        inflation: tuple[np.ndarray, np.ndarray] | None = None,
        quantiles: bool = True,
    ) -> TubeEvaluation:
        """ċ (Eq. (4)), r (Eq. (14)) and the diagnostics q_j (Eq. (5)), d̂_j (Eq. (8)), θ_j
        at the centre `center` (n,), per slot of `belief` (:meth:`ObstacleBelief.in_slots`:
        an inactive slot never reaches ċ or r and reads q = 1, d̂ = +∞, θ = 0).

        The one dispatch of the law: a belief from a port in one call of the compiled
        :func:`stt_drake.core._tube.tube_step_packed` (σ_j) or
        :func:`stt_drake.core._tube.exact_tube_step_packed` (Σ_j), which read the port
        vector themselves; otherwise the obstacles' arrays in one call of
        :func:`stt_drake.core._tube.tube_step` (σ_j) or
        :func:`stt_drake.core._tube.exact_tube_step` (Σ_j), for the
        dimensions they are compiled for and unless the numpy path is selected
        (:mod:`stt_drake.core.backend`), else :func:`stt_drake.core.tube_reference.
        evaluate_reference`.

        Args:
            prune: False computes every d̂_j exactly (see :attr:`prune_above`).
            circulation: (slots, 3) axes ω_j of :func:`carry_circulation` (3D).
            inflation: (Δ, γ) of :meth:`BeliefRateBounds.inflation`; q_j, θ_j and ċ then
                use the period lower bound of q_j (d̂_j and r stay at the belief itself);
                isotropic beliefs only
                (:func:`stt_drake.core.rules.check_continuous_for_covariance`).
            quantiles: False skips d̂_j and r (NaN): ċ, q_j and θ_j only.
        """
        mode = ("pruned" if prune else "exact") if quantiles else "rate"
        center = np.asarray(center, dtype=float)
        if not isinstance(belief, PortBelief):  # one obstacle per slot
            return self._evaluate_obstacles(center, belief, mode, circulation, inflation)
        if inflation is None:  # else only isotropic beliefs (checked in _evaluate_obstacles)
            evaluation = self._port_evaluation(
                center, belief.vector, belief.slot_task, belief.full_covariance, circulation, mode
            )
            if evaluation is not None:
                return evaluation
        circulation = belief.of_obstacles(circulation)
        evaluation = self._evaluate_obstacles(
            center, belief.obstacles(), mode, circulation, inflation
        )
        return evaluation.in_slots(belief)

    def evaluate_port(
        self,
        center: np.ndarray,
        vector: np.ndarray,
        task: ObstacleTask,
        full_covariance: bool,
        circulation: np.ndarray | None = None,
    ) -> TubeEvaluation:
        """:meth:`evaluate` of ``ObstacleBelief.from_port(vector, n, task, full_covariance)``
        at `center` (n,), float64: a system's hot path. Where the compiled kernel runs it
        reads the port `vector` itself and no belief is made, so `vector` must have the
        port's length for ``task.count`` slots (a Drake input port of the declared size
        has; a system checks `task` once when it is made)."""
        evaluation = self._port_evaluation(
            center, vector, task, full_covariance, circulation, "pruned"
        )
        if evaluation is None:
            belief = ObstacleBelief.from_port(vector, len(center), task, full_covariance)
            return self.evaluate(center, belief, circulation=circulation)
        return evaluation

    def _port_evaluation(
        self,
        center: np.ndarray,
        vector: np.ndarray,
        task: ObstacleTask,
        full: bool,
        circulation: np.ndarray | None,
        mode: str,
    ) -> TubeEvaluation | None:
        """One call of the compiled :func:`stt_drake.core._tube.tube_step_packed` (σ_j) or
        :func:`stt_drake.core._tube.exact_tube_step_packed` (Σ_j) on a port `vector`; None
        where the numpy reference runs."""
        n, count = len(center), task.count
        name = "exact_tube_step_packed" if full else "tube_step_packed"
        call = self._kernel_call(name, n, count, mode)
        if call is None:
            return None
        kernel, k2, k3, constants, axes = call
        if circulation is not None:  # (slots, 3) rows; only the axes (kernel_extras: 3× this)
            axes = np.ascontiguousarray(circulation, dtype=float).reshape(count, n)
        return evaluation_of(kernel(center, vector, task.table(), k2, k3, axes, constants), n)

    def switching_gains(self, center: np.ndarray, belief: ObstacleBelief) -> np.ndarray:
        """θ_j at `center` (no quantile is computed)."""
        return self.evaluate(center, belief, quantiles=False).theta

    def _evaluate_obstacles(
        self,
        center: np.ndarray,
        belief: ObstacleBelief,
        mode: str,
        circulation: np.ndarray | None,
        inflation: tuple[np.ndarray, np.ndarray] | None,
    ) -> TubeEvaluation:
        """:meth:`evaluate` on the obstacles' arrays (one per obstacle, not per slot)."""
        count, n = belief.mean.shape
        full = belief.covariance is not None
        if not full and circulation is None and inflation is None:
            call = self._kernel_call("tube_step_obstacles", n, count, mode)
            if call is not None:  # 7 arguments, not tube_step's 14: dispatch costs per argument
                kernel, law = call
                mean, sigma = belief.mean, belief.sigma
                out = kernel(center, mean, sigma, belief.radius, belief.epsilon, belief.p_d, law)
                return evaluation_of(out, n)
        if inflation is not None:
            check_continuous_for_covariance(full, True, "inflation", inflation, "None")
        call = self._kernel_call("exact_tube_step" if full else "tube_step", n, count, mode)
        if call is None:
            prune_above = {
                "pruned": self.anisotropic_prune_above if full else self.prune_above,
                "exact": None,
                "rate": -np.inf,
            }[mode]
            return evaluate_reference(self, center, belief, prune_above, circulation, inflation)
        kernel, k2, k3, constants, axes = call
        if circulation is not None:
            axes = kernel_extras((count, n), circulation, None)[2]
        if not full:
            reach = spread = _EMPTY
            if inflation is not None:
                reach, spread, _axes = kernel_extras((count, n), None, inflation)
            # The fields themselves, one by one: no belief.arrays() call and no argument tuple
            # to unpack (~0.15 µs of a ~4 µs evaluation).
            out = kernel(
                center,
                belief.mean,
                belief.sigma,
                belief.radius,
                belief.epsilon,
                None,  # Φ⁻¹(ε_j): computed in the kernel where a bound needs it
                belief.p_d,
                k2,
                k3,
                reach,
                spread,
                axes,
                constants,
                _EMPTY,
            )
            return evaluation_of(out, n)
        return evaluation_of(
            kernel(
                center,
                np.ascontiguousarray(belief.mean, dtype=float),
                np.ascontiguousarray(belief.covariance, dtype=float).reshape(count, n, n),
                np.asarray(belief.radius, dtype=float),
                np.asarray(belief.epsilon, dtype=float),
                np.asarray(belief.p_d, dtype=float),
                k2,
                k3,
                axes,
                constants,
            ),
            n,
        )

    #: The fixed-rate (real-time) update over one period:
    #: :func:`stt_drake.core.fixed_rate.advance` (``law.advance(center, belief, h, ...)``).
    advance = fixed_rate_advance
