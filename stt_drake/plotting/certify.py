"""What the campaign and comparison figures share: a collision frequency with its
simultaneous Clopper-Pearson interval (:func:`draw_frequency`: a band, or error bars when
the run count is too small for a band to say anything) and the words of a verdict
(:func:`verdict_text`, :func:`uncertified_note`).

A verdict record is one of campaign.json's (an obstacle's output check, or its ``tube``
sub-record) or a comparison row: ``verdict`` (``certified``, ``inconclusive`` or
``violated``) and ``runs_to_certify`` (about how many runs would certify an inconclusive
one at the frequencies seen; None when no run count would).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from stt_drake.core.statistics import (
    CERTIFIED,
    INCONCLUSIVE,
    VIOLATED,
    clopper_pearson,
    verdict_words,
)

#: The colour of each verdict's words.
VERDICT_COLORS = {CERTIFIED: "#2ca02c", INCONCLUSIVE: "#ff7f0e", VIOLATED: "#d62728"}


def band_fits(runs: int, member: float, allowed: float) -> bool:
    """Whether `runs` runs can certify a collision probability ≤ `allowed` at all: the
    upper bound at zero collisions is ≤ `allowed`. Below that count the interval is wider
    than the axis and a band would cover it."""
    return float(clopper_pearson(0.0, runs, member)[1]) <= allowed


def draw_frequency(
    ax: Any,
    t: np.ndarray,
    counts: np.ndarray,
    runs: int,
    member: float,
    allowed: float,
    color: Any,
    label: str,
) -> None:
    """The collision frequency `counts`/`runs` over `t` and its Clopper-Pearson interval
    at confidence `member`: a band when :func:`band_fits`, else one point with its error
    bar at the highest count (the first such time; the bar may run off the axis: the run
    count cannot certify `allowed`)."""
    frequency = counts / runs
    lower, upper = clopper_pearson(counts, runs, member)
    ax.plot(t, frequency, color=color, lw=1.2, label=f"{label}: frequency")
    if band_fits(runs, member, allowed):
        ax.fill_between(t, lower, upper, color=color, alpha=0.15, linewidth=0)
        return
    k = int(np.argmax(counts))
    ax.errorbar(
        t[k],
        frequency[k],
        yerr=[[frequency[k] - lower[k]], [upper[k] - frequency[k]]],
        fmt="o",
        ms=2.5,
        color=color,
        elinewidth=0.7,
        capsize=2,
        alpha=0.7,
        label=f"{label}: 99 % interval at its worst time",
    )


def verdict_text(record: Mapping[str, Any]) -> str:
    """The verdict's words (:func:`stt_drake.core.statistics.verdict_words`: ``certified``,
    ``violated``, ``inconclusive (needs ≈N runs)``), or "inconclusive (no run count would
    certify at the frequency seen)"."""
    needed = record.get("runs_to_certify")
    if record["verdict"] == INCONCLUSIVE and needed is None:
        return f"{INCONCLUSIVE} (no run count would certify at the frequency seen)"
    return verdict_words(record["verdict"], needed)


def uncertified_note(runs: int, records: Sequence[Mapping[str, Any]]) -> str | None:
    """A note for a figure whose verdicts include an inconclusive one: that `runs` runs
    cannot certify, and about how many would (the most any of them needs), or that none
    would at the frequencies seen; None when no verdict is inconclusive."""
    open_records = [r for r in records if r["verdict"] == INCONCLUSIVE]
    if not open_records:
        return None
    needed = [r.get("runs_to_certify") for r in open_records]
    note = f"inconclusive: {runs} runs cannot certify every 1 − ε_j"
    if None in needed:
        return note + "; at the frequencies seen no run count would"
    return note + f"; ≈{max(needed)} runs would"
