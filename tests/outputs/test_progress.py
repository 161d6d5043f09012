"""Stall detection (stt_drake.core.progress): the rule on synthetic trajectories, the state
vector, the run log's attraction point, the rule a scenario gets, and one closed loop that
stalls for good (a known equilibrium of Eq. (4) in front of a wall)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario
from stt_drake.assembly.guide import stall_rule
from stt_drake.cli.main import main
from stt_drake.config import GuideConfig
from stt_drake.core.progress import (
    DEFAULT_STALL_RULE,
    StallDetector,
    StallRule,
    find_stalls,
)
from stt_drake.runlog import RunLog

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"
DEADLOCK = ROOT / "tests" / "scenarios" / "omni_wall_deadlock_k3_continuous.yaml"

RULE = StallRule(stall_time=5.0, progress=0.1)
ARRIVED = 0.3
PERIOD = 0.02
ETA = np.array([4.0, 0.0])


def _times(duration: float) -> np.ndarray:
    """Logged times 0, 0.02, ..., duration, as a logger gives them (k · period)."""
    return PERIOD * np.arange(round(duration / PERIOD) + 1)


def _still(t: np.ndarray, distance: float) -> np.ndarray:
    """A centre that sits `distance` metres from ETA (along −x)."""
    return np.tile(ETA - [distance, 0.0], (t.size, 1))


def _eta(t: np.ndarray) -> np.ndarray:
    return np.tile(ETA, (t.size, 1))


def test_a_centre_that_sits_still_stalls_stall_time_after_the_start_to_the_end():
    t = _times(20.0)
    detector = StallDetector(RULE, ARRIVED)
    flags = [detector.update(t[k], _still(t, 1.0)[k], ETA) for k in range(t.size)]
    (k,) = np.flatnonzero(flags)  # True exactly once, at the detection
    assert t[k] == pytest.approx(5.0, abs=1e-12) and t[k - 1] < 5.0
    assert detector.stalled and detector.since == 0.0
    (stall,) = find_stalls(t, _still(t, 1.0), _eta(t), RULE, ARRIVED)
    assert stall["start_s"] == 0.0 and stall["end_s"] is None
    assert stall["detected_s"] == pytest.approx(5.0, abs=1e-12)
    assert stall["position"] == [3.0, 0.0] and stall["distance_m"] == pytest.approx(1.0)
    assert stall["ended"] == "end of run"


def test_the_stall_is_detected_stall_time_after_the_last_progress():
    """2 m from η until t = 3 s, then 1 m (a step of progress), then still: detected at 8 s."""
    t = _times(20.0)
    center = np.where((t < 3.0 - 1e-9)[:, None], _still(t, 2.0), _still(t, 1.0))
    (stall,) = find_stalls(t, center, _eta(t), RULE, ARRIVED)
    assert stall["start_s"] == pytest.approx(3.0, abs=1e-12)
    assert stall["detected_s"] == pytest.approx(8.0, abs=1e-12)
    assert stall["end_s"] is None and stall["ended"] == "end of run"
    assert stall["distance_m"] == pytest.approx(1.0)


def test_a_centre_oscillating_in_a_pocket_stalls():
    """±0.3 m around a point 1.5 m from η (toward and away from it, and sideways): the
    first swing counts as progress, the rest do not."""
    t = _times(30.0)
    phase = 2.0 * np.pi * 0.5 * t
    center = ETA - [1.5, 0.0] + 0.3 * np.column_stack([np.sin(phase), np.sin(2.0 * phase)])
    stalls = find_stalls(t, center, _eta(t), RULE, ARRIVED)
    assert len(stalls) == 1
    (stall,) = stalls
    assert stall["end_s"] is None and stall["ended"] == "end of run"
    assert stall["start_s"] < 2.0  # the last progress is in the first swing
    assert stall["detected_s"] == pytest.approx(stall["start_s"] + RULE.stall_time, abs=PERIOD)
    assert 1.2 - 1e-9 <= stall["distance_m"] <= np.hypot(1.8, 0.3) + 1e-9


def test_a_centre_moving_steadily_to_eta_never_stalls():
    """0.1 m/s (0.002 m per sample, far less than the 0.1 m of progress per sample), from
    3 m away, then it stays at η."""
    t = _times(40.0)
    distance = np.maximum(3.0 - 0.1 * t, 0.0)
    center = ETA - np.column_stack([distance, np.zeros_like(t)])
    assert find_stalls(t, center, _eta(t), RULE, ARRIVED) == []


def test_an_attraction_point_moving_on_ahead_of_the_centre_is_not_a_stall():
    """A guide's η running 1 m ahead of the centre: the distance never shrinks, but η moves."""
    t = _times(30.0)
    center = np.column_stack([0.3 * t, np.zeros_like(t)])
    attraction = center + np.array([1.0, 0.0])
    assert find_stalls(t, center, attraction, RULE, ARRIVED) == []


