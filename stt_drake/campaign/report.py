"""What a campaign writes and prints: ``campaign.json`` (:func:`write_summary`: the
campaign's own keys, its kind's summary, the crowd and error keys), the kind's figure and
the printed report (:func:`report`). What each kind adds is
:mod:`stt_drake.campaign.kinds`; the summaries themselves are
:mod:`stt_drake.campaign.summaries`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stt_drake.campaign.crowd_metrics import crowd_line, crowd_summary
from stt_drake.campaign.kinds import CAMPAIGN_KINDS, Prepared
from stt_drake.campaign.summaries import error_summary
from stt_drake.runlog import write_json

if TYPE_CHECKING:
    from stt_drake.campaign.spec import CampaignSpec

SUMMARY_FILE = "campaign.json"


def write_summary(
    spec: CampaignSpec,
    scenario_name: str,
    records: Sequence[dict[str, Any]],
    out_dir: Path,
    started: float,
    prepared: Prepared,
    figures: bool = True,
    malformed_lines: int = 0,
) -> dict[str, Any]:
    """Summarise the finished runs, write campaign.json (strict JSON) and the figure, and
    return the summary.

    `started` is the campaign's ``time.perf_counter()`` start; `prepared` is what the
    campaign's kind prepared (:meth:`stt_drake.campaign.kinds.CampaignKind.prepare`);
    `malformed_lines` counts the lines of ``runs.jsonl`` a resume skipped (their runs were
    redone).
    """
    kind = CAMPAIGN_KINDS[spec.kind]
    records = list(records)
    body = kind.summarise(spec, records, prepared)
    if kind.crowd:
        body.update(crowd_summary(records, spec.comfort_distance))
    body.update(error_summary(records))
    if body["error_runs"]:
        body["holds"] = False  # a run that raised checked nothing: no verdict can hold
    summary = {
        "scenario": scenario_name,
        "scenario_path": str(Path(spec.scenario)),
        "kind": spec.kind,
        "runs": spec.runs,
        "seed": spec.seed,
        "guide": spec.guide,
        "run_seed": "SeedSequence(seed, spawn_key=(i,)).generate_state(1)[0]",
        "wall_time_s": time.perf_counter() - started,
        "malformed_lines": malformed_lines,
        **body,
    }
    write_json(out_dir / SUMMARY_FILE, summary)
    if figures:
        kind.figure(summary, records, prepared).savefig(out_dir / kind.figure_file, dpi=120)
    return summary


def report(summary: dict[str, Any]) -> str:
    """The printed campaign summary: a header, the kind's lines
    (:meth:`~stt_drake.campaign.kinds.CampaignKind.report_lines`), the crowd line, the
    errors, the skipped lines of runs.jsonl and the verdict."""
    lines = [
        f"{summary['kind']} campaign on {summary['scenario']}: {summary['runs']} runs, "
        f"seed {summary['seed']}, {summary['wall_time_s']:.1f} s wall",
        *CAMPAIGN_KINDS[summary["kind"]].report_lines(summary),
    ]
    if "crowd_runs" in summary:
        lines.append(crowd_line(summary))
    if summary.get("error_runs"):
        first = summary["first_error"]
        reason = (first["reason"].strip().splitlines() or [""])[0]
        lines.append(
            f"  {summary['error_runs']} run(s) raised: first error (run {first['run']}, seed "
            f"{first['seed']}): {reason[:300]}"
        )
    if summary.get("malformed_lines"):
        lines.append(
            f"  runs.jsonl: {summary['malformed_lines']} malformed line(s) skipped; their runs "
            "were redone"
        )
    lines.append("  result: " + ("HOLDS" if summary["holds"] else "DOES NOT HOLD"))
    return "\n".join(lines)
