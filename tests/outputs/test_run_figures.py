"""The run figures a researcher reads: snapshots at the worst-margin times (or chosen
times), the collision probability per obstacle on a log axis, the distance to each
obstacle and the radius panel's legend (synthetic logs of tests.outputs.test_plotting)."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.colors import to_rgba

from stt_drake.cli.main import BadInputError
from stt_drake.cli.run import parse_times
from stt_drake.core.invariants import INVARIANT_NAMES
from stt_drake.plotting import plot_margins, plot_snapshots, save_run_figures, snapshot_times
from stt_drake.plotting import save as save_module
from stt_drake.runlog import RunLog
from tests.outputs.test_plotting import SAMPLES, make_cluttered_log, make_log

#: Worst-margin times of two guarantees this close share one snapshot (2 % of 10 s).
CLOSE = 0.1


@pytest.fixture(scope="module")
def log() -> dict[str, np.ndarray]:
    return make_log(2)


def panel_times(fig) -> list[float]:
    """The time of each snapshot panel, read from its title's first line."""
    return [
        float(ax.get_title().splitlines()[0].split("=")[1].rstrip(" s"))
        for ax in fig.axes
        if ax.get_title().startswith("t = ")
    ]


def panel_titles(fig) -> list[str]:
    """Each snapshot panel's title on one line (titles wrap)."""
    return [
        " ".join(ax.get_title().split()) for ax in fig.axes if ax.get_title().startswith("t = ")
    ]


def panel(fig, title_start: str):
    (ax,) = [ax for ax in fig.axes if ax.get_title().startswith(title_start)]
    return ax


def test_default_snapshots_are_the_start_each_worst_margin_time_and_the_end(log):
    fig = plot_snapshots(log)
    times = panel_times(fig)
    t = log["t"]
    assert times[0] == pytest.approx(t[0], abs=5e-3) and times[-1] == pytest.approx(t[-1])
    assert times == sorted(times) and len(set(times)) == len(times)
    for column, name in enumerate(INVARIANT_NAMES):
        worst = t[int(np.argmin(log["margins"][:, column]))]
        nearest = min(times, key=lambda time: abs(time - worst))
        assert abs(nearest - worst) <= 0.02 * (t[-1] - t[0]) + 5e-3, name
    assert snapshot_times(log) == pytest.approx(times, abs=5e-3)


def test_snapshots_follow_the_metrics_record_merge_close_times_and_skip_vacuous_ones(log):
    invariants = {
        "output_in_tube": {"holds": True, "worst_margin": 0.05, "t_worst": 3.0},
        "center_avoid_probability": {"holds": True, "worst_margin": 0.01, "t_worst": 3.0 + CLOSE},
        "tube_avoid_probability": {"holds": True, "worst_margin": 0.02, "t_worst": 7.0},
        "output_avoid_probability": {
            "holds": True,
            "worst_margin": 1.0,
            "t_worst": 5.0,
            "note": "no obstacles: vacuous",
        },
        "radius_positive": {"holds": True, "worst_margin": 0.2, "t_worst": 10.0 - CLOSE},
    }
    fig = plot_snapshots(log, invariants=invariants)
    t = log["t"]
    expected = [t[int(np.argmin(np.abs(t - time)))] for time in (0.0, 3.0, 7.0, 10.0)]
    assert panel_times(fig) == pytest.approx(expected, abs=5e-3)
    titles = panel_titles(fig)
    assert "output in tube" in titles[1] and "centre avoidance" in titles[1]
    assert "tube avoidance" in titles[2]
    assert "radius" in titles[3]
    assert not any("output avoidance" in title for title in titles)  # vacuous: no snapshot


def test_chosen_times_are_honoured(log):
    chosen = [1.5, 7.0, 2.0]
    fig = plot_snapshots(log, times=chosen)
    t = log["t"]
    assert panel_times(fig) == pytest.approx(
        [t[int(np.argmin(np.abs(t - time)))] for time in chosen], abs=5e-3
    )


