"""ObstacleBeliefSource: the Gaussian belief of every obstacle as a function of time."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import BasicVector, Context, LeafSystem

from stt_drake.core import backend
from stt_drake.core.belief import (
    ObstacleModel,
    belief_size,
    obstacle_belief,
    obstacle_sigma,
    record_size,
)
from stt_drake.core.motion import ConstantVelocity, Oscillation


class ObstacleBeliefSource(LeafSystem):
    """Outputs `obstacle_belief`: [mean, sigma, radius, epsilon, p_d] per obstacle
    (layout in :mod:`stt_drake.core.belief`), from each obstacle's motion model and σ schedule.

    Stands in for a tracker or SLAM front end; a user with a real one replaces this system
    by anything that writes the same port.

    The obstacles are read once, at construction: the constant fields are packed into a
    template, and oscillating and constant-velocity means are evaluated for all obstacles
    of a kind in one numpy expression (the same arithmetic as
    :meth:`stt_drake.core.motion.Oscillation.position` and
    :meth:`stt_drake.core.motion.ConstantVelocity.position`); other motion models and σ
    schedules are evaluated per obstacle.
    """

    def __init__(self, obstacles: Sequence[ObstacleModel], dimension: int) -> None:
        super().__init__()
        self._obstacles = list(obstacles)
        self._dimension = dimension
        count = len(self._obstacles)
        self._template = obstacle_belief(self._obstacles, dimension, 0.0).to_vector()
        self._template = self._template.reshape(count, record_size(dimension))

        def kind(motion_type: type) -> list[int]:
            return [j for j, o in enumerate(self._obstacles) if type(o.motion) is motion_type]

        oscillating, moving = kind(Oscillation), kind(ConstantVelocity)
        self._oscillating = np.array(oscillating, dtype=int)
        motions = [self._obstacles[j].motion for j in oscillating]
        shape = (len(motions), dimension)
        self._center = np.array([m.center for m in motions], dtype=float).reshape(shape)
        self._amplitude = np.array([m.amplitude for m in motions], dtype=float).reshape(shape)
        self._angular_frequency = np.array(
            [2.0 * np.pi * m.frequency_hz for m in motions], dtype=float
        )
        self._phase = np.array(
            [m.phase if m.phase else [0.0] * dimension for m in motions], dtype=float
        ).reshape(shape)
        self._moving = np.array(moving, dtype=int)
        motions = [self._obstacles[j].motion for j in moving]
        shape = (len(motions), dimension)
        self._start = np.array([m.start for m in motions], dtype=float).reshape(shape)
        self._velocity = np.array([m.velocity for m in motions], dtype=float).reshape(shape)
        vectorised = set(oscillating) | set(moving)
        self._other = [j for j in range(count) if j not in vectorised]
        self._scheduled = [j for j, o in enumerate(self._obstacles) if o.sigma_schedule is not None]
        self.DeclareVectorOutputPort(
            "obstacle_belief",
            belief_size(count, dimension),
            self._calc_belief,
            prerequisites_of_calc={self.time_ticket()},
        )

    @property
    def obstacle_count(self) -> int:
        return len(self._obstacles)

    def belief_vector(self, t: float) -> np.ndarray:
        """The port value at time t (equal to ``obstacle_belief(obstacles, n, t).to_vector()``)."""
        n = self._dimension
        kernels = backend.kernels()
        if kernels is not None:
            vector = kernels.belief_table(
                self._template,
                float(t),
                self._oscillating,
                self._center,
                self._amplitude,
                self._angular_frequency,
                self._phase,
                self._moving,
                self._start,
                self._velocity,
            )
            table = vector.reshape(-1, record_size(n))
        else:
            table = self._template.copy()
            vector = table.reshape(-1)
            if self._oscillating.size:
                angle = self._angular_frequency[:, None] * t + self._phase
                table[self._oscillating, :n] = self._center + self._amplitude * np.sin(angle)
            if self._moving.size:
                table[self._moving, :n] = self._start + t * self._velocity
        for j in self._other:
            table[j, :n] = self._obstacles[j].motion.position(t)
        for j in self._scheduled:
            table[j, n] = obstacle_sigma(self._obstacles[j], t)
        return vector

    def _calc_belief(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.belief_vector(context.get_time()))
