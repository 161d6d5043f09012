"""Tests of stt_drake.core.tracking (Kalman filters), stt_drake.core._tracking (its compiled
kernel) and stt_drake.core.perception (true-world deviations, sensor draws).

References are independent of the code under test: the batch Gaussian posterior of a
constant-velocity trajectory from the stacked least-squares system (plain numpy linear
algebra), Van Loan's matrix-exponential discretisation of the continuous-time model
(scipy.linalg.expm), binomial and chi-square sampling laws.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats
from scipy.linalg import block_diag, expm

from stt_drake.core import backend
from stt_drake.core.consistency import Adaptation
from stt_drake.core.perception import (
    Detections,
    SensorModel,
    draw_truth_deviation,
)
from stt_drake.core.tracking import (
    KalmanTracker,
    TrackTable,
    birth,
    blend_beliefs,
    correct,
    predict,
    predicted_position,
    update,
)

R2 = np.array([[0.04, 0.01], [0.01, 0.02]])


def van_loan(dt: float, density: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of ẋ = A x + G w, A = [[0, I], [0, 0]], G = [0; I], E[w wᵀ] = q I δ, by
    Van Loan's method: expm([[−A, G q Gᵀ], [0, Aᵀ]] dt) = [[·, F⁻¹ Q], [0, Fᵀ]]."""
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    g = np.vstack([np.zeros((n, n)), np.eye(n)])
    block = np.block([[-a, density * g @ g.T], [np.zeros_like(a), a.T]]) * dt
    e = expm(block)
    f = e[2 * n :, 2 * n :].T
    return f, f @ e[: 2 * n, 2 * n :]


