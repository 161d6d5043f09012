"""Constant-velocity Kalman tracking of obstacle slots, vectorised over slots.

Model (per slot, n axes)
------------------------
State x = [p (n), v (n)] (m, m/s) with white acceleration noise of spectral density q
(``process_density``, m²/s³) per axis: over Δt, x ← F x + w with F = [[I, Δt I], [0, I]]
and w ~ N(0, Q(Δt)), Q(Δt) = q [[Δt³/3 I, Δt²/2 I], [Δt²/2 I, Δt I]] (the exact
discretisation). Measurement z = p + e, e ~ N(0, R) (``noise_covariance``, n×n, m²).
The correction is the Joseph form, P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ with
K = P Hᵀ S⁻¹, S = H P Hᵀ + R, H = [I 0] (it keeps P positive semi-definite under rounding
where the short form P − K S Kᵀ need not), made exactly
symmetric afterwards (numpy: averaged with its transpose; kernel: upper triangle mirrored).

Tracks (:class:`KalmanTracker`)
-------------------------------
Data association is known: a detection carries its obstacle's id, which is the slot index,
and the number of slots is fixed. A slot is *born* from its first detection (mean
[z, 0], covariance diag(R, σ_v² I) with σ_v = ``initial_velocity_sigma``, m/s), corrected by
each later detection (predicted to the detection's stamp first), and *lost* (inactive)
once ``track_timeout`` seconds pass without one; a detection after that re-births it.
The belief at a time t after the last posterior is the closed-form prediction: mean
p + v Δt, covariance the position block of F P Fᵀ + Q(Δt), Δt = t − (posterior time), so it
grows continuously between detections and through dropouts.

Consistency (``KalmanTracker.adaptation``, :mod:`stt_drake.core.consistency`): a monitored
tracker also takes each correction's normalised innovation squared, runs the NIS window
test and, when adaptive, scales each track's process density (q_base·s_j, the scale in
the track's record); the belief is then predicted with the track's own density. Without
adaptation (``adaptive: false``) the state and covariance are bit for bit those of the
plain filter.

The functions take and return explicit arrays, for m slots: ``state`` (m, 2n),
``covariance`` (m, 2n, 2n), ``dt`` (m,) or a scalar (s), ``z`` (m, n) (m). The hot one,
:func:`update` (what a tracker step runs), uses the compiled kernel of
:mod:`stt_drake.core._tracking` unless :mod:`stt_drake.core.backend` selects numpy;
:func:`predict` and :func:`correct` are its numpy reference.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from stt_drake.core import backend
from stt_drake.core.belief import GaussianBelief
from stt_drake.core.consistency import Adaptation
from stt_drake.core.perception import Detections


def predict(
    state: np.ndarray,
    covariance: np.ndarray,
    dt: float | np.ndarray,
    density: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(F x, F P Fᵀ + Q(dt)) per slot, with the slot's own dt (s) and density q (m²/s³; a
    float or one per slot)."""
    dt = _per_slot(dt, state.shape[0])
    n = state.shape[1] // 2
    transition = _transitions(dt, n)
    moved = transition @ covariance @ transition.transpose(0, 2, 1)
    return np.einsum("mij,mj->mi", transition, state), moved + _process_noise(dt, density, n)


