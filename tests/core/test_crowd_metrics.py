"""Crowd-navigation metrics against the TRUE obstacles (issue 26, item 5): the closed forms
of a straight line past a static obstacle, the quadrature of the comfort time, and the new
keys of `stt-drake compare` (one layout and --draws) and of the randomisation and
end-to-end campaigns, recomputed from direct simulations of the same seeds."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario
from stt_drake.campaign.crowd_metrics import is_crowd_record, obstacle_frequencies
from stt_drake.cli.main import main
from stt_drake.core.crowd_metrics import crowd_metrics, output_reach_time, time_below
from stt_drake.core.rules import RuleError
from stt_drake.run import simulate

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"

#: A 2D omni robot from (0, 0) to (4, 0) past a fixed obstacle 0.7 m off the line (its
#: surface 0.4 m off: inside the 0.5 m comfort distance) and one random obstacle below.
FIELD = """\
name: crowd_field
start: [0.0, 0.0]
initial_set_radius: 0.3
target: [4.0, 0.0]
target_set_radius: 0.3
duration: 8.0
tube: {r_min: 0.1, r_max: 0.3, k1: 0.7, k2: 0.4, k3: 0.4, max_center_speed: 1.0}
controller: {kappa: [8.0]}
plant: {disturbance_amplitude: [0.05, 0.05], disturbance_frequency_hz: 0.3}
obstacles:
  - motion: !ConstantVelocity {start: [2.0, 0.7], velocity: [0.0, 0.0]}
    radius: 0.3
    sigma: 0.05
    epsilon: 0.9
    p_d: 0.99
random_obstacles:
  count: 1
  seed: 3
  region_min: [1.5, -1.6]
  region_max: [2.5, -1.0]
  radius: 0.2
  sigma_range: [0.05, 0.1]
  epsilon_range: [0.8, 0.9]
  p_d: 0.99
  amplitude_range: [0.0, 0.1]
  frequency_range_hz: [0.02, 0.05]
