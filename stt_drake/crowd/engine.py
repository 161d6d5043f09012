"""Stepping a crowd with JuPedSim (https://www.jupedsim.org), imported lazily: this module
loads without it, and :func:`load_jupedsim` raises :class:`CrowdUnavailableError` ("install
stt-drake[crowd]") when it is missing.

:class:`CrowdEngine` holds one ``jupedsim.Simulation`` of a :class:`CrowdSetup` with the
Collision Free Speed Model (Tordeux et al. 2016, arXiv:1512.05597: a first-order model,
an agent's velocity is a function of the current positions only, and it never walks into
another agent or a wall at its radius). It advances by whole periods and keeps, per
pedestrian slot, the last position and whether the pedestrian is still in the scene (one
that reaches its exit is removed by JuPedSim; its slot keeps its last position).

The robot is seen by the pedestrians as a hole in the walkable area: before each period the
geometry becomes the area minus the disc of `robot_radius` around the robot
(``Simulation.switch_geometry``), so the pedestrians' routing goes around the robot and the
operational model keeps them off it, re-planned every period as the robot moves. Why not an
agent of its own: JuPedSim (1.4) cannot move an agent (``Agent.position`` is read-only), an
added agent is refused when it overlaps another one (the robot's new position always overlaps
its old one, and near contact it overlaps a pedestrian), and a removal takes effect only at
the start of the next iteration, so a robot re-added each period would be missing for one
iteration in each. A hole has limits too: the walkable area must keep holding every
pedestrian and every exit, so the disc shrinks to stay clear of them by
:data:`HOLE_CLEARANCE`; a disc that would shrink below :data:`MIN_HOLE_RADIUS` or split the
area is left out for that period, counted in :attr:`CrowdEngine.hidden_periods`.
"""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np

from stt_drake.crowd.scenes import CrowdSetup

#: What a missing JuPedSim says.
MISSING_MESSAGE = (
    "crowds need JuPedSim, which is not installed: install stt-drake[crowd] "
    "(pip install 'stt-drake[crowd]')"
)
#: Longest JuPedSim iteration (s); a period is cut into equal iterations no longer than it
#: (JuPedSim's recommended step).
MAX_ITERATION = 0.01
#: Clearance the robot's hole keeps from pedestrian centres and exits (m).
HOLE_CLEARANCE = 0.01
#: A hole smaller than this (m) is left out for the period (the robot is hidden).
MIN_HOLE_RADIUS = 0.05


class CrowdUnavailableError(ImportError):
    """JuPedSim (the `crowd` extra) is not installed."""

    def __init__(self) -> None:
        super().__init__(MISSING_MESSAGE)


def load_jupedsim() -> tuple[ModuleType, ModuleType]:
    """The jupedsim and shapely modules.

    Raises:
        CrowdUnavailableError: either is missing ("install stt-drake[crowd]").
    """
    try:
        import jupedsim
        import shapely
    except ImportError as error:
        raise CrowdUnavailableError() from error
    return jupedsim, shapely


def iterations_per_period(period: float) -> int:
    """JuPedSim iterations in one period: ⌈period/MAX_ITERATION⌉ (each period/that long)."""
    if not (math.isfinite(period) and period > 0.0):
        raise ValueError(f"CrowdEngine: period must be finite and > 0 s, got {period}")
    return max(1, math.ceil(period / MAX_ITERATION - 1e-9))


