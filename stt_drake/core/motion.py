"""Obstacle motion models and sigma and covariance schedules: mean μ_j(t), σ_j(t) and
Σ_j(t) as functions of time.

Pure numpy, no Drake. Each model is a dataclass that a scenario YAML names with a tag
(``motion: !Oscillation {...}``) and that evaluates itself at a time t.

Each also bounds how fast it changes (``speed_bound`` in m/s, ``rate_bound`` in m/s for σ,
``sigma_rate_bound`` in m/s for the largest standard deviation √λ_max(Σ)):
the fixed-rate tube needs those bounds to keep its guarantee over a whole update period
(:mod:`stt_drake.core.fixed_rate`, "Discrete-time guarantee"). A piecewise-linear model may repeat a
time once: that is a step (a belief jump, e.g. a tracker's measurement update), which is
not part of the rate bound — the tube treats it as a discontinuity and recovers from it.

A recorded track (:class:`Recorded`, read from a data file by :mod:`stt_drake.config.tracks`)
exists only over its samples' span [t_first, t_last]: outside it the obstacle's slot is
inactive (:meth:`MotionTable.active`), as a tracker's slot without a track is.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Union

import numpy as np

from stt_drake.core.rules import check_finite, check_step_times, check_vector, checked_by, require


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

    def __post_init__(self) -> None:
        with checked_by("ConstantVelocity"):
            check_motion(self)

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

    def __post_init__(self) -> None:
        with checked_by("Oscillation"):
            check_motion(self)

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

    def __post_init__(self) -> None:
        with checked_by("Waypoints"):
            check_motion(self)

    def position(self, t: float) -> np.ndarray:
        positions = np.asarray(self.positions, dtype=float)
        return np.array(
            [np.interp(t, self.times, positions[:, axis]) for axis in range(positions.shape[1])]
        )

    def speed_bound(self) -> float:
        """Largest segment speed ‖Δp‖/Δt (m/s); a repeated time (a step) is not a segment."""
        return _slope_bound(self.times, np.asarray(self.positions, dtype=float))


class Track:
    """The samples of one recorded obstacle track: `times` (k,) s, strictly increasing, k ≥ 2,
    and `positions` (k, n) m. Read-only arrays; a scenario copied for another seed shares
    them (``copy.deepcopy`` returns the same track)."""

    __slots__ = ("positions", "times")

    def __init__(self, times: np.ndarray, positions: np.ndarray) -> None:
        times = np.array(times, dtype=float)
        positions = np.array(positions, dtype=float)
        if times.ndim != 1 or positions.ndim != 2 or positions.shape[0] != times.size:
            raise ValueError(
                f"Track: times must be (k,) and positions (k, n), got {times.shape} and "
                f"{positions.shape}"
            )
        if times.size < 2 or not bool(np.all(np.diff(times) > 0.0)):
            raise ValueError("Track: times must increase strictly over at least 2 samples")
        times.flags.writeable = False
        positions.flags.writeable = False
        self.times, self.positions = times, positions

    def __deepcopy__(self, memo: dict) -> "Track":
        return self

    @property
    def span(self) -> tuple[float, float]:
        """(t_first, t_last) (s): the time the track exists over."""
        return float(self.times[0]), float(self.times[-1])


@dataclass
class Recorded:
    """μ(t) from a recorded track: the samples of obstacle `id` in the data file `file`
    (CSV ``t,id,x,y[,z]`` or NPZ ``t``, ``id``, ``position``; a path relative to the
    scenario file's folder), linear between samples. The obstacle exists over the samples'
    span [t_first, t_last] only: outside it its slot is inactive (:meth:`active`;
    :meth:`position` holds the end sample there, a value nothing reads).

    The loader reads the file and attaches the samples (:mod:`stt_drake.config.tracks`);
    code that has the samples makes one with :meth:`of`."""

    file: str = ""
    id: int = 0

    @classmethod
    def of(
        cls, times: np.ndarray, positions: np.ndarray, file: str = "", id: int = 0
    ) -> "Recorded":
        """A recorded motion through `positions` (k, n) m at `times` (k,) s."""
        motion = cls(file=file, id=id)
        motion.attach(Track(times, positions))
        return motion

    def attach(self, track: Track) -> None:
        """Give the motion its samples (the loader does, once it has read the file)."""
        self.__dict__["_track"] = track

    @property
    def loaded(self) -> bool:
        """Whether the samples are attached."""
        return self.__dict__.get("_track") is not None

    @property
    def track(self) -> Track:
        track = self.__dict__.get("_track")
        if track is None:
            raise ValueError(
                f"Recorded(file={self.file!r}, id={self.id}): the track file was not read; "
                "load the scenario with stt_drake.config (or make it with Recorded.of)"
            )
        return track

    def position(self, t: float) -> np.ndarray:
        track = self.track
        return np.array([np.interp(t, track.times, axis) for axis in track.positions.T])

    def active(self, t: float) -> bool:
        """Whether the obstacle exists at t: t_first ≤ t ≤ t_last."""
        first, last = self.track.span
        return first <= t <= last

    def speed_bound(self) -> float:
        """Largest segment speed ‖Δp‖/Δt (m/s) over the samples."""
        return _slope_bound(self.track.times, self.track.positions)


Motion = Union[ConstantVelocity, Oscillation, Waypoints, Recorded]  # noqa: UP007 (drake yaml needs typing.Union)


def check_motion(motion: Motion, dimension: int | None = None) -> None:
    """The rules of a motion model in R^n, `dimension` = n: every vector n finite entries,
    frequency_hz ≥ 0, waypoint times non-decreasing with one position each (a scenario
    file's rules, :mod:`stt_drake.config.validate`; a :class:`Recorded` track is checked
    when read, :mod:`stt_drake.config.tracks`).

    The models' constructors check them with n = the length of the first vector
    (``ConstantVelocity(start=[0, 0], velocity=[1])`` is refused: ``velocity must have 2
    entries``); a model made without arguments is the blank a scenario file's loader fills
    in, checked once n is known (:func:`stt_drake.core.obstacle.check_obstacle`). A broken
    rule raises :class:`stt_drake.core.rules.RuleError` naming the field."""
    if isinstance(motion, ConstantVelocity):
        n = len(motion.start) if dimension is None else dimension
        check_vector(motion.start, "start", n)
        check_vector(motion.velocity, "velocity", n)
    elif isinstance(motion, Oscillation):
        n = len(motion.center) if dimension is None else dimension
        check_vector(motion.center, "center", n)
        check_vector(motion.amplitude, "amplitude", n)
        if motion.phase:
            check_vector(motion.phase, "phase", n)
        check_finite(motion.frequency_hz, "frequency_hz")
        require(motion.frequency_hz >= 0.0, "frequency_hz", "must be ≥ 0", motion.frequency_hz)
    elif isinstance(motion, Waypoints):
        if dimension is None and not motion.times and not motion.positions:
            return  # the loader's blank
        require(len(motion.times) >= 1, "times", "needs at least one time", motion.times)
        require(
            len(motion.positions) == len(motion.times),
            "positions",
            "needs one position per time",
            motion.positions,
        )
        check_step_times(motion.times, "times")
        n = len(motion.positions[0]) if dimension is None else dimension
        for i, position in enumerate(motion.positions):
            check_vector(position, f"positions[{i}]", n)


class MotionTable:
    """The means of many obstacles at once: oscillating and constant-velocity models are
    stacked into arrays once and evaluated in one expression each (the same functions as
    their ``position``); the piecewise-linear ones (:class:`Waypoints`, :class:`Recorded`)
    are concatenated into one sample table and looked up in one ``np.searchsorted`` call for
    all of them (:class:`_SampleTable`); any other model one by one. The stacked arrays
    and the sample table are also what the compiled belief kernel reads
    (:func:`stt_drake.core._kernels.belief_table`), which bisects each track itself.

    Every method takes one time or, ``*_at``, an array of times (one call for all)."""

    def __init__(self, motions: Sequence[Motion], dimension: int) -> None:
        self._motions = list(motions)
        self.dimension = dimension

        def kind(*motion_types: type) -> list[int]:
            return [j for j, m in enumerate(self._motions) if type(m) in motion_types]

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
        sampled = kind(Waypoints, Recorded)
        self.sampled = np.array(sampled, dtype=int)
        #: The piecewise-linear tracks of the `sampled` rows, concatenated (its arrays
        #: times, positions, first, last, bounded are what the compiled kernel reads).
        self.samples = _SampleTable([self._motions[j] for j in sampled], dimension)
        samples = self.samples
        #: The stacked arrays as the compiled kernel reads them, two arguments, not fourteen
        #: (a compiled call's cost grows with its argument count): `kernel_layout` (int64)
        #: = [n, o, v, s, S, oscillating (o), moving (v), sampled (s), first, last,
        #: bounded (s each)] for o oscillating, v moving, s sampled rows and S samples, and
        #: `kernel_values` = [center, amplitude (o·n each), angular_frequency (o), phase
        #: (o·n), start, velocity (v·n each), samples.times (S), samples.positions (S·n)].
        counts = [dimension, len(oscillating), len(moving), len(sampled), samples.times.size]
        layout = [counts, self.oscillating, self.moving, self.sampled, samples.first]
        layout += [samples.last, samples.bounded]
        self.kernel_layout = np.concatenate(layout).astype(np.int64)
        values = [self.center, self.amplitude, self.angular_frequency, self.phase, self.start]
        values += [self.velocity, samples.times, samples.positions]
        self.kernel_values = np.concatenate(values, axis=None)
        stacked = set(oscillating) | set(moving) | set(sampled)
        self.other = [j for j in range(len(self._motions)) if j not in stacked]
        #: Rows of the obstacles that exist over a span only (:class:`Recorded`).
        self.bounded = self.sampled[self.samples.bounded]

    def fill_others(self, means: np.ndarray, t: float) -> None:
        """Write the means of the models none of the stacked arrays hold (any model
        beyond the four kinds of :data:`Motion`) into rows of `means`, one by one."""
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
        if self.sampled.size:
            means[self.sampled] = self.samples.lookup(np.array([float(t)]))[0]
        self.fill_others(means, t)
        return means

    def positions_at(self, times: np.ndarray) -> np.ndarray:
        """(K, m, n): every obstacle's mean at each of `times` (K,), one call per kind."""
        times = np.asarray(times, dtype=float).reshape(-1)
        means = np.empty((times.size, len(self._motions), self.dimension))
        t = times[:, None, None]
        if self.oscillating.size:
            means[:, self.oscillating] = oscillation_positions(
                self.center, self.amplitude, self.angular_frequency[:, None], self.phase, t
            )
        if self.moving.size:
            means[:, self.moving] = constant_velocity_positions(self.start, self.velocity, t)
        if self.sampled.size:
            means[:, self.sampled] = self.samples.lookup(times)
        for j in self.other:
            means[:, j] = [self._motions[j].position(float(time)) for time in times]
        return means

    def active(self, t: float) -> np.ndarray:
        """(m,) bool: which obstacles exist at t (all but a :class:`Recorded` outside its
        span)."""
        return self.active_at(np.array([float(t)]))[0]

    def active_at(self, times: np.ndarray) -> np.ndarray:
        """(K, m) bool: :meth:`active` at each of `times` (K,)."""
        times = np.asarray(times, dtype=float).reshape(-1)
        active = np.ones((times.size, len(self._motions)), dtype=bool)
        if self.bounded.size:
            first, last = self.samples.first_time, self.samples.last_time
            bounded = self.samples.bounded
            t = times[:, None]
            active[:, self.bounded] = (first[bounded] <= t) & (t <= last[bounded])
        return active


class _SampleTable:
    """Piecewise-linear tracks (:class:`Waypoints`, :class:`Recorded`) concatenated: the
    samples of track i are rows ``first[i] .. last[i]`` of `times` and `positions`.

    A lookup finds, for every track at once, the segment [k, k + 1] holding t with one
    ``np.searchsorted`` on `keys`: track i's times shifted by i·`stride` (`stride` a power
    of two above the whole time span, so the shifted tracks follow each other and `keys` is
    sorted). The shift rounds (relative 2⁻⁵³ of i·stride), so the index found is then
    corrected exactly on the unshifted times, twice each way (a Waypoints time may repeat
    once). Held outside a track's span; at a repeated time (a step) the later sample, as
    ``np.interp`` does."""

    def __init__(self, motions: Sequence[Motion], dimension: int) -> None:
        tracks = []
        for motion in motions:
            if isinstance(motion, Recorded):
                tracks.append((motion.track.times, motion.track.positions))
            else:
                times = np.asarray(motion.times, dtype=float)
                positions = np.asarray(motion.positions, dtype=float).reshape(-1, dimension)
                if times.size == 1:  # one sample: a constant, as a zero-length step
                    times, positions = np.repeat(times, 2), np.repeat(positions, 2, axis=0)
                tracks.append((times, positions))
        self.bounded = np.array([isinstance(m, Recorded) for m in motions], dtype=bool)
        lengths = np.array([t.size for t, _ in tracks], dtype=np.int64)
        self.last = np.cumsum(lengths) - 1
        self.first = self.last - lengths + 1
        if tracks:
            self.times = np.concatenate([t for t, _ in tracks])
            self.positions = np.concatenate([p for _, p in tracks]).reshape(-1, dimension)
        else:
            self.times, self.positions = np.empty(0), np.empty((0, dimension))
        self.positions = np.ascontiguousarray(self.positions, dtype=float)
        self.first_time = self.times[self.first] if tracks else np.empty(0)
        self.last_time = self.times[self.last] if tracks else np.empty(0)
        self.origin = float(self.times.min()) if tracks else 0.0
        span = float(self.times.max()) - self.origin if tracks else 0.0
        self.stride = 2.0 ** math.ceil(math.log2(span + 1.0))
        self.shift = self.stride * np.arange(len(tracks), dtype=float)
        track_of = np.repeat(np.arange(len(tracks)), lengths)
        self.keys = (self.times - self.origin) + self.shift[track_of]

    def lookup(self, times: np.ndarray) -> np.ndarray:
        """(K, s, n): every track's position at each of `times` (K,)."""
        t = times[:, None]
        index = np.searchsorted(self.keys, (t - self.origin) + self.shift, side="right") - 1
        low, high = self.first, self.last - 1  # segment starts of each track
        index = np.clip(index, low, high)
        for _ in range(2):  # the exact segment: times[k] ≤ t < times[k + 1] where there is one
            index += (self.times[index + 1] <= t) & (index < high)
            index -= (self.times[index] > t) & (index > low)
        start, end = self.times[index], self.times[index + 1]
        step = end - start
        elapsed = t - start
        fraction = np.where(
            step > 0.0,
            np.clip(np.divide(elapsed, step, out=np.zeros_like(step), where=step > 0.0), 0, 1),
            elapsed >= 0.0,  # a step: the later sample from its time on
        )
        before, after = self.positions[index], self.positions[index + 1]
        return before + fraction[..., None] * (after - before)


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


@dataclass
class CovarianceSchedule:
    """Piecewise-linear covariance Σ(t) (m²) of an obstacle centre through `covariances`
    (n×n matrices) at `times` (s), held outside that span; a repeated time is a step.

    Σ(t) is interpolated entrywise (the same ``np.interp`` as :class:`SigmaSchedule`, so a
    step behaves alike). Between two samples Σ(t) = (1 − s)Σ_k + sΣ_{k+1}, s ∈ [0, 1]: a
    convex combination of symmetric positive definite matrices is symmetric positive
    definite (xᵀΣ(t)x = (1 − s)xᵀΣ_k x + s xᵀΣ_{k+1}x > 0 for x ≠ 0), so a schedule of
    valid covariances is valid at every t.
    """

    times: list[float] = field(default_factory=list)
    covariances: list[list[list[float]]] = field(default_factory=list)

    def covariance(self, t: float) -> np.ndarray:
        """Σ(t) (n, n), m²."""
        samples = np.asarray(self.covariances, dtype=float)
        flat = samples.reshape(samples.shape[0], -1)
        values = [np.interp(t, self.times, flat[:, i]) for i in range(flat.shape[1])]
        return np.array(values).reshape(samples.shape[1:])

    def sigma_bounds(self) -> tuple[float, float]:
        """(low, high) with low ≤ σ_max(t) ≤ high for every t, σ_max(t) = √λ_max(Σ(t)) (m).

        λ_max is convex in Σ, so along a segment λ_max(Σ(t)) ≤ max(λ_max(Σ_k), λ_max(Σ_{k+1})):
        `high` is the largest sample value, attained. λ_max(Σ) ≥ tr Σ/n and the trace is
        linear in t, so `low` = √(min_k tr Σ_k / n), a lower bound (σ_max can dip below
        every sample's: a covariance that turns, Σ_0 = diag(1, 0.01), Σ_1 = diag(0.01, 1),
        has σ_max = 1 at both samples and √0.505 halfway).
        """
        samples = np.asarray(self.covariances, dtype=float)
        n = samples.shape[-1]
        largest = np.linalg.eigvalsh(samples)[:, -1]
        traces = np.trace(samples, axis1=1, axis2=2)
        return float(np.sqrt(np.min(traces) / n)), float(np.sqrt(np.max(largest)))

    def sigma_rate_bound(self) -> float:
        """sup_t |σ̇_max(t)| (m/s) with σ_max(t) = √λ_max(Σ(t)), steps excluded.

        The segment slopes |Δ√λ_max|/Δt are not enough: on a segment Σ(t) is affine, and
        σ_max(t) = √λ_max(Σ(t)) is not (it can change inside a segment whose samples have
        the same σ_max, see :meth:`sigma_bounds`). What holds: f(t) = λ_max(Σ(t)) is convex
        along the segment (λ_max is convex in Σ), so its one-sided derivatives lie between
        those at the ends, which are values uᵀΣ̇u of unit vectors: |ḟ| ≤ ‖ΔΣ‖₂/Δt. With
        σ̇_max = ḟ/(2σ_max) and σ_max² ≥ tr Σ(t)/n ≥ min(tr Σ_k, tr Σ_{k+1})/n,

            |σ̇_max| ≤ ‖ΔΣ‖₂ / (2Δt·√(min(tr Σ_k, tr Σ_{k+1})/n))   on segment k.

        This is at least the segment slope |Δ√λ_max|/Δt (mean value theorem) and equals
        the true sup for Σ(t) = σ(t)²I. A repeated time (a step) is not a segment.
        """
        samples = np.asarray(self.covariances, dtype=float)
        dt = np.diff(np.asarray(self.times, dtype=float))
        if dt.size == 0:
            return 0.0
        n = samples.shape[-1]
        change = np.linalg.norm(np.diff(samples, axis=0), ord=2, axis=(1, 2))
        traces = np.trace(samples, axis1=1, axis2=2)
        floor = np.sqrt(np.minimum(traces[:-1], traces[1:]) / n)
        segments = dt > 0.0
        rates = change[segments] / (2.0 * dt[segments] * floor[segments])
        return float(np.max(rates, initial=0.0))


def _slope_bound(times: list[float], values: np.ndarray) -> float:
    """max ‖Δvalue‖/Δt over consecutive samples with Δt > 0 (0 for fewer than two)."""
    dt = np.diff(np.asarray(times, dtype=float))
    if dt.size == 0:
        return 0.0
    change = np.linalg.norm(np.diff(values, axis=0), axis=1)
    segments = dt > 0.0
    return float(np.max(change[segments] / dt[segments], initial=0.0))