def batch_posterior(
    times: np.ndarray, z: np.ndarray, density: float, r: np.ndarray, velocity_sigma: float
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the last state x_K given every measurement, from the stacked
    information form over all states x_0..x_K: velocity prior N(0, σ_v² I) on x_0 (position
    flat), process residuals x_{k+1} − F x_k ~ N(0, Q), measurements z_k − H x_k ~ N(0, R)."""
    count, n = z.shape
    d = 2 * n
    rows, weights, targets = [], [], []

    def residual(blocks: dict[int, np.ndarray], covariance: np.ndarray, target: np.ndarray):
        row = np.zeros((target.size, count * d))
        for k, block in blocks.items():
            row[:, k * d : (k + 1) * d] = block
        rows.append(row)
        weights.append(np.linalg.inv(covariance))
        targets.append(target)

    h = np.hstack([np.eye(n), np.zeros((n, n))])
    velocity = np.hstack([np.zeros((n, n)), np.eye(n)])
    residual({0: velocity}, velocity_sigma**2 * np.eye(n), np.zeros(n))
    for k in range(count):
        residual({k: h}, r, z[k])
    for k in range(count - 1):
        f, q = van_loan(times[k + 1] - times[k], density, n)
        residual({k + 1: np.eye(d), k: -f}, q, np.zeros(d))
    jacobian, weight, target = np.vstack(rows), block_diag(*weights), np.concatenate(targets)
    information = jacobian.T @ weight @ jacobian
    covariance = np.linalg.inv(information)
    mean = covariance @ jacobian.T @ weight @ target
    return mean[-d:], covariance[-d:, -d:]


@pytest.mark.parametrize("pure", [False, True], ids=["compiled", "numpy"])
def test_filter_matches_batch_posterior(pure):
    rng = np.random.default_rng(7)
    n, density, sigma_v = 2, 0.3, 0.8
    times = np.array([0.0, 0.1, 0.2, 0.5, 0.6, 1.1, 1.2])  # gaps: dropouts
    truth = np.array([1.0, -2.0]) + np.outer(times, [0.4, 0.3])
    z = truth + rng.multivariate_normal(np.zeros(n), R2, times.size)
    with backend.pure_numpy(pure):
        state, covariance = birth(z[:1], R2, sigma_v)
        for k in range(1, times.size):
            dt = times[k] - times[k - 1]
            state, covariance = update(state, covariance, dt, z[k : k + 1], density, R2)
    mean, expected = batch_posterior(times, z, density, R2, sigma_v)
    np.testing.assert_allclose(state[0], mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(covariance[0], expected, rtol=0, atol=1e-9)


def test_predict_matches_van_loan_discretisation():
    rng = np.random.default_rng(3)
    n, density = 3, 0.7
    a = rng.standard_normal((4, 2 * n, 2 * n))
    covariance = a @ a.transpose(0, 2, 1)
    state = rng.standard_normal((4, 2 * n))
    dt = np.array([0.0, 0.01, 0.3, 2.0])
    moved, moved_covariance = predict(state, covariance, dt, density)
    for j in range(4):
        f, q = van_loan(dt[j], density, n)
        np.testing.assert_allclose(moved[j], f @ state[j], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(moved_covariance[j], f @ covariance[j] @ f.T + q, atol=1e-10)


def test_predicted_position_is_the_position_block_of_predict():
    rng = np.random.default_rng(4)
    n, density = 2, 0.4
    a = rng.standard_normal((3, 2 * n, 2 * n))
    covariance = a @ a.transpose(0, 2, 1)
    state = rng.standard_normal((3, 2 * n))
    dt = np.array([0.0, 0.25, 1.5])
    mean, position = predicted_position(state, covariance, dt, density)
    moved, moved_covariance = predict(state, covariance, dt, density)
    np.testing.assert_allclose(mean, moved[:, :n], atol=1e-14)
    np.testing.assert_allclose(position, moved_covariance[:, :n, :n], atol=1e-12)


def test_correct_shrinks_the_position_covariance():
    rng = np.random.default_rng(5)
    a = rng.standard_normal((5, 4, 4))
    covariance = a @ a.transpose(0, 2, 1) + np.eye(4)
    state, posterior = correct(rng.standard_normal((5, 4)), covariance, np.zeros((5, 2)), R2)
    assert state.shape == (5, 4)
    for before, after in zip(covariance, posterior, strict=True):
        np.testing.assert_array_equal(after, after.T)
        assert np.all(np.linalg.eigvalsh(before - after) > -1e-12)  # P⁺ ⪯ P
        assert np.all(np.linalg.eigvalsh(after[:2, :2]) < np.linalg.eigvalsh(R2)[-1] + 1e-12)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_compiled_update_matches_numpy(n):
    rng = np.random.default_rng(10 + n)
    m = 17
    a = rng.standard_normal((m, 2 * n, 2 * n))
    covariance = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(2 * n)
    state = rng.standard_normal((m, 2 * n))
    z = rng.standard_normal((m, n))
    b = rng.standard_normal((n, n))
    noise = b @ b.T + 0.05 * np.eye(n)
    dt = rng.uniform(0.0, 0.5, m)
    with backend.pure_numpy(False):
        assert backend.compiled("track_update", n) is not None
        fast = update(state, covariance, dt, z, 0.6, noise)
    with backend.pure_numpy():
        slow = update(state, covariance, dt, z, 0.6, noise)
    for got, expected in zip(fast, slow, strict=True):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)



def random_tracks(rng: np.random.Generator, law: KalmanTracker, count: int) -> TrackTable:
    """`count` slots with random posteriors, a third of them inactive; monitored laws get
    random noise scales."""
    n = law.dimension
    a = rng.standard_normal((count, 2 * n, 2 * n))
    table = law.empty(count)
    fields = {
        "state": rng.standard_normal((count, 2 * n)),
        "covariance": a @ a.transpose(0, 2, 1) + 0.1 * np.eye(2 * n),
        "detection_time": rng.uniform(0.0, 0.4, count),
        "active": rng.random(count) > 0.33,
    }
    if law.window:
        fields["scale"] = rng.uniform(1.0, 4.0, count)
    return dataclasses.replace(table, **fields)


@pytest.mark.parametrize("monitored", [False, True])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_compiled_published_belief_matches_numpy(n, monitored):
    """The port vector of KalmanTracker.belief_vector (compiled) against belief() and
    blend_beliefs() in numpy, with and without a blend, on read-only inputs as Drake's
    discrete state gives them; a few roundings apart at most (rtol 1e-13)."""
    rng = np.random.default_rng(20 + n)
    law = KalmanTracker(n, 0.3, np.eye(n) * 0.01, 1.0, 0.5, Adaptation(n) if monitored else None)
    tracks, previous = random_tracks(rng, law, 13), random_tracks(rng, law, 13)
    vectors = [table.to_vector() for table in (tracks, previous)]
    for vector in vectors:
        vector.flags.writeable = False
    for weight in (1.0, 0.3):
        expected = law.belief(tracks, 0.7)
        if weight < 1.0:
            expected = blend_beliefs(law.belief(previous, 0.7), expected, weight)
        with backend.pure_numpy(False):
            assert backend.compiled("track_belief", n) is not None
            fast = law.belief_vector(*vectors, 0.7, weight)
        with backend.pure_numpy():
            slow = law.belief_vector(*vectors, 0.7, weight)
        np.testing.assert_array_equal(slow, expected.to_vector())
        np.testing.assert_allclose(fast, slow, rtol=1e-13, atol=1e-15)


def tracker(timeout: float = 0.5) -> KalmanTracker:
    return KalmanTracker(
        dimension=2,
        process_density=0.2,
        noise_covariance=R2,
        initial_velocity_sigma=1.5,
        track_timeout=timeout,
    )


def detections(position, detected, stamp) -> Detections:
    position = np.atleast_2d(np.asarray(position, dtype=float))
    count = position.shape[0]
    return Detections(
        position=position,
        detected=np.broadcast_to(np.asarray(detected, dtype=bool), (count,)).copy(),
        stamp=np.full(count, float(stamp)),
    )


def test_birth_initialisation():
    law = tracker()
    tracks = law.step(
        TrackTable.empty(2, 2), detections([[1.0, 2.0], [3.0, 4.0]], [1, 0], 0.1), 0.1
    )
    np.testing.assert_array_equal(tracks.active, [True, False])
    np.testing.assert_array_equal(tracks.state[0], [1.0, 2.0, 0.0, 0.0])
    expected = np.zeros((4, 4))
    expected[:2, :2] = R2
    expected[2:, 2:] = 1.5**2 * np.eye(2)
    np.testing.assert_array_equal(tracks.covariance[0], expected)
    belief = law.belief(tracks, 0.1)
    np.testing.assert_array_equal(belief.mean, [[1.0, 2.0], [0.0, 0.0]])
    np.testing.assert_array_equal(belief.covariance[0], R2)
    np.testing.assert_array_equal(belief.covariance[1], np.eye(2))  # inactive placeholder


def test_covariance_grows_monotonically_through_dropouts():
    law = tracker(timeout=10.0)
    tracks = TrackTable.empty(1, 2)
    for k in range(5):  # a few detections, then nothing
        tracks = law.step(tracks, detections([[0.1 * k, 0.0]], True, 0.1 * k), 0.1 * k)
    traces, largest = [], []
    for t in np.linspace(0.4, 3.0, 200):
        tracks = law.step(tracks, detections([[9.0, 9.0]], False, t), t)  # dropped
        covariance = law.belief(tracks, t).covariance[0]
        traces.append(np.trace(covariance))
        largest.append(np.linalg.eigvalsh(covariance)[-1])
    assert np.all(np.diff(traces) > 0.0)
    assert np.all(np.diff(largest) > 0.0)
    assert tracks.active[0]


def test_loss_after_timeout_and_rebirth():
    law = tracker(timeout=0.5)
    tracks = law.step(TrackTable.empty(1, 2), detections([[1.0, 1.0]], True, 0.0), 0.0)
    tracks = law.step(tracks, detections([[1.1, 1.0]], True, 0.1), 0.1)
    corrected_covariance = tracks.covariance[0].copy()
    assert tracks.active[0] and tracks.state[0, 2] != 0.0  # a velocity was learnt
    tracks = law.step(tracks, detections([[0.0, 0.0]], False, 0.59), 0.59)
    assert tracks.active[0]  # within the timeout of the last detection (0.1 s)
    tracks = law.step(tracks, detections([[0.0, 0.0]], False, 0.65), 0.65)
    assert not tracks.active[0]
    assert not law.belief(tracks, 0.65).active[0]
    tracks = law.step(tracks, detections([[5.0, 5.0]], True, 0.7), 0.7)
    assert tracks.active[0]
    np.testing.assert_array_equal(tracks.state[0], [5.0, 5.0, 0.0, 0.0])  # re-born, not corrected
    assert not np.allclose(tracks.covariance[0], corrected_covariance)


def test_a_stamp_is_consumed_once():
    law = tracker()
    once = law.step(TrackTable.empty(1, 2), detections([[1.0, 1.0]], True, 0.0), 0.0)
    once = law.step(once, detections([[1.2, 1.0]], True, 0.1), 0.1)
    twice = law.step(once, detections([[1.2, 1.0]], True, 0.1), 0.15)  # same sample again
    np.testing.assert_array_equal(twice.state, once.state)
    np.testing.assert_array_equal(twice.covariance, once.covariance)


def test_track_table_and_detections_round_trip():
    rng = np.random.default_rng(0)
    law = tracker()
    tracks = law.step(
        TrackTable.empty(3, 2), detections(rng.standard_normal((3, 2)), True, 0.2), 0.2
    )
    back = TrackTable.from_vector(tracks.to_vector(), 2)
    for name in ("state", "covariance", "detection_time", "active"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tracks, name))
    sample = detections(rng.standard_normal((3, 2)), [1, 0, 1], 0.3)
    again = Detections.from_vector(sample.to_vector(), 2)
    np.testing.assert_array_equal(again.position, sample.position)
    np.testing.assert_array_equal(again.detected, sample.detected)
    np.testing.assert_array_equal(again.stamp, sample.stamp)


# ----------------------------------------------------------------------------- true world
def test_truth_deviation_statistics_match_the_continuous_process():
    density, period, horizon = 0.3, 0.1, 2.0
    end = np.array(
        [
            [draw.deviation_grid[-1], draw.rate_grid[-1]]
            for draw in (
                draw_truth_deviation(2, 2, density, period, horizon, np.random.default_rng(seed))
                for seed in range(1000)
            )
        ]
    )  # (seeds, 2: δ/δ̇, count, n)
    deviation, rate = end[:, 0].ravel(), end[:, 1].ravel()  # 4000 independent per axis
    samples = deviation.size
    low, high = stats.chi2.ppf([1e-4, 1 - 1e-4], samples)  # mean known (0): N degrees
    for values, variance in ((deviation, density * horizon**3 / 3), (rate, density * horizon)):
        assert low < np.sum(values**2) / variance < high
    # Cross covariance q T²/2: the correlation ρ = √3/2 of the pair, within 5 standard
    # errors (1 − ρ²)/√N of the sample correlation.
    rho = np.mean(deviation * rate) / np.sqrt(np.mean(deviation**2) * np.mean(rate**2))
    assert abs(rho - np.sqrt(3) / 2) < 5 * (1 - 0.75) / np.sqrt(samples)


def test_hermite_interpolation_hits_the_grid_and_is_c1():
    path = draw_truth_deviation(3, 2, 0.5, 0.1, 1.0, np.random.default_rng(1))
    eps = 1e-6
    for k in range(1, 10):
        t = k * path.period
        np.testing.assert_allclose(path.deviation(t), path.deviation_grid[k], rtol=0, atol=1e-15)
        left = (path.deviation(t) - path.deviation(t - eps)) / eps
        right = (path.deviation(t + eps) - path.deviation(t)) / eps
        np.testing.assert_allclose(left, path.rate_grid[k], atol=1e-4)
        np.testing.assert_allclose(right, path.rate_grid[k], atol=1e-4)
    np.testing.assert_array_equal(path.deviation(0.0), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="outside the drawn span"):
        path.deviation(1.2)


# ----------------------------------------------------------------------------- sensor
def sensor(dropout: float, noise=R2, sensing_range=np.inf, seed=0, count=50) -> SensorModel:
    return SensorModel(
        count=count,
        dimension=2,
        period=0.05,
        horizon=100.0,
        noise_covariance=noise,
        dropout_probability=dropout,
        sensing_range=sensing_range,
        rng=np.random.default_rng(seed),
    )


def test_dropout_frequency_is_binomial():
    model = sensor(0.3)
    truth = np.zeros((50, 2))
    detected = np.array(
        [model.measure(k, truth, np.zeros(2)).detected for k in range(model.sample_count)]
    )
    trials = detected.size  # 50 × 2001
    tolerance = 5 * np.sqrt(0.3 * 0.7 / trials)
    assert abs(1 - detected.mean() - 0.3) < tolerance


def test_measurement_noise_has_the_given_covariance():
    model = sensor(0.0)
    truth = np.arange(100.0).reshape(50, 2)
    errors = np.concatenate(
        [model.measure(k, truth, np.zeros(2)).position - truth for k in range(model.sample_count)]
    )
    samples = errors.shape[0]
    estimate = errors.T @ errors / samples  # mean known (0)
    # Standard error of each entry of a sample covariance: √((R_ii R_jj + R_ij²)/N).
    error = np.sqrt((np.outer(np.diag(R2), np.diag(R2)) + R2**2) / samples)
    assert np.all(np.abs(estimate - R2) < 5 * error)
    assert abs(errors.mean()) < 5 * np.sqrt(R2.max() / samples)


def test_range_check():
    model = sensor(0.0, sensing_range=5.0, count=4)
    truth = np.array([[1.0, 1.0], [4.0, 3.0], [5.0, 0.1], [-20.0, 0.0]])
    robot = np.array([1.0, 0.0])
    sample = model.measure(3, truth + robot, robot)
    np.testing.assert_array_equal(sample.detected, [True, True, False, False])
    np.testing.assert_array_equal(sample.position[2:], 0.0)  # nothing leaks of the truth
    np.testing.assert_allclose(sample.stamp, 3 * 0.05, rtol=0, atol=1e-15)


def test_sensor_draws_are_reproducible_and_per_index():
    truth = np.zeros((50, 2))
    one, two = sensor(0.2, seed=4), sensor(0.2, seed=4)
    first = one.measure(17, truth, np.zeros(2))
    for k in range(17):  # evaluate other samples first: no effect on sample 17
        two.measure(k, truth, np.zeros(2))
    again = two.measure(17, truth, np.zeros(2))
    np.testing.assert_array_equal(first.position, again.position)
    np.testing.assert_array_equal(first.detected, again.detected)
    other = sensor(0.2, seed=5).measure(17, truth, np.zeros(2))
    assert not np.array_equal(first.position, other.position)
    with pytest.raises(ValueError, match="longer horizon"):
        one.measure(one.sample_count, truth, np.zeros(2))


def test_a_shorter_horizon_draws_the_start_of_a_longer_one():
    """Sensor noise and dropouts (and the truth) drawn for a 2 s run are the first 2 s of
    the draws for a 5 s run with the same seed: shortening a run does not change it."""
    noise = np.array([[0.01, 0.004], [0.004, 0.02]])
    short, long = (
        SensorModel(3, 2, 0.1, horizon, noise, 0.3, np.inf, np.random.default_rng(7))
        for horizon in (2.0, 5.0)
    )
    truth = np.arange(6.0).reshape(3, 2)
    for index in range(short.sample_count):
        a = short.measure(index, truth, np.zeros(2))
        b = long.measure(index, truth, np.zeros(2))
        np.testing.assert_array_equal(a.detected, b.detected)
        np.testing.assert_array_equal(a.position, b.position)
    paths = [
        draw_truth_deviation(3, 2, 0.1, 0.05, horizon, np.random.default_rng(7))
        for horizon in (2.0, 5.0)
    ]
    np.testing.assert_array_equal(paths[0].deviation(1.93), paths[1].deviation(1.93))