@pytest.mark.slow
def test_save_run_figures_draws_the_snapshots_at_the_chosen_times(log, tmp_path, monkeypatch):
    seen = []

    def recording(run, times=None, invariants=None):
        seen.append(list(times))
        return original(run, times, invariants)

    original = save_module.plot_snapshots
    monkeypatch.setattr(save_module, "plot_snapshots", recording)
    save_run_figures(log, tmp_path, snapshot_times=[2.5, 4.0])
    assert seen == [[2.5, 4.0]]


def test_snapshot_option_reads_comma_separated_times_within_the_run():
    assert parse_times("1.5,3.0", 10.0) == [1.5, 3.0]
    assert parse_times("0,10", 10.0) == [0.0, 10.0]
    for bad in ("", "1.5,x", "-1", "11", "nan", "1,,2"):
        with pytest.raises(BadInputError, match="--snapshots"):
            parse_times(bad, 10.0)


def test_collision_probability_is_on_a_log_axis_with_each_obstacles_bound(log):
    ax = panel(plot_margins(log), "output collision probability")
    assert ax.get_yscale() == "log"
    assert ax.get_ylim()[0] <= 1e-12
    expected = np.maximum(1.0 - log["output_avoid_probability"], 1e-12)
    lines = [line for line in ax.lines if len(line.get_ydata()) == SAMPLES]
    solid = [line for line in lines if line.get_linestyle() == "-"]
    dashed = [line for line in lines if line.get_linestyle() == "--"]
    assert len(solid) == len(dashed) == 3
    for j in range(3):
        (curve,) = [s for s in solid if np.allclose(s.get_ydata(), expected[:, j], atol=0.0)]
        (bound,) = [d for d in dashed if np.all(d.get_ydata() == 1.0 - log["epsilon"][j])]
        assert to_rgba(curve.get_color()) == to_rgba(bound.get_color())
    labels = [text.get_text() for text in ax.get_legend().get_texts()]
    assert all(any(label.startswith(f"obstacle {j}") for label in labels) for j in range(3))


def test_distance_panel_shows_the_surface_distance_and_zero(log):
    ax = panel(plot_margins(log), "distance from the output")
    run = RunLog.of(log)
    expected = np.linalg.norm(log["output"][:, None, :] - run.mean, axis=2) - log["obstacle_radius"]
    curves = [np.asarray(line.get_ydata()) for line in ax.lines if len(line.get_ydata()) == SAMPLES]
    for j in range(3):
        assert any(np.allclose(curve, expected[:, j]) for curve in curves), j
    assert any(tuple(line.get_ydata()) == (0.0, 0.0) for line in ax.lines)
    assert "r_{o,j}" in ax.get_ylabel() and "(m)" in ax.get_ylabel()


def test_many_obstacles_show_the_most_likely_collisions_in_colour():
    cluttered = make_cluttered_log(50)
    ax = panel(plot_margins(cluttered), "output collision probability")
    peak = np.max(np.maximum(1.0 - cluttered["output_avoid_probability"], 1e-12), axis=0)
    order = np.argsort(-peak)
    assert peak[order[5]] > peak[order[6]]  # the six are well defined
    labels = [text.get_text() for text in ax.get_legend().get_texts()]
    named = sorted(
        int(label.split(":")[0].split()[1]) for label in labels if label.startswith("obstacle ")
    )
    assert named == sorted(order[:6].tolist())
    assert "44 other obstacles" in labels


def test_radius_legend_explains_r_min_r_max_and_recovery(log):
    texts = [t.get_text() for t in plot_margins(log).axes[0].get_legend().get_texts()]
    (r_min,) = [text for text in texts if text.startswith("r_min")]
    assert "buffer" in r_min and "soft-min" in r_min and "recovering" in r_min
    assert any(text.startswith("r_max") for text in texts)
    assert not any(text.startswith("recovering") for text in texts)
    recovering = np.zeros((SAMPLES, 3))
    recovering[10:14, 1] = 1.0
    texts = [
        t.get_text()
        for t in plot_margins(dict(log, recovery=recovering)).axes[0].get_legend().get_texts()
    ]
    assert any(text.startswith("recovering") for text in texts)
