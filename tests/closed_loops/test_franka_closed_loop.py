"""Closed loops of the FR3 pick-and-place (paper Sec. 5.3) against the paper's guarantees.

Every guarantee is recomputed from the raw logs (the recomputation of the omni closed-loop
tests, reused), the task sequence is re-derived from the logged target and tube, the
limits from the logged joints against the published FR3 numbers, and the jerks' effect
against the undisturbed run.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario, parse_scenario
from stt_drake.cli.main import main
from stt_drake.core.invariants import HOLDS_TOLERANCE
from stt_drake.plotting import level_set_radius
from stt_drake.run import simulate, summary
from tests.closed_loops.test_closed_loop import (
    test_logged_run_meets_guarantees_by_independent_recomputation as recompute_guarantees,
)
from tests.closed_loops.test_closed_loop import (
    test_tube_stays_in_target_after_reach_time as check_final_stay,
)
from tests.outputs.test_replay import METRICS_KEYS, animation, check_self_contained, rotate
from tests.systems.test_franka_model import (
    EFFORT,
    POSITION_LOWER,
    POSITION_UPPER,
    VELOCITY,
    dh_frames,
)

SCENARIOS = ["franka_pick_place_case1", "franka_pick_place_case2", "franka_disturbance"]
DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"


@pytest.fixture(scope="module")
def no_gravity_compensation():
    """Case 1 with the robot's gravity compensation switched off."""
    text = (DIAGRAMS / "franka_pick_place_case1.yaml").read_text()
    old = "  gravity_compensation: true"
    assert old in text
    scenario = parse_scenario(text.replace(old, "  gravity_compensation: false"), "no_gravity")
    return simulate(scenario)


def _segments_from_log(log: dict, targets: np.ndarray) -> list[tuple[int, int]]:
    """(first, last + 1) sample ranges of each target, from the logged task target."""
    active = np.array(
        [np.argmin(np.linalg.norm(targets - row, axis=1)) for row in log["task_target"]]
    )
    np.testing.assert_allclose(log["task_target"], targets[active])  # only the given targets
    starts = np.concatenate([[0], np.flatnonzero(np.diff(active)) + 1])
    assert list(active[starts]) == list(range(len(starts)))  # in order, none skipped
    return list(zip(starts, [*starts[1:], len(active)], strict=True))


def _check_run(result, scenario) -> None:
    metrics, log = result.metrics, result.log
    failed = {k: v for k, v in metrics["invariants"].items() if not v["holds"]}
    assert not failed, f"guarantees violated: {failed}"
    assert metrics["reached"] and result.success and metrics["strict_stop"] is None
    # The pick-and-place sequence: four tasks, each reached and held before the next.
    targets = np.array([*scenario.plant.waypoints, scenario.target])
    ranges = _segments_from_log(log, targets)
    assert len(ranges) == len(targets) == len(metrics["segments"]) == 4
    hold = scenario.plant.hold_time
    radius_t = scenario.target_set_radius
    for k, ((first, stop), segment) in enumerate(zip(ranges, metrics["segments"], strict=True)):
        t = log["t"][first:stop]
        gap = (
            np.linalg.norm(log["center"][first:stop] - targets[k], axis=1)
            + log["radius"][first:stop]
            - radius_t
        )
        assert segment["completed"] and segment["t_tube_in_target"] is not None
        after = t >= segment["t_tube_in_target"]
        assert np.all(gap[after] <= HOLDS_TOLERANCE)  # Γ(t) ⊂ T_k from t_tube_in_target on
        assert gap[~after][-1:].size == 0 or gap[~after][-1] > HOLDS_TOLERANCE
        assert np.all(
            np.linalg.norm(log["output"][first:stop][after] - targets[k], axis=1) <= radius_t
        )
        if k + 1 < len(targets):  # switched only after Γ ⊂ T_k held for hold_time
            assert t[-1] - segment["t_tube_in_target"] >= hold - 2 * scenario.log_period
    assert metrics["t_tube_in_target"] == pytest.approx(metrics["segments"][-1]["t_tube_in_target"])
    # Joint position, velocity and torque limits (published FR3 numbers), every sample.
    q, v = log["joint_state"][:, :7], log["joint_state"][:, 7:]
    assert np.all((q > POSITION_LOWER) & (q < POSITION_UPPER))
    assert np.all(np.abs(v) < VELOCITY)
    assert np.all(np.abs(log["requested_torque"]) < EFFORT)
    np.testing.assert_allclose(log["applied_torque"], log["requested_torque"])  # unsaturated
    worst = min(np.min(q - POSITION_LOWER), np.min(POSITION_UPPER - q))
    assert metrics["limits"]["joint_position"]["worst_margin"] == pytest.approx(worst)
    assert all(record["holds"] for record in metrics["limits"].values())
    # The output is the TCP of the logged joints (DH kinematics).
    for k in range(0, len(log["t"]), 50):
        np.testing.assert_allclose(log["output"][k], dh_frames(q[k])[-1][:3, 3], atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS)
