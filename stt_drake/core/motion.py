"""Obstacle motion models and sigma schedules: mean μ_j(t) and σ_j(t) as functions of time.

Pure numpy, no Drake. Each model is a dataclass that a scenario YAML names with a tag
(``motion: !Oscillation {...}``) and that evaluates itself at a time t.

Each also bounds how fast it changes (``speed_bound`` in m/s, ``rate_bound`` in m/s for σ):
the fixed-rate tube needs those bounds to keep its guarantee over a whole update period
(:mod:`stt_drake.core.tube`, "Discrete-time guarantee"). A piecewise-linear model may repeat a
time once: that is a step (a belief jump, e.g. a tracker's measurement update), which is
not part of the rate bound — the tube treats it as a discontinuity and recovers from it.
"""

from dataclasses import dataclass, field
from typing import Union

import numpy as np


@dataclass
class ConstantVelocity:
    """μ(t) = start + velocity·t (metres, metres per second)."""

    start: list[float] = field(default_factory=list)
    velocity: list[float] = field(default_factory=list)

    def position(self, t: float) -> np.ndarray:
        return np.asarray(self.start, dtype=float) + t * np.asarray(self.velocity, dtype=float)

    def speed_bound(self) -> float:
        """sup_t ‖μ̇(t)‖ = ‖velocity‖ (m/s)."""
        return float(np.linalg.norm(np.asarray(self.velocity, dtype=float)))


@dataclass
class Oscillation:
    """μ(t) = center + amplitude·sin(2π·frequency_hz·t + phase) per axis (phase in radians)."""

    center: list[float] = field(default_factory=list)
    amplitude: list[float] = field(default_factory=list)
    frequency_hz: float = 0.1
    phase: list[float] = field(default_factory=list)

    def position(self, t: float) -> np.ndarray:
        phase = np.asarray(self.phase, dtype=float) if self.phase else 0.0
        angle = 2.0 * np.pi * self.frequency_hz * t + phase
        return np.asarray(self.center, dtype=float) + np.asarray(self.amplitude) * np.sin(angle)

    def speed_bound(self) -> float:
        """sup_t ‖μ̇(t)‖ ≤ 2π·frequency_hz·‖amplitude‖ (m/s; equality when the phases agree)."""
        return float(2.0 * np.pi * self.frequency_hz * np.linalg.norm(self.amplitude))


@dataclass
class Waypoints:
    """Piecewise-linear μ(t) through `positions` at `times` (s), held outside that span."""

    times: list[float] = field(default_factory=list)
    positions: list[list[float]] = field(default_factory=list)

    def position(self, t: float) -> np.ndarray:
        positions = np.asarray(self.positions, dtype=float)
        return np.array(
            [np.interp(t, self.times, positions[:, axis]) for axis in range(positions.shape[1])]
        )

    def speed_bound(self) -> float:
        """Largest segment speed ‖Δp‖/Δt (m/s); a repeated time (a step) is not a segment."""
        return _slope_bound(self.times, np.asarray(self.positions, dtype=float))


Motion = Union[ConstantVelocity, Oscillation, Waypoints]  # noqa: UP007 (drake yaml needs typing.Union)


@dataclass
class SigmaSchedule:
    """Piecewise-linear standard deviation σ(t) (metres) through `values` at `times` (s)."""

    times: list[float] = field(default_factory=list)
    values: list[float] = field(default_factory=list)

    def sigma(self, t: float) -> float:
        return float(np.interp(t, self.times, self.values))

    def rate_bound(self) -> float:
        """Largest |Δσ|/Δt over the segments (m/s); a repeated time (a step) is not a segment."""
        return _slope_bound(self.times, np.asarray(self.values, dtype=float)[:, None])


def _slope_bound(times: list[float], values: np.ndarray) -> float:
    """max ‖Δvalue‖/Δt over consecutive samples with Δt > 0 (0 for fewer than two)."""
    dt = np.diff(np.asarray(times, dtype=float))
    if dt.size == 0:
        return 0.0
    change = np.linalg.norm(np.diff(values, axis=0), axis=1)
    segments = dt > 0.0
    return float(np.max(change[segments] / dt[segments], initial=0.0))
