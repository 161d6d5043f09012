"""The campaign kinds are objects in one registry (stt_drake.campaign.kinds): each says
what a run is, what counts as a failure, how it is summarised and drawn."""

from __future__ import annotations

import pytest

from stt_drake.campaign.kinds import (
    CAMPAIGN_KINDS,
    CROWD_KINDS,
    KINDS,
    SAMPLING_KINDS,
    CampaignKind,
)

REQUIRED = ("scenario_problem", "prepare", "failed", "summarise", "report_lines", "figure")


@pytest.mark.parametrize("kind", list(CAMPAIGN_KINDS.values()), ids=list(CAMPAIGN_KINDS))
def test_every_kind_answers_every_question(kind):
    assert CAMPAIGN_KINDS[kind.name] is kind
    assert kind.true_obstacles and kind.figure_file.endswith(".png")
    for method in REQUIRED:
        assert getattr(type(kind), method) is not getattr(CampaignKind, method), method


def test_the_registry_keeps_the_kinds_order_and_their_groups():
    assert KINDS == ("true-obstacles", "randomisation", "end-to-end")
    assert SAMPLING_KINDS == ("true-obstacles",)
    assert CROWD_KINDS == ("randomisation", "end-to-end")


def test_what_counts_as_a_failure():
    randomisation, end_to_end = CAMPAIGN_KINDS["randomisation"], CAMPAIGN_KINDS["end-to-end"]
    assert CAMPAIGN_KINDS["true-obstacles"].failed({"output": [[], [[3, 5]]]})
    assert not CAMPAIGN_KINDS["true-obstacles"].failed({"output": [[], []]})
    assert not randomisation.failed({"status": "rejected"})
    assert randomisation.failed({"status": "error"})
    assert randomisation.failed({"status": "simulated", "success": False})
    assert end_to_end.failed({"status": "simulated", "output": [[[0, 1]]]})
    assert not end_to_end.failed({"status": "simulated", "output": [[]]})
