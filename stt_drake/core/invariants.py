"""The guarantees every run checks (docs/guide/guarantees.md).

Pure numpy. A *margin* is positive when a guarantee holds with room to spare:

========================== ========================================================
name                       margin
========================== ========================================================
output_in_tube             r − ‖y − c‖ (metres): y(t) ∈ Γ(t), Theorem 4.1
center_avoid_probability   min_j q_j(c) − ε_j: buffered centre avoidance, Theorem 3.2 (ii) part 1
tube_avoid_probability     min_j P(‖c − O_j‖ ≥ r_o_j + r) − ε_j: Eq. (3d) / Theorem 3.2 (ii)
output_avoid_probability   min_j P(‖y − O_j‖ ≥ r_o_j) − ε_j: the PrT-RAS task, Definition 2.3
radius_positive            r (metres): Theorem 3.2 (iii)
========================== ========================================================

The tube sits on its ε level set by design, so a margin may be 0 up to rounding; a
guarantee *holds* when its worst margin is ≥ −HOLDS_TOLERANCE.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from stt_drake.core import anisotropic, backend
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.probability import avoid_probability

#: The guarantees, in the order of the invariant monitor's `margins` port and of
#: :meth:`InvariantTracker.update`'s margins (each margin is in the table above).
INVARIANT_NAMES = (
    "output_in_tube",
    "center_avoid_probability",
    "tube_avoid_probability",
    "output_avoid_probability",
    "radius_positive",
)

#: A margin ≥ −HOLDS_TOLERANCE counts as holding (margins can sit at 0 up to rounding).
HOLDS_TOLERANCE = 1e-9


class InvariantSample(NamedTuple):
    """Margins at one instant, plus the per-obstacle probabilities behind them (a
    NamedTuple: made once per integrator step, cheaper than a frozen dataclass)."""

    margins: np.ndarray  # (5,) in INVARIANT_NAMES order
    output_avoid_probability: np.ndarray  # (m,) P(‖y − O_j‖ ≥ r_o_j)
    tube_avoid_probability: np.ndarray  # (m,) P(‖c − O_j‖ ≥ r_o_j + r)


def evaluate_invariants(
    output: np.ndarray, center: np.ndarray, radius: float, belief: ObstacleBelief, r_min: float
) -> InvariantSample:
    """Compute every margin at one instant, independently of the tube's own diagnostics:
    :func:`evaluate_tube_invariants` of the tube [c, r] = [`center`, `radius`]."""
    center = np.asarray(center, dtype=float)
    tube = np.empty(center.shape[0] + 1)
    tube[:-1] = center
    tube[-1] = radius
    return evaluate_tube_invariants(output, tube, belief, r_min)


def evaluate_tube_invariants(
    output: np.ndarray, tube: np.ndarray, belief: ObstacleBelief, r_min: float
) -> InvariantSample:
    """Compute every margin at one instant for the tube [c, r] (the tube port's value),
    independently of the tube's own diagnostics: the probabilities per slot of `belief`
    (:meth:`ObstacleBelief.in_slots`; an inactive slot reads 1 and takes no part in the
    margins).

    For a belief from a port, one compiled call (:func:`port_invariants`, the monitor's hot
    path). Otherwise, with full covariances, each Σ_j exactly by
    :func:`_anisotropic_probabilities` (which also names a Σ_j that breaks a rule); else
    one call of the compiled :func:`stt_drake.core._kernels.invariant_margins` for n ≤ 3
    (unless the numpy path is selected, see :mod:`stt_drake.core.backend`), else numpy.
    """
    output = np.asarray(output, dtype=float)
    tube = np.ascontiguousarray(tube, dtype=float)
    dimension = output.shape[0]
    port = belief.port_arrays
    if port is not None:
        sample = port_invariants(output, tube, *port, belief.packed is None, r_min)
        if sample is not None:  # else the arrays' path below (it names a Σ_j that breaks a rule)
            return sample
    center, radius = tube[:-1], float(tube[-1])
    obstacles = belief.obstacles()
    if obstacles.covariance is not None:
        center_q, tube_q, output_q = _anisotropic_probabilities(
            output, center, radius, obstacles, r_min
        )
        margins = _margins(output, center, radius, obstacles.epsilon, center_q, tube_q, output_q)
    else:
        kernel = backend.compiled("invariant_margins", dimension)
        if kernel is not None:
            margins, output_q, tube_q = kernel(
                output,
                center,
                radius,
                obstacles.mean,
                obstacles.sigma,
                obstacles.radius,
                obstacles.epsilon,
                float(r_min),
            )
        else:
            center_q = avoid_probability(
                center, obstacles.mean, obstacles.sigma, obstacles.radius + r_min
            )
            tube_q = avoid_probability(
                center, obstacles.mean, obstacles.sigma, obstacles.radius + max(radius, 0.0)
            )
            output_q = avoid_probability(output, obstacles.mean, obstacles.sigma, obstacles.radius)
            margins = _margins(
                output, center, radius, obstacles.epsilon, center_q, tube_q, output_q
            )
    return InvariantSample(margins, belief.in_slots(output_q, 1.0), belief.in_slots(tube_q, 1.0))


def port_invariants(
    output: np.ndarray,
    tube: np.ndarray,
    vector: np.ndarray,
    task: np.ndarray,
    full_covariance: bool,
    r_min: float,
) -> InvariantSample | None:
    """:func:`evaluate_tube_invariants` of the belief a port `vector` holds (`task`: the rows
    [r_o, ε, p_d, Φ⁻¹(ε)] per slot, :meth:`ObstacleTask.table`) in one compiled call, without making
    the belief: :func:`stt_drake.core._kernels.invariant_margins_packed` (σ_j) or, with
    `full_covariance`, :func:`stt_drake.core._invariants.anisotropic_invariants_packed`
    (each Σ_j). `output` and `tube` are float arrays. None where the belief's path must run
    instead: the numpy path is selected, the dimension is not compiled, or some Σ_j breaks
    a rule (that path names it)."""
    name = "anisotropic_invariants_packed" if full_covariance else "invariant_margins_packed"
    kernel = backend.compiled(name, output.shape[0])
    if kernel is None:
        return None
    if not full_covariance:
        return InvariantSample._make(kernel(output, tube, vector, task, r_min))
    *sample, valid = kernel(
        output, tube, vector, task, r_min, anisotropic.SYMMETRY_RTOL, anisotropic.MAX_CONDITION
    )
    return InvariantSample._make(sample) if valid else None


def _margins(
    output: np.ndarray,
    center: np.ndarray,
    radius: float,
    epsilon: np.ndarray,
    center_q: np.ndarray,
    tube_q: np.ndarray,
    output_q: np.ndarray,
) -> np.ndarray:
    """The margins in :data:`INVARIANT_NAMES` order from the three probabilities."""
    # With no obstacle a probability margin is vacuous; 1 exceeds every real one (1 − ε < 1).
    return np.array(
        [
            radius - float(np.linalg.norm(np.asarray(output) - np.asarray(center))),
            np.min(center_q - epsilon, initial=1.0),
            np.min(tube_q - epsilon, initial=1.0),
            np.min(output_q - epsilon, initial=1.0),
            radius,
        ]
    )


def center_avoid_probability(
    center: np.ndarray, belief: ObstacleBelief, r_min: float
) -> np.ndarray:
    """q_j(c) with the buffered radius r_o_j + r_min, per slot of `belief` (an inactive slot
    reads 1; full covariances where the belief has them)."""
    obstacles = belief.obstacles()
    if obstacles.covariance is None:
        q = avoid_probability(center, obstacles.mean, obstacles.sigma, obstacles.radius + r_min)
    else:
        q = _anisotropic_probabilities(center, center, 0.0, obstacles, r_min)[0]
    return belief.in_slots(q, 1.0)


def _anisotropic_probabilities(
    output: np.ndarray, center: np.ndarray, radius: float, belief: ObstacleBelief, r_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q_j(c) with r_o + r_min, q_j(c) with r_o + r, q_j(y) with r_o) for a belief with
    full covariances, each Σ_j checked and decomposed once: one call of the compiled
    :func:`stt_drake.core._invariants.anisotropic_invariants` for n = 2, 3 (unless the
    numpy path is selected), else :func:`_anisotropic_reference`. Not the tube's kernel, so
    the monitor does not share the tube's code path.

    Raises:
        ValueError: a Σ_j breaks a rule of :func:`stt_drake.core.anisotropic.
            eigen_decomposition` (named with the obstacle's index).
    """
    kernel = backend.compiled("anisotropic_invariants", belief.dimension)
    if kernel is None:
        return _anisotropic_reference(output, center, radius, belief, r_min)
    q, valid = kernel(
        np.asarray(output, dtype=float),
        np.asarray(center, dtype=float),
        float(radius),
        np.ascontiguousarray(belief.mean, dtype=float),
        np.ascontiguousarray(belief.covariance, dtype=float),
        np.ascontiguousarray(belief.radius, dtype=float),
        float(r_min),
        anisotropic.SYMMETRY_RTOL,
        anisotropic.MAX_CONDITION,
    )
    for j in np.flatnonzero(~valid):
        _decomposed(belief.covariance, j)  # raises the rule Σ_j breaks
        raise ValueError(f"obstacle {j}: covariance is not a valid Σ (numerically singular)")
    return q[:, 0], q[:, 1], q[:, 2]


def _decomposed(covariance: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`stt_drake.core.anisotropic.eigen_decomposition` of Σ_j, its error naming j."""
    try:
        return anisotropic.eigen_decomposition(covariance[j])
    except ValueError as error:
        raise ValueError(f"obstacle {j}: {error}") from None


def _anisotropic_reference(
    output: np.ndarray, center: np.ndarray, radius: float, belief: ObstacleBelief, r_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_anisotropic_probabilities` in numpy, obstacle by obstacle
    (:mod:`stt_drake.core.anisotropic`)."""
    count = belief.count
    center_q, tube_q, output_q = np.empty(count), np.empty(count), np.empty(count)
    center = np.asarray(center, dtype=float)
    output = np.asarray(output, dtype=float)
    for j in range(count):
        variances, axes = _decomposed(belief.covariance, j)
        at_center = ((center - belief.mean[j]) @ axes)[None, :]
        at_output = ((output - belief.mean[j]) @ axes)[None, :]
        r_o = float(belief.radius[j])
        center_q[j] = anisotropic.ball_probabilities(variances, at_center, r_o + r_min)[1][0]
        tube_q[j] = anisotropic.ball_probabilities(variances, at_center, r_o + max(radius, 0.0))[1][
            0
        ]
        output_q[j] = anisotropic.ball_probabilities(variances, at_output, r_o)[1][0]
    return center_q, tube_q, output_q


@dataclass
class InvariantRecord:
    """Worst margin of one guarantee over a run and when it occurred."""

    worst_margin: float = np.inf
    t_worst: float = 0.0

    @property
    def holds(self) -> bool:
        return bool(self.worst_margin >= -HOLDS_TOLERANCE)

    def as_dict(self) -> dict[str, float | bool]:
        return {"holds": self.holds, "worst_margin": self.worst_margin, "t_worst": self.t_worst}


class InvariantTracker:
    """Keeps the worst margin of every guarantee over a run, and the first violation."""

    def __init__(self) -> None:
        self.records = {name: InvariantRecord() for name in INVARIANT_NAMES}
        self.first_violation: str | None = None

    def update(self, t: float, margins: np.ndarray) -> str | None:
        """Fold in the margins at time t; return a violation message if one is new here."""
        message = None
        values = np.asarray(margins, dtype=float).tolist()  # Python floats: no numpy scalars
        for name, margin in zip(INVARIANT_NAMES, values, strict=True):
            record = self.records[name]
            if not math.isfinite(margin):
                margin = -math.inf
            if margin < record.worst_margin:
                record.worst_margin, record.t_worst = margin, float(t)
            if margin < -HOLDS_TOLERANCE and message is None:
                message = (
                    f"invariant {name} violated at t = {t:.6g} s: margin {margin:.6g} "
                    f"(holds needs ≥ −{HOLDS_TOLERANCE:g})"
                )
        if message is not None and self.first_violation is None:
            self.first_violation = message
        return message

    def update_many(self, times: np.ndarray, margins: np.ndarray) -> None:
        """Fold in a logged series: times (T,), margins (T, 5)."""
        for t, row in zip(times, margins, strict=True):
            self.update(t, row)

    @property
    def holds(self) -> bool:
        return all(record.holds for record in self.records.values())

    def as_dict(self) -> dict[str, dict[str, float | bool]]:
        return {name: record.as_dict() for name, record in self.records.items()}


class RecoveryTracker:
    """The tube's recovery episodes at every integrator step (metrics.json `recovery`).

    An episode of obstacle j is a maximal run of steps with the tube's `recovery` flag j
    set (continuous tube: q_j(c) ≤ ε_j; fixed-rate tube: a period whose segment could not
    be certified for j). Watched at every step by the Simulator monitor, so an episode
    shorter than a log period is recorded too (sampling the logged flag missed them).
    """

    def __init__(self) -> None:
        self._open: dict[int, dict[str, float | int | None]] = {}
        self._closed: list[dict[str, float | int | None]] = []

    @property
    def active(self) -> bool:
        """Whether some episode is still open."""
        return bool(self._open)

    def update(self, t: float, recovering: np.ndarray, margin: np.ndarray) -> None:
        """Fold in the step that ended at time t: `recovering` (m,) flags and the centre's
        margins q_j(c) − ε_j (m,). An episode opens at its first flagged step, keeps the
        smallest margin of its steps and ends at the first step no longer flagged."""
        for j, flag in enumerate(np.asarray(recovering, dtype=bool).tolist()):
            episode = self._open.get(j)
            if flag:
                if episode is None:
                    episode = {"obstacle": j, "start_s": float(t), "end_s": None}
                    episode["worst_margin"] = math.inf
                    self._open[j] = episode
                episode["worst_margin"] = min(episode["worst_margin"], float(margin[j]))
            elif episode is not None:
                episode["end_s"] = float(t)
                self._closed.append(self._open.pop(j))

    def episodes(self) -> list[dict[str, float | int | None]]:
        """Every episode, ordered by obstacle then start: `obstacle`, `start_s`, `end_s`
        (None while it still runs) and `worst_margin`."""
        every = self._closed + list(self._open.values())
        return [dict(e) for e in sorted(every, key=lambda e: (e["obstacle"], e["start_s"]))]


@dataclass(frozen=True)
class ReachStory:
    """When the tube entered and left the target set over a run (logged samples).

    Attributes:
        first_entry_s: the first sample time with Γ(t) ⊂ T, None if never.
        entries_s: every sample time at which Γ went from outside T to inside (the first
            sample counts as an entry when Γ starts inside).
        exits_s: every sample time at which Γ went from inside T to outside (the first
            sample outside).
        final_entry_s: t_c of guarantee 4, the entry after which Γ stays inside T to the
            end; None if the run ends outside (or, for a task sequence, not in its last task).
    """

    first_entry_s: float | None
    entries_s: list[float]
    exits_s: list[float]
    final_entry_s: float | None

    def as_dict(self) -> dict[str, float | list[float] | None]:
        return {
            "first_entry_s": self.first_entry_s,
            "entries_s": list(self.entries_s),
            "exits_s": list(self.exits_s),
            "final_entry_s": self.final_entry_s,
        }


def tube_in_target(
    center: np.ndarray, radius: np.ndarray, target: np.ndarray, target_set_radius: float
) -> np.ndarray:
    """Γ = B(c, r) ⊂ T = B(η, R_T): ‖c − η‖ + r ≤ R_T (up to HOLDS_TOLERANCE) and r > 0,
    per sample (rows of `center`, entries of `radius`; `target` one η or one per sample).

    A non-positive radius (an honest violation during recovery) is no tube at all: it
    would meet ‖c − η‖ + r ≤ R_T trivially."""
    radius = np.asarray(radius, dtype=float)
    gap = (
        np.linalg.norm(np.asarray(center, dtype=float) - np.asarray(target, dtype=float), axis=-1)
        + radius
    )
    return (gap <= target_set_radius + HOLDS_TOLERANCE) & (radius > 0.0)


def reach_story(
    t: np.ndarray,
    center: np.ndarray,
    radius: np.ndarray,
    target: np.ndarray,
    target_set_radius: float,
    final_target: np.ndarray | None = None,
) -> ReachStory:
    """Entries into and exits from the target set T = B(η, R_T), sample by sample.

    Γ(t) = B(c, r) lies in T iff ‖c − η‖ + r ≤ R_T (up to HOLDS_TOLERANCE) and r > 0.

    Args:
        t: (T,) sample times.
        center: (T, n) tube centres c.
        radius: (T,) tube radii r.
        target: (n,) η, or (T, n) the target active at each sample (a task sequence).
        target_set_radius: R_T.
        final_target: with per-sample targets, the sequence's last target: the run has a
            final entry only if it ends in that task (None: no such condition).
    """
    t = np.asarray(t, dtype=float)
    target = np.asarray(target, dtype=float)
    inside = tube_in_target(center, radius, target, target_set_radius)
    previous = np.zeros_like(inside)  # inside at the sample before (none before the first)
    previous[1:] = inside[:-1]
    entries = t[inside & ~previous].tolist()
    exits = t[~inside & previous].tolist()
    ends_inside = bool(inside.size and inside[-1])
    if ends_inside and final_target is not None and target.ndim == 2:
        ends_inside = bool(np.array_equal(target[-1], np.asarray(final_target, dtype=float)))
    return ReachStory(
        first_entry_s=entries[0] if entries else None,
        entries_s=entries,
        exits_s=exits,
        final_entry_s=entries[-1] if ends_inside else None,
    )


def tube_reach_time(
    t: np.ndarray,
    center: np.ndarray,
    radius: np.ndarray,
    target: np.ndarray,
    target_set_radius: float,
) -> float | None:
    """t_c of guarantee 4: the first sample time from which Γ(t) ⊂ T holds to the end
    (:attr:`ReachStory.final_entry_s` of :func:`reach_story`); None if it does not hold at
    the last sample."""
    return reach_story(t, center, radius, target, target_set_radius).final_entry_s
