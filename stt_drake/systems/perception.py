"""A simulated perception chain: true obstacles → sensor → Kalman tracker → `obstacle_belief`.

Thin Drake systems around :mod:`stt_drake.core.perception` (true world, sensor draws) and
:mod:`stt_drake.core.tracking` (the Kalman filters). Wire them as::

    TrueObstacles.true_obstacle_position → ObstacleSensor.true_obstacle_position
    (robot output)                       → ObstacleSensor.robot_position
    ObstacleSensor.detections            → ObstacleTracker.detections
    ObstacleTracker.obstacle_belief      → (tube, monitor, ...)

Data association is known (slot j is obstacle j) and the slot count is fixed at build.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from stt_drake.core.belief import GaussianBelief, belief_size
from stt_drake.core.motion import Motion, MotionTable
from stt_drake.core.perception import Detections, SensorModel, TruthPath, detection_size
from stt_drake.core.tracking import KalmanTracker, TrackTable, blend_beliefs


class TrueObstacles(LeafSystem):
    """Output `true_obstacle_position` (m·n, obstacle-major): each obstacle's true centre
    O_j(t) = μ_j(t) + δ_j(t), its scenario motion plus the drawn deviation `truth`
    (:mod:`stt_drake.core.perception`). A function of time only."""

    def __init__(self, motions: Sequence[Motion], dimension: int, truth: TruthPath) -> None:
        super().__init__()
        count = len(motions)
        if truth.deviation_grid.shape[1:] != (count, dimension):
            raise ValueError(
                f"TrueObstacles: the truth path is drawn for {truth.deviation_grid.shape[1:]} "
                f"(count, dimension), the motions need ({count}, {dimension})"
            )
        self._motions = MotionTable(motions, dimension)
        self._truth = truth
        self.DeclareVectorOutputPort(
            "true_obstacle_position",
            count * dimension,
            self._calc_positions,
            prerequisites_of_calc={self.time_ticket()},
        )

    def positions(self, t: float) -> np.ndarray:
        """(m, n) true centres at time t (s), metres."""
        return self._motions.positions(t) + self._truth.deviation(t)

    def _calc_positions(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.positions(context.get_time()).ravel())


class ObstacleSensor(LeafSystem):
    """Samples the obstacles every ``model.period`` seconds (offset 0) with the pre-drawn
    noise and dropouts of `model` (by sample index), and delivers each sample `latency`
    seconds after it was taken.

    Inputs: `robot_position` (n, m; for the range check), `true_obstacle_position` (m·n).
    Output `detections` (held in discrete state): per slot ``[position (n), detected
    (1.0/0.0), stamp (s)]`` of the last sample delivered
    (:class:`stt_drake.core.perception.Detections`); before the first delivery nothing is
    detected and the stamps are −inf.

    With a latency the samples wait in a ring of ⌊latency/period⌋ + 1 records (a second
    discrete state group) between a measuring event at k·period and a delivering event at
    k·period + latency.
    """

    def __init__(self, model: SensorModel, latency: float = 0.0) -> None:
        super().__init__()
        if latency < 0.0:
            raise ValueError(f"ObstacleSensor: latency must be >= 0 s, got {latency}")
        self._model = model
        self._latency = latency
        count, n = model.count, model.dimension
        self._robot_port = self.DeclareVectorInputPort("robot_position", n)
        self._truth_port = self.DeclareVectorInputPort("true_obstacle_position", count * n)
        empty = Detections.none(count, n).to_vector()
        self._delivered = self.DeclareDiscreteState(empty)
        if latency == 0.0:
            self.DeclarePeriodicDiscreteUpdateEvent(model.period, 0.0, self._measure_and_deliver)
        else:
            self._depth = math.floor(latency / model.period) + 1
            self._pending = self.DeclareDiscreteState(np.tile(empty, self._depth))
            self.DeclarePeriodicDiscreteUpdateEvent(model.period, 0.0, self._measure)
            self.DeclarePeriodicDiscreteUpdateEvent(model.period, latency, self._deliver)
        self.DeclareStateOutputPort("detections", self._delivered)

    def _sample(self, context: Context) -> tuple[int, np.ndarray]:
        """(index, detections vector) of the sample taken at the context's time."""
        index = self._model.sample_index(context.get_time())
        detections = self._model.measure(
            index, self._truth_port.Eval(context), self._robot_port.Eval(context)
        )
        return index, detections.to_vector()

    def _measure_and_deliver(self, context: Context, discrete_state: DiscreteValues) -> None:
        discrete_state.set_value(self._delivered, self._sample(context)[1])

    def _measure(self, context: Context, discrete_state: DiscreteValues) -> None:
        index, record = self._sample(context)
        ring = discrete_state.get_mutable_vector(self._pending).get_mutable_value()
        ring.reshape(self._depth, -1)[index % self._depth] = record

    def _deliver(self, context: Context, discrete_state: DiscreteValues) -> None:
        index = self._model.sample_index(context.get_time() - self._latency)
        ring = context.get_discrete_state(self._pending).value().reshape(self._depth, -1)
        discrete_state.set_value(self._delivered, ring[index % self._depth])


