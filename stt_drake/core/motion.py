"""Obstacle motion models and sigma schedules: mean μ_j(t) and σ_j(t) as functions of time.

Pure numpy, no Drake. Each model is a dataclass that a scenario YAML names with a tag
(``motion: !Oscillation {...}``) and that evaluates itself at a time t.

Each also bounds how fast it changes (``speed_bound`` in m/s, ``rate_bound`` in m/s for σ):
the fixed-rate tube needs those bounds to keep its guarantee over a whole update period
(:mod:`stt_drake.core.fixed_rate`, "Discrete-time guarantee"). A piecewise-linear model may repeat a
time once: that is a step (a belief jump, e.g. a tracker's measurement update), which is
not part of the rate bound — the tube treats it as a discontinuity and recovers from it.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Union

import numpy as np


def constant_velocity_positions(start: np.ndarray, velocity: np.ndarray, t: float) -> np.ndarray:
    """μ(t) = start + velocity·t, for one model (n,) or stacked rows (m, n)."""
    return start + t * velocity


def oscillation_positions(
    center: np.ndarray,
    amplitude: np.ndarray,
    angular_frequency: np.ndarray,
    phase: np.ndarray,
    t: float,
) -> np.ndarray:
    """μ(t) = center + amplitude·sin(ω·t + phase), for one model (n,) or stacked rows (m, n)
    with ω = 2π·frequency_hz as (m, 1)."""
    return center + amplitude * np.sin(angular_frequency * t + phase)


@dataclass
class ConstantVelocity:
    """μ(t) = start + velocity·t (metres, metres per second)."""

    start: list[float] = field(default_factory=list)
    velocity: list[float] = field(default_factory=list)

    def position(self, t: float) -> np.ndarray:
        return constant_velocity_positions(
            np.asarray(self.start, dtype=float), np.asarray(self.velocity, dtype=float), t
        )

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
        return oscillation_positions(
            np.asarray(self.center, dtype=float),
            np.asarray(self.amplitude, dtype=float),
            2.0 * np.pi * self.frequency_hz,
            phase,
            t,
        )

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


class MotionTable:
    """The means of many obstacles at once: oscillating and constant-velocity models are
    stacked into arrays once and evaluated in one expression each (the same functions as
    their ``position``), other models one by one. The arrays are also what the compiled
    belief kernel reads (:func:`stt_drake.core._kernels.belief_table`)."""

    def __init__(self, motions: Sequence[Motion], dimension: int) -> None:
        self._motions = list(motions)
        self.dimension = dimension

        def kind(motion_type: type) -> list[int]:
            return [j for j, m in enumerate(self._motions) if type(m) is motion_type]

        oscillating, moving = kind(Oscillation), kind(ConstantVelocity)
        self.oscillating = np.array(oscillating, dtype=int)
        models = [self._motions[j] for j in oscillating]
        shape = (len(models), dimension)
        self.center = np.array([m.center for m in models], dtype=float).reshape(shape)
        self.amplitude = np.array([m.amplitude for m in models], dtype=float).reshape(shape)
        self.angular_frequency = np.array(
            [2.0 * np.pi * m.frequency_hz for m in models], dtype=float
        )
        self.phase = np.array(
            [m.phase if m.phase else [0.0] * dimension for m in models], dtype=float
        ).reshape(shape)
        self.moving = np.array(moving, dtype=int)
        models = [self._motions[j] for j in moving]
        shape = (len(models), dimension)
        self.start = np.array([m.start for m in models], dtype=float).reshape(shape)
        self.velocity = np.array([m.velocity for m in models], dtype=float).reshape(shape)
        stacked = set(oscillating) | set(moving)
        self.other = [j for j in range(len(self._motions)) if j not in stacked]

    def fill_others(self, means: np.ndarray, t: float) -> None:
        """Write the means of the models that are not stacked into rows of `means`."""
        for j in self.other:
            means[j] = self._motions[j].position(t)

    def positions(self, t: float) -> np.ndarray:
        """(m, n): every obstacle's mean μ_j(t)."""
        means = np.empty((len(self._motions), self.dimension))
        if self.oscillating.size:
            means[self.oscillating] = oscillation_positions(
                self.center, self.amplitude, self.angular_frequency[:, None], self.phase, t
            )
        if self.moving.size:
            means[self.moving] = constant_velocity_positions(self.start, self.velocity, t)
        self.fill_others(means, t)
        return means


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
