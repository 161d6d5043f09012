"""The figures of `stt-drake campaign`, one per campaign kind, drawn from plain data (the
campaign package sits above plotting in the import layers and passes arrays and records,
never its own types):

* :func:`plot_collision_frequency` (true-obstacles, ``collision_frequency.png``);
* :func:`plot_randomisation` (randomisation, ``randomisation.png``);
* :func:`plot_end_to_end` (end-to-end, ``end_to_end.png``).

Collision counts are (check, obstacle, logged time) arrays with the checks in the order
``output``, ``tube`` (:data:`stt_drake.campaign.sampling.CHECKS`); every interval is the
simultaneous Clopper-Pearson interval at the per-member confidence `member`
(:func:`stt_drake.core.statistics.family_confidence`), drawn as a band or, at run counts
too small to certify, as error bars (:mod:`stt_drake.plotting.certify`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from stt_drake.core.consistency import CALIBRATION_LEVEL
from stt_drake.core.statistics import CERTIFIED, INCONCLUSIVE, VIOLATED
from stt_drake.plotting.certify import (
    VERDICT_COLORS,
    draw_frequency,
    uncertified_note,
    verdict_text,
)
from stt_drake.plotting.style import PALETTE

#: Colour and label of each check of a true-obstacle campaign.
_CHECK_STYLES = {"output": (PALETTE["trajectory"], "output y"), "tube": (PALETTE["tube"], "tube Γ")}


def plot_collision_frequency(
    t: np.ndarray,
    epsilon: np.ndarray,
    counts: np.ndarray,
    runs: int,
    member: float,
    model: Mapping[str, np.ndarray],
    verdicts: Sequence[Mapping[str, Any]] | None = None,
) -> Figure:
    """Empirical collision frequency over time per obstacle (output and tube) with its
    simultaneous 99 % Clopper-Pearson interval, against 1 − ε_j and the belief's
    prediction.

    `t` (T,) logged times (s); `epsilon` (m,) ε_j; `counts` (checks, m, T) runs that
    collided; `model` the belief's collision probability (T, m) per check, in the order of
    `counts`; `verdicts` campaign.json's ``obstacles`` (each obstacle's output verdict,
    its tube verdict in ``tube``): written in each panel, and a note in the title when the
    run count cannot certify (:func:`~stt_drake.plotting.certify.uncertified_note`).
    The interval is a band, or error bars when the run count is too small for a band
    (:func:`~stt_drake.plotting.certify.draw_frequency`)."""
    count = len(epsilon)
    figure = Figure(figsize=(8.0, 1.9 * count + 0.9), layout="constrained")
    axes = figure.subplots(count, 1, sharex=True, squeeze=False)[:, 0]
    for j, ax in enumerate(axes):
        allowed = 1.0 - epsilon[j]
        for c, check in enumerate(model):
            colour, label = _CHECK_STYLES[check]
            draw_frequency(ax, t, counts[c, j], runs, member, allowed, colour, label)
            ax.plot(t, model[check][:, j], color=colour, lw=0.8, ls=":", label=f"{label}: belief")
        ax.axhline(allowed, color=PALETTE["violation"], ls="--", lw=1.0, label="1 − ε_j (allowed)")
        ax.set_ylim(0.0, max(1.6 * allowed, 1.1 * float(np.max(counts[:, j])) / runs))
        ax.set_ylabel(f"obstacle {j}\nP(collision)")
        ax.set_title(
            f"obstacle {j}: ε = {epsilon[j]:.3g}, 1 − ε = {allowed:.3g}", fontsize=9, loc="left"
        )
        if verdicts is not None:
            _verdict_box(ax, verdicts[j])
    figure.legend(
        handles=axes[0].get_legend_handles_labels()[0],
        fontsize=7,
        ncols=4,
        loc="outside lower center",
        frameon=False,
    )
    axes[-1].set_xlabel("t (s)")
    _campaign_title(figure, f"true-obstacle campaign, {runs} runs", runs, verdicts)
    return figure


def _verdict_box(ax: Any, record: Mapping[str, Any]) -> None:
    """An obstacle's output and tube verdicts, top left in its panel."""
    lines = [f"output: {verdict_text(record)}"]
    if "tube" in record:
        lines.append(f"tube: {verdict_text(record['tube'])}")
    verdicts = [record["verdict"], *([record["tube"]["verdict"]] if "tube" in record else [])]
    worst = next(v for v in (VIOLATED, INCONCLUSIVE, CERTIFIED) if v in verdicts)
    ax.text(
        0.01,
        0.95,
        "\n".join(lines),
        transform=ax.transAxes,
        va="top",
        fontsize=7,
        color=VERDICT_COLORS.get(worst, "black"),
        bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.85},
    )


