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
from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE, check_comfort_distance
from stt_drake.core.rules import RuleError

KINDS = ("true-obstacles", "randomisation", "end-to-end")
#: The kinds whose runs sample the true obstacles around the belief (``--true-obstacle-motion``
#: and ``--ou-tau`` apply to them only).
SAMPLING_KINDS = ("true-obstacles",)
#: The kinds whose runs simulate and record the crowd metrics against the true obstacles
#: (:mod:`stt_drake.campaign.crowd_metrics`; ``--comfort-distance`` applies to them only).
CROWD_KINDS = ("randomisation", "end-to-end")
#: The most runs a campaign (and a comparison's campaign, or its draws) may ask for: every
#: run is a record kept in memory and a line of runs.jsonl, so a mistyped count is refused
#: before any work instead of filling the memory or looping at start-up.
MAX_RUNS = 10_000_000
#: Defaults of the true-obstacle motion (the spec's, and the command's when not given).
DEFAULT_MOTION, DEFAULT_TAU = "static", 2.0


def check_runs(runs: int, option: str = "--runs") -> None:
    """Raise CampaignError naming `option` unless 1 ≤ `runs` ≤ :data:`MAX_RUNS`."""
    if not 1 <= runs <= MAX_RUNS:
        raise CampaignError(f"{option}: must be ≥ 1 and ≤ {MAX_RUNS:,} (got {runs})")


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
    motion: str = DEFAULT_MOTION
    tau: float = DEFAULT_TAU
    #: False: the scenario's guide section is dropped (the reactive tube, same draws).
    guide: bool = True
    #: d_c (m): a run's `comfort_violation_s` counts the time closer than this
    #: (:mod:`stt_drake.core.crowd_metrics`); a spec written before it existed meant the default.
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE

    def validate(self) -> None:
        """Raise CampaignError naming the option of the first bad value."""
        if self.kind not in KINDS:
            raise CampaignError(f"--kind: must be one of {', '.join(KINDS)} (got {self.kind!r})")
        check_runs(self.runs)
        if self.seed < 0:
            raise CampaignError(f"--seed: must be ≥ 0 (got {self.seed})")
        if self.motion not in MOTIONS:
            raise CampaignError(
                f"--true-obstacle-motion: must be one of {', '.join(MOTIONS)} (got {self.motion!r})"
            )
        if not (self.tau > 0.0 and math.isfinite(self.tau)):
            raise CampaignError(f"--ou-tau: must be a finite time > 0 s (got {self.tau})")
        if self.kind not in SAMPLING_KINDS and self.motion != DEFAULT_MOTION:
            raise CampaignError(sampling_only("--true-obstacle-motion", self.kind))
        if self.tau != DEFAULT_TAU and (self.kind not in SAMPLING_KINDS or self.motion != "ou"):
            raise CampaignError(sampling_only("--ou-tau", self.kind, self.motion))
        try:
            check_comfort_distance(self.comfort_distance, "--comfort-distance")
        except RuleError as error:
            raise CampaignError(str(error)) from None
        if self.kind not in CROWD_KINDS and self.comfort_distance != DEFAULT_COMFORT_DISTANCE:
            raise CampaignError(
                f"--comfort-distance: applies only to --kind {' or '.join(CROWD_KINDS)} (the "
                f"runs that are simulated against their true obstacles); a campaign of --kind "
                f"{self.kind} samples the obstacles against one closed loop"
            )


def sampling_only(option: str, kind: str, motion: str | None = None) -> str:
    """Why `option` does not apply to a campaign of `kind` (and `motion`)."""
    if kind not in SAMPLING_KINDS:
        return (
            f"{option}: applies only to --kind {' or '.join(SAMPLING_KINDS)} (the true "
            f"obstacles sampled around the belief); a campaign of --kind {kind} "
            + (
                "simulates its own true obstacles (perception: process noise)"
                if kind == "end-to-end"
                else "simulates each draw's scripted obstacles"
            )
        )
    return f"{option}: applies only with --true-obstacle-motion ou (got {motion})"