def test_every_guarantee_task_and_limit_holds(run_scenario, name):
    _check_run(run_scenario(name), load_scenario(DIAGRAMS / f"{name}.yaml"))
    recompute_guarantees(run_scenario, name)
    check_final_stay(run_scenario, name)


@pytest.mark.slow
def test_guarantees_hold_without_the_robots_gravity_compensation(
    run_scenario, no_gravity_compensation
):
    scenario = load_scenario(DIAGRAMS / "franka_pick_place_case1.yaml")
    _check_run(no_gravity_compensation, scenario)
    # The STT controller now carries the arm's weight: at the pick point (end of task 1,
    # arm still) its torque is the holding torque, which was ~0 with compensation.
    log, compensated = no_gravity_compensation.log, run_scenario("franka_pick_place_case1").log
    at_rest = lambda run: np.argmin(np.abs(run["t"] - 4.5))  # noqa: E731
    heavy = np.abs(log["control"][at_rest(log), 1]) + np.abs(log["control"][at_rest(log), 3])
    assert heavy > 20.0  # N·m on joints 2 and 4
    assert np.max(np.abs(compensated["control"][at_rest(compensated)])) < 2.0


@pytest.mark.slow
def test_the_more_uncertain_obstacle_gets_the_wider_detour(run_scenario):
    """Cases 1 and 2 swap the variances and ε of two mirror-image obstacles."""
    report = {
        case: run_scenario(f"franka_pick_place_case{case}").metrics["obstacles"] for case in (1, 2)
    }
    distance = {case: [o["min_distance_to_mean"] for o in report[case]] for case in (1, 2)}
    sigma = {case: [o["sigma"] for o in report[case]] for case in (1, 2)}
    assert sigma[1][0] > 4 * sigma[1][1] and sigma[2][1] > 4 * sigma[2][0]
    assert distance[1][0] > distance[1][1] + 0.03  # case 1: wider berth to obstacle 0
    assert distance[2][1] > distance[2][0] + 0.03  # case 2: wider berth to obstacle 1
    assert distance[1][0] > distance[2][0] + 0.03 and distance[2][1] > distance[1][1] + 0.03
    # Each passes outside the ε level set of its point avoidance probability (Definition 2.3).
    for case in (1, 2):
        for o in report[case]:
            reach = level_set_radius(o["epsilon"], o["sigma"], o["radius"], 3)
            assert o["min_distance_to_mean"] > reach


