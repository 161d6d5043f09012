"""The run-log schema (stt_drake.runlog): reading the loggers, the cut to common samples,
the log.npz round trip and the decoded belief table against the belief's port layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario
from stt_drake.core.belief import GaussianBelief, ObstacleTask
from stt_drake.runlog import RunLog

CASE1 = Path(__file__).resolve().parents[2] / "diagrams" / "omni_hardware_case1.yaml"
CONTEXT = object()
PERIOD = 0.02


class FakeLog:
    """A VectorLog: `data` is (width, samples), as Drake stores it."""

    def __init__(self, data: np.ndarray) -> None:
        self._data = data

    def num_samples(self) -> int:
        return self._data.shape[1]

    def data(self) -> np.ndarray:
        return self._data

    def sample_times(self) -> np.ndarray:
        return PERIOD * np.arange(self._data.shape[1])


class FakeSink:
    """A VectorLogSink whose log lives in CONTEXT."""

    def __init__(self, data: np.ndarray) -> None:
        self._log = FakeLog(data)

    def FindLog(self, context: object) -> FakeLog:  # noqa: N802 - Drake's name
        assert context is CONTEXT
        return self._log


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(CASE1)


def beliefs(samples: int, count: int, dimension: int) -> list[GaussianBelief]:
    """A distinct belief of `count` slots per sample (every field differs; some slots
    inactive)."""
    rng = np.random.default_rng(1)
    result = []
    for _ in range(samples):
        factor = rng.normal(size=(count, dimension, dimension))
        covariance = factor @ np.swapaxes(factor, 1, 2) + 0.1 * np.eye(dimension)
        active = rng.uniform(size=count) < 0.8
        result.append(GaussianBelief(rng.normal(size=(count, dimension)), covariance, active))
    return result


def signals(scenario, samples: dict[str, int] | None = None) -> dict[str, np.ndarray]:
    """Logger data (width, samples) for every logged signal of the scenario, plus an extra
    `wind`; `samples` overrides how many samples a logger holds (default 6)."""
    n, m = scenario.dimension, len(scenario.obstacles)
    widths = {
        "output": n,
        "tube": n + 1,
        "belief": m * (n + n * n + 1),
        "diagnostics": 3 * m,
        "recovery": m,
        "control": n,
        "margins": 5,
        "output_avoid_probability": m,
        "tube_avoid_probability": m,
        "wind": n,
    }
    rng = np.random.default_rng(0)
    counts = {name: 6 for name in widths} | (samples or {})
    data = {name: rng.normal(size=(width, counts[name])) for name, width in widths.items()}
    rows = [belief.to_vector() for belief in beliefs(counts["belief"], m, n)]
    data["belief"] = np.array(rows).reshape(counts["belief"], -1).T
    return data


def from_signals(scenario, data: dict[str, np.ndarray]) -> RunLog:
    sinks = {name: FakeSink(values) for name, values in data.items()}
    constants = {"effort_limit": [1.0, 2.0]}
    return RunLog.from_loggers(sinks, CONTEXT, scenario, ("wind",), constants)


def test_from_loggers_lays_out_every_signal_samples_first(scenario):
    data = signals(scenario)
    log = from_signals(scenario, data)
    n, m = scenario.dimension, len(scenario.obstacles)
    assert list(log)[:14] == [
        "name",
        "t",
        "output",
        "center",
        "radius",
        "belief",
        "avoid_probability",
        "quantile_distance",
        "theta",
        "recovery",
        "control",
        "margins",
        "output_avoid_probability",
        "tube_avoid_probability",
    ]
    assert list(log)[-6:] == [
        "sigma_rate_bound",
        "obstacle_radius",
        "epsilon",
        "p_d",
        "wind",
        "effort_limit",
    ]
    np.testing.assert_array_equal(log["t"], PERIOD * np.arange(6))
    np.testing.assert_array_equal(log["center"], data["tube"][:n].T)
    np.testing.assert_array_equal(log["radius"], data["tube"][n])
    diagnostics = data["diagnostics"].T
    np.testing.assert_array_equal(log["avoid_probability"], diagnostics[:, :m])
    np.testing.assert_array_equal(log["quantile_distance"], diagnostics[:, m : 2 * m])
    np.testing.assert_array_equal(log["theta"], diagnostics[:, 2 * m :])
    for name in ("output", "belief", "control", "margins", "wind"):
        np.testing.assert_array_equal(log[name], data[name].T)
    assert log.name == scenario.name and log.dimension == n and log.count == m
    assert log["effort_limit"].dtype == float
    np.testing.assert_array_equal(log.target, scenario.target)
    assert (log.r_min, log.r_max) == (scenario.tube.r_min, scenario.tube.r_max)
    speeds = [np.hypot(0.05, 0.05), 0.08, 0.1, np.hypot(0.02, 0.05)]  # the YAML's velocities
    np.testing.assert_allclose(log.mean_speed_bound, speeds, rtol=1e-12)


def test_an_interrupted_run_is_cut_to_the_samples_every_logger_has(scenario):
    # An exception during a publish: some loggers hold one sample more than others.
    data = signals(scenario, {"tube": 7, "margins": 7, "wind": 7, "belief": 5})
    log = from_signals(scenario, data)
    assert log.samples == 5
    for name in ("t", "output", "center", "radius", "belief", "avoid_probability", "margins"):
        assert len(log[name]) == 5, name
    assert log["wind"].shape == (5, scenario.dimension)
    np.testing.assert_array_equal(log["t"], PERIOD * np.arange(5))
    np.testing.assert_array_equal(log["margins"], data["margins"][:, :5].T)
    # A run that failed before its first sample: every signal empty, the views too.
    empty = from_signals(scenario, signals(scenario, {"output": 0}))
    m, n = len(scenario.obstacles), scenario.dimension
    assert empty.samples == 0 and empty.count == m
    assert empty.mean.shape == (0, m, n) and empty.margins.shape == (0, 5)


def test_save_and_load_round_trip_every_member(scenario, tmp_path):
    log = from_signals(scenario, signals(scenario))
    path = log.save(tmp_path / "log.npz")
    loaded = RunLog.load(path)
    assert list(loaded) == list(log)
    for name in log:
        assert loaded[name].dtype == log[name].dtype, name
        assert loaded[name].shape == log[name].shape, name
        assert np.array_equal(loaded[name], log[name]), name
    with np.load(path) as npz:  # any mapping reads the same
        assert np.array_equal(RunLog.of(npz).mean, log.mean)
    assert RunLog.of(log) is log
    assert dict(log).keys() == dict(**log).keys() == set(log)


def test_the_belief_table_is_the_port_layout_per_sample(scenario):
    data = signals(scenario)
    log = from_signals(scenario, data)
    n, m = scenario.dimension, len(scenario.obstacles)
    expected = beliefs(6, m, n)
    task = ObstacleTask.of(scenario.obstacles)
    assert log.mean.shape == (6, m, n) and log.sigma.shape == (6, m)
    assert not log.full_covariance and log.covariance is None
    for k, belief in enumerate(expected):
        np.testing.assert_array_equal(log.mean[k], belief.mean)
        np.testing.assert_array_equal(log.belief_covariance[k], belief.covariance)
        np.testing.assert_array_equal(log.active[k], belief.active)
        largest = [np.sqrt(np.max(np.linalg.eigvals(c).real)) for c in belief.covariance]
        np.testing.assert_allclose(log.sigma[k], largest, rtol=1e-12)
        # the task numbers are the scenario's, the same at every sample
        np.testing.assert_array_equal(log.obstacle_radius[k], task.radius)
        np.testing.assert_array_equal(log.epsilon[k], task.epsilon)
        np.testing.assert_array_equal(log.p_d[k], task.p_d)
        # belief_at: the active slots as the law reads them
        law_belief = log.belief_at(k)
        np.testing.assert_array_equal(law_belief.mean, belief.mean[belief.active])
        np.testing.assert_array_equal(law_belief.epsilon, task.epsilon[belief.active])
        # Record j of row k is [mean (n), covariance (n², row-major), active], slot-major.
        width = n + n * n + 1
        for j in range(m):
            record = log["belief"][k, j * width : (j + 1) * width]
            np.testing.assert_array_equal(record[:n], log.mean[k, j])
            np.testing.assert_array_equal(record[n:-1], log.belief_covariance[k, j].ravel())
            assert record[-1] == float(log.active[k, j])


def test_a_belief_row_that_is_no_whole_number_of_records_is_refused():
    log = RunLog({"t": np.zeros(2), "dimension": np.array(2), "belief": np.zeros((2, 8))})
    with pytest.raises(ValueError, match="7-long slot records"):
        _ = log.mean


def test_the_active_target_is_the_task_target_or_the_fixed_target():
    t = np.arange(3.0)
    fixed = RunLog({"t": t, "dimension": np.array(2), "target": np.array([1.0, 2.0])})
    np.testing.assert_array_equal(fixed.active_target, [[1.0, 2.0]] * 3)
    tasks = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 2.0]])
    sequence = RunLog({**fixed, "task_target": tasks})
    np.testing.assert_array_equal(sequence.active_target, tasks)
    assert fixed.r_max is None and fixed.name == "" and fixed.control is None
