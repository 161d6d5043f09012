"""The tracker knows when it is wrong (issue 26, item 3): the NIS test, adaptive process
noise, calibration against the truth, metrics.json `tracks` and the run's WARNING.

References: the χ² distribution of the NIS of a filter whose model is the truth's
(Bar-Shalom, Li & Kirubarajan ch. 5.4; scipy), Monte Carlo over independent tracks, and
the calibration recomputed from log.npz with an explicit inverse."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from stt_drake.config.load import parse_schema
from stt_drake.config.schema import ScenarioError
from stt_drake.core import backend
from stt_drake.core.consistency import Adaptation
from stt_drake.core.perception import Detections
from stt_drake.core.tracking import (
    KalmanTracker,
    TrackTable,
    birth,
    monitored_update,
    monitored_update_numpy,
    update,
)

N = 2
PERIOD = 0.1
R = 0.05**2 * np.eye(N)
Q = 0.01  # m²/s³
SIGMA_V = 0.5


def _adaptation(adaptive: bool, window: int = 10) -> Adaptation:
    from stt_drake.core.consistency import density_bounds

    floor, ceiling = density_bounds(R, PERIOD)
    return Adaptation(
        N, window=window, adaptive=adaptive, density_floor=floor, density_ceiling=ceiling
    )


def _track(tracker: KalmanTracker, truth: np.ndarray, rng: np.random.Generator):
    """Run `tracker` over the truth positions (steps, m, n) sampled every PERIOD with
    N(0, R) noise; yield the table after each update."""
    steps, m, _ = truth.shape
    tracks = tracker.empty(m)
    noise = rng.multivariate_normal(np.zeros(N), R, size=(steps, m))
    for k in range(steps):
        t = k * PERIOD
        seen = Detections(truth[k] + noise[k], np.ones(m, dtype=bool), np.full(m, t))
        tracks = tracker.step(tracks, seen, t)
        yield tracks


def _cv_truth(m: int, steps: int, rng: np.random.Generator) -> np.ndarray:
    """The filter's own model: velocity from N(0, σ_v²) (the birth prior), white
    acceleration of density Q, exact discretisation; positions (steps, m, n)."""
    cov = Q * np.array([[PERIOD**3 / 3, PERIOD**2 / 2], [PERIOD**2 / 2, PERIOD]])
    chol = np.linalg.cholesky(cov)
    p = np.zeros((m, N))
    v = rng.normal(0.0, SIGMA_V, size=(m, N))
    out = np.empty((steps, m, N))
    for k in range(steps):
        out[k] = p
        w = np.einsum("ab,mbn->man", chol, rng.normal(size=(m, 2, N)))
        p, v = p + PERIOD * v + w[:, 0], v + w[:, 1]
    return out


@pytest.fixture(scope="module")
def cv_runs():
    """NIS and test outcomes of 400 tracks × 80 updates on the filter's own model, with
    the adaptation off and on (same truth, same noise)."""
    rng = np.random.default_rng(7)
    truth = _cv_truth(400, 81, rng)
    runs = {}
    for adaptive in (False, True):
        tracker = KalmanTracker(N, Q, R, SIGMA_V, 1.0, _adaptation(adaptive))
        tables = list(_track(tracker, truth, np.random.default_rng(8)))[1:]  # k=0: births
        runs[adaptive] = {
            "nis": np.array([t.nis for t in tables]),
            "test": np.array([t.test for t in tables]),
            "scale": np.array([t.scale for t in tables]),
        }
    return runs


def test_nis_of_a_consistent_filter_is_chi_square(cv_runs):
    """Mean ≈ n and the fraction below each χ²_n quantile ≈ its level; the innovations
    of a filter whose model is the truth's are independent, so every value counts."""
    nis = cv_runs[False]["nis"].ravel()
    count = nis.size
    # Var ν = 2n: the mean's standard deviation is sqrt(2n / count); 5 of them.
    assert abs(nis.mean() - N) < 5.0 * np.sqrt(2.0 * N / count)
    for level in (0.1, 0.5, 0.9, 0.95, 0.99):
        below = np.mean(nis <= chi2.ppf(level, N))
        assert abs(below - level) < 5.0 * np.sqrt(level * (1 - level) / count), level


def test_window_test_false_alarms_at_its_design_level(cv_runs):
    """Each update's window sum is χ²_{kn}, above its interval with probability
    (1 − c)/2 = 0.025. Overlapping windows correlate the outcomes of one track: the
    tolerance counts count/W independent ones. With the adaptation on the scale rises
    only after high NIS values, so the alarms can only be rarer and the scale stays
    near 1."""
    window = 10
    plain = cv_runs[False]["test"]
    count = plain.size / window
    tolerance = 5.0 * np.sqrt(0.025 * 0.975 / count)
    assert abs(np.mean(plain > 0) - 0.025) < tolerance
    adaptive = cv_runs[True]
    assert np.mean(adaptive["test"] > 0) < 0.025 + tolerance
    # The scale rises at once and relaxes at ρ = 0.7 of the rate: on the filter's own
    # model it hovers a few times above 1 (conservative), never near its ceiling.
    assert np.median(adaptive["scale"]) < 10.0
    assert np.mean(adaptive["test"] < 0) > np.mean(plain < 0)


