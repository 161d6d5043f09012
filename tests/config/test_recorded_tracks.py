"""Recorded obstacle tracks from data files (issue 26, item 1): ``!Recorded {file, id}``.

The references are independent of the code under test: ``np.interp`` per axis for the
piecewise-linear means, the same motion written inline as ``!Waypoints``, the closed form
of a straight walk's speed, and the scenario's own numbers for the active spans.
"""

from __future__ import annotations

import copy
import fnmatch
import json
import pickle
import tomllib
from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario, parse_scenario
from stt_drake.assembly.guide import guide_settings
from stt_drake.assembly.laws import make_tube_law
from stt_drake.cli.main import main, packaged_scenarios
from stt_drake.config import ScenarioError
from stt_drake.config import tracks as tracks_module
from stt_drake.config.assumptions import target_separation
from stt_drake.core import backend
from stt_drake.core.belief import GaussianBelief, obstacle_rate_bounds
from stt_drake.core.guide import RoutePlanner, ScriptedForecast
from stt_drake.core.motion import MotionTable, Recorded, Waypoints
from stt_drake.core.probability import avoid_probability
from stt_drake.run import simulate
from stt_drake.systems.belief_source import ObstacleBeliefSource

EPS = np.finfo(float).eps

HEAD = """name: recorded
start: [0.5, 0.5]
initial_set_radius: 0.3
target: [4.5, 4.5]
target_set_radius: 0.3
duration: {duration}
tube: {{r_min: 0.21, r_max: 0.27, k1: 0.7, k2: 0.4, k3: 0.4, max_center_speed: 1.4{rate}}}
controller: {{kappa: [8.0]}}
{extra}obstacles:
"""
OBSTACLE = "  - {{motion: {motion}, radius: 0.2, sigma: 0.05, epsilon: 0.9, p_d: 0.9999}}\n"


def _walks(duration: float, rate_hz: float = 10.0, count: int = 3) -> dict[int, np.ndarray]:
    """Per id, (k, 3) rows [t, x, y] of a swaying walk across the robot's way over [0,
    duration] (ids 0..count-1), times on a 1/rate_hz grid."""
    times = np.round(np.arange(round(duration * rate_hz) + 1) / rate_hz, 10)
    walks = {}
    for j in range(count):
        x = 4.5 - 0.2 * times + 0.1 * np.sin(1.3 * times + j)
        y = 1.2 + 1.1 * j + 0.15 * np.cos(0.7 * times)
        walks[j] = np.column_stack([times, x, y])
    return walks


