"""Executor tasks that fail the way a broken run does, for campaigns in tests: a local
pool's worker imports this module by name (tests/ is on the path of the forkserver that a
test's campaign starts), so a test can swap a campaign's task for one of these."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from stt_drake.config import ScenarioText


def raising_end_to_end_task(
    source: ScenarioText,
    steps: int,
    guide: bool,
    comfort_distance: float,
    runs: Sequence[tuple[int, int]],
) -> list[dict[str, Any]]:
    """What :func:`stt_drake.campaign.end_to_end.end_to_end_task` gives when every run's
    simulation raises: an ``error`` record per run, colliding at every logged time."""
    count = len(source.parse(guide).obstacles)
    every = [[[0, steps]] for _ in range(count)]
    return [
        {
            "run": index,
            "seed": seed,
            "status": "error",
            "reason": f"RuntimeError: the simulation of run {index} raised",
            "output": every,
            "tube": every,
        }
        for index, seed in runs
    ]