def correct(
    state: np.ndarray, covariance: np.ndarray, z: np.ndarray, noise_covariance: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The posterior after measuring the position z (m, n) of every slot with noise
    covariance R (n, n), Joseph form (module docstring)."""
    n = z.shape[1]
    gain_t = np.linalg.solve(covariance[:, :n, :n] + noise_covariance, covariance[:, :n, :])
    gain = gain_t.transpose(0, 2, 1)
    posterior = state + np.einsum("mai,mi->ma", gain, z - state[:, :n])
    complement = np.eye(2 * n) - np.concatenate([gain, np.zeros_like(gain)], axis=2)
    joseph = complement @ covariance @ complement.transpose(0, 2, 1)
    joseph += gain @ noise_covariance @ gain_t
    return posterior, 0.5 * (joseph + joseph.transpose(0, 2, 1))


def update(
    state: np.ndarray,
    covariance: np.ndarray,
    dt: float | np.ndarray,
    z: np.ndarray,
    density: float,
    noise_covariance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`predict` by dt, then :func:`correct` with z: one tracker update per slot."""
    kernel = backend.compiled("track_update", z.shape[1])
    if kernel is not None:
        return kernel(
            state, covariance, _per_slot(dt, state.shape[0]), z, float(density), noise_covariance
        )
    return correct(*predict(state, covariance, dt, density), z, noise_covariance)


def birth(
    z: np.ndarray, noise_covariance: np.ndarray, initial_velocity_sigma: float
) -> tuple[np.ndarray, np.ndarray]:
    """New tracks from first detections z (k, n): mean [z, 0], covariance
    diag(R, σ_v² I) with σ_v = `initial_velocity_sigma` (m/s, a standard deviation)."""
    count, n = z.shape
    state = np.concatenate([z, np.zeros_like(z)], axis=1)
    covariance = np.zeros((count, 2 * n, 2 * n))
    covariance[:, :n, :n] = noise_covariance
    covariance[:, n:, n:] = initial_velocity_sigma**2 * np.eye(n)
    return state, covariance


def predicted_position(
    state: np.ndarray,
    covariance: np.ndarray,
    dt: float | np.ndarray,
    density: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The position belief dt (s) after the posterior, in closed form: mean p + v dt (m, n)
    and covariance (m, n, n), the position block of F P Fᵀ + Q(dt):
    P_pp + dt (P_pv + P_vp) + dt² P_vv + q dt³/3 I (q: a float or one per slot, m²/s³)."""
    if isinstance(density, np.ndarray):
        density = density[:, None, None]
    n = state.shape[1] // 2
    dt = _per_slot(dt, state.shape[0])[:, None, None]
    mean = state[:, :n] + dt[:, 0] * state[:, n:]
    cross = covariance[:, :n, n:]
    position = (
        covariance[:, :n, :n]
        + dt * (cross + cross.transpose(0, 2, 1))
        + dt**2 * covariance[:, n:, n:]
        + (density * dt**3 / 3.0) * np.eye(n)
    )
    return mean, position


def _per_slot(dt: float | np.ndarray, count: int) -> np.ndarray:
    """dt as a contiguous (count,) float array."""
    spread = np.empty(count)
    spread[:] = dt  # broadcasts as np.broadcast_to would, at an eighth of its cost
    return spread


def _transitions(dt: np.ndarray, n: int) -> np.ndarray:
    """F = [[I, dt I], [0, I]] per slot, (m, 2n, 2n)."""
    transition = np.broadcast_to(np.eye(2 * n), (dt.size, 2 * n, 2 * n)).copy()
    transition[:, :n, n:] = dt[:, None, None] * np.eye(n)
    return transition


def _process_noise(dt: np.ndarray, density: float | np.ndarray, n: int) -> np.ndarray:
    """Q(dt) = q [[dt³/3, dt²/2], [dt²/2, dt]] ⊗ I_n per slot, (m, 2n, 2n); q a float or
    one per slot (m,)."""
    density = np.asarray(density, dtype=float)
    if density.ndim:  # one density per slot
        density = density[:, None, None]
    blocks = density * np.stack(
        [np.stack([dt**3 / 3.0, dt**2 / 2.0], -1), np.stack([dt**2 / 2.0, dt], -1)], -2
    )
    return np.kron(blocks, np.eye(n))


def track_record_size(dimension: int, window: int = 0) -> int:
    """Length of one slot's record in :meth:`TrackTable.to_vector`; `window` W > 0 adds the
    consistency fields (scale, NIS count, last NIS, test, W NIS values)."""
    d = 2 * dimension
    return d + d * d + 2 + (4 + window if window else 0)


@dataclass(frozen=True)
class TrackTable:
    """Every slot's track (arrays over m slots): the tracker's whole state.

    A posterior stays at the stamp of the detection that made it (the belief at a later
    time is predicted from it in closed form), so one time per slot is the posterior's
    time, the last detection's time and the last stamp consumed at once.

    Attributes:
        state: (m, 2n) posterior mean [p, v] (m, m/s).
        covariance: (m, 2n, 2n) posterior covariance.
        detection_time: (m,) stamp of the last detection consumed, = the posterior's time
            (s; −inf: none yet).
        active: (m,) bool, whether the slot holds a track.
        scale: (m,) process-noise scale s of each track (:mod:`stt_drake.core.consistency`;
            None: an unmonitored tracker, as are the four below).
        nis_count: (m,) corrections since the track's birth.
        nis: (m,) the NIS ν of the last correction (0 before one).
        test: (m,) the window test at the last correction: +1 above its interval
            (overconfident), −1 below, 0 inside.
        nis_window: (m, W) the last W NIS values (a ring indexed by count mod W).

    An inactive slot's state and covariance are placeholders.
    """

    state: np.ndarray
    covariance: np.ndarray
    detection_time: np.ndarray
    active: np.ndarray
    scale: np.ndarray | None = None
    nis_count: np.ndarray | None = None
    nis: np.ndarray | None = None
    test: np.ndarray | None = None
    nis_window: np.ndarray | None = None

    @property
    def window(self) -> int:
        """W (0: unmonitored)."""
        return 0 if self.nis_window is None else self.nis_window.shape[1]

    @classmethod
    def empty(cls, count: int, dimension: int, window: int = 0) -> TrackTable:
        """No track: zero means, identity covariances, no detection consumed (and, with
        `window` > 0, scale 1 and no NIS)."""
        d = 2 * dimension
        monitored = {}
        if window:
            monitored = {
                "scale": np.ones(count),
                "nis_count": np.zeros(count),
                "nis": np.zeros(count),
                "test": np.zeros(count),
                "nis_window": np.zeros((count, window)),
            }
        return cls(
            state=np.zeros((count, d)),
            covariance=np.broadcast_to(np.eye(d), (count, d, d)).copy(),
            detection_time=np.full(count, -np.inf),
            active=np.zeros(count, dtype=bool),
            **monitored,
        )

    def to_vector(self) -> np.ndarray:
        """Slot-major records ``[state (2n), covariance ((2n)², row-major), detection_time,
        active (1.0/0.0)]``, monitored: then ``[scale, nis_count, nis, test, nis_window (W)]``."""
        count, d = self.state.shape
        columns = [
            self.state,
            self.covariance.reshape(count, d * d),
            self.detection_time,
            self.active.astype(float),
        ]
        if self.window:
            columns += [self.scale, self.nis_count, self.nis, self.test, self.nis_window]
        return np.column_stack(columns).ravel()

    @classmethod
    def from_vector(cls, vector: np.ndarray, dimension: int, window: int = 0) -> TrackTable:
        """Unpack :meth:`to_vector`'s layout (`window`: the W it was packed with)."""
        d = 2 * dimension
        table = np.asarray(vector, dtype=float).reshape(-1, track_record_size(dimension, window))
        base = d + d * d
        monitored = {}
        if window:
            monitored = {
                "scale": table[:, base + 2],
                "nis_count": table[:, base + 3],
                "nis": table[:, base + 4],
                "test": table[:, base + 5],
                "nis_window": table[:, base + 6 :],
            }
        return cls(
            state=table[:, :d],
            covariance=table[:, d:base].reshape(-1, d, d),
            detection_time=table[:, base],
            active=table[:, base + 1] > 0.5,
            **monitored,
        )


def monitored_update(
    tracks: TrackTable,
    rows: np.ndarray,
    dt: np.ndarray,
    z: np.ndarray,
    density: float,
    noise_covariance: np.ndarray,
    adaptation: Adaptation,
) -> tuple[np.ndarray, ...]:
    """The update of slots `rows` with their NIS, window test and adaptive noise
    (:mod:`stt_drake.core.consistency`); the compiled kernel unless numpy is selected.

    Returns:
        (state, covariance, scale, nis_window, nis_count, nis, test) of those rows.
    """
    n = z.shape[1]
    base = adaptation.base_density(density)
    count = int(np.count_nonzero(rows))

    def pick(values: np.ndarray) -> np.ndarray:  # every row: no copy (the kernel copies)
        return values if count == len(rows) else values[rows]

    arguments = (
        pick(tracks.state),
        pick(tracks.covariance),
        _per_slot(dt, count),
        z,
        float(base),
        noise_covariance,
        pick(tracks.scale),
        pick(tracks.nis_window),
        pick(tracks.nis_count),
    )
    max_scale = adaptation.max_scale(density)
    if backend.compiled("track_update", n) is not None:
        kernel = importlib.import_module("stt_drake.core._tracking").track_update_monitored
        return kernel(
            *arguments,
            adaptation.lower,
            adaptation.upper,
            float(adaptation.step_gain),
            float(adaptation.step_cap),
            float(adaptation.relax),
            float(max_scale),
        )
    return monitored_update_numpy(*arguments, adaptation, max_scale)


def monitored_update_numpy(
    state: np.ndarray,
    covariance: np.ndarray,
    dt: np.ndarray,
    z: np.ndarray,
    base: float,
    noise_covariance: np.ndarray,
    scale: np.ndarray,
    ring: np.ndarray,
    count: np.ndarray,
    adaptation: Adaptation,
    max_scale: float,
) -> tuple[np.ndarray, ...]:
    """Numpy reference of the monitored update (:mod:`stt_drake.core.consistency`; the kernel is
    :func:`stt_drake.core._tracking.track_update_monitored`): predict with base·scale,
    ν, window test, scale rule, extra noise, Joseph correction.

    Returns:
        (state, covariance, scale, ring, count, nis, test) as new arrays; test is +1 above
        the window interval, −1 below, 0 inside.
    """
    n = z.shape[1]
    x, p = predict(state, covariance, dt, base * scale)
    innovation = z - x[:, :n]
    s_matrix = p[:, :n, :n] + noise_covariance
    nis = np.einsum(
        "mi,mi->m", innovation, np.linalg.solve(s_matrix, innovation[..., None])[..., 0]
    )
    ring, count = ring.copy(), count.copy()
    rows = np.arange(len(nis))
    window = ring.shape[1]
    ring[rows, count.astype(int) % window] = nis
    count = count + 1.0
    used = np.minimum(count, window).astype(int)
    total = np.where(np.arange(window)[None, :] < used[:, None], ring, 0.0).sum(axis=1)
    test = np.where(
        total > adaptation.upper[used - 1],
        1.0,
        np.where(total < adaptation.lower[used - 1], -1.0, 0.0),
    )
    new_scale = scale.copy()
    gain = adaptation.step_gain
    if gain > 0.0:
        step = np.minimum(nis / n - 1.0, adaptation.step_cap)
        step = np.where(step < 0.0, adaptation.relax * step, step)
        new_scale = np.clip(scale * np.exp(gain * step), 1.0, max_scale)
        p = p + _process_noise(np.asarray(dt, dtype=float), base * (new_scale - scale), n)
    x, p = correct(x, p, z, noise_covariance)
    return x, p, new_scale, ring, count, nis, test


@dataclass(frozen=True)
class KalmanTracker:
    """The tracking rules of the module docstring, for slots in R^dimension.

    Attributes:
        dimension: n.
        process_density: white-acceleration spectral density q of the model (m²/s³).
        noise_covariance: (n, n) measurement noise covariance R (m²).
        initial_velocity_sigma: standard deviation of a new track's velocity (m/s).
        track_timeout: seconds without a detection after which a track is lost; it should
            exceed the sensor period plus its latency plus the tracker period.
        adaptation: the NIS test and adaptive process noise
            (:class:`stt_drake.core.consistency.Adaptation`); None: neither, the tracks
            unmonitored (a shorter record).
    """

    dimension: int
    process_density: float
    noise_covariance: np.ndarray
    initial_velocity_sigma: float
    track_timeout: float
    adaptation: Adaptation | None = None

    @property
    def window(self) -> int:
        """W of the track records (0: unmonitored)."""
        return 0 if self.adaptation is None else self.adaptation.window

    @property
    def record_size(self) -> int:
        """One slot's record length (:func:`track_record_size`)."""
        return track_record_size(self.dimension, self.window)

    def empty(self, count: int) -> TrackTable:
        """`count` slots without a track, in this tracker's record layout."""
        return TrackTable.empty(count, self.dimension, self.window)

    def unpack(self, vector: np.ndarray) -> TrackTable:
        """:meth:`TrackTable.from_vector` in this tracker's record layout."""
        return TrackTable.from_vector(vector, self.dimension, self.window)

    def densities(self, tracks: TrackTable) -> float | np.ndarray:
        """The process density each track predicts with (m²/s³): q, or q_base·s per slot."""
        if self.adaptation is None:
            return self.process_density
        return self.adaptation.base_density(self.process_density) * tracks.scale

    def step(self, tracks: TrackTable, detections: Detections, t: float) -> TrackTable:
        """The tracks at time t (s) after consuming `detections`: a slot detected with a stamp
        later than its last one is corrected (predicted to the stamp first) if its track is
        alive at that stamp, else born; a slot whose last detection is more than
        `track_timeout` before t is lost. Monitored, a correction also takes the NIS, runs
        the window test and adapts the scale; a birth resets them."""
        last, stamp = tracks.detection_time, detections.stamp
        new = detections.detected & (stamp > last)
        alive = tracks.active & (stamp <= last + self.track_timeout)
        corrected, born = new & alive, new & ~alive
        state, covariance = tracks.state.copy(), tracks.covariance.copy()
        z = np.asarray(detections.position, dtype=float)
        r = np.asarray(self.noise_covariance, dtype=float)
        monitored = {}
        if self.adaptation is not None:
            monitored = {
                name: getattr(tracks, name).copy()
                for name in ("scale", "nis_count", "nis", "test", "nis_window")
            }
        if corrected.any():
            dt = stamp[corrected] - last[corrected]
            if self.adaptation is None:
                state[corrected], covariance[corrected] = update(
                    state[corrected],
                    covariance[corrected],
                    dt,
                    z[corrected],
                    self.process_density,
                    r,
                )
            else:
                result = monitored_update(
                    tracks,
                    corrected,
                    dt,
                    z[corrected],
                    self.process_density,
                    r,
                    self.adaptation,
                )
                state[corrected], covariance[corrected] = result[0], result[1]
                for name, value in zip(
                    ("scale", "nis_window", "nis_count", "nis", "test"), result[2:], strict=True
                ):
                    monitored[name][corrected] = value
        if born.any():
            state[born], covariance[born] = birth(z[born], r, self.initial_velocity_sigma)
            if monitored:
                monitored["scale"][born] = 1.0
                for name in ("nis_count", "nis", "test", "nis_window"):
                    monitored[name][born] = 0.0
        detection_time = np.where(new, stamp, last)
        return TrackTable(
            state=state,
            covariance=covariance,
            detection_time=detection_time,
            active=(tracks.active | new) & (t <= detection_time + self.track_timeout),
            **monitored,
        )

    def belief(self, tracks: TrackTable, t: float) -> GaussianBelief:
        """The belief at time t (s): :func:`predicted_position` from each active slot's
        posterior (with its own density, :meth:`densities`); inactive slots hold mean 0
        and covariance I (placeholders)."""
        active = tracks.active
        dt = np.where(active, t - tracks.detection_time, 0.0)
        mean, covariance = predicted_position(
            tracks.state, tracks.covariance, dt, self.densities(tracks)
        )
        mean[~active] = 0.0
        covariance[~active] = np.eye(self.dimension)
        return GaussianBelief(mean=mean, covariance=covariance, active=active.copy())

    def belief_vector(
        self, tracks: np.ndarray, previous: np.ndarray, t: float, weight: float
    ) -> np.ndarray:
        """The `obstacle_belief` port vector at time t (s) from the packed track tables
        (:meth:`TrackTable.to_vector`): :meth:`belief` of `tracks`, blended from the belief
        of `previous` by `weight` (:func:`blend_beliefs`; ≥ 1: no blend). One call of the
        compiled :func:`stt_drake.core._tracking.track_belief` for n ≤ 3 (unless the numpy
        path is selected), else these numpy functions."""
        kernel = self._belief_kernel if backend.using_compiled() else None
        if kernel is None:
            belief = self.belief(self.unpack(tracks), t)
            if weight < 1.0:
                belief = blend_beliefs(self.belief(self.unpack(previous), t), belief, weight)
            return belief.to_vector()
        records, density, scale_column = self._belief_constants
        return kernel(
            tracks.reshape(records),  # the method: a third of np.reshape's cost per call
            previous.reshape(records),
            float(t),
            float(weight),
            density,
            scale_column,
            self.dimension,
        )

    @cached_property
    def _belief_kernel(self) -> Callable[..., np.ndarray] | None:
        """The compiled track_belief for this dimension, looked up once (read while it is
        selected; None where it is not compiled)."""
        return backend.compiled("track_belief", self.dimension)

    @cached_property
    def _belief_constants(self) -> tuple[tuple[int, int], float, int]:
        """(record shape, density, scale column) :meth:`belief_vector` passes its kernel: made
        once, they are fixed by the (frozen) rules."""
        density, scale_column = self.process_density, -1
        if self.adaptation is not None:
            density = self.adaptation.base_density(self.process_density)
            scale_column = track_record_size(self.dimension)  # the first monitored field
        return (-1, self.record_size), float(density), scale_column


def blend_beliefs(old: GaussianBelief, new: GaussianBelief, weight: float) -> GaussianBelief:
    """The belief moving from `old` to `new` as `weight` goes from 0 to 1: in each slot
    active in both, the moment-matched mixture (1 − w)·N(μ_old, Σ_old) + w·N(μ_new, Σ_new),
    mean μ = (1 − w)μ_old + wμ_new and covariance
    Σ = (1 − w)Σ_old + wΣ_new + w(1 − w)(μ_new − μ_old)(μ_new − μ_old)ᵀ — continuous in w,
    equal to `old` at 0 and `new` at 1, and never narrower than the mixture it summarises.
    Other slots (born or lost in between) are `new`'s."""
    w = float(np.clip(weight, 0.0, 1.0))
    both = old.active & new.active
    mean, covariance = new.mean.copy(), new.covariance.copy()
    jump = new.mean[both] - old.mean[both]
    mean[both] = (1.0 - w) * old.mean[both] + w * new.mean[both]
    covariance[both] = (
        (1.0 - w) * old.covariance[both]
        + w * new.covariance[both]
        + w * (1.0 - w) * jump[:, :, None] * jump[:, None, :]
    )
    return GaussianBelief(mean=mean, covariance=covariance, active=new.active.copy())


def consistency_stats(
    stats: np.ndarray, before: TrackTable, after: TrackTable, t: float
) -> np.ndarray:
    """The running NIS statistics per slot (:mod:`stt_drake.core.consistency`), an array
    (m, :data:`~stt_drake.core.consistency.CONSISTENCY_FIELDS`) of rows
    ``[NIS sum, corrections, events, first event time (s; NaN: none), time spent
    overconfident (s, closed episodes), start of the current episode (s; NaN: none),
    largest noise scale]``, after the tracker update at t (s) from `before` to `after`
    (monitored tables). An *event* (episode) starts at a correction whose window test is
    above its interval (overconfident) and ends at the first correction inside or below
    it, or when the track is lost or re-born."""
    stats = stats.copy()
    corrected = after.nis_count > before.nis_count
    high = corrected & (after.test > 0.5)
    failing = np.isfinite(stats[:, 5])
    ends = failing & ((corrected & ~high) | (after.nis_count < before.nis_count) | ~after.active)
    stats[corrected, 0] += after.nis[corrected]
    stats[corrected, 1] += 1.0
    stats[ends, 4] += t - stats[ends, 5]
    stats[ends, 5] = np.nan
    starts = high & ~failing
    stats[starts, 2] += 1.0
    stats[starts & np.isnan(stats[:, 3]), 3] = t
    stats[starts, 5] = t
    stats[:, 6] = np.maximum(stats[:, 6], np.where(after.active, after.scale, 0.0))
    return stats