def _write_csv(path: Path, walks: dict[int, np.ndarray], header: str = "t,id,x,y") -> Path:
    rows = sorted((t, j, x, y) for j, walk in walks.items() for t, x, y in walk)
    lines = [header] + [f"{float(t)!r},{j},{float(x)!r},{float(y)!r}" for t, j, x, y in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _write_npz(path: Path, walks: dict[int, np.ndarray]) -> Path:
    t = np.concatenate([walk[:, 0] for walk in walks.values()])
    ids = np.concatenate([np.full(len(walk), j) for j, walk in walks.items()])
    position = np.concatenate([walk[:, 1:] for walk in walks.values()])
    np.savez(path, t=t, id=ids, position=position)
    return path


def _scenario_text(motions: list[str], duration: float = 6.0, rate: float = 0.0, extra="") -> str:
    head = HEAD.format(
        duration=duration, rate=f", update_rate_hz: {rate}" if rate else "", extra=extra
    )
    return head + "".join(OBSTACLE.format(motion=m) for m in motions)


def _recorded(file: str, ids) -> list[str]:
    return [f"!Recorded {{file: {file}, id: {j}}}" for j in ids]


def _waypoints(walks: dict[int, np.ndarray]) -> list[str]:
    return [
        f"!Waypoints {{times: {w[:, 0].tolist()}, positions: {w[:, 1:].tolist()}}}"
        for w in walks.values()
    ]


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# --------------------------------------------------------------------------- same as inline


@pytest.mark.parametrize("kind", ["csv", "npz"])
def test_a_recorded_track_gives_the_belief_of_the_same_waypoints(tmp_path, kind):
    walks = _walks(6.0)
    writer = _write_csv if kind == "csv" else _write_npz
    writer(tmp_path / f"tracks.{kind}", walks)
    recorded = load_scenario(
        _write(tmp_path / "rec.yaml", _scenario_text(_recorded(f"tracks.{kind}", walks)))
    )
    inline = load_scenario(_write(tmp_path / "wp.yaml", _scenario_text(_waypoints(walks))))
    n = 2
    sources = [ObstacleBeliefSource(s.obstacles, n) for s in (recorded, inline)]
    sample_times = walks[0][:, 0]
    times = np.concatenate([np.linspace(0.0, 6.0, 397), sample_times])
    # Both evaluate p_k + w (p_{k+1} − p_k), np.interp p_k + slope (t − t_k): a few
    # roundings apart, each ≤ ε|p| with |p| < 6 m: 8ε·6 m bounds the difference.
    tolerance = 8 * EPS * 6.0
    for compiled in (True, False):
        with backend.pure_numpy(not compiled):
            for t in times:
                beliefs = [GaussianBelief.from_vector(src.belief_vector(t), n) for src in sources]
                reference = np.array(
                    [[np.interp(t, w[:, 0], w[:, 1 + a]) for a in range(n)] for w in walks.values()]
                )
                for belief in beliefs:
                    np.testing.assert_allclose(belief.mean, reference, rtol=0, atol=tolerance)
                    assert belief.active.all()  # the tracks cover the whole run
                np.testing.assert_array_equal(beliefs[0].covariance, beliefs[1].covariance)


def test_a_recorded_track_gives_the_closed_loop_of_the_same_waypoints(tmp_path):
    walks = _walks(4.0)
    _write_csv(tmp_path / "tracks.csv", walks)
    runs = [
        simulate(load_scenario(_write(tmp_path / f"{name}.yaml", _scenario_text(m, 4.0))))
        for name, m in (("rec", _recorded("tracks.csv", walks)), ("wp", _waypoints(walks)))
    ]
    recorded, inline = (run.log for run in runs)
    # The two beliefs agree to a few ulp (previous test); both take one table lookup per
    # evaluation (the same arithmetic), so the integrator sees the same inputs: the logs
    # agree to rounding, 1e-12 m leaves room for a last-bit reordering only.
    assert recorded.t.shape == inline.t.shape
    np.testing.assert_allclose(recorded.center, inline.center, rtol=0, atol=1e-12)
    np.testing.assert_allclose(recorded.radius, inline.radius, rtol=0, atol=1e-12)
    assert runs[0].metrics["holds"] == runs[1].metrics["holds"]


# --------------------------------------------------------------------------- the time span


def _spans_scenario(tmp_path: Path, perception: str = "") -> tuple[Path, dict]:
    """Obstacle 0 exists over [1.0, 3.0] s only, obstacle 1 over the whole 5 s run."""
    walks = _walks(5.0, count=2)
    walks[0] = walks[0][(walks[0][:, 0] >= 1.0) & (walks[0][:, 0] <= 3.0)]
    _write_csv(tmp_path / "tracks.csv", walks)
    text = _scenario_text(_recorded("tracks.csv", walks), 5.0, extra=perception)
    return _write(tmp_path / "spans.yaml", text), walks


def test_an_obstacle_is_inactive_outside_its_track_span(tmp_path):
    path, _ = _spans_scenario(tmp_path)
    scenario = load_scenario(path)
    source = ObstacleBeliefSource(scenario.obstacles, 2)
    for compiled in (True, False):
        with backend.pure_numpy(not compiled):
            for t, expected in (
                (0.0, False),
                (0.99, False),
                (1.0, True),
                (2.0, True),
                (3.0, True),
                (3.01, False),
                (5.0, False),
            ):
                belief = GaussianBelief.from_vector(source.belief_vector(t), 2)
                assert belief.active.tolist() == [expected, True], t
    result = simulate(scenario)
    log = result.log
    inside = (log.t >= 1.0) & (log.t <= 3.0)
    np.testing.assert_array_equal(log.active[:, 0], inside)
    assert log.active[:, 1].all()
    # The monitor and the tube read an absent obstacle as q = 1: no margin, no recovery.
    for name in ("avoid_probability", "output_avoid_probability", "tube_avoid_probability"):
        assert np.all(log[name][~inside, 0] == 1.0), name
    assert not log["recovery"][~inside, 0].any()
    assert result.metrics["holds"]


def test_an_absent_true_obstacle_is_not_detected_nor_tracked(tmp_path):
    perception = "perception: {sensor_period: 0.1, noise_sigma: 0.05, track_timeout: 0.5}\n"
    path, _ = _spans_scenario(tmp_path, perception)
    log = simulate(load_scenario(path)).log
    truth = log.rows("true_obstacle_position").reshape(log.samples, 2, 2)
    inside = (log.t >= 1.0) & (log.t <= 3.0)
    assert np.isnan(truth[~inside, 0]).all() and np.isfinite(truth[inside, 0]).all()
    assert np.isfinite(truth[:, 1]).all()
    # The tracker holds no track of it before its first detection (t = 1 s) nor after the
    # timeout once it is gone (3 s + 0.5 s + one sensor period of slack).
    assert not log.active[log.t < 1.0, 0].any()
    assert not log.active[log.t > 3.65, 0].any()
    assert log.active[(log.t > 1.2) & (log.t < 3.0), 0].all()


def test_the_load_time_checks_skip_an_absent_obstacle(tmp_path):
    """A track that starts at the robot's start point 2 s in does not break the initial
    avoidance condition, and one that sits on the target only before 3 s does not break
    Assumption 3 in a strict scenario; q reads 1 outside the spans."""
    times = np.arange(0.0, 2.05, 0.1)
    walks = {
        0: np.column_stack([times + 2.0, 0.5 + 0.0 * times, 0.5 + 0.5 * times]),
        1: np.column_stack([times + 1.0, 4.5 + 0.0 * times, 4.5 + 0.0 * times]),
    }
    _write_csv(tmp_path / "tracks.csv", walks)
    text = _scenario_text(_recorded("tracks.csv", walks), 6.0).replace(
        "name: recorded\n", "name: recorded\nstrict: true\n"
    )
    scenario = load_scenario(_write(tmp_path / "s.yaml", text))
    separation = target_separation(scenario, 61)
    table = MotionTable([o.motion for o in scenario.obstacles], 2)
    for k, t in enumerate(separation.times):
        means = np.array([o.motion.position(t) for o in scenario.obstacles])
        q = avoid_probability(np.array([4.5, 4.5]), means, np.full(2, 0.05), np.full(2, 0.41))
        present = np.array([w[0, 0] <= t <= w[-1, 0] for w in walks.values()])
        np.testing.assert_allclose(separation.q[k], np.where(present, q, 1.0), rtol=1e-12)
        np.testing.assert_array_equal(table.active(t), present)
    # Held on the target over [1, 3] s it is a real breach there.
    assert separation.below()[(separation.times > 1.0) & (separation.times < 3.0), 1].all()


def test_the_scripted_forecast_drops_an_absent_obstacle(tmp_path):
    path, walks = _spans_scenario(tmp_path, "guide: {}\n")
    scenario = load_scenario(path)
    knots = np.linspace(0.0, 5.0, 26)
    forecast = ScriptedForecast(scenario.obstacles, 2)(knots)
    expected = (knots >= 1.0) & (knots <= 3.0)
    np.testing.assert_array_equal(forecast.active[:, 0], expected)
    assert forecast.active[:, 1].all()
    law = make_tube_law(scenario)
    radius, epsilon = np.full(2, 0.2), np.full(2, 0.9)
    planner = RoutePlanner(guide_settings(scenario, law), radius, epsilon, law.r_min, 2)
    for radii in planner.blocking_radii(forecast):  # soft and hard: none while absent
        assert np.all(radii[~expected, 0] == 0.0) and np.all(radii[expected, 0] > 0.2)
        assert np.all(radii[:, 1] > 0.2)
    for k, t in enumerate(knots):
        reference = [np.interp(t, walks[0][:, 0], walks[0][:, 1 + a]) for a in range(2)]
        np.testing.assert_allclose(forecast.means[k, 0], reference, rtol=0, atol=8 * EPS * 6)


# --------------------------------------------------------------------------- models


def test_the_sample_table_agrees_with_np_interp_with_steps_and_single_samples():
    rng = np.random.default_rng(7)
    motions = []
    for k in (1, 2, 5, 9, 30):
        times = np.sort(rng.uniform(-2.0, 20.0, k)).round(1)
        times = np.unique(times)
        if times.size >= 4:  # a step at the 2nd time, and one at the last time
            times = np.insert(times, [2, times.size], [times[1], times[-1]])
        positions = rng.normal(size=(times.size, 3))
        motions.append(Waypoints(times=times.tolist(), positions=positions.tolist()))
    motions.append(Recorded.of(np.arange(0.0, 5.0, 0.1), rng.normal(size=(50, 3))))
    table = MotionTable(motions, 3)
    knots = [np.asarray(m.times if isinstance(m, Waypoints) else m.track.times) for m in motions]
    times = np.concatenate([np.linspace(-5.0, 25.0, 601), *knots])
    at = table.positions_at(times)
    for k, t in enumerate(times):
        reference = np.array(
            [
                [np.interp(t, knot, np.asarray(_positions(m))[:, a]) for a in range(3)]
                for m, knot in zip(motions, knots, strict=True)
            ]
        )
        # |p| < 6 (normal draws): a few roundings of ε|p| apart.
        np.testing.assert_allclose(at[k], reference, rtol=0, atol=8 * EPS * 6)
        np.testing.assert_allclose(table.positions(t), reference, rtol=0, atol=8 * EPS * 6)


def _positions(motion):
    return motion.positions if isinstance(motion, Waypoints) else motion.track.positions


def test_the_speed_bound_is_the_largest_segment_speed_and_sigma_is_unaffected():
    times = np.arange(0.0, 4.05, 0.1)
    fast = (times >= 2.0).astype(float)  # 1.0 m/s, then 1.3 m/s along a 3-4-5 direction
    speed = np.where(fast, 1.3, 1.0)
    distance = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.diff(times))])
    positions = np.outer(distance, [0.6, 0.8])
    motion = Recorded.of(times, positions)
    assert motion.speed_bound() == pytest.approx(1.3, rel=1e-12)

    class _Obstacle:
        radius, sigma, sigma_schedule, epsilon, p_d = 0.2, 0.1, None, 0.9, 0.9999
        covariance = axes_sigma = rotation = covariance_schedule = None

    obstacle = _Obstacle()
    obstacle.motion = motion
    mean_speed, sigma_rate = obstacle_rate_bounds([obstacle])
    assert mean_speed[0] == pytest.approx(1.3, rel=1e-12) and sigma_rate[0] == 0.0


