"""Crowds from JuPedSim (issue 26, item 2): the scenes, the offline tracks and their CSV,
`stt-drake crowd`, the interactive CrowdSimulator (pedestrians that see the robot) and the
scenario's `crowd:` section."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from stt_drake.assembly import parse_scenario
from stt_drake.cli.main import main
from stt_drake.config import ScenarioError
from stt_drake.config.validate_crowd import CROWD_SCENES
from stt_drake.core.perception import Detections, SensorModel
from stt_drake.core.rules import RuleError
from stt_drake.crowd import (
    CSV_HEADER,
    SCENE_NAMES,
    CrowdUnavailableError,
    make_scene,
    run_tracks,
)
from stt_drake.crowd.engine import load_jupedsim
from stt_drake.crowd.scenes import DEFAULT_AREAS, START_GAP
from stt_drake.systems.crowd import CrowdSimulator
from stt_drake.systems.perception import ObstacleSensor

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "diagrams" / "crowd_crossing_interactive.yaml"
RATE = 10.0


def _pairwise_min(points: np.ndarray) -> float:
    if len(points) < 2:
        return np.inf
    gaps = np.linalg.norm(points[:, None] - points[None], axis=2)
    return float(gaps[np.triu_indices(len(points), 1)].min())


def _distance_to_box(point: np.ndarray, box: np.ndarray) -> float:
    """Euclidean distance from `point` to the axis-aligned polygon `box` (0 inside)."""
    low, high = box.min(axis=0), box.max(axis=0)
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(low - point, point - high))))


# --------------------------------------------------------------------------- scenes


def test_the_config_knows_the_same_scenes():
    assert CROWD_SCENES == SCENE_NAMES


@pytest.mark.parametrize("scene", SCENE_NAMES)
def test_each_scene_walks_n_tracks_at_their_speeds_without_overlap(scene):
    count, speed_range = 12, (0.9, 1.3)
    setup = make_scene(scene, count, seed=4, speed_range=speed_range)
    tracks = run_tracks(setup, duration=60.0, rate=RATE)
    assert tracks.positions.shape == (len(tracks.times), count, 2)
    # The drawn set-up: N starts inside the area, speeds in the range, starts apart.
    assert np.all((speed_range[0] <= setup.desired_speeds) & (setup.desired_speeds <= 1.3))
    np.testing.assert_array_equal(tracks.positions[0], setup.starts)
    x0, y0, x1, y1 = DEFAULT_AREAS[scene]
    assert np.all((setup.starts > [x0, y0]) & (setup.starts < [x1, y1]))
    assert _pairwise_min(setup.starts) >= 2 * setup.radius + START_GAP - 1e-12
    # Speeds: the Collision Free Speed Model never exceeds an agent's desired speed, so a
    # sample's displacement is at most v0·Δt (relative slack for the float sums only).
    step = np.linalg.norm(np.diff(tracks.positions, axis=0), axis=2) * RATE
    both = tracks.active[1:] & tracks.active[:-1]
    assert np.all(
        step[both] <= np.broadcast_to(setup.desired_speeds, step.shape)[both] * (1 + 1e-9)
    )
    assert np.median(step[both]) > 0.5 * speed_range[0]  # they do walk
    # No two pedestrians ever overlap at their radius (the model's guarantee).
    closest = min(_pairwise_min(p[a]) for p, a in zip(tracks.positions, tracks.active, strict=True))
    assert closest >= 2 * setup.radius
    # Every pedestrian reaches its own exit: its last sample in the scene is within one
    # sample's walk of the exit polygon, and its track ends there.
    assert not tracks.active[-1].any()
    for i in range(count):
        times, positions = tracks.track(i)
        assert times[-1] < tracks.times[-1]
        box = setup.exits[setup.exit_of[i]]
        reach = setup.desired_speeds[i] / RATE
        assert _distance_to_box(positions[-1], box) <= reach + 1e-9


def test_the_scenes_go_where_their_names_say():
    crossing = make_scene("crossing", 10, seed=1)
    first = crossing.exit_of == 0
    travel = crossing.goals() - crossing.starts
    assert np.all(travel[first, 0] > np.abs(travel[first, 1]))  # the first flow: +x
    assert np.all(travel[~first, 1] > np.abs(travel[~first, 0]))  # the second: +y
    circle = make_scene("circle", 9, seed=1)
    centre = np.array([5.0, 5.0])
    np.testing.assert_allclose(circle.goals() - centre, centre - circle.starts, atol=1e-12)
    both = make_scene("bidirectional", 9, seed=1)
    direction = np.sign((both.goals() - both.starts)[:, 0])
    assert sorted(direction.tolist()) == [-1.0] * 4 + [1.0] * 5


def test_a_seed_fixes_the_draw():
    a, b = make_scene("crossing", 15, seed=7), make_scene("crossing", 15, seed=7)
    np.testing.assert_array_equal(a.starts, b.starts)
    np.testing.assert_array_equal(a.desired_speeds, b.desired_speeds)
    other = make_scene("crossing", 15, seed=8)
    assert not np.array_equal(a.starts, other.starts)


@pytest.mark.parametrize(
    ("arguments", "field"),
    [
        ({"scene": "mall"}, "scene"),
        ({"pedestrians": 0}, "pedestrians"),
        ({"pedestrians": 500}, "pedestrians"),  # 500 do not fit in the start regions
        ({"speed_range": (1.4, 1.0)}, "speed_range"),
        ({"speed_range": (0.0, 1.0)}, "speed_range"),
        ({"area": (0.0, 0.0, 1.0, 10.0)}, "area"),
        ({"radius": -0.2}, "radius"),
        ({"seed": -1}, "seed"),
    ],
)
def test_bad_scene_arguments_name_the_argument(arguments, field):
    call = {"scene": "crossing", "pedestrians": 10, "seed": 0, **arguments}
    with pytest.raises(RuleError) as info:
        make_scene(**call)
    assert info.value.field == field


def test_too_many_on_the_circle_is_refused_with_the_limit():
    # Ring of radius 5 − 2·0.2 − 0.05 = 4.55 m, neighbours 0.45 m apart: at most
    # ⌊π / asin(0.45 / 9.1)⌋ = 63 pedestrians.
    make_scene("circle", 63, seed=0)
    with pytest.raises(RuleError, match=r"at most 63") as info:
        make_scene("circle", 64, seed=0)
    assert info.value.field == "pedestrians"


def test_missing_jupedsim_says_install_the_extra(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "jupedsim", None)  # import jupedsim → ImportError
    with pytest.raises(CrowdUnavailableError, match=r"install stt-drake\[crowd\]"):
        load_jupedsim()
    out = tmp_path / "tracks.csv"
    assert main(["crowd", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "install stt-drake[crowd]" in err and "Traceback" not in err
    assert not out.exists()
    # A crowd scenario is refused at load (exit 2), not with a traceback at build.
    with pytest.raises(ScenarioError, match=r"^scenario.crowd: .*install stt-drake\[crowd\]"):
        parse_scenario(SCENARIO.read_text(encoding="utf-8"))
    assert main(["run", str(SCENARIO), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "install stt-drake[crowd]" in err and "Traceback" not in err


# --------------------------------------------------------------------------- CLI and CSV


def test_the_cli_writes_tracks_grouped_by_id_in_time(tmp_path, capsys):
    out = tmp_path / "sub" / "tracks.csv"
    arguments = ["--scene", "corridor", "--pedestrians", "6", "--seed", "2"]
    assert main(["crowd", *arguments, "--duration", "25", "--rate", "5", "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    lines = out.read_text(encoding="utf-8").splitlines()
    assert lines[0] == CSV_HEADER
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    ids = table[:, 1].astype(int)
    assert sorted(set(ids)) == list(range(6))
    assert np.all(np.diff(ids) >= 0)  # grouped by id
    expected = run_tracks(make_scene("corridor", 6, seed=2), duration=25.0, rate=5.0)
    for i in range(6):
        rows = table[ids == i]
        assert np.all(np.diff(rows[:, 0]) > 0)  # t increasing
        times, positions = expected.track(i)
        np.testing.assert_allclose(rows[:, 0], times, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rows[:, 2:], positions, rtol=0, atol=5e-7)  # %.6f
        # The corridor is 20 m long and 25 s is enough: every track ends before the run.
        assert rows[-1, 0] < 25.0


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--pedestrians", "0"], "--pedestrians must be ≥ 1"),
        (["--rate", "0"], "--rate must lie in (0, 1000] Hz"),
        (["--rate", "-5"], "--rate must lie in (0, 1000] Hz"),
        (["--duration", "nan"], "--duration must lie in"),
        (["--speed-range", "1.5", "1.0"], "--speed-range must satisfy"),
        (["--pedestrians", "2000"], "--pedestrians do not fit"),
    ],
)
def test_the_cli_refuses_bad_input_with_exit_2(tmp_path, capsys, arguments, message):
    out = tmp_path / "tracks.csv"
    assert main(["crowd", *arguments, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_an_unknown_scene_exits_2(tmp_path, capsys):
    out = tmp_path / "t.csv"
    with pytest.raises(SystemExit) as info:  # argparse's usage error
        main(["crowd", "--scene", "mall", "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'mall'" in err and "Traceback" not in err
    assert not out.exists()


def test_the_cli_refuses_an_unwritable_out(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for out in (blocker / "tracks.csv", tmp_path):
        assert main(["crowd", "--pedestrians", "2", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "--out" in err and "Traceback" not in err


# --------------------------------------------------------------------------- interactive


def _corridor_walker(seed: int):
    """One pedestrian in a 20 m × 3 m corridor and the midpoint of its free path."""
    setup = make_scene("corridor", 1, seed=seed, area=(0.0, 0.0, 20.0, 3.0))
    midpoint = setup.starts[0] + 0.5 * (setup.goals()[0] - setup.starts[0])
    return setup, midpoint


def _walk(setup, robot, duration=18.0, robot_radius=0.3):
    builder = DiagramBuilder()
    crowd = builder.AddSystem(CrowdSimulator(setup, robot_radius, period=0.05))
    source = builder.AddSystem(ConstantVectorSource(np.asarray(robot, dtype=float)))
    builder.Connect(source.get_output_port(), crowd.GetInputPort("robot_position"))
    positions = LogVectorOutput(crowd.GetOutputPort("true_obstacle_position"), builder, 0.01)
    active = LogVectorOutput(crowd.GetOutputPort("pedestrian_active"), builder, 0.01)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration)
    context = simulator.get_context()
    path = positions.FindLog(context).data().T
    present = active.FindLog(context).data().T[:, 0] > 0.5
    return path, present, crowd.hidden_periods(crowd.GetMyContextFromRoot(context))


@pytest.mark.parametrize("seed", [0, 3])
def test_a_pedestrian_walks_around_a_robot_in_its_way(seed):
    setup, robot = _corridor_walker(seed)
    blocked, present, hidden = _walk(setup, robot)
    free, free_present, _ = _walk(setup, [-50.0, -50.0])  # the robot off the area
    # Alone, the pedestrian walks straight through the robot's spot (within 1 cm).
    assert np.linalg.norm(free[free_present] - robot, axis=1).min() < 0.01
    # With the robot there it keeps out of the robot's disc of 0.3 m by its own radius
    # (the robot is a hole in its walkable area, a 32-gon inscribed in the disc: measured
    # 0.56 m), its path is a different one, and it still reaches its exit.
    assert hidden == 0
    clearance = np.linalg.norm(blocked[present] - robot, axis=1).min()
    assert clearance >= 0.3 + setup.radius
    assert np.abs(blocked - free).max() > 0.3
    assert not present[-1] and not free_present[-1]


def test_a_second_simulation_starts_the_crowd_afresh_and_a_clone_cannot_be_stepped():
    setup, robot = _corridor_walker(1)
    builder = DiagramBuilder()
    crowd = builder.AddSystem(CrowdSimulator(setup, 0.3))
    source = builder.AddSystem(ConstantVectorSource(robot))
    builder.Connect(source.get_output_port(), crowd.GetInputPort("robot_position"))
    diagram = builder.Build()
    port = crowd.GetOutputPort("true_obstacle_position")

    def position_at(simulator, t):
        simulator.AdvanceTo(t)
        return port.Eval(crowd.GetMyContextFromRoot(simulator.get_context())).copy()

    first = Simulator(diagram)
    first.Initialize()
    first.Initialize()  # twice at t = 0: the same start
    position_at(first, 1.0)
    clone = first.get_context().Clone()
    at_two = position_at(first, 2.0)
    assert np.linalg.norm(at_two - setup.starts[0]) > 1.0  # it walked
    second = Simulator(diagram)  # a fresh Context: the crowd starts again from t = 0
    np.testing.assert_array_equal(position_at(second, 2.0), at_two)
    with pytest.raises(RuntimeError, match="only moves forward"):
        Simulator(diagram, clone).Initialize()  # the engine is at 2 s, the clone at 1 s
    again = Simulator(diagram, clone)
    clone.SetTime(0.0)  # back at the start: initialization resets the crowd
    np.testing.assert_array_equal(position_at(again, 2.0), at_two)


def test_the_sensor_does_not_detect_an_absent_pedestrian():
    model = SensorModel(2, 2, 0.1, 1.0, 0.01 * np.eye(2), 0.0, np.inf, np.random.default_rng(0))
    builder = DiagramBuilder()
    sensor = builder.AddSystem(ObstacleSensor(model, presence=True))
    inputs = {
        "true_obstacle_position": [1.0, 1.0, 2.0, 2.0],
        "robot_position": [0.0, 0.0],
        "obstacle_present": [1.0, 0.0],
    }
    for name, value in inputs.items():
        source = builder.AddSystem(ConstantVectorSource(np.array(value)))
        builder.Connect(source.get_output_port(), sensor.GetInputPort(name))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    detections = Detections.from_vector(
        sensor.GetOutputPort("detections").Eval(sensor.GetMyContextFromRoot(context)), 2
    )
    assert detections.detected.tolist() == [True, False]


# --------------------------------------------------------------------------- scenario


def _text(**changes: str) -> str:
    text = SCENARIO.read_text(encoding="utf-8")
    for old, new in changes.items():
        assert old in text, old
        text = text.replace(old, new)
    return text


def test_the_crowd_scenario_has_one_obstacle_slot_per_pedestrian():
    scenario = parse_scenario(_text())
    crowd = scenario.crowd
    assert len(scenario.obstacles) == crowd.pedestrians == 20
    assert {o.radius for o in scenario.obstacles} == {crowd.radius + crowd.robot_radius}
    assert {(o.sigma, o.epsilon, o.p_d) for o in scenario.obstacles} == {(0.05, 0.9, 0.9999)}
    again = parse_scenario(_text())
    assert [o.motion.positions for o in again.obstacles] == [
        o.motion.positions for o in scenario.obstacles
    ]
    other = parse_scenario(_text(), seed=scenario.seed + 1)  # the run seed draws anew
    assert other.obstacles[0].motion.positions != scenario.obstacles[0].motion.positions


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"  scene: crossing\n": "  scene: mall\n"}, "scenario.crowd.scene"),
        ({"  pedestrians: 20\n": "  pedestrians: 0\n"}, "scenario.crowd.pedestrians"),
        ({"  pedestrians: 20\n": "  pedestrians: 400\n"}, "scenario.crowd.pedestrians"),
        ({"  epsilon: 0.9\n": ""}, "scenario.crowd.epsilon"),
        ({"  p_d: 0.9999\n": "  p_d: 0.5\n"}, "scenario.crowd.p_d"),
        ({"  speed_range: [1.0, 1.4]": "  speed_range: [1.4, 1.0]"}, "scenario.crowd.speed_range"),
        ({"  robot_radius: 0.25": "  robot_radius: -0.25"}, "scenario.crowd.robot_radius"),
    ],
)
def test_a_bad_crowd_section_names_the_field(changes, field):
    with pytest.raises(ScenarioError) as info:
        parse_scenario(_text(**changes))
    assert str(info.value).startswith(field + ":")


def test_a_crowd_needs_perception_and_no_other_obstacles():
    text = _text()
    start = text.index("perception:\n")
    end = text.index("plant:")
    with pytest.raises(ScenarioError, match=r"^scenario.perception: an interactive crowd"):
        parse_scenario(text[:start] + text[end:])
    obstacle = (
        "obstacles:\n  - motion: !ConstantVelocity {start: [5.0, 5.0], velocity: [0.0, 0.0]}\n"
        "    radius: 0.2\n    sigma: 0.05\n    epsilon: 0.9\n    p_d: 0.9999\n"
    )
    with pytest.raises(ScenarioError, match=r"^scenario.obstacles: must be empty with a crowd"):
        parse_scenario(text + obstacle)


def _recorded_crowd_text(duration: float) -> str:
    """The packaged crowd, not interactive and without perception (the scripted belief)."""
    text = _text(**{"  interactive: true\n": "  interactive: false\n"})
    start, end = text.index("perception:\n"), text.index("plant:")
    return (text[:start] + text[end:]).replace("duration: 30.0", f"duration: {duration}")


def test_a_crowd_that_is_not_interactive_is_a_recorded_crowd_drawn_per_seed():
    """Each pedestrian is a recorded track of the crowd simulated without the robot (the
    tracks `stt-drake crowd` writes), over its time in the scene; a new seed, a new crowd."""
    from stt_drake.assembly.load import crowd_setup
    from stt_drake.core.motion import Recorded
    from stt_drake.crowd import run_tracks

    text = _recorded_crowd_text(12.0)
    scenario = parse_scenario(text)
    assert all(isinstance(o.motion, Recorded) for o in scenario.obstacles)
    tracks = run_tracks(crowd_setup(scenario), 12.0, 1.0 / scenario.crowd.period)
    for i, obstacle in enumerate(scenario.obstacles):
        times, positions = tracks.track(i)
        np.testing.assert_array_equal(obstacle.motion.track.times, times)
        np.testing.assert_array_equal(obstacle.motion.track.positions, positions)
    other = parse_scenario(text, seed=scenario.seed + 1)
    first, again = scenario.obstacles[0].motion.track, other.obstacles[0].motion.track
    assert not np.array_equal(first.positions[:2], again.positions[:2])


@pytest.mark.slow
def test_a_recorded_crowd_runs_and_compares_over_seeds(tmp_path, monkeypatch):
    """Without perception every controller of compare runs on it, over crowd draws."""
    from stt_drake.cli.main import main

    monkeypatch.chdir(tmp_path)
    path = tmp_path / "crowd.yaml"
    path.write_text(_recorded_crowd_text(3.0))
    controllers = ["--controllers", "stt", "stt-guided", "cbf", "apf"]
    assert main(["compare", str(path), *controllers, "--draws", "2", "--out", "c"]) in (0, 1)
    lines = (tmp_path / "c" / "draws.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    assert len(records) == 8 and {r["status"] for r in records} <= {"simulated", "rejected"}
    assert {r["seed"] for r in records if r["controller"] == "stt"} == {
        r["seed"] for r in records if r["controller"] == "cbf"
    }


def test_the_interactive_scenario_runs_in_the_simulator():
    from stt_drake.run import simulate

    scenario = parse_scenario(_text(**{"duration: 30.0": "duration: 1.5"}))
    result = simulate(scenario)
    assert result.metrics["sim_time_s"] == pytest.approx(1.5)
    assert result.metrics["stop_reason"] is None
    active = np.asarray(result.log["pedestrian_active"])
    assert active.shape[1] == 20 and np.all(active[0] == 1.0)  # (samples, slots)
    truth = np.asarray(result.log["true_obstacle_position"])
    starts = np.array([o.motion.positions[0] for o in scenario.obstacles])
    np.testing.assert_allclose(truth[0].reshape(20, 2), starts, atol=1e-12)
    walked = np.linalg.norm(truth[-1].reshape(20, 2) - starts, axis=1)
    assert np.median(walked) > 1.0  # 1.5 s at 1.0-1.4 m/s, some held up by others


def test_pedestrians_faster_than_the_centre_are_named_before_the_run():
    """Where pedestrians outrun the tube (a level set faster than max_center_speed), the
    run's warnings say so before it starts: claim (ii) cannot be guaranteed for them."""
    from stt_drake.assembly.feasibility import scenario_warnings

    text = (
        (ROOT / "diagrams" / "crowd_crossing.yaml")
        .read_text()
        .replace("duration: 30.0", "duration: 5.0")
    )
    assert not [w for w in scenario_warnings(parse_scenario(text)) if "claim (ii)" in w]
    slow = text.replace("max_center_speed: 2.0", "max_center_speed: 0.9")
    scenario = parse_scenario(slow)
    warned = {
        int(re.search(r"obstacle (\d+)", w).group(1))
        for w in scenario_warnings(scenario)
        if "claim (ii)" in w
    }
    fastest = [  # each pedestrian's fastest step between its recorded samples (σ is fixed)
        np.max(np.linalg.norm(np.diff(o.motion.track.positions, axis=0), axis=1))
        / np.diff(o.motion.track.times)[0]
        for o in scenario.obstacles
    ]
    assert warned == {j for j, v in enumerate(fastest) if v >= 0.9} and len(warned) >= 15
