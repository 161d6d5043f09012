"""What a campaign is: :class:`CampaignSpec` (kept as ``campaign_spec.json``; its checks,
which depend on the kind, are :func:`stt_drake.campaign.kinds.validate_spec`),
:class:`CampaignError`, the error for bad campaign input, and
:class:`CampaignStoppedError`, the end of a campaign that could not finish.

Its own module so that both the runner (:mod:`stt_drake.campaign.executor`) and the report
(:mod:`stt_drake.campaign.report`) read it without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass

from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE

#: The most runs a campaign (and a comparison's campaign, or its draws) may ask for: every
#: run is a record kept in memory and a line of runs.jsonl, so a mistyped count is refused
#: before any work instead of filling the memory or looping at start-up.
MAX_RUNS = 10_000_000
#: Defaults of the true-obstacle motion (the spec's, and the command's when not given).
DEFAULT_MOTION, DEFAULT_TAU = "static", 2.0


def check_runs(runs: int) -> None:
    """Raise CampaignError naming the parameter `runs` unless 1 ≤ `runs` ≤ :data:`MAX_RUNS`."""
    if not 1 <= runs <= MAX_RUNS:
        raise CampaignError(f"`runs`: must be ≥ 1 and ≤ {MAX_RUNS:,} (got {runs})")


class CampaignError(ValueError):
    """Bad campaign input; the message names the parameter (in backticks, e.g.
    ```runs```: the command line shows its flag, :func:`stt_drake.cli.main.flag_message`)
    or the scenario's field."""


class CampaignStoppedError(RuntimeError):
    """The campaign could not go on (its cluster was lost, no worker came, local worker
    processes kept dying); every run recorded so far is kept in ``runs.jsonl``."""


@dataclass(frozen=True)
class CampaignSpec:
    """What a campaign is; `runs.jsonl` of one spec can be resumed only by the same spec
    (up to `runs`). Checked by :func:`stt_drake.campaign.kinds.validate_spec`."""

    scenario: str  # path as given
    kind: str = "true-obstacles"
    runs: int = 1000
    seed: int = 0
    motion: str = DEFAULT_MOTION
    tau: float = DEFAULT_TAU
    #: False: the scenario's guide section is dropped (the reactive tube, same draws).
    guide: bool = True
    #: d_c (m): a run's `comfort_violation_s` counts the time closer than this
    #: (:mod:`stt_drake.core.crowd_metrics`); a spec written before it existed meant the default.
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE
