"""The Gaussian obstacle belief of Definition 2.1, and its layout on a Drake vector port.

Obstacle j is the ball B(O_j, r_o_j) with an uncertain centre O_j ~ N(mean_j, sigma_j² I).
Each obstacle also carries its own task numbers: the minimum avoidance probability
epsilon_j (Def. 2.2) and the separation level p_d_j of Assumption 3.1.

On a port the belief of `count` obstacles in dimension n is one vector, obstacle-major:
``[mean (n), sigma, radius, epsilon, p_d]`` for obstacle 0, then obstacle 1, ...
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Number of scalars after the mean in one obstacle's record: sigma, radius, epsilon, p_d.
_SCALAR_FIELDS = 4


def record_size(dimension: int) -> int:
    """Length of one obstacle's record in the belief vector: mean (n) + 4 scalars."""
    return dimension + _SCALAR_FIELDS


def belief_size(count: int, dimension: int) -> int:
    """Length of the belief vector for `count` obstacles in R^dimension."""
    return count * record_size(dimension)


@dataclass(frozen=True)
class ObstacleBelief:
    """Belief over all obstacles at one instant (arrays over obstacles j).

    Attributes:
        mean: (m, n) mean of each obstacle centre, metres.
        sigma: (m,) standard deviation of each centre per axis, metres (not a variance).
        radius: (m,) obstacle radius r_o, metres.
        epsilon: (m,) required avoidance probability, in (0, 1].
        p_d: (m,) separation probability of Assumption 3.1, in (epsilon, 1].
    """

    mean: np.ndarray
    sigma: np.ndarray
    radius: np.ndarray
    epsilon: np.ndarray
    p_d: np.ndarray

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
