"""The benchmark history's campaign rows: one whole campaign of each kind of
:data:`stt_drake.bench.campaigns.CAMPAIGNS` (the campaign rows of `stt-drake bench`) on one
local worker process (`workers=1`), from the scenario file to campaign.json, figures off. The
saved row's ``extra_info`` holds the throughput, ``runs_per_core_second``: runs divided by
the median wall time of the campaign, which on one worker is about the core-seconds it
used (the parent process only waits)."""

from __future__ import annotations

import pytest

from stt_drake.bench.campaigns import CAMPAIGNS
from stt_drake.bench.loops import DIAGRAMS
from stt_drake.campaign import CampaignSpec, run_campaign


@pytest.mark.parametrize(("kind", "name", "runs"), CAMPAIGNS, ids=[c[0] for c in CAMPAIGNS])
def test_campaign(benchmark, tmp_path, kind, name, runs):
    spec = CampaignSpec(scenario=str(DIAGRAMS / f"{name}.yaml"), kind=kind, runs=runs, seed=0)
    folders = iter(range(1_000))

    def campaign() -> dict:
        out = tmp_path / f"round{next(folders)}"
        return run_campaign(spec, out, workers=1, progress=False, figures=False).summary

    summary = benchmark.pedantic(campaign, rounds=2, iterations=1)
    benchmark.extra_info["runs"] = runs
    benchmark.extra_info["runs_per_core_second"] = runs / benchmark.stats.stats.median
    assert summary["kind"] == kind
