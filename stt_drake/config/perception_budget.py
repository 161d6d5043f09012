"""What the perception chain (:mod:`stt_drake.core.perception`, :mod:`stt_drake.systems.perception`)
allocates and copies, estimated from the scenario before anything is drawn, for the memory
and work budgets of :mod:`stt_drake.config.limits`.

All three pieces are drawn or held over the horizon H = duration + latency + sensor_period
(``stt_drake.assembly.perception.add_perception``), for m obstacles in R^n:

* the truth path (:func:`stt_drake.core.perception.draw_truth_deviation`; nothing when
  `process_noise_density` is 0): K = H/truth_period grid steps; the kicks are drawn as
  (K, m, n, 2) normals and multiplied by the 2×2 factor (two such arrays at once), then the
  rate and deviation grids (K + 1, m, n) are summed up with two more temporaries: a peak of
  :data:`TRUTH_ARRAYS` arrays of K·m·n doubles;
* the sensor's pre-drawn samples (:class:`stt_drake.core.perception.SensorModel`):
  S = H/sensor_period + 1 samples of (m, n) normals, their product with the noise factor,
  and (S, m) uniform draws for the dropouts: S·m·(2n + 1) doubles;
* the latency ring (:class:`stt_drake.systems.perception.ObstacleSensor`):
  ⌊latency/sensor_period⌋ + 1 records of m·(n + 2) doubles in Drake's discrete state. Drake
  holds it :data:`RING_COPIES` times (the model value, the context, the discrete update's
  scratch copy, ...: 1.6 GB measured for 300 obstacles, a 19 001-record ring of 0.18 GB
  and 0.34 GB of sensor draws), and copies it whole at each of the sensor's two events
  per period: ~63 ms per period for that ring here, :data:`RING_COPY_SECONDS_PER_BYTE`.

The tracker's state (a few hundred bytes per slot) is part of the per-obstacle bytes of
:data:`stt_drake.config.limits.OBSTACLE_BYTES`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from stt_drake.config.schema import Perception

#: Arrays of K·m·n doubles alive at once while the truth path is summed up (see above).
TRUTH_ARRAYS = 6

#: Times Drake holds the sensor's latency ring (measured ~5.3; see the module docstring).
RING_COPIES = 6

#: Wall seconds per byte of the latency ring and per sensor period: the ring is copied
#: whole at the sensor's events (measured: 63 ms per period for a 0.18 GB ring).
RING_COPY_SECONDS_PER_BYTE = 0.35e-9

_DOUBLE = 8


@dataclass(frozen=True)
class Demand:
    """One allocation of the perception chain: its size (bytes, a float: it may be huge),
    the field that drives it and one phrase saying what it is."""

    path: str
    bytes: float
    what: str


def horizon(perception: Perception, duration: float) -> float:
    """H = duration + latency + sensor_period (s), the span everything is drawn over."""
    return duration + perception.latency + perception.sensor_period


def ring_records(perception: Perception) -> float:
    """Records in the sensor's latency ring (0 without a latency)."""
    if perception.latency <= 0.0:
        return 0.0
    return math.floor(perception.latency / perception.sensor_period) + 1.0


def _usable(perception: Perception) -> bool:
    """Periods and latency a budget can be computed from (the rules of
    :mod:`stt_drake.config.validate_perception` refuse the others later)."""
    return (
        perception.truth_period > 0.0
        and perception.sensor_period > 0.0
        and perception.latency >= 0.0
        and perception.process_noise_density >= 0.0
    )


def perception_demands(
    perception: Perception, obstacles: int, dimension: int, duration: float
) -> list[Demand]:
    """The truth path, the sensor draws and the latency ring of `obstacles` obstacles in
    R^`dimension` over a run of `duration` s (module docstring), each with the field that
    drives it: the latency when it is longer than the run, else the period."""
    if not _usable(perception) or obstacles == 0:
        return []
    span = horizon(perception, duration)
    long_latency = perception.latency > duration
    path = "scenario.perception."
    demands = []
    if perception.process_noise_density > 0.0:
        steps = span / perception.truth_period + 1.0
        demands.append(
            Demand(
                path + ("latency" if long_latency else "truth_period"),
                TRUTH_ARRAYS * _DOUBLE * steps * obstacles * dimension,
                f"the truth path: {steps:.3g} steps of truth_period over duration + latency "
                f"+ sensor_period = {span:.4g} s × {obstacles} obstacles × {dimension} axes "
                f"× {TRUTH_ARRAYS} arrays × 8 B",
            )
        )
    samples = span / perception.sensor_period + 1.0
    demands.append(
        Demand(
            path + ("latency" if long_latency else "sensor_period"),
            _DOUBLE * samples * obstacles * (2 * dimension + 1),
            f"the sensor's draws: {samples:.3g} samples × {obstacles} obstacles × "
            f"(2·{dimension} + 1) × 8 B",
        )
    )
    records = ring_records(perception)
    if records > 0.0:
        demands.append(
            Demand(
                path + "latency",
                RING_COPIES * ring_bytes(perception, obstacles, dimension),
                f"the latency ring: {records:.3g} records of {obstacles} × ({dimension} + 2) "
                f"values × 8 B, held {RING_COPIES} times",
            )
        )
    return demands


def ring_bytes(perception: Perception, obstacles: int, dimension: int) -> float:
    """Bytes of one copy of the sensor's latency ring."""
    return ring_records(perception) * obstacles * (dimension + 2) * _DOUBLE


def ring_copy_seconds(
    perception: Perception, obstacles: int, dimension: int, duration: float
) -> float:
    """Wall seconds the run spends copying the latency ring: one copy's bytes ×
    duration/sensor_period × :data:`RING_COPY_SECONDS_PER_BYTE`."""
    if not _usable(perception):
        return 0.0
    periods = duration / perception.sensor_period
    return ring_bytes(perception, obstacles, dimension) * periods * RING_COPY_SECONDS_PER_BYTE
