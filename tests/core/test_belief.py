"""The belief at a system's input (stt_drake.core.belief): the port vector made into the one
type the law, the monitor and the visualizer read (ObstacleBelief.from_port), unpacked only
when a field is read, its results spread back over the slots."""

from __future__ import annotations

import numpy as np
import pytest

from stt_drake.core.belief import GaussianBelief, ObstacleBelief, ObstacleTask, PortBelief

TASK = ObstacleTask(
    radius=np.array([0.2, 0.3, 0.25, 0.4]),
    epsilon=np.array([0.9, 0.8, 0.95, 0.85]),
    p_d=np.array([0.999, 0.99, 0.9999, 0.999]),
)
ACTIVE = np.array([True, False, True, True])


def port_vector(dimension: int = 2) -> np.ndarray:
    rng = np.random.default_rng(3)
    root = rng.normal(size=(4, dimension, dimension))
    covariance = root @ np.swapaxes(root, 1, 2) + 0.01 * np.eye(dimension)
    return GaussianBelief(rng.normal(size=(4, dimension)), covariance, ACTIVE).to_vector()


@pytest.mark.parametrize("full_covariance", [False, True])
def test_a_port_belief_is_the_active_slots_with_their_task_numbers(full_covariance):
    vector = port_vector()
    belief = ObstacleBelief.from_port(vector, 2, TASK, full_covariance)
    assert isinstance(belief, PortBelief) and isinstance(belief, ObstacleBelief)
    expected = ObstacleBelief.of(GaussianBelief.from_vector(vector, 2), TASK, full_covariance)
    assert belief.count == 3 and belief.dimension == 2
    for name in ("mean", "sigma", "radius", "epsilon", "p_d"):
        np.testing.assert_array_equal(getattr(belief, name), getattr(expected, name))
    port_vector_read, port_rows = belief.port_arrays
    assert port_vector_read is belief.vector
    np.testing.assert_array_equal(port_rows, TASK.table())
    if full_covariance:
        np.testing.assert_array_equal(belief.covariance, expected.covariance)
        assert belief.packed is None  # the isotropic kernels must not read it
    else:
        assert belief.covariance is None
        packed_vector, rows = belief.packed
        assert packed_vector is belief.vector
        np.testing.assert_array_equal(rows, TASK.table())


def test_the_isotropic_hot_path_unpacks_nothing():
    """What the compiled law and margins read of an isotropic port belief (whether it has
    covariances, its dimension, the port vector and task rows) unpacks no slot."""
    belief = ObstacleBelief.from_port(port_vector(), 2, TASK)
    assert belief.covariance is None and belief.dimension == 2 and belief.packed is not None
    assert "_obstacles" not in belief.__dict__ and "slots" not in belief.__dict__
    belief.sigma  # noqa: B018 (a read unpacks, once)
    assert belief.obstacles() is belief.obstacles()


def test_results_are_spread_over_the_slots():
    belief = ObstacleBelief.from_port(port_vector(), 2, TASK)
    np.testing.assert_array_equal(belief.in_slots(np.array([1.0, 2.0, 3.0]), 9.0), [1, 9, 2, 3])
    rows = np.arange(12.0).reshape(4, 3)
    np.testing.assert_array_equal(belief.of_obstacles(rows), rows[ACTIVE])
    assert belief.of_obstacles(None) is None
    scripted = belief.obstacles()  # obstacle j is slot j: nothing to spread
    values = np.array([1.0, 2.0, 3.0])
    assert scripted.in_slots(values, 9.0) is values and scripted.of_obstacles(rows) is rows
    assert scripted.packed is None and scripted.port_arrays is None


def test_a_port_vector_that_does_not_fit_the_task_is_refused():
    with pytest.raises(ValueError, match="not a whole number of 7-long slot records"):
        ObstacleBelief.from_port(np.zeros(10), 2, TASK)
    with pytest.raises(ValueError, match="3 slots on the port but 4 obstacles' task numbers"):
        ObstacleBelief.from_port(np.zeros(21), 2, TASK)
