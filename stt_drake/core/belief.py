"""The Gaussian obstacle belief of Definition 2.1, and its layout on a Drake vector port.

Obstacle j is the ball B(O_j, r_o_j) with an uncertain centre O_j ~ N(mean_j, sigma_j² I).
Each obstacle also carries its own task numbers: the minimum avoidance probability
epsilon_j (Definition 2.3) and the separation level p_d_j of Assumption 3.

On a port the belief of `count` obstacles in dimension n is one vector, obstacle-major:
``[mean (n), sigma, radius, epsilon, p_d]`` for obstacle 0, then obstacle 1, ...
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from stt_drake.core.motion import Motion, MotionTable, SigmaSchedule

#: Number of scalars after the mean in one obstacle's record: sigma, radius, epsilon, p_d.
_SCALAR_FIELDS = 4


def record_size(dimension: int) -> int:
    """Length of one obstacle's record in the belief vector: mean (n) + 4 scalars."""
    return dimension + _SCALAR_FIELDS


def belief_size(count: int, dimension: int) -> int:
    """Length of the belief vector for `count` obstacles in R^dimension."""
    return count * record_size(dimension)


def covariance_size(count: int, dimension: int) -> int:
    """Length of the `obstacle_covariance` port vector: each Σ_j row-major, obstacle-major."""
    return count * dimension * dimension


@dataclass(frozen=True)
class ObstacleBelief:
    """Belief over all obstacles at one instant (arrays over obstacles j).

    Attributes:
        mean: (m, n) mean of each obstacle centre, metres.
        sigma: (m,) standard deviation of each centre per axis, metres (not a variance).
        radius: (m,) obstacle radius r_o, metres.
        epsilon: (m,) required avoidance probability, in (0, 1].
        p_d: (m,) separation probability of Assumption 3, in (epsilon, 1].
        covariance: (m, n, n) full covariance Σ_j of each centre (m², symmetric positive
            definite), or None: Σ_j = sigma_j² I. When given, `sigma` holds √λ_max(Σ_j)
            (the largest standard deviation) and the tube law uses Σ_j exactly
            (:mod:`stt_drake.core.anisotropic_tube`). Not part of the belief port's record:
            the covariances travel on a port of their own (:func:`covariance_size`).
    """

    mean: np.ndarray
    sigma: np.ndarray
    radius: np.ndarray
    epsilon: np.ndarray
    p_d: np.ndarray
    covariance: np.ndarray | None = None

    @property
    def count(self) -> int:
        return self.mean.shape[0]

    @property
    def dimension(self) -> int:
        return self.mean.shape[1]

    def to_vector(self) -> np.ndarray:
        """Pack into the port layout described in the module docstring."""
        scalars = np.column_stack([self.sigma, self.radius, self.epsilon, self.p_d])
        return np.hstack([self.mean, scalars]).ravel()

    @classmethod
    def from_vector(cls, vector: np.ndarray, dimension: int) -> ObstacleBelief:
        """Unpack a port vector (views, no copies)."""
        record = record_size(dimension)
        vector = np.asarray(vector, dtype=float)
        if vector.size % record:
            raise ValueError(
                f"belief vector of length {vector.size} is not a whole number of "
                f"{record}-long obstacle records for dimension {dimension}"
            )
        table = vector.reshape(-1, record)
        return cls(
            mean=table[:, :dimension],
            sigma=table[:, dimension],
            radius=table[:, dimension + 1],
            epsilon=table[:, dimension + 2],
            p_d=table[:, dimension + 3],
        )


class ObstacleModel(Protocol):
    """What the belief of one obstacle is made from: the mean's motion model, σ (constant,
    or a schedule), and the task numbers r_o, ε, p_d (a scenario's ``Obstacle`` is one)."""

    motion: Motion
    radius: float
    sigma: float
    sigma_schedule: SigmaSchedule | None
    epsilon: float
    p_d: float


def obstacle_belief(obstacles: Sequence[ObstacleModel], dimension: int, t: float) -> ObstacleBelief:
    """The belief of every obstacle in `obstacles` at time t."""
    return ObstacleBelief(
        mean=MotionTable([o.motion for o in obstacles], dimension).positions(t),
        sigma=np.array([obstacle_sigma(o, t) for o in obstacles]),
        radius=np.array([o.radius for o in obstacles]),
        epsilon=np.array([o.epsilon for o in obstacles]),
        p_d=np.array([o.p_d for o in obstacles]),
    )


def obstacle_rate_bounds(obstacles: Sequence[ObstacleModel]) -> tuple[np.ndarray, np.ndarray]:
    """Per obstacle, sup ‖μ̇_j‖ and sup |σ̇_j| (m/s) from its motion model and σ schedule,
    steps excluded (a step is a belief discontinuity, see :mod:`stt_drake.core.motion`)."""
    mean_speed = np.array([o.motion.speed_bound() for o in obstacles], dtype=float)
    sigma_rate = np.array(
        [0.0 if o.sigma_schedule is None else o.sigma_schedule.rate_bound() for o in obstacles],
        dtype=float,
    )
    return mean_speed, sigma_rate


def obstacle_sigma(obstacle: ObstacleModel, t: float) -> float:
    """σ_j(t): the schedule where given, else the constant `sigma`."""
    if obstacle.sigma_schedule is not None:
        return obstacle.sigma_schedule.sigma(t)
    return obstacle.sigma
