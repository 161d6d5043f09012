"""ObstacleBeliefSource: the Gaussian belief of every obstacle as a function of time."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import cached_property

import numpy as np
from pydrake.systems.framework import BasicVector, Context, LeafSystem

from stt_drake.core import backend
from stt_drake.core.belief import (
    ObstacleModel,
    belief_size,
    obstacle_belief,
    obstacle_covariance,
    obstacle_sigma,
    record_size,
)
from stt_drake.core.motion import MotionTable
from stt_drake.systems.memo import LastResult


class ObstacleBeliefSource(LeafSystem):
    """Outputs `obstacle_belief`: [mean (n), covariance (n²), active] per obstacle (layout in
    :mod:`stt_drake.core.belief`), from each obstacle's motion model and uncertainty (σ_j(t)² I,
    or a full Σ_j(t)); every slot active but a recorded track outside its span.

    Stands in for a tracker or SLAM front end; a user with a real one replaces this system
    by anything that writes the same port (:class:`stt_drake.systems.perception.ObstacleTracker`
    is one). The task numbers r_o, ε, p_d are not on the port: they are the tube's.

    The obstacles are read once, at construction: the constant fields are packed into a
    template and the motion models into a :class:`stt_drake.core.motion.MotionTable`
    (oscillating and constant-velocity means in one expression per kind, the piecewise-linear
    ones in one lookup); σ and Σ schedules are evaluated per obstacle.

    A recorded track (:class:`stt_drake.core.motion.Recorded`) exists over its samples' span
    only: outside it the slot is inactive (active = 0.0), as a tracker's slot without a track.
    """

    def __init__(self, obstacles: Sequence[ObstacleModel], dimension: int) -> None:
        super().__init__()
        self._obstacles = list(obstacles)
        self._dimension = dimension
        count = len(self._obstacles)
        belief = obstacle_belief(self._obstacles, dimension, 0.0)
        self._template = belief.to_vector().reshape(count, record_size(dimension))
        #: Whether some obstacle has a full covariance (not σ² I).
        self.full_covariance = belief.covariance is not None
        motions = self._motions = MotionTable([o.motion for o in self._obstacles], dimension)
        self._scheduled = [
            j
            for j, o in enumerate(self._obstacles)
            if o.sigma_schedule is not None or getattr(o, "covariance_schedule", None) is not None
        ]
        #: Whether some row needs Python after the kernel (another motion model, a schedule).
        self._per_obstacle = bool(motions.other or self._scheduled)
        self.DeclareVectorOutputPort(
            "obstacle_belief",
            belief_size(count, dimension),
            self._calc_belief,
            prerequisites_of_calc={self.time_ticket()},
        )
        self._last_belief = LastResult()  # stt_drake.systems.memo

    @cached_property
    def _kernel(self) -> Callable[..., np.ndarray] | None:
        """The compiled belief_table, looked up once (read while it is selected)."""
        return backend.compiled("belief_table")

    @property
    def obstacle_count(self) -> int:
        return len(self._obstacles)

    def belief_vector(self, t: float) -> np.ndarray:
        """The port value at time t (equal to ``obstacle_belief(obstacles, n, t).to_vector()``
        with the active flags of :meth:`stt_drake.core.motion.MotionTable.active`)."""
        n, motions = self._dimension, self._motions
        kernel = self._kernel if backend.using_compiled() else None
        if kernel is not None:
            vector = kernel(self._template, float(t), motions.kernel_values, motions.kernel_layout)
            if not self._per_obstacle:  # the kernel wrote every row
                return vector
            table = vector.reshape(self._template.shape)
            motions.fill_others(table[:, :n], t)
        else:
            table = self._template.copy()
            vector = table.reshape(-1)
            table[:, :n] = motions.positions(t)
            if motions.bounded.size:  # a recorded track exists over its span only
                table[:, -1] = motions.active(t)
        for j in self._scheduled:  # σ(t)² I, or Σ(t)
            obstacle = self._obstacles[j]
            full = obstacle_covariance(obstacle, t, n)
            covariance = obstacle_sigma(obstacle, t) ** 2 * np.eye(n) if full is None else full
            table[j, n:-1] = covariance.ravel()
        return vector

    def _calc_belief(self, context: Context, output: BasicVector) -> None:
        t = context.get_time()
        key, vector = self._last_belief.lookup(t)  # a step's first stage repeats the last time
        if vector is None:
            vector = self._last_belief.store(key, self.belief_vector(t))
        output.SetFromVector(vector)
