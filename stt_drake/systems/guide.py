"""TubeGuide: the tube's attraction point η(t) from a route over the predicted beliefs."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Context, DiscreteValues, EventStatus, LeafSystem

from stt_drake.core.belief import GaussianBelief, belief_size
from stt_drake.core.guide import (
    Forecast,
    GuideSettings,
    Route,
    RoutePlanner,
    ScriptedForecast,
    tracked_forecast,
)
from stt_drake.core.guide import attraction_point as route_point
from stt_drake.core.progress import StallDetector, StallRule
from stt_drake.core.tracking import KalmanTracker

#: Stalled regions the guide remembers at once (the oldest is dropped).
MAX_AVOIDED = 8
#: How long a stalled region is avoided, in stall times.
AVOID_STALL_TIMES = 5.0
#: The most corners a route keeps in the guide's state.
MAX_ROUTE_POINTS = 256
#: The `guide_status` output: [replans, stalls, expansions of the last plan, route reached].
STATUS_SIZE = 4


class TubeGuide(LeafSystem):
    """Outputs the tube's attraction point η(t) (`target`, n) on a route planned over the
    obstacles' predicted beliefs (:mod:`stt_drake.core.guide`, where the safety argument
    is: claims (ii)/(iii) of Theorem 3.2 hold for any η(t)). Connect `target` to the tube's
    `target` input (:func:`stt_drake.assembly.stt.AddStt` with ``target_input=True``); the
    task's own target stays the goal.

    Inputs: `tube` ([c, r], n + 1); `obstacle_belief` (the belief port, to notice a track
    born or lost); with a `tracker`, `tracks` (the tracker's
    :class:`~stt_drake.core.tracking.TrackTable` vector: the forecast is its own
    constant-velocity prediction), else the forecast is the scripted motion
    (:class:`~stt_drake.core.guide.ScriptedForecast`); with ``goal_input=True``, `goal`
    (n: a task sequencer's current target), else `goal` is fixed.

    Every `period` seconds (and at initialisation) it replans from the tube's centre when
    `replan_period` has passed, the goal changed, a slot's active flag changed or the
    centre stalled (:class:`~stt_drake.core.progress.StallDetector` on ‖c − η‖ with
    `stall_rule`); a stall also marks a region around the centre that the next routes avoid
    for :data:`AVOID_STALL_TIMES` stall times. Then η moves to the route's point for now
    (:func:`stt_drake.core.guide.attraction_point`). η is discrete state: constant between
    ticks, so the integrator sees it change only at event times. (A ramp of η between
    ticks, tried, removes the kink of ċ at a tick but costs more per evaluation than the
    integrator steps it saves.)

    Output `guide_status` = [replans so far, stalls so far, expansions of the last search,
    1 if the last route reached the goal].
    """

    def __init__(
        self,
        planner: RoutePlanner,
        settings: GuideSettings,
        count: int,
        dimension: int,
        period: float,
        replan_period: float,
        stall_rule: StallRule,
        arrived: float,
        goal: np.ndarray | None = None,
        forecast: ScriptedForecast | None = None,
        tracker: KalmanTracker | None = None,
    ) -> None:
        super().__init__()
        if (forecast is None) == (tracker is None):
            raise ValueError("TubeGuide: give exactly one of `forecast` and `tracker`")
        self._planner, self._settings = planner, settings
        self._n, self._count = dimension, count
        self._replan_period = replan_period
        self._stall_rule, self._arrived = stall_rule, arrived
        self._forecast, self._tracker = forecast, tracker
        n = dimension
        self._tube_port = self.DeclareVectorInputPort("tube", n + 1)
        self._belief_port = self.DeclareVectorInputPort("obstacle_belief", belief_size(count, n))
        self._tracks_port = (
            self.DeclareVectorInputPort("tracks", count * tracker.record_size)
            if tracker is not None
            else None
        )
        self._goal = None if goal is None else np.asarray(goal, dtype=float)
        self._goal_port = self.DeclareVectorInputPort("goal", n) if goal is None else None
        self._eta = self.DeclareDiscreteState(np.zeros(n))
        # [last update time, last replan time, progress along the route (m), goal (n),
        #  active flags (count)]
        self._book = self.DeclareDiscreteState(
            np.concatenate([[-np.inf, -np.inf, 0.0], np.zeros(n), np.zeros(count)])
        )
        self._status = self.DeclareDiscreteState(np.zeros(STATUS_SIZE))
        self._stall = self.DeclareDiscreteState(np.zeros(StallDetector.vector_size(n)))
        self._route = self.DeclareDiscreteState(route_to_vector(_no_route(n), n))
        # rows [centre (n), radius, until] of the stalled regions (until = −∞: no region)
        avoid = np.zeros((MAX_AVOIDED, n + 2))
        avoid[:, -1] = -np.inf
        self._avoid = self.DeclareDiscreteState(avoid.ravel())
        # All of the guide's state is numeric and fixed-size, so a discrete update (which
        # declares that only discrete state changes) carries it; the route is a padded
        # vector (route_to_vector) rather than abstract state.
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("target", self._eta)
        self.DeclareStateOutputPort("guide_status", self._status)

    def route(self, context: Context) -> Route:
        """The route in force in `context`."""
        return route_from_vector(context.get_discrete_state(self._route).value(), self._n)

    def _goal_in(self, context: Context) -> np.ndarray:
        if self._goal_port is None:
            return self._goal
        return np.array(self._goal_port.Eval(context))

    def _predict(self, context: Context, t: float) -> Forecast:
        times = t + self._settings.knots
        if self._tracker is None:
            return self._forecast(times)
        tracks = self._tracker.unpack(self._tracks_port.Eval(context))
        return tracked_forecast(self._tracker, tracks, times)

    def _update(self, context: Context, discrete_state: DiscreteValues) -> EventStatus:
        t, n = context.get_time(), self._n
        book = context.get_discrete_state(self._book).value().copy()
        if book[0] == t:
            return EventStatus.DidNothing()  # initialisation, then the grid at t = 0
        center = np.array(self._tube_port.Eval(context))[:n]
        goal = self._goal_in(context)
        belief = GaussianBelief.from_vector(self._belief_port.Eval(context), n)
        active = belief.active.astype(float)
        status = context.get_discrete_state(self._status).value().copy()
        detector = StallDetector.from_vector(
            context.get_discrete_state(self._stall).value(), self._stall_rule, self._arrived
        )
        eta_now = context.get_discrete_state(self._eta).value()
        avoid = context.get_discrete_state(self._avoid).value().reshape(MAX_AVOIDED, n + 2)
        avoid = avoid[avoid[:, -1] > t]  # the regions still avoided
        stalled = book[1] > -np.inf and detector.update(t, center, eta_now)
        if stalled:
            status[1] += 1
            radius = self._settings.stall_radius
            until = t + AVOID_STALL_TIMES * self._stall_rule.stall_time
            avoid = np.vstack([avoid, [*center, radius, until]])[-MAX_AVOIDED:]
        progress = book[2]
        replan = (
            stalled
            or t - book[1] >= self._replan_period - 1e-9
            or not np.array_equal(goal, book[3 : 3 + n])
            or not np.array_equal(active, book[3 + n :])
        )
        if replan:
            route = self._planner.plan(
                center, goal, t, self._predict(context, t), avoid[:, : n + 1]
            )
            status[0] += 1
            status[2] = route.expansions
            status[3] = float(route.reached)
            progress = 0.0
            book = np.concatenate([[t, t, 0.0], goal, active])
            discrete_state.set_value(self._route, route_to_vector(route, n))
        else:
            route = self.route(context)
        eta, progress = route_point(route, center, t, self._settings, progress)
        if stalled:  # the stall is answered: its clock starts over with the new route
            detector.reset(t, center, eta)
        book[0], book[2] = t, progress
        padded = np.zeros((MAX_AVOIDED, n + 2))
        padded[:, -1] = -np.inf
        padded[: len(avoid)] = avoid
        discrete_state.set_value(self._book, book)
        discrete_state.set_value(self._eta, eta)
        discrete_state.set_value(self._status, status)
        discrete_state.set_value(self._stall, detector.as_vector(n))
        discrete_state.set_value(self._avoid, padded.ravel())
        return EventStatus.Succeeded()


def route_to_vector(route: Route, n: int) -> np.ndarray:
    """A route as a fixed-length vector [length L, reached, expansions, points
    (MAX_ROUTE_POINTS × n), times (MAX_ROUTE_POINTS)]; a longer route keeps every k-th corner
    and its end."""
    points, times = route.points, route.times
    if len(points) > MAX_ROUTE_POINTS:
        keep = np.unique(
            np.append(np.arange(0, len(points), -(-len(points) // (MAX_ROUTE_POINTS - 1))), -1)
            % len(points)
        )
        points, times = points[keep], times[keep]
    vector = np.zeros(3 + MAX_ROUTE_POINTS * (n + 1))
    length = len(points)
    vector[:3] = [length, float(route.reached), route.expansions]
    vector[3 : 3 + length * n] = points.ravel()
    offset = 3 + MAX_ROUTE_POINTS * n
    vector[offset : offset + length] = times
    return vector


def route_from_vector(vector: np.ndarray, n: int) -> Route:
    """The inverse of :func:`route_to_vector`."""
    length = int(vector[0])
    offset = 3 + MAX_ROUTE_POINTS * n
    return Route(
        points=np.array(vector[3 : 3 + length * n]).reshape(length, n),
        times=np.array(vector[offset : offset + length]),
        reached=bool(vector[1]),
        expansions=int(vector[2]),
    )


def _no_route(n: int) -> Route:
    """The placeholder before the first plan."""
    return Route(np.zeros((1, n)), np.zeros(1), False, 0)
