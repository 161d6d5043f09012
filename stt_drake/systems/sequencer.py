"""TargetSequencer: a sequence of reach-avoid-stay tasks for one tube (e.g. pick-and-place)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from stt_drake.core.invariants import tube_in_target


class TargetSequencer(LeafSystem):
    """Switches the tube's target η through `targets`, one reach-avoid-stay task each.

    Task k is done once Γ(t) ⊂ T_k = B(η_k, R_T), i.e. ‖c − η_k‖ + r ≤ R_T, has held at every
    update for `hold_time` seconds; the target then becomes η_{k+1}. The last target stays.
    Checked every `period` seconds (a periodic discrete update).

    Input `tube` = [c, r] (n + 1). Output `target` = η_k (n), which depends on the discrete
    state only (so a tube that reads it forms no algebraic loop). Discrete state:
    [k, t_hold (the time Γ ⊂ T_k began to hold, NaN if it does not)].
    """

    def __init__(
        self,
        targets: Sequence[np.ndarray],
        target_set_radius: float,
        hold_time: float,
        period: float,
    ) -> None:
        super().__init__()
        self._targets = np.array([np.asarray(t, dtype=float) for t in targets])
        if self._targets.ndim != 2 or len(self._targets) == 0:
            raise ValueError("TargetSequencer: need at least one target of dimension n")
        if hold_time < 0.0 or period <= 0.0 or target_set_radius <= 0.0:
            raise ValueError(
                "TargetSequencer: need hold_time ≥ 0, period > 0 and target_set_radius > 0 "
                f"(got {hold_time}, {period}, {target_set_radius})"
            )
        self._radius = float(target_set_radius)
        self._hold = float(hold_time)
        dimension = self._targets.shape[1]
        self._tube = self.DeclareVectorInputPort("tube", dimension + 1)
        self._state = self.DeclareDiscreteState(np.array([0.0, np.nan]))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort(
            "target", dimension, self._calc_target, prerequisites_of_calc={self.xd_ticket()}
        )

    @property
    def targets(self) -> np.ndarray:
        """(K, n) the targets in order."""
        return self._targets.copy()

    def segment(self, context: Context) -> int:
        """Index k of the active target."""
        return int(context.get_discrete_state(self._state).GetAtIndex(0))

    def _calc_target(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._targets[self.segment(context)])

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        k, hold_start = context.get_discrete_state(self._state).CopyToVector()
        k = int(k)
        tube = self._tube.Eval(context)
        t = context.get_time()
        if not tube_in_target(tube[:-1], tube[-1], self._targets[k], self._radius):
            hold_start = np.nan
        elif np.isnan(hold_start):
            hold_start = t
        if k + 1 < len(self._targets) and t - hold_start >= self._hold:  # NaN compares False
            k, hold_start = k + 1, np.nan
        discrete_state.set_value(self._state, np.array([float(k), hold_start]))
