"""The campaign and comparison figures: the 1 − ε lines, the obstacle labels, the note when
the run count cannot certify, and error bars instead of a band at small run counts."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.container import ErrorbarContainer

from stt_drake.core.statistics import family_confidence, simultaneous_verdict
from stt_drake.plotting.campaign import plot_collision_frequency, plot_end_to_end
from stt_drake.plotting.compare import plot_comparison
from stt_drake.runlog import RunLog
from tests.outputs.test_plotting import EPSILON, make_log

TIMES = np.linspace(0.0, 5.0, 11)
#: ε_j of the campaign figures' two obstacles.
CAMPAIGN_EPSILON = np.array([0.99, 0.9])
#: Enough runs to certify both bounds with no collision; too few for either.
ENOUGH, FEW = 5000, 20


def record(counts: np.ndarray, runs: int, allowed: float, member: float) -> dict:
    """A campaign.json verdict record (the fields the figures read)."""
    verdict = simultaneous_verdict(counts, runs, allowed, member)
    return {"verdict": verdict.verdict, "runs_to_certify": verdict.runs_to_certify}


def campaign(runs: int) -> tuple[np.ndarray, float, list[dict]]:
    """No collision at all in `runs` runs: counts (checks, m, T), the member confidence and
    each obstacle's output and tube verdicts."""
    counts = np.zeros((2, CAMPAIGN_EPSILON.size, TIMES.size))
    member = family_confidence(0.99, counts.size)
    verdicts = []
    for j, epsilon in enumerate(CAMPAIGN_EPSILON):
        entry = record(counts[0, j], runs, 1.0 - epsilon, member)
        entry["tube"] = record(counts[1, j], runs, 1.0 - epsilon, member)
        verdicts.append(entry)
    return counts, member, verdicts


def collision_figure(runs: int):
    counts, member, verdicts = campaign(runs)
    model = {check: np.zeros((TIMES.size, CAMPAIGN_EPSILON.size)) for check in ("output", "tube")}
    return plot_collision_frequency(
        TIMES, CAMPAIGN_EPSILON, counts, runs, member, model, verdicts
    ), verdicts


def has_band(ax) -> bool:
    """Whether `ax` holds a filled band (fill_between)."""
    return any(isinstance(c, PolyCollection) for c in ax.collections)


def title(figure) -> str:
    return "" if figure._suptitle is None else figure._suptitle.get_text()


def test_few_runs_note_that_they_cannot_certify_and_draw_error_bars():
    figure, verdicts = collision_figure(FEW)
    assert {v["verdict"] for v in verdicts} == {"inconclusive"}
    note = title(figure)
    assert "inconclusive" in note and f"{FEW} runs cannot certify" in note
    assert str(max(v["runs_to_certify"] for v in verdicts)) in note
    for j, ax in enumerate(figure.axes):
        assert not has_band(ax)
        assert any(isinstance(c, ErrorbarContainer) for c in ax.containers)
        # the bound 1 − ε_j, and the verdict with the runs that would certify it
        assert any(
            np.all(np.asarray(line.get_ydata()) == 1.0 - CAMPAIGN_EPSILON[j]) for line in ax.lines
        )
        words = " ".join(text.get_text() for text in ax.texts)
        assert f"needs ≈{verdicts[j]['runs_to_certify']:,} runs" in words
        assert f"obstacle {j}" in ax.get_title(loc="left")


def test_enough_runs_certify_without_a_note_and_draw_bands():
    figure, verdicts = collision_figure(ENOUGH)
    assert {v["verdict"] for v in verdicts} == {"certified"}
    assert "inconclusive" not in title(figure)
    for ax in figure.axes:
        assert has_band(ax)
        assert not any(isinstance(c, ErrorbarContainer) for c in ax.containers)


@pytest.mark.parametrize("runs", [FEW, ENOUGH])
def test_end_to_end_figure_notes_only_an_uncertified_run_count(runs):
    counts, member, verdicts = campaign(runs)
    figure = plot_end_to_end(TIMES, CAMPAIGN_EPSILON, counts, runs, member, [0.9, None], verdicts)
    assert ("cannot certify" in title(figure)) == (runs == FEW)


def comparison_rows(runs: int) -> list[dict]:
    member = family_confidence(0.99, 2 * EPSILON.size * TIMES.size)
    allowed = float(np.min(1.0 - EPSILON))
    verdict = simultaneous_verdict(np.zeros(TIMES.size), runs, allowed, member)
    row = {
        "model_error": None,
        "success_rate": 1.0,
        "worst_collision_frequency": verdict.frequency,
        "clopper_pearson_lower_99": verdict.lower,
        "clopper_pearson_upper_99": verdict.upper,
        "verdict": verdict.verdict,
        "runs_to_certify": verdict.runs_to_certify,
        "t_output_in_target_s": 8.0,
        "path_length_m": 10.0,
        "min_clearance_m": 0.3,
        "step_us_median": 20.0,
    }
    return [dict(row, controller="stt"), dict(row, controller="apf")]


@pytest.mark.parametrize("runs", [FEW, ENOUGH])
def test_comparison_figure_has_the_strictest_bound_labels_and_the_note(runs):
    rows = comparison_rows(runs)
    log = RunLog.of(make_log(2))
    figure = plot_comparison({"stt": log, "apf": log}, rows, runs)
    paths = next(ax for ax in figure.axes if ax.get_title().endswith("output paths"))
    assert {f"obstacle {j}" for j in range(EPSILON.size)} <= {t.get_text() for t in paths.texts}
    (bars,) = [ax for ax in figure.axes if ax.get_title().startswith("worst collision")]
    strictest = float(np.min(1.0 - EPSILON))
    (bound,) = [line for line in bars.lines if np.all(np.asarray(line.get_ydata()) == strictest)]
    assert "strictest" in bound.get_label() and f"obstacle {int(np.argmin(1.0 - EPSILON))}" in (
        bound.get_label()
    )
    assert [t.get_text().split()[0] for t in bars.texts] == [rows[0]["verdict"]] * 2
    note = title(figure)
    if runs == FEW:
        assert rows[0]["verdict"] == "inconclusive"
        assert f"{FEW} runs cannot certify" in note and str(rows[0]["runs_to_certify"]) in note
        # the interval runs off the axis, and its upper bound is written
        assert rows[0]["clopper_pearson_upper_99"] > bars.get_ylim()[1]
        assert "99 % upper" in bars.texts[0].get_text()
    else:
        assert rows[0]["verdict"] == "certified" and note == ""
