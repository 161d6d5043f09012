"""Obstacle motion models and sigma schedules: mean μ_j(t) and σ_j(t) as functions of time.

Pure numpy, no Drake. Each model is a dataclass that a scenario YAML names with a tag
(``motion: !Oscillation {...}``) and that evaluates itself at a time t.
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


Motion = Union[ConstantVelocity, Oscillation, Waypoints]  # noqa: UP007 (drake yaml needs typing.Union)


@dataclass
class SigmaSchedule:
    """Piecewise-linear standard deviation σ(t) (metres) through `values` at `times` (s)."""

    times: list[float] = field(default_factory=list)
    values: list[float] = field(default_factory=list)

    def sigma(self, t: float) -> float:
        return float(np.interp(t, self.times, self.values))