"""
#: The crowd keys of a campaign's run record (written out, not imported from the code).
RUN_KEYS = {
    "collided",
    "first_collision_s",
    "obstacle_collisions",
    "obstacle_epsilon",
    "min_distance_m",
    "comfort_violation_s",
    "path_length_m",
    "time_to_goal_s",
}


@pytest.fixture(scope="module")
def field(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("crowd") / "field.yaml"
    path.write_text(FIELD)
    return path


# --------------------------------------------------------------- closed forms, by hand


def _straight_line(h: float, x0: float = -3.0, speed: float = 1.0, duration: float = 6.0):
    """y(t) = (x0 + v t, 0) sampled every h seconds (t = 0 .. duration)."""
    t = np.arange(round(duration / h) + 1) * h
    return t, np.column_stack([x0 + speed * t, np.zeros_like(t)])


@pytest.mark.parametrize("h", [0.04, 0.01])
@pytest.mark.parametrize("x0", [-3.0, -3.013])
def test_straight_line_past_a_static_obstacle_matches_the_closed_forms(h, x0):
    """Obstacle at (0, b), radius r: d(t) = √((x0 + vt)² + b²) − r, so min d = b − r (at
    t* = −x0/v) and d < d_c for 2√((r + d_c)² − b²)/v seconds."""
    b, r, comfort, speed = 0.6, 0.3, 0.5, 1.0
    t, y = _straight_line(h, x0=x0, speed=speed)
    centres = np.broadcast_to([[0.0, b]], (t.size, 1, 2))
    metrics = crowd_metrics(t, y, centres, [r], [3.0, 0.0], 0.25, comfort)
    # The nearest sample is ≤ h/2 from t*, where d − (b − r) ≤ (v·h/2)²/(2b).
    assert b - r - 1e-12 <= metrics.min_distance_m <= b - r + (speed * h / 2) ** 2 / (2 * b)
    exact = 2.0 * math.sqrt((r + comfort) ** 2 - b**2) / speed
    # The linear interpolant of d errs by ≤ h²/8·max|d''| (d'' = v²b²/ρ³ ≤ v²/b), which
    # moves each of the two crossings by that over |d'| = v·√((r+d_c)² − b²)/(r + d_c).
    slope = speed * math.sqrt((r + comfort) ** 2 - b**2) / (r + comfort)
    bound = 2.0 * (h**2 / 8.0) * (speed**2 / b) / slope
    assert abs(metrics.comfort_violation_s - exact) <= bound
    assert bound < h / 10  # second order: a rectangle rule on the samples errs by up to 2h
    assert not metrics.collided and metrics.first_collision_s is None
    assert metrics.obstacle_collisions == [False]
    assert metrics.path_length_m == pytest.approx(speed * t[-1], rel=1e-12)
    # Reach and stay: x(t) ≥ 3 − 0.25 from t = (2.75 − x0)/v on; the first sample after.
    entry = (2.75 - x0) / speed
    assert entry - 1e-9 <= metrics.time_to_goal_s <= entry + h + 1e-9


def test_a_collision_its_first_time_and_which_obstacle():
    """Obstacle 0 at (0, 0.2), r = 0.3, is hit while |x| < √(r² − b²); obstacle 1 at
    (0, 2) is not. The first sample with a hit is the first with x > −√(0.09 − 0.04)."""
    h = 0.01
    t, y = _straight_line(h)
    centres = np.broadcast_to([[0.0, 0.2], [0.0, 2.0]], (t.size, 2, 2))
    metrics = crowd_metrics(t, y, centres, [0.3, 0.3], [3.0, 0.0], 0.25)
    entry = (-math.sqrt(0.3**2 - 0.2**2) + 3.0) / 1.0
    assert metrics.collided and metrics.obstacle_collisions == [True, False]
    assert entry < metrics.first_collision_s <= entry + h
    assert metrics.min_distance_m == pytest.approx(0.2 - 0.3, abs=1e-12)
    # A robot radius is a larger obstacle: b = 0.6, r = 0.3 with r_robot = 0.2 is d = b − 0.5.
    centres = np.broadcast_to([[0.0, 0.6]], (t.size, 1, 2))
    wide = crowd_metrics(t, y, centres, [0.3], [3.0, 0.0], 0.25, robot_radius=0.2)
    assert wide.min_distance_m == pytest.approx(0.1, abs=1e-12)


def test_time_below_against_a_fine_midpoint_rule():
    """On random samples, the exact integral of the interpolant's indicator against a
    midpoint rule on 2 000 sub-intervals per interval (error ≤ one sub-interval per
    crossing)."""
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.05, 0.2, 40))
    values = rng.normal(0.5, 0.3, 40)
    fine = 2000
    position = (np.arange(fine) + 0.5) / fine
    h = np.diff(t)
    middle = values[:-1, None] + np.diff(values)[:, None] * position[None, :]
    reference = float(np.sum(h[:, None] / fine * (middle < 0.4)))
    crossings = int(np.sum(np.diff(np.sign(values - 0.4)) != 0))
    assert abs(time_below(t, values, 0.4) - reference) <= (crossings + 1) * h.max() / fine
    assert time_below(t[:1], values[:1], 0.4) == 0.0


def test_output_reach_time_is_reach_and_stay():
    t = np.arange(5.0)
    y = np.array([[3.0], [0.0], [3.0], [0.1], [0.0]])
    assert output_reach_time(t, y, np.zeros(1), 0.5) == 3.0
    assert output_reach_time(t, y[::-1], np.zeros(1), 0.5) is None


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf, True])
def test_a_bad_comfort_distance_is_refused_naming_it(bad):
    t, y = _straight_line(0.1)
    centres = np.zeros((t.size, 1, 2))
    with pytest.raises(RuleError, match=r"comfort_distance: must be a finite distance ≥ 0 m"):
        crowd_metrics(t, y, centres, [0.1], [3.0, 0.0], 0.25, bad)


def test_frequencies_against_one_minus_epsilon_and_record_shapes():
    """Per obstacle index over the runs that have it; 1 − ε averaged over them."""
    records = [
        {"obstacle_collisions": [True, False], "obstacle_epsilon": [0.9, 0.8]},
        {"obstacle_collisions": [False], "obstacle_epsilon": [0.7]},
    ]
    first, second = obstacle_frequencies(records)
    assert (first["runs"], first["collisions"], first["frequency"]) == (2, 1, 0.5)
    assert first["allowed_collision_probability"] == pytest.approx(0.2)  # (0.1 + 0.3)/2
    assert not first["within_allowed"]
    assert (second["runs"], second["frequency"], second["within_allowed"]) == (1, 0.0, True)
    whole = {
        "collided": True,
        "first_collision_s": 1.0,
        "obstacle_collisions": [True],
        "obstacle_epsilon": [0.9],
        "min_distance_m": -0.1,
        "comfort_violation_s": 2.0,
        "path_length_m": 3.0,
        "time_to_goal_s": None,
    }
    assert is_crowd_record(whole, 1) and is_crowd_record({"run": 0})  # older: none
    assert not is_crowd_record(whole, 2)
    assert not is_crowd_record({**whole, "collided": False})  # flags say otherwise
    assert not is_crowd_record({k: v for k, v in whole.items() if k != "min_distance_m"})


# ------------------------------------------------------------ recomputed from a simulation


def _surface(log, centres: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(T, m) ‖y − O_j‖ − r_o_j, plain numpy."""
    return np.linalg.norm(log.output[:, None, :] - centres, axis=2) - radius