def test_a_centre_at_eta_has_arrived_and_never_stalls():
    t = _times(30.0)
    assert find_stalls(t, _still(t, 0.2), _eta(t), RULE, ARRIVED) == []
    assert find_stalls(t, _still(t, ARRIVED), _eta(t), RULE, ARRIVED) == []  # ≤ arrived


@pytest.mark.parametrize(
    ("after", "attraction_after", "ended"),
    [
        (1.0, ETA, "progress"),  # 0.5 m closer
        (1.5, ETA + np.array([0.0, 0.5]), "attraction point moved"),  # η moved 0.5 m on
        (0.1, ETA, "arrived"),
    ],
)
def test_an_episode_ends_at_the_next_progress_event_and_says_why(after, attraction_after, ended):
    """Still 1.5 m from η until t = 8 s, then the event; still again afterwards, but for
    less than stall_time."""
    t = _times(12.0)
    late = (t >= 8.0 - 1e-9)[:, None]
    attraction = np.where(late, attraction_after, ETA)
    center = np.where(late, attraction - [after, 0.0], ETA - [1.5, 0.0])
    (stall,) = find_stalls(t, center, attraction, RULE, ARRIVED)
    assert stall["start_s"] == 0.0 and stall["detected_s"] == pytest.approx(5.0, abs=1e-12)
    assert stall["end_s"] == pytest.approx(8.0, abs=1e-12) and stall["ended"] == ended


def test_two_episodes_and_reset():
    t = _times(30.0)
    center = np.where((t < 12.0 - 1e-9)[:, None], _still(t, 2.0), _still(t, 1.0))
    stalls = find_stalls(t, center, _eta(t), RULE, ARRIVED)
    assert [(s["start_s"], s["end_s"], s["ended"]) for s in stalls] == [
        (0.0, pytest.approx(12.0), "progress"),
        (pytest.approx(12.0), None, "end of run"),
    ]
    detector = StallDetector(RULE, ARRIVED)
    for k in range(300):  # 6 s still: stalled
        detector.update(t[k], center[k], ETA)
    assert detector.stalled
    detector.reset(t[300], center[300], ETA)  # e.g. a replan
    assert not detector.stalled and detector.since == t[300]
    assert detector.last_event == "start"


def test_the_state_vector_round_trips():
    t = _times(20.0)
    phase = 2.0 * np.pi * 0.5 * t
    center = ETA - [1.5, 0.0] + 0.3 * np.column_stack([np.sin(phase), np.zeros_like(t)])
    fresh = StallDetector(RULE, ARRIVED)
    vector = fresh.as_vector(2)
    assert vector.shape == (StallDetector.vector_size(2),)
    with pytest.raises(ValueError, match="give n"):
        fresh.as_vector()
    original = StallDetector.from_vector(vector, RULE, ARRIVED)
    for k in range(200):
        original.update(t[k], center[k], ETA)
    state = original.as_vector()
    assert state.shape == vector.shape and np.all(np.isfinite(state))
    copy = StallDetector.from_vector(state, RULE, ARRIVED)
    np.testing.assert_array_equal(copy.as_vector(), state)
    for k in range(200, t.size):  # both go on identically
        assert copy.update(t[k], center[k], ETA) == original.update(t[k], center[k], ETA)
        np.testing.assert_array_equal(copy.as_vector(), original.as_vector())
    assert copy.stalled and copy.last_event == original.last_event