class ObstacleTracker(LeafSystem):
    """One constant-velocity Kalman filter per obstacle slot
    (:class:`stt_drake.core.tracking.KalmanTracker`), updated every `period` seconds
    (offset 0) from the `detections` input: each slot with a detection newer than its last
    one is corrected (predicted to the detection's stamp first) or born; a slot without one
    for ``tracker.track_timeout`` seconds is lost.

    Known data association (slot j is obstacle j); the slot count `count` is fixed at build.
    Discrete state: :class:`stt_drake.core.tracking.TrackTable`, per slot ``[KF state (2n),
    covariance ((2n)²), detection time (= the posterior's time, s), active]``.

    Output `obstacle_belief` (:class:`stt_drake.core.belief.GaussianBelief` layout, per slot
    ``[mean (n), covariance (n²), active]``): each active slot's posterior predicted in
    closed form to the context time; an inactive slot has active = 0, mean 0 and covariance
    I (placeholders). It depends on time and the discrete state only. Use the sensor's
    period: detections delivered between two tracker updates are not seen.

    A correction moves the posterior at once; with ``blend_time`` τ > 0 the output moves
    from the old track's prediction to the new one over τ seconds
    (:func:`stt_drake.core.tracking.blend_beliefs`: the moment-matched mixture, so the
    belief the tube reads is continuous in time and its mean moves at most |Δμ|/τ faster
    than the tracks'); τ = 0 publishes the jump, which the tube meets with its recovery
    behaviour (:mod:`stt_drake.core.tube`). Births and losses are never blended.

    Output `tracks`: the track table itself (:meth:`TrackTable.to_vector`), for a system
    that predicts further ahead (a guide). Output `belief_updates` (m): per slot, how many
    updates so far changed its track (a correction, a birth or a loss), which a run's
    metrics list as belief discontinuities.
    """

    def __init__(
        self, tracker: KalmanTracker, count: int, period: float, blend_time: float = 0.0
    ) -> None:
        super().__init__()
        if not 0.0 <= blend_time <= period:
            raise ValueError(
                f"ObstacleTracker: blend_time must be in [0, period = {period} s] (a blend "
                f"ends before the next update), got {blend_time}"
            )
        self._blend_time = blend_time
        self._tracker = tracker
        n = tracker.dimension
        self._detections_port = self.DeclareVectorInputPort("detections", detection_size(count, n))
        self._tracks = self.DeclareDiscreteState(TrackTable.empty(count, n).to_vector())
        self._updates = self.DeclareDiscreteState(np.zeros(count))
        # The tracks before the last update, and its time (the blend's start).
        self._previous = self.DeclareDiscreteState(TrackTable.empty(count, n).to_vector())
        self._update_time = self.DeclareDiscreteState([-np.inf])
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("belief_updates", self._updates)
        self.DeclareStateOutputPort("tracks", self._tracks)
        self.DeclareVectorOutputPort(
            "obstacle_belief",
            belief_size(count, n),
            self._calc_belief,
            prerequisites_of_calc={self.time_ticket(), self.xd_ticket()},
        )

    @property
    def model(self) -> KalmanTracker:
        """The tracking rules (what a guide predicts the tracks with)."""
        return self._tracker

    def tracks(self, context: Context) -> TrackTable:
        """The track table held in `context` (this system's context)."""
        vector = context.get_discrete_state(self._tracks).value()
        return TrackTable.from_vector(vector, self._tracker.dimension)

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        detections = Detections.from_vector(
            self._detections_port.Eval(context), self._tracker.dimension
        )
        before = context.get_discrete_state(self._tracks).value()
        after = self._tracker.step(self.tracks(context), detections, context.get_time())
        vector = after.to_vector()
        changed = np.any((vector != before).reshape(len(after.active), -1), axis=1)
        discrete_state.set_value(self._tracks, vector)
        counts = context.get_discrete_state(self._updates).value() + changed
        discrete_state.set_value(self._updates, counts)
        discrete_state.set_value(self._previous, before)
        discrete_state.set_value(self._update_time, [context.get_time()])

    def belief(self, context: Context) -> GaussianBelief:
        """The published belief at the context time (blended after an update)."""
        t = context.get_time()
        belief = self._tracker.belief(self.tracks(context), t)
        elapsed = t - context.get_discrete_state(self._update_time).value()[0]
        if elapsed >= self._blend_time:
            return belief
        vector = context.get_discrete_state(self._previous).value()
        previous = TrackTable.from_vector(vector, self._tracker.dimension)
        old = self._tracker.belief(previous, t)
        return blend_beliefs(old, belief, elapsed / self._blend_time)

    def _calc_belief(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.belief(context).to_vector())