@pytest.mark.slow
def test_jerks_push_the_end_effector_visibly_and_it_recovers(run_scenario):
    disturbed = run_scenario("franka_disturbance")
    nominal = run_scenario("franka_pick_place_case1").log
    log, scenario = disturbed.log, load_scenario(DIAGRAMS / "franka_disturbance.yaml")
    jerks = scenario.plant.jerks
    assert len(jerks) >= 3 and len(disturbed.metrics["jerks"]) == len(jerks)
    e1 = np.linalg.norm(log["output"] - log["center"], axis=1) / log["radius"]
    first = jerks[0].time
    n = min(len(nominal["t"]), len(log["t"]))
    before = log["t"][:n] < first
    # Identical runs until the first push (same scenario otherwise) ...
    np.testing.assert_allclose(log["output"][:n][before], nominal["output"][:n][before], atol=1e-9)
    window = (log["t"][:n] >= first) & (log["t"][:n] <= first + 1.0)
    deviation = np.linalg.norm(log["output"][:n] - nominal["output"][:n], axis=1)
    assert np.max(deviation[window]) > 0.015  # ... then the push moves the hand > 1.5 cm
    for jerk, report in zip(jerks, disturbed.metrics["jerks"], strict=True):
        force = log["external_force"][
            (log["t"] >= jerk.time) & (log["t"] <= jerk.time + jerk.duration)
        ]
        assert np.max(np.linalg.norm(force, axis=1)) == pytest.approx(
            np.linalg.norm(jerk.force), rel=0.05
        )  # the logged push is the scenario's pulse
        prior = np.flatnonzero(log["t"] < jerk.time)[-1]
        after = (log["t"] >= jerk.time) & (log["t"] <= jerk.time + 1.0)
        assert np.max(e1[after]) > e1[prior] + 0.05  # visible in the funnel error
        assert np.max(e1[after]) < 1.0  # and still inside the tube
        assert report["peak_stage1_error"] == pytest.approx(np.max(e1[after]), abs=1e-6)
        assert report["peak_stage2_error"] < 1.0


@pytest.mark.slow
def test_cli_writes_the_contract_figures_and_an_arm_replay(tmp_path):
    out = tmp_path / "case2"
    code = main(
        ["run", str(DIAGRAMS / "franka_pick_place_case2.yaml"), "--out", str(out), "--meshcat"]
    )
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) >= METRICS_KEYS | {"segments", "limits", "jerks"}
    for figure in ("snapshots.png", "margins.png", "joint_torques.png"):
        assert (out / figure).stat().st_size > 20_000
    html = (out / "replay.html").read_text()
    check_self_contained(html)
    fps, tracks = animation(html)
    hand = tracks["/stt/arm/fr3/fr3_hand"]  # Drake's MeshcatVisualizer of the FR3 plant
    log = np.load(out / "log.npz")
    frames = hand[".position@frames"]
    assert frames.size > 100
    # The hand's recorded pose puts its TCP (0.1034 m along its z axis) on the logged output
    # at the frames that fall on a logged sample (publish times k/30 s, samples every
    # log_period) — up to the rounding of the publish time, within one sample's motion.
    t, output = np.asarray(log["t"]), np.asarray(log["output"])
    pairs = [(i, k) for i, f in enumerate(frames) for k in np.flatnonzero(np.isclose(t, f / fps))]
    assert len(pairs) >= 20
    step = np.linalg.norm(np.diff(output, axis=0), axis=1).max()
    exact = []
    for i, k in pairs:
        tcp = hand[".position"][i] + rotate(hand[".quaternion"][i], np.array([0.0, 0.0, 0.1034]))
        error = np.linalg.norm(output[k] - tcp)
        assert error <= step + 1e-6
        exact.append(error < 1e-6)
    assert np.mean(exact) >= 0.8


def test_the_run_summary_lists_the_arms_tasks_from_its_plant_hook(run_scenario):
    """The arm's summary lines come from its plant builder's `summary` hook (run.py knows no
    plant): one line per task segment with its t_c, one per limit, one per jerk."""
    result = run_scenario("franka_disturbance")
    text = summary(result)
    assert "tasks, joint limits and jerks:" in text
    for segment in result.metrics["segments"]:
        assert f"segment {segment['index']} → " in text
    assert len(result.metrics["jerks"]) >= 1
    assert text.count("    jerk ") == len(result.metrics["jerks"])
    for name in result.metrics["limits"]:
        assert f"    {name:<16} " in text