def test_a_copied_or_pickled_scenario_keeps_its_tracks(tmp_path):
    path, walks = _spans_scenario(tmp_path)
    scenario = load_scenario(path)
    twin = copy.deepcopy(scenario)
    assert twin.obstacles[0].motion.track is scenario.obstacles[0].motion.track  # shared
    thawed = pickle.loads(pickle.dumps(scenario.obstacles))  # a worker's copy
    np.testing.assert_array_equal(thawed[0].motion.track.times, walks[0][:, 0])


# --------------------------------------------------------------------------- files and paths


def test_each_file_is_read_once_however_many_obstacles_name_it(tmp_path, monkeypatch):
    walks = _walks(6.0, count=40)
    _write_csv(tmp_path / "tracks.csv", walks)
    reads = []
    original = tracks_module._read_csv
    monkeypatch.setattr(tracks_module, "_read_csv", lambda *a: reads.append(a[0]) or original(*a))
    text = _scenario_text(_recorded("tracks.csv", walks), 6.0).replace("sigma: 0.05", "sigma: 0.01")
    scenario = parse_scenario_in(tmp_path, text)
    assert len(reads) == 1 and len(scenario.obstacles) == 40
    np.testing.assert_array_equal(scenario.obstacles[17].motion.track.positions, walks[17][:, 1:])