class CrowdEngine:
    """One JuPedSim simulation of `setup`, advanced `period` seconds per :meth:`step`
    (module docstring). `robot_radius` (m) is the disc the pedestrians keep out of around
    the robot position given to :meth:`step` (0: they do not see the robot).

    This object is state outside any Drake Context: it only moves forward. A run that must
    start again makes a new engine.
    """

    def __init__(self, setup: CrowdSetup, period: float, robot_radius: float = 0.0) -> None:
        jupedsim, shapely = load_jupedsim()
        if not (math.isfinite(robot_radius) and robot_radius >= 0.0):
            raise ValueError(
                f"CrowdEngine: robot_radius must be finite and ≥ 0 m, got {robot_radius}"
            )
        self._jps, self._shapely = jupedsim, shapely
        self.setup = setup
        self.period = float(period)
        self._iterations = iterations_per_period(period)
        self._robot_radius = float(robot_radius)
        self._area = shapely.box(*setup.area)
        self._sim = jupedsim.Simulation(
            model=jupedsim.CollisionFreeSpeedModel(),
            geometry=self._area,
            dt=self.period / self._iterations,
        )
        self._exits = [shapely.Polygon(polygon) for polygon in setup.exits]
        stages = [self._sim.add_exit_stage(polygon) for polygon in self._exits]
        journeys = [self._sim.add_journey(jupedsim.JourneyDescription([s])) for s in stages]
        self._agent_ids = np.empty(setup.count, dtype=np.int64)
        for slot in range(setup.count):
            exit_index = int(setup.exit_of[slot])
            self._agent_ids[slot] = self._sim.add_agent(
                jupedsim.CollisionFreeSpeedModelAgentParameters(
                    position=tuple(float(v) for v in setup.starts[slot]),
                    desired_speed=float(setup.desired_speeds[slot]),
                    radius=setup.radius,
                    journey_id=journeys[exit_index],
                    stage_id=stages[exit_index],
                )
            )
        self._slot_of = {int(agent): slot for slot, agent in enumerate(self._agent_ids)}
        self._positions = np.array(setup.starts, dtype=float)
        self._active = np.ones(setup.count, dtype=bool)
        self._holed = False
        self.steps = 0
        self.hidden_periods = 0

    @property
    def time(self) -> float:
        """Crowd time (s): periods stepped × period."""
        return self.steps * self.period

    @property
    def positions(self) -> np.ndarray:
        """(N, 2) each slot's position (m); a pedestrian that left keeps its last one."""
        return self._positions.copy()

    @property
    def active(self) -> np.ndarray:
        """(N,) whether each pedestrian is still in the scene."""
        return self._active.copy()

    def step(self, robot_position: np.ndarray | None = None) -> None:
        """Advance one period with the robot (its hole) at `robot_position` (m; None or
        robot_radius 0: no robot) for the whole period."""
        if robot_position is not None and self._robot_radius > 0.0:
            self._place_robot(np.asarray(robot_position, dtype=float)[:2])
        self._sim.iterate(self._iterations)
        self.steps += 1
        present = np.zeros(self.setup.count, dtype=bool)
        for agent in self._sim.agents():
            slot = self._slot_of.get(agent.id)
            if slot is not None:
                present[slot] = True
                self._positions[slot] = agent.position
        self._active &= present

    def _hole_radius(self, robot: np.ndarray) -> float:
        """The robot's hole radius this period: robot_radius, shrunk to keep
        HOLE_CLEARANCE from every pedestrian centre and exit."""
        radius = self._robot_radius
        if self._active.any():
            gaps = np.linalg.norm(self._positions[self._active] - robot, axis=1)
            radius = min(radius, float(gaps.min()) - HOLE_CLEARANCE)
        point = self._shapely.Point(robot)
        for polygon in self._exits:
            radius = min(radius, float(polygon.distance(point)) - HOLE_CLEARANCE)
        return radius

    def _place_robot(self, robot: np.ndarray) -> None:
        shapely = self._shapely
        disc = shapely.Point(robot).buffer(self._robot_radius, quad_segs=8)
        if not disc.intersects(self._area):  # off the area: nobody can meet it
            self._set_geometry(None)
            return
        radius = self._hole_radius(robot)
        geometry = None
        if radius >= MIN_HOLE_RADIUS:
            geometry = self._area.difference(shapely.Point(robot).buffer(radius, quad_segs=8))
            if geometry.geom_type != "Polygon" or geometry.is_empty:
                geometry = None
        if geometry is None or not self._set_geometry(geometry):
            self.hidden_periods += 1

    def _set_geometry(self, geometry: object | None) -> bool:
        """Switch to `geometry` (None: the plain area); False if JuPedSim refuses it (the
        plain area is then kept)."""
        if geometry is None:
            if self._holed:
                self._sim.switch_geometry(self._area)
                self._holed = False
            return True
        try:
            self._sim.switch_geometry(geometry)
        except RuntimeError:
            self._set_geometry(None)
            return False
        self._holed = True
        return True
