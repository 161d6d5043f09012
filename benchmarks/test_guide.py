"""The benchmark history's guide rows: one replan of the guide (the scripted forecast over
its horizon, the level-set radii and the space-time A*) on the 50-obstacle fields of
`stt-drake bench`'s ``guide_plan_ms`` (:func:`stt_drake.bench.guide.plan_workload`), from
the point 30 % of the way to the goal at t = 20 s. The level-set tables are warm after the
first round, as in a run after its first replans."""

from __future__ import annotations

import numpy as np
import pytest

from stt_drake.bench.guide import PLAN_FIELDS, plan_workload


@pytest.mark.parametrize("key", list(PLAN_FIELDS))
def test_guide_plan(benchmark, key):
    workload = plan_workload(key)
    route = benchmark(workload.plan, 30, 60)
    assert route.expansions > 0 and np.all(np.isfinite(route.points))