def parse_scenario_in(folder: Path, text: str):
    from stt_drake.config import parse_schema

    return parse_schema(text, base=folder)


def test_a_relative_file_is_found_beside_the_scenario_or_in_the_current_folder(
    tmp_path, monkeypatch
):
    walks = _walks(6.0)
    (tmp_path / "data").mkdir()
    _write_csv(tmp_path / "data" / "tracks.csv", walks)
    text = _scenario_text(_recorded("data/tracks.csv", walks))
    path = _write(tmp_path / "s.yaml", text)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert load_scenario(path).obstacles[0].motion.track.times.size == walks[0].shape[0]
    with pytest.raises(ScenarioError, match=r"scenario\.obstacles\[0\]\.motion\.file: no such"):
        parse_scenario(text)  # text without a path: relative to the current folder
    monkeypatch.chdir(tmp_path)
    assert len(parse_scenario(text).obstacles) == 3


def test_a_one_megabyte_csv_loads(tmp_path):
    """Correctness only; the load time is measured, not asserted (docs/guide/crowds.md)."""
    rng = np.random.default_rng(1)
    times = np.round(np.arange(0.0, 60.0, 0.1), 1)
    walks = {
        j: np.column_stack([times, *(rng.uniform(0.0, 5.0, 2)[:, None] + 0.0 * times)])
        for j in range(45)
    }
    path = _write_csv(tmp_path / "big.csv", walks)
    assert path.stat().st_size > 1_000_000
    text = _scenario_text(_recorded("big.csv", [3, 44]), 6.0).replace(
        "max_center_speed: 1.4", "max_center_speed: 0.5"
    )
    text = text.replace("start: [0.5, 0.5]", "start: [-3.0, -3.0]").replace(
        "target: [4.5, 4.5]", "target: [-3.0, 9.0]"
    )
    scenario = parse_scenario_in(tmp_path, text)
    for obstacle, j in zip(scenario.obstacles, (3, 44), strict=True):
        np.testing.assert_array_equal(obstacle.motion.track.times, times)
        np.testing.assert_array_equal(obstacle.motion.track.positions, walks[j][:, 1:])


