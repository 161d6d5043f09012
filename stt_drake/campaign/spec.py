"""What a campaign is: :class:`CampaignSpec` (kept as ``campaign_spec.json``), its kinds,
:class:`CampaignError`, the error for bad campaign input, and :class:`CampaignStoppedError`,
the end of a campaign that could not finish.

Its own module so that both the runner (:mod:`stt_drake.campaign.executor`) and the report
(:mod:`stt_drake.campaign.report`) read it without importing each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from stt_drake.campaign.sampling import MOTIONS

KINDS = ("true-obstacles", "randomisation", "end-to-end")


class CampaignError(ValueError):
    """Bad campaign input; the message names the option or field."""


class CampaignStoppedError(RuntimeError):
    """The campaign could not go on (its cluster was lost, no worker came, local worker
    processes kept dying); every run recorded so far is kept in ``runs.jsonl``."""


@dataclass(frozen=True)
class CampaignSpec:
    """What a campaign is; `runs.jsonl` of one spec can be resumed only by the same spec
    (up to `runs`)."""

    scenario: str  # path as given
    kind: str = "true-obstacles"
    runs: int = 1000
    seed: int = 0
    motion: str = "static"
    tau: float = 2.0
    #: False: the scenario's guide section is dropped (the reactive tube, same draws).
    guide: bool = True

    def validate(self) -> None:
        """Raise CampaignError naming the option of the first bad value."""
        if self.kind not in KINDS:
            raise CampaignError(f"--kind: must be one of {', '.join(KINDS)} (got {self.kind!r})")
        if self.runs < 1:
            raise CampaignError(f"--runs: must be ≥ 1 (got {self.runs})")
        if self.seed < 0:
            raise CampaignError(f"--seed: must be ≥ 0 (got {self.seed})")
        if self.motion not in MOTIONS:
            raise CampaignError(
                f"--true-obstacle-motion: must be one of {', '.join(MOTIONS)} (got {self.motion!r})"
            )
        if not (self.tau > 0.0 and math.isfinite(self.tau)):
            raise CampaignError(f"--ou-tau: must be a finite time > 0 s (got {self.tau})")