def test_a_rule_must_be_positive_and_finite():
    for bad in ({"stall_time": 0.0, "progress": 0.1}, {"stall_time": 5.0, "progress": -1.0}):
        with pytest.raises(ValueError):
            StallRule(**bad)
    with pytest.raises(ValueError):
        StallRule(stall_time=float("nan"), progress=0.1)


def test_the_run_log_attraction_point_is_the_guide_target_else_the_active_target():
    t = _times(1.0)
    base = {"t": t, "dimension": np.array(2), "target": ETA}
    np.testing.assert_array_equal(RunLog(base).attraction_point, _eta(t))
    tasks = np.column_stack([t, -t])
    np.testing.assert_array_equal(RunLog({**base, "task_target": tasks}).attraction_point, tasks)
    guide = np.column_stack([2.0 * t, t])
    log = RunLog({**base, "task_target": tasks, "guide_target": guide})
    np.testing.assert_array_equal(log.attraction_point, guide)


def test_the_rule_of_a_scenario():
    scenario = load_scenario(CASE1)
    assert scenario.guide is None and stall_rule(scenario) == DEFAULT_STALL_RULE
    scenario.guide = GuideConfig(stall_time=3.0)  # stall_progress 0: the tube's r_min
    assert stall_rule(scenario) == StallRule(3.0, scenario.tube.r_min)
    scenario.guide = GuideConfig(stall_time=3.0, stall_progress=0.4)
    assert stall_rule(scenario) == StallRule(3.0, 0.4)


@pytest.mark.slow
def test_the_wall_deadlock_ends_in_a_stall_through_the_cli(tmp_path, capsys):
    """omni_wall_deadlock_k3_continuous: the centre rests at ≈ [1.77, −0.18] in front of the
    wall from t ≈ 2 s (an equilibrium of Eq. (4)); the run names the stall and exits 1."""
    out = tmp_path / "run"
    code = main(["run", str(DEADLOCK), "--out", str(out), "--no-figures"])
    captured = capsys.readouterr()
    assert code == 1
    assert "Traceback" not in captured.out + captured.err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["reached"] is False and metrics["holds"] is True
    assert metrics["sim_time_s"] == pytest.approx(15.0)  # it ran to the end
    *_, last = metrics["stalls"]
    assert last["end_s"] is None and last["ended"] == "end of run"
    assert 1.0 < last["start_s"] < 4.0
    assert last["detected_s"] == pytest.approx(last["start_s"] + DEFAULT_STALL_RULE.stall_time)
    position = np.array(last["position"])
    np.testing.assert_allclose(position, [1.77, -0.18], atol=0.05)
    assert last["distance_m"] == pytest.approx(np.linalg.norm(position - [4.0, 0.0]))
    reason = metrics["stop_reason"]
    assert reason.startswith(
        "stall: the tube centre made no progress toward its attraction point from "
        f"t = {last['start_s']:.2f} s to the end (c = [{position[0]:.2f}, {position[1]:.2f}], "
        f"{last['distance_m']:.2f} m from it); worst margin so far: "
    )
    assert "STALLED: stall:" in captured.out and "stalls: 1" in captured.out
    assert "result: FAILURE" in captured.out
    # The same stall recomputed from log.npz alone.
    log = RunLog.load(out / "log.npz")
    rule, arrived = DEFAULT_STALL_RULE, log.target_set_radius
    recomputed = find_stalls(log.t, log.center, log.attraction_point, rule, arrived)
    assert recomputed == metrics["stalls"]
