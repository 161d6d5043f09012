"""A simulated perception chain: true obstacles → sensor → Kalman tracker → `obstacle_belief`.

Thin Drake systems around :mod:`stt_drake.core.perception` (true world, sensor draws) and
:mod:`stt_drake.core.tracking` (the Kalman filters). Wire them as::

    TrueObstacles.true_obstacle_position → ObstacleSensor.true_obstacle_position
    (robot output)                       → ObstacleSensor.robot_position
    ObstacleSensor.detections            → ObstacleTracker.detections
    ObstacleTracker.obstacle_belief      → (tube, monitor, ...)

with the tracker updating at the sensor's delivery times (its period, offset = the
latency). Latency L delivers the sample taken at t (stamped t) at t + L: the belief at τ
holds every detection stamped ≤ τ − L and none later, L = 0 included.

Data association is known (slot j is obstacle j) and the slot count is fixed at build.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from stt_drake.core.belief import belief_size
from stt_drake.core.consistency import CONSISTENCY_FIELDS
from stt_drake.core.motion import Motion, MotionTable
from stt_drake.core.perception import Detections, SensorModel, TruthPath, detection_size
from stt_drake.core.tracking import KalmanTracker, TrackTable, consistency_stats

#: Relative slack when counting sensor periods (a latency of 3 periods is 3, not 2.999...).
_PERIOD_SLACK = 1e-9


class TrueObstacles(LeafSystem):
    """Output `true_obstacle_position` (m·n, obstacle-major): each obstacle's true centre
    O_j(t) = μ_j(t) + δ_j(t), its scenario motion plus the drawn deviation `truth`
    (:mod:`stt_drake.core.perception`). A function of time only. An obstacle that does not
    exist at t (a recorded track outside its span) is NaN there: no sensor detects it
    (a NaN distance is never within range) and it hits nothing."""

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
        """(m, n) true centres at time t (s), metres (NaN rows: absent obstacles)."""
        positions = self._motions.positions(t) + self._truth.deviation(t)
        if self._motions.bounded.size:
            positions[~self._motions.active(t)] = np.nan
        return positions

    def _calc_positions(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.positions(context.get_time()).ravel())


class ObstacleSensor(LeafSystem):
    """Samples the obstacles every ``model.period`` seconds (sample k at k·period) with the
    pre-drawn noise and dropouts of `model` (by sample index), and delivers each sample
    `latency` seconds after it was taken.

    Inputs: `robot_position` (n, m; for the range check), `true_obstacle_position` (m·n).
    Output `detections`: per slot ``[position (n), detected (1.0/0.0), stamp (s)]``
    (:class:`stt_drake.core.perception.Detections`) of the latest sample delivered at the
    context time τ, sample k* = ⌊(τ − latency)/period⌋ (the largest k with
    k·period + latency ≤ τ); before the first delivery nothing is detected and the stamps
    are −inf. A system that reads it at τ therefore sees every sample stamped ≤ τ − latency
    and none later: update it at the delivery times k·period + latency
    (:class:`ObstacleTracker` with ``offset=latency``).

    The output is computed from the time, the discrete state and, for a sample taken at τ
    itself, the inputs. A measuring event at each k·period writes sample k into a ring of
    ⌈latency/period⌉ + 1 records (discrete state: every sample taken and not yet
    superseded by a delivered one), where the output finds k*. At a sample instant with
    latency 0, another system's discrete update at that same instant reads the state
    before the measuring event (Drake: all updates of one instant read the state before
    them), which does not hold sample k* yet: the output then measures it from the inputs
    at τ = k*·period, with the same pre-drawn noise and dropout, the same value the event
    stores. So at latency 0 a tracker updating at k·period consumes sample k at k·period.
    """

    def __init__(self, model: SensorModel, latency: float = 0.0, presence: bool = False) -> None:
        super().__init__()
        if not 0.0 <= latency < math.inf:
            raise ValueError(f"ObstacleSensor: latency must be finite and >= 0 s, got {latency}")
        self._model = model
        self._latency = latency
        count, n = model.count, model.dimension
        self._robot_port = self.DeclareVectorInputPort("robot_position", n)
        self._truth_port = self.DeclareVectorInputPort("true_obstacle_position", count * n)
        # With `presence`: input `obstacle_present` (m, 1.0/0.0); an absent slot (a
        # pedestrian not in the scene, CrowdSimulator.pedestrian_active) is never detected.
        self._present_port = (
            self.DeclareVectorInputPort("obstacle_present", count) if presence else None
        )
        self._depth = ring_depth(latency, model.period)
        empty = Detections.none(count, n).to_vector()
        self._ring = self.DeclareDiscreteState(np.tile(empty, self._depth))
        # The sample index each ring record holds (−1: none yet).
        self._ring_index = self.DeclareDiscreteState(np.full(self._depth, -1.0))
        self.DeclarePeriodicDiscreteUpdateEvent(model.period, 0.0, self._measure)
        self.DeclareVectorOutputPort(
            "detections",
            detection_size(count, n),
            self._calc_detections,
            prerequisites_of_calc={
                self.time_ticket(),
                self.xd_ticket(),
                self.all_input_ports_ticket(),
            },
        )

    @property
    def latency(self) -> float:
        """Seconds from a sample to its delivery."""
        return self._latency

    @property
    def depth(self) -> int:
        """Records in the ring: ⌈latency/period⌉ + 1."""
        return self._depth

    def delivered_index(self, t: float) -> int:
        """Index k* of the latest sample delivered at time t (s): the largest k with
        k·period + latency ≤ t (up to a relative rounding slack); negative: none yet."""
        return math.floor((t - self._latency) / self._model.period + _PERIOD_SLACK)

    def _measured(self, index: int, context: Context) -> np.ndarray:
        """The detections vector of sample `index` from the inputs in `context`."""
        detections = self._model.measure(
            index, self._truth_port.Eval(context), self._robot_port.Eval(context)
        )
        if self._present_port is not None:
            absent = self._present_port.Eval(context) <= 0.5
            detections.detected[absent] = False
            detections.position[absent] = 0.0
        return detections.to_vector()

    def _measure(self, context: Context, discrete_state: DiscreteValues) -> None:
        index = self._model.sample_index(context.get_time())
        record = self._measured(index, context)
        ring = discrete_state.get_mutable_vector(self._ring).get_mutable_value()
        ring.reshape(self._depth, -1)[index % self._depth] = record
        held = discrete_state.get_mutable_vector(self._ring_index).get_mutable_value()
        held[index % self._depth] = index

    def detections(self, context: Context) -> np.ndarray:
        """The `detections` vector at the context time (class docstring).

        Raises:
            RuntimeError: sample k* is neither in the ring nor taken at the context time
                (the ring is too short: a bug).
        """
        t = context.get_time()
        index = self.delivered_index(t)
        if index < 0:
            return Detections.none(self._model.count, self._model.dimension).to_vector()
        slot = index % self._depth
        if context.get_discrete_state(self._ring_index).value()[slot] == index:
            ring = context.get_discrete_state(self._ring).value()
            return ring.reshape(self._depth, -1)[slot].copy()
        if abs(t - index * self._model.period) <= _PERIOD_SLACK * self._model.period:
            # Taken at this instant, before the measuring event has stored it.
            return self._measured(index, context)
        raise RuntimeError(
            f"ObstacleSensor: sample {index} (delivered at t = {t} s) is not in the "
            f"{self._depth}-record ring"
        )

    def _calc_detections(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.detections(context))


def ring_depth(latency: float, period: float) -> int:
    """Records the sensor's ring needs, ⌈latency/period⌉ + 1 (1 at latency 0): at any time
    τ the samples taken and not superseded by a delivered one are k* = ⌊(τ − latency)/period⌋
    up to ⌊τ/period⌋, at most ⌈latency/period⌉ + 1 of them."""
    return math.ceil(latency / period - _PERIOD_SLACK) + 1


class ObstacleTracker(LeafSystem):
    """One constant-velocity Kalman filter per obstacle slot
    (:class:`stt_drake.core.tracking.KalmanTracker`), updated at ``offset + k·period``
    (k = 0, 1, ...) from the `detections` input: each slot with a detection newer than its
    last one is corrected (predicted to the detection's stamp first) or born; a slot
    without one for ``tracker.track_timeout`` seconds is lost. Give it the sensor's period
    and, as `offset`, its latency: it then updates at every delivery time, so its belief at
    τ holds every sample stamped ≤ τ − latency (:class:`ObstacleSensor`).

    Known data association (slot j is obstacle j); the slot count `count` is fixed at build.
    Discrete state: :class:`stt_drake.core.tracking.TrackTable`, per slot ``[KF state (2n),
    covariance ((2n)²), detection time (= the posterior's time, s), active]``, then for a
    monitored tracker (``tracker.adaptation``) ``[noise scale, corrections, last NIS, window
    test, the last W NIS values]`` (:meth:`KalmanTracker.unpack`), so the system is a pure
    function of its discrete state.

    Output `obstacle_belief` (:class:`stt_drake.core.belief.GaussianBelief` layout, per slot
    ``[mean (n), covariance (n²), active]``): each active slot's posterior predicted in
    closed form to the context time; an inactive slot has active = 0, mean 0 and covariance
    I (placeholders). It depends on time and the discrete state only. Detections delivered
    between two tracker updates and superseded before the next one are not seen.

    A correction moves the posterior at once; with ``blend_time`` τ > 0 the output moves
    from the old track's prediction to the new one over τ seconds
    (:func:`stt_drake.core.tracking.blend_beliefs`: the moment-matched mixture, so the
    belief the tube reads is continuous in time and its mean moves at most |Δμ|/τ faster
    than the tracks'); τ = 0 publishes the jump, which the tube meets with its recovery
    behaviour (:mod:`stt_drake.core.tube`). Births and losses are never blended.

    Output `consistency` (m × :data:`~stt_drake.core.consistency.CONSISTENCY_FIELDS`,
    slot-major): each track's running NIS statistics
    (:func:`stt_drake.core.tracking.consistency_stats`; zeros for an unmonitored tracker).

    Output `tracks`: the track table itself (:meth:`TrackTable.to_vector`), for a system
    that predicts further ahead (a guide). Output `belief_updates` (m): per slot, how many
    updates so far changed its track (a correction, a birth or a loss), which a run's
    metrics list as belief discontinuities.
    """

    def __init__(
        self,
        tracker: KalmanTracker,
        count: int,
        period: float,
        blend_time: float = 0.0,
        offset: float = 0.0,
    ) -> None:
        super().__init__()
        if not 0.0 <= offset < math.inf:
            raise ValueError(f"ObstacleTracker: offset must be finite and >= 0 s, got {offset}")
        if not 0.0 <= blend_time <= period:
            raise ValueError(
                f"ObstacleTracker: blend_time must be in [0, period = {period} s] (a blend "
                f"ends before the next update), got {blend_time}"
            )
        self._blend_time = blend_time
        self._tracker = tracker
        n = tracker.dimension
        self._detections_port = self.DeclareVectorInputPort("detections", detection_size(count, n))
        self._tracks = self.DeclareDiscreteState(tracker.empty(count).to_vector())
        self._updates = self.DeclareDiscreteState(np.zeros(count))
        # The blend's start: the last update's time, then the tracks before it (one group:
        # the belief, evaluated at nearly every derivative evaluation, reads it in one lookup).
        self._blend_start = self.DeclareDiscreteState(
            np.concatenate([[-np.inf], tracker.empty(count).to_vector()])
        )
        stats = np.zeros((count, CONSISTENCY_FIELDS))
        stats[:, [3, 5]] = np.nan  # no event yet, not failing
        self._consistency = self.DeclareDiscreteState(stats.ravel())
        self.DeclarePeriodicDiscreteUpdateEvent(period, offset, self._update)
        self.DeclareStateOutputPort("belief_updates", self._updates)
        self.DeclareStateOutputPort("tracks", self._tracks)
        self.DeclareStateOutputPort("consistency", self._consistency)
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
        return self._tracker.unpack(context.get_discrete_state(self._tracks).value())

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        detections = Detections.from_vector(
            self._detections_port.Eval(context), self._tracker.dimension
        )
        before = context.get_discrete_state(self._tracks).value()
        tracks = self.tracks(context)
        after = self._tracker.step(tracks, detections, context.get_time())
        vector = after.to_vector()
        if after.window:
            stats = context.get_discrete_state(self._consistency).value()
            stats = consistency_stats(
                stats.reshape(len(after.active), -1), tracks, after, context.get_time()
            )
            discrete_state.set_value(self._consistency, stats.ravel())
        changed = np.any((vector != before).reshape(len(after.active), -1), axis=1)
        discrete_state.set_value(self._tracks, vector)
        counts = context.get_discrete_state(self._updates).value() + changed
        discrete_state.set_value(self._updates, counts)
        discrete_state.set_value(self._blend_start, np.concatenate([[context.get_time()], before]))

    def belief_vector(self, context: Context) -> np.ndarray:
        """The published belief at the context time, as the `obstacle_belief` port vector
        (blended for `blend_time` after an update)."""
        t = context.get_time()
        state = context.get_discrete_state()  # once: each group lookup from the context costs
        blend_start = state.get_value(self._blend_start)
        elapsed = t - blend_start.item(0)  # a Python float, not numpy's
        weight = elapsed / self._blend_time if elapsed < self._blend_time else 1.0
        return self._tracker.belief_vector(
            state.get_value(self._tracks), blend_start[1:], t, weight
        )

    def _calc_belief(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.belief_vector(context))
