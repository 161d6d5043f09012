"""`stt-drake bench`, the campaign rows: how many runs per core-second each campaign kind
does, one whole campaign per kind on one local worker process (from the scenario file to
campaign.json, figures off; the worker's start included, as a user's campaign pays it)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from stt_drake.bench.loops import DIAGRAMS

#: (kind, packaged scenario, runs at scale 1): the true-obstacle draws around one simulated
#: loop, redrawn random fields simulated one by one, and the tracked loop simulated end to
#: end (sensor, tracker and plant every run).
CAMPAIGNS = (
    ("true-obstacles", "omni_hardware_case1", 2000),
    ("randomisation", "liveness_clutter_2d", 4),
    ("end-to-end", "omni_tracked", 2),
)


def campaign_runs(runs: int, scale: float) -> int:
    """The runs of a campaign row at `scale` (> 0): at least one."""
    return max(1, round(runs * scale))


def bench_campaigns(scale: float = 1.0) -> dict[str, dict[str, Any]]:
    """One campaign of each kind of :data:`CAMPAIGNS` with its runs times `scale`, on one
    worker: by kind, the scenario, the runs, the wall time (s) and ``runs_per_core_second``
    (runs over wall time: one worker is one core, the parent process only waits)."""
    from stt_drake.campaign import CampaignSpec, run_campaign

    results: dict[str, dict[str, Any]] = {}
    for kind, name, runs in CAMPAIGNS:
        runs = campaign_runs(runs, scale)
        spec = CampaignSpec(scenario=str(DIAGRAMS / f"{name}.yaml"), kind=kind, runs=runs, seed=0)
        with tempfile.TemporaryDirectory() as folder:
            wall = time.perf_counter()
            run_campaign(spec, Path(folder) / "campaign", workers=1, progress=False, figures=False)
            wall = time.perf_counter() - wall
        results[kind] = {
            "scenario": name,
            "runs": runs,
            "wall_s": wall,
            "runs_per_core_second": runs / wall,
        }
    return results
