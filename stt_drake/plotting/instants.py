"""When the snapshot figures look at a run: the start, the time of each guarantee's worst
margin and the end (:func:`snapshot_times`), or the times a caller chooses.

The worst-margin times are those of the run's
:class:`~stt_drake.core.invariants.InvariantTracker` (``metrics.json``'s ``invariants``,
``t_worst`` per guarantee) when the caller passes them; without them they are found in the
logged margins by the same rule (the logged samples only, so within a log period of the
monitor's).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from stt_drake.core.invariants import InvariantTracker
from stt_drake.runlog import RunLog

#: Words for each guarantee in a snapshot's caption.
GUARANTEE_WORDS = {
    "output_in_tube": "output in tube",
    "center_avoid_probability": "centre avoidance",
    "tube_avoid_probability": "tube avoidance",
    "output_avoid_probability": "output avoidance",
    "radius_positive": "radius",
}
#: Characters a line of a snapshot's title holds before it wraps.
TITLE_WIDTH = 40
#: Worst-margin times closer than this fraction of the run's duration share one snapshot.
MERGE_FRACTION = 0.02


def worst_margin_times(
    log: Mapping[str, Any], invariants: Mapping[str, Mapping[str, Any]] | None = None
) -> dict[str, float]:
    """The time (s) of each guarantee's worst margin, by guarantee name.

    Args:
        log: a run log (see :mod:`stt_drake.plotting`).
        invariants: ``metrics.json``'s ``invariants`` (name → ``t_worst``, ``worst_margin``
            and, for an obstacle guarantee of a run without obstacles, a ``note``). None:
            found in the logged margins with :class:`InvariantTracker`.

    Returns:
        Name → ``t_worst``, leaving out the vacuous guarantees (a ``note``) and those
        whose worst margin is +∞ (never evaluated).
    """
    if invariants is None:
        run = RunLog.of(log)
        tracker = InvariantTracker()
        tracker.update_many(run.t, run.margins)
        invariants = tracker.as_dict()
    return {
        name: float(record["t_worst"])
        for name, record in invariants.items()
        if "note" not in record and record.get("worst_margin") != math.inf
    }


def snapshot_plan(
    log: Mapping[str, Any],
    times: Sequence[float] | None = None,
    invariants: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[tuple[int, list[str]]]:
    """The snapshots to draw: (sample index, guarantees whose worst margin it shows).

    Default times (`times` None or empty): the start, each guarantee's worst-margin time
    (:func:`worst_margin_times`) and the end; times closer than :data:`MERGE_FRACTION` of
    the duration share one snapshot (the earliest; the start or the end when among them).
    Chosen `times` are drawn as given (each snapped to the nearest sample; repeats drawn
    once). A guarantee is named on the snapshot nearest its worst time when that is within
    the merge distance.
    """
    run = RunLog.of(log)
    t = run.t
    t0, t_end = float(t[0]), float(t[-1])
    tolerance = MERGE_FRACTION * (t_end - t0)
    worst = worst_margin_times(run, invariants)
    if times:
        chosen = [float(time) for time in times]
    else:
        chosen = []
        for time in sorted([t0, *worst.values(), t_end]):
            if chosen and time - chosen[-1] <= tolerance:
                if time == t_end:  # the end stands for its cluster
                    chosen[-1] = t_end
                continue
            chosen.append(time)
    indices = list(dict.fromkeys(int(np.argmin(np.abs(t - time))) for time in chosen))
    names: list[list[str]] = [[] for _ in indices]
    shown = t[indices]
    for name, time in worst.items():
        nearest = int(np.argmin(np.abs(shown - time)))
        if abs(shown[nearest] - time) <= tolerance:
            names[nearest].append(name)
    return list(zip(indices, names, strict=True))


def snapshot_times(
    log: Mapping[str, Any], invariants: Mapping[str, Mapping[str, Any]] | None = None
) -> list[float]:
    """The logged times (s) the snapshot figures show by default (:func:`snapshot_plan`)."""
    run = RunLog.of(log)
    return [float(run.t[index]) for index, _ in snapshot_plan(run, None, invariants)]


def snapshot_title(time: float, names: Sequence[str]) -> str:
    """A snapshot panel's title: its time, and the guarantees whose worst margin it shows."""
    title = f"t = {time:.2f} s"
    if names:
        words = ", ".join(GUARANTEE_WORDS.get(name, name.replace("_", " ")) for name in names)
        title += "\n" + textwrap.fill(f"worst margin: {words}", TITLE_WIDTH)
    return title


def panel_grid(panels: int, columns: int) -> tuple[int, int]:
    """(rows, columns) of the most even grid holding `panels` panels, at most `columns` a
    row (five panels: two rows of three)."""
    rows = math.ceil(panels / columns)
    return rows, math.ceil(panels / rows)