def test_adaptive_off_is_the_plain_filter_bit_for_bit():
    rng = np.random.default_rng(3)
    truth = _cv_truth(20, 40, rng)
    plain = KalmanTracker(N, Q, R, SIGMA_V, 1.0)
    monitored = KalmanTracker(N, Q, R, SIGMA_V, 1.0, _adaptation(False))
    for a, b in zip(
        _track(plain, truth, np.random.default_rng(4)),
        _track(monitored, truth, np.random.default_rng(4)),
        strict=True,
    ):
        np.testing.assert_array_equal(a.state, b.state)
        np.testing.assert_array_equal(a.covariance, b.covariance)
        t = 0.05 + a.detection_time.max()
        np.testing.assert_array_equal(
            plain.belief(a, t).covariance, monitored.belief(b, t).covariance
        )


@pytest.mark.parametrize("adaptive", [False, True])
def test_compiled_monitored_update_matches_numpy(adaptive):
    if backend.compiled("track_update", N) is None:
        pytest.fail("numba kernels unavailable")
    rng = np.random.default_rng(5)
    m, window = 7, 4
    adaptation = _adaptation(adaptive, window)
    state, covariance = birth(rng.normal(size=(m, N)), R, SIGMA_V)
    # a plain tracker's scale is 1 for ever
    scale = np.array([1.0, 3.0, 1.0, 50.0, 1.0, 2.0, 1.0]) if adaptive else np.ones(m)
    tracks = TrackTable(
        state, covariance, np.zeros(m), np.ones(m, dtype=bool), scale,
        np.arange(m, dtype=float), np.zeros(m), np.zeros(m), rng.random((m, window)),
    )  # fmt: skip
    z = state[:, :N] + rng.normal(scale=0.3, size=(m, N))
    dt = np.full(m, PERIOD)
    rows = np.ones(m, dtype=bool)
    compiled = monitored_update(tracks, rows, dt, z, Q, R, adaptation)
    reference = monitored_update_numpy(
        state, covariance, dt, z, adaptation.base_density(Q), R, scale,
        tracks.nis_window, tracks.nis_count, adaptation, adaptation.max_scale(Q),
    )  # fmt: skip
    for a, b in zip(compiled, reference, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    if not adaptive:  # the plain update of the same prior, exactly
        x, p = update(state, covariance, dt, z, Q, R)
        np.testing.assert_array_equal(compiled[0], x)
        np.testing.assert_array_equal(compiled[1], p)


def _manoeuvre(kind: str) -> np.ndarray:
    """One walker at 1 m/s along x for 5 s, then a 90° turn or a stop, then 15 s straight."""
    times = np.arange(0.0, 20.0 + 1e-9, PERIOD)
    after = np.array([0.0, 1.0]) if kind == "turn" else np.zeros(2)
    position = np.where(
        (times <= 5.0)[:, None],
        times[:, None] * np.array([1.0, 0.0]),
        np.array([5.0, 0.0]) + (times - 5.0)[:, None] * after,
    )
    return position[:, None, :]


@pytest.mark.parametrize("kind", ["turn", "stop"])
def test_a_manoeuvre_is_detected_inflates_and_relaxes(kind):
    """CV model with a tiny q: the turn (or stop) at 5 s breaks it. The window test fires
    within 3 updates; with the adaptation the covariance grows at once (velocity block
    > 100×, position > 3×; the plain filter's does not) and the scale relaxes once the
    walker is straight again."""
    truth = _manoeuvre(kind)
    turn = round(5.0 / PERIOD)
    tables = {}
    for adaptive in (False, True):
        tracker = KalmanTracker(N, 1e-4, R, SIGMA_V, 1.0, _adaptation(adaptive))
        tables[adaptive] = list(_track(tracker, truth, np.random.default_rng(11)))
    for adaptive in (False, True):
        fired = [k for k in range(turn, turn + 10) if tables[adaptive][k].test[0] > 0]
        assert fired and fired[0] - turn <= 3, (adaptive, fired)

    def growth(adaptive: bool, block: slice) -> float:
        """Largest trace of a covariance block in the 5 updates after the manoeuvre over
        its trace at the manoeuvre."""
        runs = tables[adaptive]
        trace = [np.trace(t.covariance[0, block, block]) for t in runs[turn : turn + 6]]
        return max(trace[1:]) / trace[0]

    # The velocity grows most; the posterior position is capped by R (its variance ≤ R).
    assert growth(True, slice(N, 2 * N)) > 100.0
    assert growth(True, slice(0, N)) > 3.0
    assert growth(False, slice(N, 2 * N)) < 1.5
    adaptive = tables[True]
    raised = max(t.scale[0] for t in adaptive[turn : turn + 10])
    assert raised > 100.0
    # Relaxed in the 15 s straight: the geometric mean of the last 5 s is > 10× below the
    # peak. (Not to 1: the down-steps are ρ = 0.7 of the up-steps, so the scale settles
    # where the mean NIS is ≈ 0.8 n, a conservative filter, with the tiny model q here.)
    settled = np.exp(np.mean(np.log([t.scale[0] for t in adaptive[-50:]])))
    assert settled < 0.1 * raised


def test_perception_fields_are_validated_by_name():
    base = Path("diagrams/omni_tracked.yaml").read_text()
    for field, value, rule in [
        ("nis_window", 0, "integer in [1,"),
        ("nis_confidence", 1.0, "in (0, 1)"),
        ("nis_confidence", 0.0, "in (0, 1)"),
        ("nis_window", 5000, "integer in [1,"),
        ("adaptive", '"yes"', "true or false"),
    ]:
        text = base.replace("  track_timeout: 1.0", f"  track_timeout: 1.0\n  {field}: {value}")
        with pytest.raises(ScenarioError, match=rf"scenario\.perception\.{field}: must .*"):
            from stt_drake.config.load import complete_scenario

            complete_scenario(parse_schema(text, "bad"))
        with pytest.raises(ScenarioError) as error:
            complete_scenario(parse_schema(text, "bad"))
        assert rule in str(error.value)


OSCILLATING = """
name: oscillating_tracked
start: [0.5, 0.5]
initial_set_radius: 0.3
target: [4.5, 4.5]
target_set_radius: 0.3
duration: 20.0
tube: {r_min: 0.21, r_max: 0.27, k1: 0.7, k2: 0.4, k3: 0.4, max_center_speed: 1.0}
controller: {kappa: [8.0]}
perception: {sensor_period: 0.1, noise_sigma: 0.05, dropout_probability: 0.1,
             initial_velocity_sigma: 0.5, track_timeout: 1.0, EXTRA}
obstacles:
  - motion: !Oscillation {center: [1.5, 2.5], amplitude: [0.6, 0.3], frequency_hz: 0.15}
    {O}
  - motion: !Oscillation {center: [3.0, 2.0], amplitude: [0.2, 0.7], frequency_hz: 0.1}
    {O}
  - motion: !Oscillation {center: [2.5, 4.0], amplitude: [0.5, 0.5], frequency_hz: 0.2,
                          phase: [0.0, 1.57]}
    {O}
  - motion: !Waypoints {times: [0, 4, 6, 10, 13, 20], positions: [[4, 1], [4, 3], [4, 3],
                        [1, 3.5], [1, 1], [3, 0]]}
    {O}
""".replace("{O}", "radius: 0.15\n    sigma: 0.05\n    epsilon: 0.9\n    p_d: 0.9999")


def _oscillating(extra: str = "", seed: int = 0):
    from stt_drake.assembly import prepare_scenario

    text = OSCILLATING.replace(", EXTRA", f", {extra}" if extra else "")
    return prepare_scenario(parse_schema(text, "oscillating_tracked"), seed)


@pytest.fixture(scope="module")
def adaptive_run(tmp_path_factory):
    from stt_drake.run import simulate, summary, write_outputs

    result = simulate(_oscillating())
    folder = tmp_path_factory.mktemp("adaptive")
    write_outputs(result, folder, figures=False)
    return result, summary(result), folder


@pytest.fixture(scope="module")
def wrong_run():
    """Tiny process noise and no adaptation: the belief ignores the oscillations."""
    from stt_drake.run import simulate, summary

    result = simulate(_oscillating("adaptive: false, tracker_process_density: 1.0e-6"))
    return result, summary(result)


@pytest.mark.slow
def test_closed_loop_calibration_of_an_oscillating_scenario(adaptive_run):
    result, _, _ = adaptive_run
    tracks = result.metrics["tracks"]
    inside = sum(t["calibration_95"] * t["tracked_samples"] for t in tracks)
    total = sum(t["tracked_samples"] for t in tracks)
    assert 0.90 <= inside / total <= 0.98


@pytest.mark.slow
def test_metrics_tracks_agree_with_the_log(adaptive_run):
    """calibration_95 recomputed from log.npz with an explicit inverse and scipy's χ²
    quantile; nis_mean and the episode count from the logged running statistics."""
    _, _, folder = adaptive_run
    metrics = json.loads((folder / "metrics.json").read_text())
    log = dict(np.load(folder / "log.npz"))
    samples = log["t"].size
    truth = log["true_obstacle_position"].reshape(samples, 4, N)
    belief = log["belief"].reshape(samples, 4, N + N * N + 1)
    stats = log["tracker_consistency"].reshape(samples, 4, -1)[-1]
    for j, track in enumerate(metrics["tracks"]):
        assert track["index"] == j
        active = belief[:, j, -1] > 0.5
        inside = 0
        for k in np.nonzero(active)[0]:
            error = truth[k, j] - belief[k, j, :N]
            cov = belief[k, j, N : N + N * N].reshape(N, N)
            inside += error @ np.linalg.inv(cov) @ error <= chi2.ppf(0.95, N)
        assert track["tracked_samples"] == int(active.sum())
        assert track["calibration_95"] == pytest.approx(inside / active.sum(), abs=1e-12)
        assert track["nis_updates"] == int(stats[j, 1]) > 100
        assert track["nis_mean"] == pytest.approx(stats[j, 0] / stats[j, 1], rel=1e-12)
        lo, hi = track["nis_interval"]
        updates = track["nis_updates"]
        assert hi == pytest.approx(chi2.ppf(0.975, updates * N) / updates, rel=1e-9)
        assert lo < N < hi
        assert track["nis_mean_above_interval"] == (track["nis_mean"] > hi)
        events = track["events"]
        assert events["count"] == int(stats[j, 2])
        assert (events["first_s"] is None) == (events["count"] == 0)
        assert 0.0 <= events["duration_s"] <= log["t"][-1]
        step = log["t"][1] - log["t"][0]
        share = events["duration_s"] / (track["tracked_samples"] * step)
        assert events["share"] == pytest.approx(share, rel=1e-9)
        assert (track["warning"] is None) == (
            track["calibration_95"] >= 0.9 and events["share"] <= 0.2
        )
        assert track["max_noise_scale"] >= 1.0


@pytest.mark.slow
def test_warning_for_a_wrong_model_and_none_for_a_calibrated_one(adaptive_run, wrong_run):
    result, text = wrong_run
    warned = [t for t in result.metrics["tracks"] if t["warning"]]
    assert warned and all(t["calibration_95"] < 0.9 or t["events"]["share"] > 0.2 for t in warned)
    for track in warned:
        assert f"WARNING: belief inconsistent with the truth, track {track['index']}:" in text
    assert all(t["events"]["count"] >= 1 for t in warned)
    _, calibrated, _ = adaptive_run
    assert "WARNING" not in calibrated
    assert "tracker: true centre in the belief's 95 % ellipsoid" in calibrated


def _markov_indicator(rng, p, persistence, count):
    """A two-state Markov chain with stationary P(inside) = p whose lag-1 autocorrelation
    is `persistence` (each step keeps the state with extra probability)."""
    x = np.empty(count, dtype=bool)
    x[0] = rng.random() < p
    for k in range(1, count):
        x[k] = x[k - 1] if rng.random() < persistence else rng.random() < p
    return x


def test_one_runs_calibration_bound_accounts_for_correlated_times():
    """A calibrated belief (p = 0.95) whose misses come in long episodes has single runs at
    0.8 and below; the bound must not call such runs miscalibrated more often than its 1 %
    (a little more for the AR(1) approximation), and must catch an i.i.d. 0.5."""
    from stt_drake.core.consistency import CALIBRATION_WARNING, calibration_upper_bound

    rng = np.random.default_rng(5)
    runs = [_markov_indicator(rng, 0.95, 0.97, 600) for _ in range(400)]
    means = np.array([r.mean() for r in runs])
    assert np.mean(means < 0.9) > 0.1  # plenty of single runs look bad
    false_alarms = np.mean([calibration_upper_bound(r)[0] < CALIBRATION_WARNING for r in runs])
    assert false_alarms <= 0.03
    # runs with misses: ρ = 0.97 → N_eff = N·0.03/1.97 ≈ 9; the lag-1 estimate from one
    # short run is biased low (≈ ρ − (1 + 4ρ)/N, N_eff ≈ 12), so about 12, far below 600
    mixed = [calibration_upper_bound(r)[1] for r in runs if 0.0 < r.mean() < 1.0]
    assert 6.0 < np.median(mixed) < 25.0
    wrong = rng.random(600) < 0.5
    upper, effective = calibration_upper_bound(wrong)
    assert upper < 0.6 and effective > 300  # independent misses: ~all 600 count
    # p = 1: (1 + z²/N)/(1 + z²/N) = 1, to a few roundings
    assert calibration_upper_bound(np.ones(50, dtype=bool))[0] == pytest.approx(1.0, abs=1e-15)
