"""An interactive crowd inside a Drake Diagram: JuPedSim pedestrians that see the robot.

:class:`CrowdSimulator` replaces :class:`stt_drake.systems.perception.TrueObstacles` in
front of the :class:`~stt_drake.systems.perception.ObstacleSensor`: the same output port
`true_obstacle_position` (m·n, obstacle-major, slot j = pedestrian j), plus
`pedestrian_active` for the sensor's `obstacle_present` input, so a pedestrian that has left
the scene is not detected.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from stt_drake.crowd.engine import CrowdEngine
from stt_drake.crowd.scenes import CrowdSetup

#: Default period of the crowd's discrete update (s).
DEFAULT_PERIOD = 0.05
#: Relative slack on times compared with the engine's.
_TIME_SLACK = 1e-9


class CrowdSimulator(LeafSystem):
    """A JuPedSim crowd (:class:`stt_drake.crowd.engine.CrowdEngine`, the Collision Free
    Speed Model) stepped every `period` seconds by a periodic discrete update, with the
    robot (input `robot_position`, n = 2, m) a hole of `robot_radius` m in the pedestrians'
    walkable area, so they route around it and keep off it.

    Timing: the update at t_k = k·period reads the robot position at t_k, advances the crowd
    from t_k to t_{k+1} with the robot held there, and stores the positions at both ends.
    Output `true_obstacle_position` (m·2) at t ∈ [t_k, t_{k+1}) interpolates them linearly
    (a continuous truth; the crowd's motion over a period is decided at its start, from the
    robot position then). Output `pedestrian_active` (m, 1.0/0.0): whether pedestrian j was
    in the scene at t_k; one that has left (reached its exit) keeps its last position and is
    inactive (the sensor must not detect it). Both outputs are functions of the time and
    the discrete state only.

    Discrete state (in the Context): positions at t_k and t_{k+1} (2·m·2), active at t_k
    and t_{k+1} (2·m), and [t_k, t_{k+1}, hidden periods] (the periods in which the robot
    could not be placed in the crowd, :class:`CrowdEngine`).

    **The JuPedSim simulation is external state**: it lives in this system, not in the
    Context, and only moves forward. So a Context of this system cannot be cloned and
    stepped twice, nor rewound; the update checks that the Context is the one the engine
    followed (the same time and positions) and raises RuntimeError otherwise. An
    initialization event starts the crowd afresh when the Context is at t = 0 (so
    ``Simulator.Initialize()`` twice, or a second Simulator with a fresh Context of the same
    Diagram, each run the same crowd from its start); initializing a Context later than
    t = 0 keeps the engine only if it matches that Context. Two simulations at once need two
    systems.
    """

    def __init__(
        self, setup: CrowdSetup, robot_radius: float, period: float = DEFAULT_PERIOD
    ) -> None:
        super().__init__()
        self._setup = setup
        self._robot_radius = float(robot_radius)
        self._period = float(period)
        self._engine = CrowdEngine(setup, period, robot_radius)
        count = setup.count
        self._count = count
        starts = np.asarray(setup.starts, dtype=float).ravel()
        self._robot_port = self.DeclareVectorInputPort("robot_position", 2)
        self._positions = self.DeclareDiscreteState(np.concatenate([starts, starts]))
        self._active = self.DeclareDiscreteState(np.ones(2 * count))
        self._clock = self.DeclareDiscreteState(np.zeros(3))
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._step)
        prerequisites = {self.time_ticket(), self.xd_ticket()}
        self.DeclareVectorOutputPort(
            "true_obstacle_position",
            2 * count,
            self._calc_positions,
            prerequisites_of_calc=prerequisites,
        )
        self.DeclareVectorOutputPort(
            "pedestrian_active",
            count,
            self._calc_active,
            prerequisites_of_calc={self.xd_ticket()},
        )

    @property
    def setup(self) -> CrowdSetup:
        """The crowd's set-up."""
        return self._setup

    @property
    def period(self) -> float:
        """Seconds between two crowd updates."""
        return self._period

    def hidden_periods(self, context: Context) -> int:
        """Periods so far in which the robot could not be placed in the crowd."""
        return int(context.get_discrete_state(self._clock).value()[2])

    def positions(self, context: Context) -> np.ndarray:
        """(m, 2) pedestrian positions at the context time (m; class docstring)."""
        state = context.get_discrete_state(self._positions).value().reshape(2, self._count, 2)
        active = context.get_discrete_state(self._active).value().reshape(2, self._count) > 0.5
        start, end, _ = context.get_discrete_state(self._clock).value()
        if end <= start:
            return state[0].copy()
        alpha = float(np.clip((context.get_time() - start) / (end - start), 0.0, 1.0))
        moving = (active[0] & active[1])[:, None]
        return np.where(moving, (1.0 - alpha) * state[0] + alpha * state[1], state[0])

    def active(self, context: Context) -> np.ndarray:
        """(m,) whether each pedestrian was in the scene at the last update."""
        return context.get_discrete_state(self._active).value()[: self._count] > 0.5

    def _calc_positions(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.positions(context).ravel())

    def _calc_active(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.active(context).astype(float))

    def _in_step(self, context: Context) -> bool:
        """Whether the engine is where `context` says the crowd is: its time is the
        state's t_{k+1} and its positions the state's positions there."""
        end = context.get_discrete_state(self._clock).value()[1]
        stored = context.get_discrete_state(self._positions).value().reshape(2, -1)[1]
        engine = self._engine
        return abs(engine.time - end) <= _TIME_SLACK * max(1.0, end) and np.array_equal(
            engine.positions.ravel(), stored
        )

    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        if context.get_time() == 0.0:
            if self._engine.steps > 0:  # a fresh start: the engine cannot be rewound
                self._engine = CrowdEngine(self._setup, self._period, self._robot_radius)
            starts = np.asarray(self._setup.starts, dtype=float).ravel()
            discrete_state.set_value(self._positions, np.concatenate([starts, starts]))
            discrete_state.set_value(self._active, np.ones(2 * self._count))
            discrete_state.set_value(self._clock, np.zeros(3))
            return
        if not self._in_step(context):
            raise RuntimeError(self._external_state_message(context))

    def _step(self, context: Context, discrete_state: DiscreteValues) -> None:
        t = context.get_time()
        engine = self._engine
        end = context.get_discrete_state(self._clock).value()[1]
        if not self._in_step(context) or abs(t - end) > _TIME_SLACK * max(1.0, t) + 1e-12:
            raise RuntimeError(self._external_state_message(context))
        before, active_before = engine.positions, engine.active
        engine.step(self._robot_port.Eval(context))
        discrete_state.set_value(
            self._positions, np.concatenate([before.ravel(), engine.positions.ravel()])
        )
        discrete_state.set_value(
            self._active, np.concatenate([active_before, engine.active]).astype(float)
        )
        discrete_state.set_value(
            self._clock, [engine.time - self._period, engine.time, engine.hidden_periods]
        )

    def _external_state_message(self, context: Context) -> str:
        return (
            f"CrowdSimulator: the JuPedSim crowd is at t = {self._engine.time:g} s, the "
            f"Context at t = {context.get_time():g} s with other positions: the crowd is "
            "state outside the Context and only moves forward, so a cloned or rewound "
            "Context cannot be stepped (start from t = 0, which Simulator.Initialize() "
            "resets, or build a fresh system)"
        )