def test_a_3d_track_reads_from_csv_and_npz_alike(tmp_path):
    times = np.arange(0.0, 1.05, 0.1)
    positions = np.column_stack([times, 2.0 * times, 3.0 - times])
    rows = [
        f"{float(t)!r},7,{float(x)!r},{float(y)!r},{float(z)!r}"
        for t, (x, y, z) in zip(times, positions, strict=True)
    ]
    (tmp_path / "t.csv").write_text("\n".join(["t,id,x,y,z", *rows]) + "\n")
    np.savez(tmp_path / "t.npz", t=times, id=np.full(times.size, 7), position=positions)
    for name in ("t.csv", "t.npz"):
        file = tracks_module.read_track_file(tmp_path / name, "f")
        track = tracks_module.track_from_file(file, 7, 3, "m")
        np.testing.assert_array_equal(track.times, times)
        np.testing.assert_array_equal(track.positions, positions)
        assert Recorded.of(track.times, track.positions).speed_bound() == pytest.approx(
            np.sqrt(6.0),
            rel=1e-12,  # ‖(1, 2, −1)‖ m/s
        )


# --------------------------------------------------------------------------- bad files


def _bad_csv(tmp_path: Path, rows: list[str], header: str = "t,id,x,y") -> str:
    (tmp_path / "bad.csv").write_text("\n".join([header, *rows]) + "\n")
    return "bad.csv"


GOOD_ROWS = ["0.0,0,4.0,2.0", "0.1,0,4.0,2.1", "0.2,0,4.0,2.2"]

