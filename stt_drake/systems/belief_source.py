"""ObstacleBeliefSource: the Gaussian belief of every obstacle as a function of time."""

from __future__ import annotations

from pydrake.systems.framework import BasicVector, Context, LeafSystem

from stt_drake.belief import belief_size
from stt_drake.scenario import Obstacle, obstacle_belief


class ObstacleBeliefSource(LeafSystem):
    """Outputs `obstacle_belief`: [mean, sigma, radius, epsilon, p_d] per obstacle
    (layout in :mod:`stt_drake.belief`), from each obstacle's motion model and σ schedule.

    Stands in for a tracker or SLAM front end; a user with a real one replaces this system
    by anything that writes the same port.
    """

    def __init__(self, obstacles: list[Obstacle], dimension: int) -> None:
        super().__init__()
        self.set_name("obstacle_belief_source")
        self._obstacles = list(obstacles)
        self._dimension = dimension
        self.DeclareVectorOutputPort(
            "obstacle_belief",
            belief_size(len(self._obstacles), dimension),
            self._calc_belief,
            prerequisites_of_calc={self.time_ticket()},
        )

    @property
    def obstacle_count(self) -> int:
        return len(self._obstacles)

    def _calc_belief(self, context: Context, output: BasicVector) -> None:
        belief = obstacle_belief(self._obstacles, self._dimension, context.get_time())
        output.SetFromVector(belief.to_vector())
