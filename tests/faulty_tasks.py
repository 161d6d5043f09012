"""Executor tasks that fail the way a broken run does, for campaigns in tests: a local
pool's worker imports this module by name (tests/ is on the path of the forkserver that a
test's campaign starts), so a test can swap a campaign's task for one of these."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def raising_end_to_end_task(
    text: str, name: str, steps: int, guide: bool, runs: Sequence[tuple[int, int]]
) -> list[dict[str, Any]]:
    """What :func:`stt_drake.campaign.end_to_end.end_to_end_task` gives when every run's
    simulation raises: an ``error`` record per run, colliding at every logged time."""
    from stt_drake.config import parse_schema

    count = len(parse_schema(text, name, guide).obstacles)
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