def _campaign_title(
    figure: Figure, title: str, runs: int, verdicts: Sequence[Mapping[str, Any]] | None
) -> None:
    """The figure's title: `title`, the interval's meaning, and the note when the run
    count cannot certify."""
    title += " (99 % simultaneous Clopper-Pearson intervals)"
    records = [r for v in verdicts or () for r in (v, *([v["tube"]] if "tube" in v else []))]
    note = uncertified_note(runs, records)
    if note is not None:
        title += f"\n{note}"
    figure.suptitle(title, color="black" if note is None else VERDICT_COLORS[INCONCLUSIVE])


def plot_end_to_end(
    times: np.ndarray,
    epsilon: np.ndarray,
    counts: np.ndarray,
    runs: int,
    member: float,
    calibration: Sequence[float | None],
    verdicts: Sequence[Mapping[str, Any]] | None = None,
) -> Figure:
    """Collision frequency with the TRUE obstacles over time per obstacle (output), with
    its simultaneous 99 % CP interval (a band, or error bars at small run counts), against
    1 − ε_j; and the belief's calibration per obstacle (the fraction of tracked times with
    the true centre in the belief's 95 % ellipsoid, None: never tracked) against 0.95.

    `times` (T,) logged times (s); `epsilon` (m,); `counts` (checks, m, T), the output
    check first; `verdicts` campaign.json's ``obstacles`` (the title notes when the run
    count cannot certify)."""
    count = len(epsilon)
    figure = Figure(figsize=(10.0, 3.8), layout="constrained")
    left, right = figure.subplots(1, 2, width_ratios=[2, 1])
    for j in range(count):
        colour = f"C{j % 10}"
        allowed = 1.0 - epsilon[j]
        draw_frequency(left, times, counts[0, j], runs, member, allowed, colour, f"obstacle {j}")
        left.axhline(allowed, color=colour, ls="--", lw=0.8)
    top = max(1.6 * float(np.max(1.0 - epsilon)), 1.1 * float(np.max(counts[0])) / runs)
    left.set_ylim(0.0, top)
    left.set(xlabel="t (s)", ylabel="P(‖y − O_true‖ < r_o)", title="collisions (dashed: 1 − ε_j)")
    left.legend(fontsize=7)
    right.bar(range(count), [value or 0.0 for value in calibration], color=PALETTE["tube"])
    right.axhline(CALIBRATION_LEVEL, color=PALETTE["reference"], ls="--", lw=1.0)
    right.set(xlabel="obstacle", ylabel="true centre in 95 % ellipsoid", ylim=(0.0, 1.0))
    right.set_xticks(range(count))
    _campaign_title(figure, f"end-to-end campaign, {runs} runs", runs, verdicts)
    return figure


def plot_randomisation(
    simulated: Sequence[dict[str, Any]],
    failed: Sequence[bool],
    names: Sequence[str],
    title: str,
) -> Figure:
    """t_c histogram and every simulated run's worst margin per guarantee (red: failed
    runs).

    `simulated` the run records of the simulated draws (``t_tube_in_target`` in s or None,
    ``invariants`` by guarantee name with its ``worst_margin``); `failed` per record,
    whether the run failed; `names` the guarantees drawn, in order."""
    figure = Figure(figsize=(10.0, 3.6), layout="constrained")
    left, right = figure.subplots(1, 2, width_ratios=[1, 2])
    reach = [r["t_tube_in_target"] for r in simulated if r["t_tube_in_target"] is not None]
    left.hist(reach, bins=max(5, int(np.sqrt(len(reach) or 1))), color=PALETTE["tube"])
    left.set_xlabel("t_c (s)")
    left.set_ylabel("runs")
    left.set_title(f"reached: {len(reach)} / {len(simulated)} simulated", fontsize=9)
    colours = [PALETTE["violation"] if f else PALETTE["margin"] for f in failed]
    for k, name in enumerate(names):
        margins = np.array([r["invariants"][name]["worst_margin"] for r in simulated])
        jitter = np.linspace(-0.25, 0.25, len(margins)) if len(margins) > 1 else [0.0]
        right.scatter(k + np.asarray(jitter), margins, c=colours, s=8)
    right.axhline(0.0, color=PALETTE["reference"], lw=0.8)
    right.set_yscale("symlog", linthresh=1e-3)
    right.set_xticks(range(len(names)), [n.replace("_", "\n") for n in names], fontsize=7)
    right.set_ylabel("worst margin per run")
    figure.suptitle(title)
    return figure
