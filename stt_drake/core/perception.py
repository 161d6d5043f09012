"""A simulated perception front end: where the obstacles truly are, and what a sensor reports.

True world
----------
Obstacle j's true centre is its scenario motion plus a random deviation,
``O_j(t) = μ_j(t) + δ_j(t)``, where δ_j is a double integrator driven by white acceleration
noise of spectral density q (m²/s³) on each axis, independently: ``δ̈ = w``,
``E[w(t) w(s)] = q δ(t − s)``, δ(0) = 0, δ̇(0) = 0. It is drawn on a grid of period h with
the exact discretisation of that process: the state [δ, δ̇] of one axis moves by
``x_{k+1} = [[1, h], [0, 1]] x_k + w_k``, ``w_k ~ N(0, q [[h³/3, h²/2], [h²/2, h]])``, so
the grid values have exactly the law of the continuous process at the grid times (e.g.
Var δ(t_k) = q t_k³/3). Between grid points δ is the cubic Hermite interpolant of the grid
values and rates (C¹ in time) (:class:`TruthPath`, :func:`draw_truth_deviation`).

Sensor
------
Every `period` seconds (sample k at t_k = k·period) each obstacle within `sensing_range`
of the robot is detected unless the detection drops out (independently per obstacle and
sample, probability `dropout_probability`); a detection measures the true centre plus
Gaussian noise N(0, `noise_covariance`). Every noise and dropout draw is made at
construction for every sample index up to the horizon (:class:`SensorModel`), so a run is
reproducible from the seed and does not depend on how often anything is evaluated.

Data association is known: a detection carries its obstacle's id, the slot index j.
A sample's detections travel as :class:`Detections`; on a port, per slot
``[position (n), detected (1.0/0.0), stamp (s)]``, slot-major (:func:`detection_size`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Relative slack on the drawn time span: a time a rounding error past its end is inside.
_SPAN_SLACK = 1e-9


@dataclass(frozen=True)
class TruthPath:
    """The deviations δ_j(t) of every obstacle's true centre from its scenario motion, on a
    grid of period `period` from t = 0, with C¹ cubic Hermite interpolation in between.

    Attributes:
        deviation_grid: (K + 1, m, n) δ at the grid times k·period, metres.
        rate_grid: (K + 1, m, n) δ̇ at the grid times, m/s.
        period: grid period h, seconds.
    """

    deviation_grid: np.ndarray
    rate_grid: np.ndarray
    period: float

    @property
    def end(self) -> float:
        """Last time of the grid (s); :meth:`deviation` is defined on [0, end]."""
        return (self.deviation_grid.shape[0] - 1) * self.period

    def deviation(self, t: float) -> np.ndarray:
        """δ(t) (m, n), metres.

        Raises:
            ValueError: t is outside [0, end].
        """
        if not -_SPAN_SLACK * self.period <= t <= self.end + _SPAN_SLACK * self.period:
            raise ValueError(
                f"truth path: t = {t} s is outside the drawn span [0, {self.end}] s; "
                "draw it with a longer horizon"
            )
        k = min(max(math.floor(t / self.period), 0), self.deviation_grid.shape[0] - 2)
        s = t / self.period - k
        h00 = (2.0 * s - 3.0) * s * s + 1.0
        h10 = ((s - 2.0) * s + 1.0) * s
        h01 = (3.0 - 2.0 * s) * s * s
        h11 = (s - 1.0) * s * s
        grid, rate, h = self.deviation_grid, self.rate_grid, self.period
        return h00 * grid[k] + h10 * h * rate[k] + h01 * grid[k + 1] + h11 * h * rate[k + 1]


def draw_truth_deviation(
    count: int,
    dimension: int,
    density: float,
    period: float,
    horizon: float,
    rng: np.random.Generator,
) -> TruthPath:
    """Draw δ_j(t) for `count` obstacles in R^dimension on [0, ≥ horizon] (model in the module
    docstring): white acceleration noise of spectral density `density` q (m²/s³) per axis,
    exact discretisation on a grid of period `period` (s), δ(0) = δ̇(0) = 0.

    With `density` 0 the truth is exactly the scripted motion: nothing is drawn (`rng` is
    left untouched) and the path is δ ≡ 0 on one grid interval spanning the same [0, end]
    (the Cholesky factor of 0·Q does not exist, and K zero rows would cost memory for
    nothing)."""
    steps = max(math.ceil(horizon / period - _SPAN_SLACK), 1)
    if density == 0.0:
        zero = np.zeros((2, count, dimension))
        return TruthPath(deviation_grid=zero, rate_grid=zero.copy(), period=steps * period)
    h = period
    # Per axis, w_k = L ζ with L the Cholesky factor of q [[h³/3, h²/2], [h²/2, h]].
    factor = np.linalg.cholesky(density * np.array([[h**3 / 3.0, h**2 / 2.0], [h**2 / 2.0, h]]))
    kicks = rng.standard_normal((steps, count, dimension, 2)) @ factor.T
    rate = np.zeros((steps + 1, count, dimension))
    rate[1:] = np.cumsum(kicks[..., 1], axis=0)
    deviation = np.zeros_like(rate)
    deviation[1:] = np.cumsum(h * rate[:-1] + kicks[..., 0], axis=0)
    return TruthPath(deviation_grid=deviation, rate_grid=rate, period=period)


def detection_size(count: int, dimension: int) -> int:
    """Length of the `detections` port vector: per slot position (n), detected, stamp."""
    return count * (dimension + 2)


@dataclass(frozen=True)
class Detections:
    """One sensor sample, per obstacle slot j (known association: slot j is obstacle j).

    Attributes:
        position: (m, n) measured centres, metres (0 where not detected).
        detected: (m,) bool, whether slot j was detected.
        stamp: (m,) time each measurement was taken, seconds (−inf: no sample yet).
    """

    position: np.ndarray
    detected: np.ndarray
    stamp: np.ndarray

    @classmethod
    def none(cls, count: int, dimension: int) -> Detections:
        """No detection and no sample yet (stamps −inf)."""
        return cls(
            position=np.zeros((count, dimension)),
            detected=np.zeros(count, dtype=bool),
            stamp=np.full(count, -np.inf),
        )

    def to_vector(self) -> np.ndarray:
        """Per slot ``[position (n), detected (1.0/0.0), stamp]``, slot-major."""
        return np.column_stack([self.position, self.detected.astype(float), self.stamp]).ravel()

    @classmethod
    def from_vector(cls, vector: np.ndarray, dimension: int) -> Detections:
        """Unpack a port vector (views where possible)."""
        table = np.asarray(vector, dtype=float).reshape(-1, dimension + 2)
        return cls(position=table[:, :dimension], detected=table[:, -2] > 0.5, stamp=table[:, -1])


class SensorModel:
    """The sensor's random draws for every sample index 0..K−1 (t_k = k·period ≤ horizon),
    made at construction from `rng`, and the detection rule (module docstring).

    Args:
        count: obstacle slots m.
        dimension: n.
        period: sample period (s).
        horizon: last time a sample is needed (s).
        noise_covariance: (n, n) measurement noise covariance (m², symmetric positive
            semi-definite; anisotropic allowed).
        dropout_probability: probability in [0, 1] that an in-range detection is lost.
        sensing_range: detection radius around the robot (m); inf: everywhere.
        rng: the random generator, consumed at construction only.
    """

    def __init__(
        self,
        count: int,
        dimension: int,
        period: float,
        horizon: float,
        noise_covariance: np.ndarray,
        dropout_probability: float,
        sensing_range: float,
        rng: np.random.Generator,
    ) -> None:
        if not 0.0 <= dropout_probability <= 1.0:
            raise ValueError(f"dropout_probability must be in [0, 1], got {dropout_probability}")
        self.count = count
        self.dimension = dimension
        self.period = period
        self.sensing_range = sensing_range
        samples = math.floor(horizon / period + _SPAN_SLACK) + 1
        # Noise and dropouts from streams of their own, each filled sample by sample: the
        # first k samples are the same whatever the horizon (a shorter run is the start of
        # a longer one).
        noise_draws, dropout_draws = rng.spawn(2)
        self._noise = (
            noise_draws.standard_normal((samples, count, dimension))
            @ _square_root(np.asarray(noise_covariance, dtype=float)).T
        )
        self._dropped = dropout_draws.random((samples, count)) < dropout_probability

    @property
    def sample_count(self) -> int:
        """Number K of pre-drawn samples (indices 0..K−1)."""
        return self._dropped.shape[0]

    def sample_index(self, t: float) -> int:
        """Index k of the sample taken at time t (nearest k·period)."""
        return round(t / self.period)

    def measure(
        self, index: int, true_position: np.ndarray, robot_position: np.ndarray
    ) -> Detections:
        """Sample `index` taken with the obstacles at `true_position` (m, n) and the robot at
        `robot_position` (n,).

        Raises:
            ValueError: `index` is outside the pre-drawn samples.
        """
        if not 0 <= index < self.sample_count:
            raise ValueError(
                f"sensor: sample {index} (t = {index * self.period} s) is outside the "
                f"{self.sample_count} samples drawn; build the sensor with a longer horizon"
            )
        true_position = np.asarray(true_position, dtype=float).reshape(self.count, -1)
        distance = np.linalg.norm(true_position - robot_position, axis=1)
        detected = (distance <= self.sensing_range) & ~self._dropped[index]
        return Detections(
            position=np.where(detected[:, None], true_position + self._noise[index], 0.0),
            detected=detected,
            stamp=np.full(self.count, index * self.period),
        )


def _square_root(covariance: np.ndarray) -> np.ndarray:
    """A factor A with A Aᵀ = covariance (symmetric positive semi-definite), via eigh."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    return vectors * np.sqrt(np.clip(values, 0.0, None))