BAD_FILES = {
    "missing file": (lambda p: "nope.csv", ".motion.file", "no such track file"),
    "missing id": (lambda p: _bad_csv(p, GOOD_ROWS), ".motion.id", "not a track id"),
    "NaN": (
        lambda p: _bad_csv(p, [*GOOD_ROWS, "0.3,0,nan,2.3"]),
        ".motion.file",
        "must be finite",
    ),
    "decreasing time": (
        lambda p: _bad_csv(p, ["0.0,0,4,2", "0.2,0,4,2", "0.1,0,4,2"]),
        ".motion.id",
        "increase strictly",
    ),
    "repeated time": (
        lambda p: _bad_csv(p, ["0.0,0,4,2", "0.1,0,4,2", "0.1,0,4,3"]),
        ".motion.id",
        "a repeated time is refused",
    ),
    "wrong dimension": (
        lambda p: _bad_csv(p, ["0.0,0,4,2,1", "0.1,0,4,2,1"], "t,id,x,y,z"),
        ".motion.file",
        "3D positions; this scenario is 2D",
    ),
    "one sample": (lambda p: _bad_csv(p, ["0.0,0,4,2"]), ".motion.id", "at least 2"),
    "wrong header": (
        lambda p: _bad_csv(p, GOOD_ROWS, "time,id,x,y"),
        ".motion.file",
        "header t,id,x,y",
    ),
    "not numbers": (
        lambda p: _bad_csv(p, [*GOOD_ROWS, "0.3,0,four,2"]),
        ".motion.file",
        "numbers separated by commas",
    ),
    "gap": (
        lambda p: _bad_csv(p, [*GOOD_ROWS, "0.3,0,4,2.3", "2.0,0,4,2.4"]),
        ".motion.id",
        "split the track into two ids",
    ),
    "every track after the run (another clock)": (
        lambda p: _bad_csv(p, ["100.0,0,4,2", "100.1,0,4,2"]),
        ".motion.file",
        "every recorded track starts after the run",
    ),
    "ends before the run": (
        lambda p: _bad_csv(p, ["-2.0,0,4,2", "-1.9,0,4,2"]),
        ".motion.id",
        "ends before the run starts",
    ),
    "npz without position": (
        lambda p: np.savez(p / "bad.npz", t=np.zeros(2), id=np.zeros(2)) or "bad.npz",
        ".motion.file",
        "missing: position",
    ),
    "other format": (lambda p: "tracks.txt", ".motion.file", "must be a .csv"),
}


@pytest.mark.parametrize(
    ("motion", "field"),
    [("!Recorded {file: t.csv}", "id"), ("!Recorded {id: 3}", "file")],
)
def test_a_recorded_motion_must_name_its_file_and_id(motion, field):
    with pytest.raises(
        ScenarioError, match=rf"scenario\.obstacles\[0\]\.motion\.{field}: required"
    ):
        parse_scenario(_scenario_text([motion]))


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_a_bad_track_file_is_refused_naming_the_field_and_the_rule(tmp_path, capsys, case):
    make, field, rule = BAD_FILES[case]
    file = make(tmp_path)
    track_id = 1 if case == "missing id" else 0
    text = _scenario_text([f"!Recorded {{file: {file}, id: {track_id}}}"], 6.0)
    path = _write(tmp_path / "s.yaml", text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert f"scenario.obstacles[0]{field}: " in message and rule in message, message
    code = main(["run", str(path), "--out", str(tmp_path / "out"), "--no-figures"])
    captured = capsys.readouterr()
    assert code == 2
    assert f"scenario.obstacles[0]{field}" in captured.err and rule in captured.err
    assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "out").exists()


