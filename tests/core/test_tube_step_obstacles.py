"""The 7-argument entry of the compiled tube step (stt_drake.core._tube.tube_step_obstacles):
it is tube_step on the law's gains and constants packed in one array, and the law sends a
plain belief there (circulation or inflation still go to tube_step's 14 arguments)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from stt_drake.bench import obstacle_field
from stt_drake.core import _tube, backend
from stt_drake.core.tube import TubeLaw

MODES = ("pruned", "exact", "rate")


def laws(law: TubeLaw, count: int) -> list[TubeLaw]:
    """`law`, and the same law with one k2 and k3 per obstacle."""
    per_obstacle = replace(law, k2=np.linspace(0.2, 0.6, count), k3=np.linspace(0.0, 0.9, count))
    return [law, per_obstacle]


@pytest.mark.parametrize("worst", [False, True])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_it_is_tube_step_on_the_packed_law(n, worst):
    """The same compiled arithmetic on the same inputs (tube_step is what it calls, on
    views of the packed array): the same bits."""
    count = 40
    base, center, belief = obstacle_field(count, max(n, 2), worst_case=worst, seed=3)
    if n == 1:  # obstacle_field draws n = 2, 3: a 1D field from the first coordinate
        center, belief = center[:1], replace(belief, mean=belief.mean[:, :1])
        base = replace(base, target=base.target[:1])
    empty = np.empty(0)
    for law in laws(base, count):
        for mode in MODES:
            kernel, packed = law._kernel_call("tube_step_obstacles", n, count, mode)
            _, k2, k3, constants, axes = law._kernel_call("tube_step", n, count, mode)
            arrays = (belief.mean, belief.sigma, belief.radius, belief.epsilon, belief.p_d)
            expected = _tube.tube_step(
                center, *arrays[:4], None, arrays[4], k2, k3, empty, empty, axes, constants, empty
            )
            np.testing.assert_array_equal(kernel(center, *arrays, packed), expected)


def test_the_law_sends_plain_beliefs_to_it_and_the_rest_to_tube_step():
    law, center, belief = obstacle_field(30, 3, seed=4)
    law.evaluate(center, belief)
    assert ("tube_step_obstacles", 3, 30, "pruned") in law._kernel_calls
    assert ("tube_step", 3, 30, "pruned") not in law._kernel_calls
    axes = np.zeros((30, 3))
    axes[:, 2] = 1.0
    law.evaluate(center, belief, circulation=axes)
    assert ("tube_step", 3, 30, "pruned") in law._kernel_calls
    with backend.pure_numpy():  # the numpy path looks up no kernel
        fresh = law.with_target(law.target)
        fresh.evaluate(center, belief)
        assert fresh._kernel_calls == {}
