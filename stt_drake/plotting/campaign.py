"""The figures of `stt-drake campaign`, one per campaign kind, drawn from plain data (the
campaign package sits above plotting in the import layers and passes arrays and records,
never its own types):

* :func:`plot_collision_frequency` (true-obstacles, ``collision_frequency.png``);
* :func:`plot_randomisation` (randomisation, ``randomisation.png``);
* :func:`plot_end_to_end` (end-to-end, ``end_to_end.png``).

Collision counts are (check, obstacle, logged time) arrays with the checks in the order
``output``, ``tube`` (:data:`stt_drake.campaign.sampling.CHECKS`); every band is the
simultaneous Clopper-Pearson interval at the per-member confidence `member`
(:func:`stt_drake.core.statistics.family_confidence`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from stt_drake.core.consistency import CALIBRATION_LEVEL
from stt_drake.core.statistics import clopper_pearson
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
) -> Figure:
    """Empirical collision frequency over time per obstacle (output and tube) with its
    simultaneous 99 % Clopper-Pearson band, against 1 − ε_j and the belief's prediction.

    `t` (T,) logged times (s); `epsilon` (m,) ε_j; `counts` (checks, m, T) runs that
    collided; `model` the belief's collision probability (T, m) per check, in the order of
    `counts`."""
    count = len(epsilon)
    figure = Figure(figsize=(8.0, 1.9 * count + 0.8), layout="constrained")
    axes = figure.subplots(count, 1, sharex=True, squeeze=False)[:, 0]
    for j, ax in enumerate(axes):
        allowed = 1.0 - epsilon[j]
        for c, check in enumerate(model):
            colour, label = _CHECK_STYLES[check]
            lower, upper = clopper_pearson(counts[c, j], runs, member)
            ax.fill_between(t, lower, upper, color=colour, alpha=0.15, linewidth=0)
            ax.plot(t, counts[c, j] / runs, color=colour, lw=1.2, label=f"{label}: frequency")
            ax.plot(t, model[check][:, j], color=colour, lw=0.8, ls=":", label=f"{label}: belief")
        ax.axhline(allowed, color=PALETTE["violation"], ls="--", lw=1.0, label="1 − ε_j")
        ax.set_ylim(0.0, max(1.6 * allowed, 1.1 * float(np.max(counts[:, j])) / runs))
        ax.set_ylabel(f"obstacle {j}\nP(collision)")
        ax.set_title(f"obstacle {j}: ε = {epsilon[j]:.3g}", fontsize=9, loc="left")
    axes[0].legend(fontsize=7, ncols=3, loc="upper right")
    axes[-1].set_xlabel("t (s)")
    figure.suptitle(f"true-obstacle campaign, {runs} runs (bands: simultaneous 99 % CP)")
    return figure


def plot_end_to_end(
    times: np.ndarray,
    epsilon: np.ndarray,
    counts: np.ndarray,
    runs: int,
    member: float,
    calibration: Sequence[float | None],
) -> Figure:
    """Collision frequency with the TRUE obstacles over time per obstacle (output), with
    its simultaneous 99 % CP band, against 1 − ε_j; and the belief's calibration per
    obstacle (the fraction of tracked times with the true centre in the belief's 95 %
    ellipsoid, None: never tracked) against 0.95.

    `times` (T,) logged times (s); `epsilon` (m,); `counts` (checks, m, T), the output
    check first."""
    count = len(epsilon)
    figure = Figure(figsize=(10.0, 3.6), layout="constrained")
    left, right = figure.subplots(1, 2, width_ratios=[2, 1])
    for j in range(count):
        colour = f"C{j % 10}"
        lower, upper = clopper_pearson(counts[0, j], runs, member)
        left.fill_between(times, lower, upper, color=colour, alpha=0.12, linewidth=0)
        left.plot(times, counts[0, j] / runs, color=colour, lw=1.2, label=f"obstacle {j}")
        left.axhline(1.0 - epsilon[j], color=colour, ls="--", lw=0.8)
    left.set(xlabel="t (s)", ylabel="P(‖y − O_true‖ < r_o)", title="collisions (dashed: 1 − ε_j)")
    left.legend(fontsize=7)
    right.bar(range(count), [value or 0.0 for value in calibration], color=PALETTE["tube"])
    right.axhline(CALIBRATION_LEVEL, color=PALETTE["reference"], ls="--", lw=1.0)
    right.set(xlabel="obstacle", ylabel="true centre in 95 % ellipsoid", ylim=(0.0, 1.0))
    right.set_xticks(range(count))
    figure.suptitle(f"end-to-end campaign, {runs} runs (bands: simultaneous 99 % CP)")
    return figure


def plot_randomisation(
    simulated: Sequence[dict[str, Any]],
    failed: Sequence[bool],
    names: Sequence[str],
    title: str,
) -> Figure:
    """t_c histogram and every simulated run's worst margin per guarantee (red: failed
    runs).

    `simulated` the run records of the simulated draws (``t_reach`` in s or None,
    ``invariants`` by guarantee name with its ``worst_margin``); `failed` per record,
    whether the run failed; `names` the guarantees drawn, in order."""
    figure = Figure(figsize=(10.0, 3.6), layout="constrained")
    left, right = figure.subplots(1, 2, width_ratios=[1, 2])
    reach = [r["t_reach"] for r in simulated if r["t_reach"] is not None]
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