def test_the_fixed_rate_tube_needs_tracks_that_cover_the_run(tmp_path):
    path, _ = _spans_scenario(tmp_path)
    rate = "max_center_speed: 1.4, update_rate_hz: 50"
    text = path.read_text().replace("max_center_speed: 1.4", rate)
    with pytest.raises(ScenarioError, match=r"obstacles\[0\]\.motion\.id: .*the fixed-rate tube"):
        load_scenario(_write(tmp_path / "rate.yaml", text))
    full = _walks(5.0, count=1)
    _write_csv(tmp_path / "full.csv", full)
    covered = _scenario_text(_recorded("full.csv", full), 5.0, rate=50.0)
    scenario = load_scenario(_write(tmp_path / "covered.yaml", covered))
    assert scenario.tube.update_rate_hz == 50.0


# --------------------------------------------------------------------------- the example


@pytest.mark.slow
def test_the_packaged_recorded_pedestrians_run_and_reach(tmp_path, monkeypatch, capsys):
    path = packaged_scenarios()["omni_recorded_pedestrians"]
    assert (path.parent / "omni_recorded_pedestrians.csv").stat().st_size <= 50_000
    scenario = load_scenario(path)
    spans = [o.motion.track.span for o in scenario.obstacles]
    assert len(spans) == 6 and all(first > 0.0 for first, _ in spans)  # all enter later
    speeds = [o.motion.speed_bound() for o in scenario.obstacles]
    assert all(0.9 < s < 1.5 for s in speeds), speeds  # 1.0-1.3 m/s walks, 0.04 m sway
    monkeypatch.chdir(tmp_path)  # by name, from an unrelated folder
    code = main(["run", "omni_recorded_pedestrians", "--out", str(tmp_path / "o"), "--no-figures"])
    assert code == 0, capsys.readouterr().out


def test_the_wheel_ships_every_track_file_a_packaged_scenario_names():
    """The package data patterns (pyproject.toml) cover each recorded track file beside a
    packaged scenario, so an installed wheel finds it (tests/test_packaging.py builds one)."""
    project = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    patterns = project["tool"]["setuptools"]["package-data"]["stt_drake.diagrams"]
    named = {
        obstacle.motion.file
        for path in packaged_scenarios().values()
        for obstacle in load_scenario(path).obstacles
        if isinstance(obstacle.motion, Recorded) and obstacle.motion.file  # not a drawn crowd
    }
    assert named, "no packaged scenario names a track file"
    for file in named:
        assert any(fnmatch.fnmatch(file, pattern) for pattern in patterns), file


@pytest.mark.slow
def test_campaigns_and_draws_read_tracks_beside_the_scenario_from_any_folder(
    tmp_path, monkeypatch
):
    """The worker processes of a campaign and of ``compare --draws`` get the scenario's
    folder with its text: its track files are found from any working folder."""
    folder = tmp_path / "scenarios"
    folder.mkdir()
    packaged = Path(__file__).resolve().parents[2] / "diagrams"
    text = (packaged / "omni_recorded_pedestrians.yaml").read_text()
    text = text.replace("duration: 25.0", "duration: 2.0") + (
        "random_obstacles: {count: 1, seed: 3, region_min: [2.0, 0.0], region_max: [3.0, 1.0],"
        " radius: 0.2, sigma_range: [0.05, 0.05], epsilon_range: [0.9, 0.9], p_d: 0.9999}\n"
    )
    (folder / "walkers.yaml").write_text(text)
    (folder / "omni_recorded_pedestrians.csv").write_bytes(
        (packaged / "omni_recorded_pedestrians.csv").read_bytes()
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    scenario = str(folder / "walkers.yaml")
    common = ["--runs", "2", "--workers", "1", "--no-progress", "--no-figures"]
    # 2 s do not reach the target (exit 1, a failed draw); a track not found would be 2
    assert main(["campaign", scenario, "--kind", "randomisation", *common, "--out", "c"]) == 1
    records = [json.loads(line) for line in Path("c/runs.jsonl").read_text().splitlines()]
    assert [r["status"] for r in records] == ["simulated", "simulated"]
    draws = ["--controllers", "stt", "--draws", "1", "--workers", "1", "--out", "d"]
    assert main(["compare", scenario, *draws]) == 0
    assert json.loads(Path("d/draws.jsonl").read_text())["status"] == "simulated"
