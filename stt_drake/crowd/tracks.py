"""Running a crowd offline into tracks (t, id, x, y), and the tracks' CSV file.

The CSV format (read back by a scenario's ``!Recorded {file, id}`` obstacles): a header
``t,id,x,y``, then one row per sample in SI units (s, m), rows grouped by pedestrian id
(0..N−1, the set-up's slot) with t increasing inside a group. A pedestrian that has left the
scene (reached its exit) is no longer written: its track ends at its last sample in the
scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from stt_drake.crowd.engine import CrowdEngine
from stt_drake.crowd.scenes import CrowdSetup

#: The CSV header.
CSV_HEADER = "t,id,x,y"
#: Default sample rate (Hz).
DEFAULT_RATE = 10.0
#: Most samples (times × pedestrians) one offline run records.
MAX_SAMPLES = 20_000_000


@dataclass(frozen=True)
class Tracks:
    """Sampled crowd: `times` (K,) s from 0; `positions` (K, N, 2) m; `active` (K, N),
    whether pedestrian i was in the scene at sample k (its position is the last one held
    when not)."""

    times: np.ndarray
    positions: np.ndarray
    active: np.ndarray

    def track(self, pedestrian: int) -> tuple[np.ndarray, np.ndarray]:
        """(times, positions) of one pedestrian while it was in the scene."""
        keep = self.active[:, pedestrian]
        return self.times[keep], self.positions[keep, pedestrian]


def sample_count(duration: float, rate: float) -> int:
    """Samples at k/rate for k = 0, 1, ... up to `duration` (s) inclusive."""
    return math.floor(duration * rate + 1e-9) + 1


def run_tracks(setup: CrowdSetup, duration: float, rate: float = DEFAULT_RATE) -> Tracks:
    """Simulate `setup` alone (no robot) for `duration` s and sample it at `rate` Hz.

    Raises:
        ValueError: duration < 0 or not finite, rate ≤ 0 or not finite, or more than
            :data:`MAX_SAMPLES` samples.
        CrowdUnavailableError: JuPedSim is not installed.
    """
    if not (math.isfinite(duration) and duration >= 0.0):
        raise ValueError(f"duration must be finite and ≥ 0 s (got {duration})")
    if not (math.isfinite(rate) and rate > 0.0):
        raise ValueError(f"rate must be finite and > 0 Hz (got {rate})")
    count = sample_count(duration, rate)
    if count * setup.count > MAX_SAMPLES:
        raise ValueError(
            f"duration × rate × pedestrians = {count * setup.count} samples, more than "
            f"{MAX_SAMPLES} (shorten the duration or lower the rate)"
        )
    engine = CrowdEngine(setup, 1.0 / rate)
    positions = np.empty((count, setup.count, 2))
    active = np.empty((count, setup.count), dtype=bool)
    for k in range(count):
        if k > 0:
            engine.step()
        positions[k], active[k] = engine.positions, engine.active
    return Tracks(np.arange(count) / rate, positions, active)


def write_tracks_csv(tracks: Tracks, stream: TextIO) -> int:
    """Write `tracks` as CSV (module docstring) to `stream`; returns the rows written."""
    stream.write(CSV_HEADER + "\n")
    rows = 0
    for pedestrian in range(tracks.positions.shape[1]):
        times, positions = tracks.track(pedestrian)
        block = np.column_stack([times, np.full(len(times), pedestrian), positions])
        np.savetxt(stream, block, fmt=["%.10g", "%d", "%.6f", "%.6f"], delimiter=",")
        rows += len(times)
    return rows