def _scripted_centres(scenario, t: np.ndarray) -> np.ndarray:
    """(T, m, n) the scripted means from the scenario's motion models (not the log)."""
    return np.array([[o.motion.position(time) for o in scenario.obstacles] for time in t])


def _check_against_log(record: dict, log, centres: np.ndarray, radius, comfort: float) -> None:
    """The record's crowd keys against what the log and the true centres give."""
    surface = _surface(log, centres, np.asarray(radius))
    nearest = surface.min(axis=1)
    assert record["min_distance_m"] == pytest.approx(nearest.min(), abs=1e-9)
    assert record["collided"] == bool(np.any(surface < 0.0))
    assert record["obstacle_collisions"] == np.any(surface < 0.0, axis=0).tolist()
    h = np.diff(log.t)
    fine = 400
    position = (np.arange(fine) + 0.5) / fine
    middle = nearest[:-1, None] + np.diff(nearest)[:, None] * position[None, :]
    reference = float(np.sum(h[:, None] / fine * (middle < comfort)))
    crossings = int(np.sum(np.diff(np.sign(nearest - comfort)) != 0))
    assert abs(record["comfort_violation_s"] - reference) <= (crossings + 1) * h.max() / fine


@pytest.mark.slow
def test_compare_over_draws_has_the_crowd_keys_of_each_draw(field, tmp_path, capsys):
    out = tmp_path / "draws"
    code = main(
        ["compare", str(field), "--controllers", "stt", "cbf", "--draws", "2",
         "--workers", "2", "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    document = json.loads((out / "comparison.json").read_text())
    assert document["comfort_distance_m"] == 0.5
    records = [json.loads(line) for line in (out / "draws.jsonl").read_text().splitlines()]
    assert "true collision" in capsys.readouterr().out
    for row in document["rows"]:
        mine = [r for r in records if r["controller"] == row["controller"]]
        assert len(mine) == 2 and all(r["status"] == "simulated" for r in mine)
        assert row["collision_rate"] == np.mean([r["collided"] for r in mine])
        assert row["min_distance_m"] == pytest.approx(np.mean([r["min_distance_m"] for r in mine]))
        assert row["min_distance_worst_m"] == min(r["min_distance_m"] for r in mine)
        comfort = np.mean([r["comfort_violation_s"] for r in mine])
        assert row["comfort_violation_s"] == pytest.approx(comfort)
        assert [e["runs"] for e in row["obstacle_collision_frequency"]] == [2, 2]
        assert row["comfort_violation_s"] > 0.0  # the fixed obstacle's surface is 0.4 m off
    for record in (r for r in records if r["controller"] == "stt"):
        scenario = load_scenario(field, seed=record["seed"])
        log = simulate(scenario).log
        centres = _scripted_centres(scenario, log.t)
        radius = [o.radius for o in scenario.obstacles]
        _check_against_log(record, log, centres, radius, 0.5)
        assert record["obstacle_epsilon"] == [o.epsilon for o in scenario.obstacles]


@pytest.mark.slow
def test_compare_on_one_layout_has_the_crowd_keys(field, tmp_path):
    out = tmp_path / "one"
    code = main(
        ["compare", str(field), "--controllers", "stt", "--runs", "20", "--workers", "1",
         "--comfort-distance", "0.6", "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    document = json.loads((out / "comparison.json").read_text())
    (row,) = document["rows"]
    assert document["comfort_distance_m"] == 0.6
    scenario = load_scenario(field)
    log = simulate(scenario).log
    record = {**row, "collided": row["collision_rate"] == 1.0}
    record["obstacle_collisions"] = [
        e["collisions"] == 1 for e in row["obstacle_collision_frequency"]
    ]
    radius = [o.radius for o in scenario.obstacles]
    _check_against_log(record, log, _scripted_centres(scenario, log.t), radius, 0.6)
    assert "comfort violation (s)" in (out / "comparison.md").read_text()


@pytest.mark.slow
def test_a_randomisation_campaign_records_and_summarises_them(field, tmp_path):
    out = tmp_path / "random"
    common = ["campaign", str(field), "--kind", "randomisation", "--runs", "2", "--workers", "1"]
    common += ["--no-progress", "--no-figures", "--out", str(out)]
    assert main([*common, "--comfort-distance", "0.6"]) == 0
    records = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    summary = json.loads((out / "campaign.json").read_text())
    for record in records:
        assert set(record) >= RUN_KEYS
        scenario = load_scenario(field, seed=record["seed"])
        log = simulate(scenario).log
        radius = [o.radius for o in scenario.obstacles]
        _check_against_log(record, log, _scripted_centres(scenario, log.t), radius, 0.6)
        assert record["time_to_goal_s"] is not None and record["path_length_m"] > 4.0 - 0.6
    assert summary["comfort_distance_m"] == 0.6 and summary["crowd_runs"] == 2
    assert summary["collision_rate"] == np.mean([r["collided"] for r in records])
    distances = [r["min_distance_m"] for r in records]
    assert summary["min_distance_m"]["p5"] == pytest.approx(np.percentile(distances, 5))
    comfort = [r["comfort_violation_s"] for r in records]
    assert summary["comfort_violation_s"]["p90"] == pytest.approx(np.percentile(comfort, 90))
    # The comfort distance is part of the spec: a resume must match it; an older spec
    # (written before it existed) meant the default.
    assert main([*common, "--resume"]) == 2
    spec = json.loads((out / "campaign_spec.json").read_text())
    spec.pop("comfort_distance")
    (out / "campaign_spec.json").write_text(json.dumps(spec))
    assert main([*common, "--resume"]) == 0


@pytest.mark.slow
def test_an_end_to_end_campaign_measures_against_the_true_centres(tmp_path):
    """With perception, the truth is the logged true_obstacle_position, not the scripted
    means: the record matches the former (and differs from the latter)."""
    scenario_path = tmp_path / "tracked.yaml"
    text = (DIAGRAMS / "omni_tracked.yaml").read_text()
    scenario_path.write_text(text.replace("duration: 12.0", "duration: 4.0"))
    out = tmp_path / "e2e"
    code = main(
        ["campaign", str(scenario_path), "--kind", "end-to-end", "--runs", "1", "--workers",
         "1", "--no-progress", "--no-figures", "--out", str(out)]
    )  # fmt: skip
    assert code in (0, 1)
    (record,) = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert set(record) >= RUN_KEYS
    scenario = load_scenario(scenario_path, seed=record["seed"])
    log = simulate(scenario).log
    truth = log.rows("true_obstacle_position").reshape(log.samples, log.count, 2)
    radius = [o.radius for o in scenario.obstacles]
    _check_against_log(record, log, truth, radius, 0.5)
    scripted = _surface(log, _scripted_centres(scenario, log.t), np.asarray(radius))
    assert record["min_distance_m"] != pytest.approx(scripted.min(), abs=1e-6)
    summary = json.loads((out / "campaign.json").read_text())
    assert summary["collision_rate"] == float(record["collided"])


@pytest.mark.parametrize(
    "words",
    [
        ["compare", "--controllers", "stt", "--draws", "2"],
        ["compare", "--controllers", "stt", "--runs", "5"],
        ["campaign", "--kind", "randomisation", "--runs", "2"],
    ],
)
def test_a_negative_comfort_distance_is_refused(field, tmp_path, capsys, words):
    command, *rest = words
    code = main([command, str(field), *rest, "--comfort-distance", "-1", "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert "--comfort-distance: must be a finite distance ≥ 0 m (got -1.0)" in err
    assert "Traceback" not in err


def test_the_comfort_distance_needs_a_simulating_campaign(field, tmp_path, capsys):
    code = main(
        ["campaign", str(field), "--runs", "2", "--comfort-distance", "0.3", "--out",
         str(tmp_path)]
    )  # fmt: skip
    assert code == 2
    assert "--comfort-distance: applies only to --kind randomisation or end-to-end" in (
        capsys.readouterr().err
    )


def test_the_resume_command_keeps_the_comfort_distance(tmp_path):
    from stt_drake.campaign.spec import CampaignSpec
    from stt_drake.cli.campaign import resume_command

    spec = CampaignSpec(scenario="f.yaml", kind="randomisation", runs=3, comfort_distance=0.6)
    assert "--comfort-distance 0.6 " in resume_command(spec, tmp_path)
    default = CampaignSpec(scenario="f.yaml", kind="randomisation", runs=3)
    assert "--comfort-distance" not in resume_command(default, tmp_path)


ABSENT_ON_THE_PATH = """
name: absent_on_the_path
start: [0.0, 0.0]
initial_set_radius: 0.3
target: [4.0, 0.0]
target_set_radius: 0.3
duration: 8.0
tube: {r_min: 0.1, r_max: 0.25, k1: 0.8, k2: 0.4, k3: 0.4, max_center_speed: 1.5}
controller: {kappa: [8.0]}
obstacles:
  - motion: !Recorded {file: walker.csv, id: 0}
    radius: 0.3
    sigma: 0.05
    epsilon: 0.9
    p_d: 0.9999
"""


def test_an_obstacle_outside_its_track_is_nowhere(tmp_path):
    """A pedestrian walks onto the robot's straight path and its track ends there at
    0.6 s, long before the robot arrives: it no longer exists, so nothing collides with
    it — not the crowd metrics, not the belief's collision probabilities, not a sampled
    true obstacle (its held end sample is a value nothing may read)."""
    from stt_drake.campaign import ClosedLoop
    from stt_drake.campaign.crowd_metrics import crowd_record
    from stt_drake.campaign.sampling import sample_true_obstacles

    rows = [f"{0.1 * k:.1f},0,2.0,{-0.6 + 0.1 * k:.1f}" for k in range(7)]  # ends at (2, 0)
    (tmp_path / "walker.csv").write_text("t,id,x,y\n" + "\n".join(rows) + "\n")
    (tmp_path / "absent.yaml").write_text(ABSENT_ON_THE_PATH)
    log = simulate(load_scenario(tmp_path / "absent.yaml")).log
    crossing = np.abs(log.output[:, 0] - 2.0) < 0.1
    assert np.any(crossing) and not np.any(log.active[crossing, 0])  # passed where it ended
    record = crowd_record(log)
    assert not record["collided"] and record["obstacle_collisions"] == [False]
    assert record["min_distance_m"] > 0.5  # only while the walker existed, 2 m away
    loop = ClosedLoop.from_log(log)
    collision = loop.collision_probability()
    assert np.all(collision["output"][~log.active[:, 0], 0] == 0.0)
    records = sample_true_obstacles(loop, "static", 1.0, [(0, 1), (1, 2)])
    assert all(record["output"] == [[]] for record in records)
