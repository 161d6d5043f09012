"""`stt-drake campaign`: certification, a check that can fail, Dask, resume, failing draws.

References are independent of the code under test: collision probabilities from
``scipy.stats.ncx2`` directly, interval bounds from ``scipy.stats.binomtest``, seeds from
``numpy.random.SeedSequence.spawn``, replays through ``stt-drake run``.
"""

from __future__ import annotations

import copy
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from distributed import LocalCluster
from scipy.stats import binom, binomtest, ncx2

from stt_drake.assembly import load_scenario
from stt_drake.campaign import (
    CLOSED_LOOP_FILE,
    CampaignSpec,
    ClosedLoop,
    read_records,
    run_campaign,
    run_seed,
    sample_true_obstacles,
    sample_xi,
)
from stt_drake.campaign.folder import record_line
from stt_drake.cli.main import main
from stt_drake.run import simulate

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"
RANDOM = ROOT / "tests" / "data" / "random_small.yaml"
#: Enough for every case-1 obstacle: ε = 0.99 with no collision needs 1444 runs at the
#: simultaneous level, the tube's 1.1e-3 peak at obstacle 0 about 2000.
CASE1_RUNS = 4000
RANDOM_RUNS = 10
SUMMARY_KEYS = {"scenario", "kind", "runs", "seed", "wall_time_s", "holds", "obstacles"}
OBSTACLE_KEYS = {
    "epsilon",
    "worst_collision_frequency",
    "t_worst",
    "clopper_pearson_upper_99",
    "clopper_pearson_lower_99",
    "verdict",
}


def _console_script() -> str:
    return str(Path(sys.executable).parent / "stt-drake")


def _summary(out: Path) -> dict:
    return json.loads((out / "campaign.json").read_text())


def _records(out: Path) -> list[dict]:
    """Every line of runs.jsonl (duplicates kept), by run, without its checksum."""
    lines = (out / "runs.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    assert all(isinstance(r.pop("sha256"), str) for r in records)  # every line is signed
    return sorted(records, key=lambda r: r["run"])


def _without_wall_time(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k != "wall_time_s"}


def _model_collision_probability(loop: ClosedLoop) -> dict[str, np.ndarray]:
    """P(‖x − O_j‖ < R) with ‖x − O_j‖²/σ² ~ χ'²_n(‖x − μ_j‖²/σ²), straight from scipy."""
    n = loop.output.shape[1]
    reach = {
        "output": (loop.output, loop.obstacle_radius),
        "tube": (loop.center, loop.obstacle_radius + loop.radius[:, None]),
    }
    result = {}
    for check, (point, limit) in reach.items():
        offset = np.sum((point[:, None, :] - loop.mean) ** 2, axis=2) / loop.sigma**2
        result[check] = ncx2.cdf((limit / loop.sigma) ** 2, n, offset)
    return result


def _assert_frequencies_match_the_belief(loop: ClosedLoop, records: list[dict]) -> None:
    """Every count k_j(t) lies in the central Binomial(n, p_j(t)) region that holds at
    every (check, obstacle, time) jointly with probability ≥ 99.9 %."""
    runs, steps = len(records), len(loop.t)
    model = _model_collision_probability(loop)
    tail = 0.001 / (2 * len(model) * loop.count * steps)  # α/(2F), each side
    for check, probability in model.items():
        counts = np.zeros((steps, loop.count), dtype=int)
        for record in records:
            for j, ranges in enumerate(record[check]):
                for start, stop in ranges:
                    counts[start:stop, j] += 1
        low = binom.ppf(tail, runs, probability)
        high = binom.isf(tail, runs, probability)
        assert np.all((low <= counts) & (counts <= high)), check
        assert counts.max() > 0, check  # the comparison is not vacuous


# --------------------------------------------------------------------------- true obstacles


@pytest.fixture(scope="module")
def case1(tmp_path_factory):
    out = tmp_path_factory.mktemp("case1")
    code = main(
        [
            "campaign",
            str(CASE1),
            "--runs",
            str(CASE1_RUNS),
            "--workers",
            "2",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    return code, out


@pytest.mark.slow
def test_case1_campaign_certifies_every_obstacle(case1, capsys):
    code, out = case1
    assert code == 0
    summary = _summary(out)
    assert set(summary) >= SUMMARY_KEYS
    assert summary["kind"] == "true-obstacles" and summary["runs"] == CASE1_RUNS
    assert summary["scenario"] == "omni_hardware_case1" and summary["seed"] == 0
    assert summary["holds"] is True
    assert summary["closed_loop"]["simulations"] == 1
    scenario = load_scenario(CASE1)
    assert [o["epsilon"] for o in summary["obstacles"]] == [o.epsilon for o in scenario.obstacles]
    steps = len(ClosedLoop.load(out / CLOSED_LOOP_FILE).t)
    family = 2 * len(scenario.obstacles) * steps
    assert summary["procedure"]["family_size"] == family
    confidence = 1 - 0.01 / family
    for obstacle in summary["obstacles"]:
        for record in (obstacle, obstacle["tube"]):
            assert set(record) >= OBSTACLE_KEYS
            assert record["verdict"] == "certified"
            allowed = 1 - obstacle["epsilon"]
            assert record["worst_collision_frequency"] <= record["clopper_pearson_upper_99"]
            assert record["clopper_pearson_upper_99"] <= allowed
            k = round(record["worst_collision_frequency"] * CASE1_RUNS)
            reference = binomtest(k, CASE1_RUNS).proportion_ci(
                confidence_level=confidence, method="exact"
            )
            assert record["clopper_pearson_upper_99"] == pytest.approx(reference.high, rel=1e-6)
            assert 0 <= record["t_worst"] <= scenario.duration
    assert (out / "collision_frequency.png").stat().st_size > 0


@pytest.mark.slow
def test_case1_runs_are_one_line_each_and_replayable_from_their_seed(case1):
    _, out = case1
    records = _records(out)
    assert [r["run"] for r in records] == list(range(CASE1_RUNS))
    spawned = np.random.SeedSequence(0).spawn(CASE1_RUNS)
    for record in records[:: CASE1_RUNS // 20]:
        assert record["seed"] == run_seed(0, record["run"])
        assert record["seed"] == int(spawned[record["run"]].generate_state(1)[0])
    loop = ClosedLoop.load(out / CLOSED_LOOP_FILE)
    collided = next(r for r in records if any(r["tube"]))
    replay = sample_true_obstacles(loop, "static", 2.0, [(collided["run"], collided["seed"])])
    assert replay == [collided]


def test_case1_collision_frequencies_match_the_belief(case1):
    """The sampled collisions reproduce the noncentral χ² probability at every time."""
    _, out = case1
    _assert_frequencies_match_the_belief(ClosedLoop.load(out / CLOSED_LOOP_FILE), _records(out))


@pytest.mark.slow
def test_ornstein_uhlenbeck_true_obstacles_keep_the_marginal_and_wander(case1, tmp_path):
    _, out = case1
    loop = ClosedLoop.load(out / CLOSED_LOOP_FILE)
    spec = CampaignSpec(scenario=str(CASE1), runs=2000, seed=3, motion="ou", tau=0.5)
    outcome = run_campaign(spec, tmp_path, workers=2, progress=False, closed_loop=loop)
    assert outcome.summary["true_obstacle_motion"] == "ou"
    assert outcome.summary["ou_tau_s"] == 0.5
    _assert_frequencies_match_the_belief(loop, outcome.records)
    # a wandering obstacle collides in more, shorter episodes than a frozen one
    episodes = [sum(len(x) for x in r["tube"]) for r in outcome.records]
    frozen = [sum(len(x) for x in r["tube"]) for r in _records(out)[:2000]]
    assert max(episodes) > max(frozen)


def test_ornstein_uhlenbeck_paths_are_stationary_with_the_right_correlation():
    times = np.arange(0.0, 4.0, 0.02)
    tau = 0.5
    xi = sample_xi(list(range(4000)), times, (1, 2), "ou", tau)[:, :, 0, :]
    assert xi.shape == (4000, len(times), 2)
    for k in (0, len(times) // 2, len(times) - 1):
        assert np.var(xi[:, k]) == pytest.approx(1.0, abs=0.08)
        assert abs(np.mean(xi[:, k])) < 0.06
    lag = 10
    correlation = np.mean(xi[:, 50] * xi[:, 50 + lag])
    assert correlation == pytest.approx(np.exp(-lag * 0.02 / tau), abs=0.05)
    static = sample_xi([1, 2], times, (1, 2), "static", tau)
    assert np.all(static[:, 0] == static[:, -1])


@pytest.mark.slow
def test_a_tube_that_ignores_epsilon_is_caught(tmp_path):
    """Simulate case 1 with every ε = 0.5 and no buffer (r_min = 0.02), then check the
    same closed loop against the scenario's real ε: the campaign must call it violated."""
    scenario = load_scenario(CASE1)
    wrong = copy.deepcopy(scenario)
    for obstacle in wrong.obstacles:
        obstacle.epsilon = 0.5
    wrong.tube.r_min = 0.02
    loop = ClosedLoop.from_log(simulate(wrong).log, epsilon=[o.epsilon for o in scenario.obstacles])
    assert np.all(loop.epsilon == [o.epsilon for o in scenario.obstacles])
    spec = CampaignSpec(scenario=str(CASE1), runs=600, seed=1)
    outcome = run_campaign(spec, tmp_path, workers=2, progress=False, closed_loop=loop)
    summary = outcome.summary
    assert summary["holds"] is False
    output = [o for o in summary["obstacles"] if o["verdict"] == "violated"]
    tube = [o for o in summary["obstacles"] if o["tube"]["verdict"] == "violated"]
    assert output and len(tube) >= 2
    for o in output:
        assert o["clopper_pearson_lower_99"] > 1 - o["epsilon"]
    model = _model_collision_probability(loop)
    for o in tube:  # the belief agrees this tube breaks ε: the campaign is not noise
        assert model["tube"][:, o["index"]].max() > 1 - o["epsilon"]


# --------------------------------------------------------------------------- randomisation


def _randomisation_args(out: Path, *extra: str) -> list[str]:
    return [
        "campaign",
        str(RANDOM),
        "--kind",
        "randomisation",
        "--runs",
        str(RANDOM_RUNS),
        "--seed",
        "0",
        "--out",
        str(out),
        "--no-progress",
        *extra,
    ]


@pytest.fixture(scope="module")
def randomised(tmp_path_factory):
    out = tmp_path_factory.mktemp("random")
    code = main(_randomisation_args(out, "--workers", "2"))
    return code, out


@pytest.mark.slow
def test_randomisation_reports_fractions_and_keeps_failing_draws(randomised):
    code, out = randomised
    summary = _summary(out)
    records = _records(out)
    assert [r["run"] for r in records] == list(range(RANDOM_RUNS))
    assert set(summary) >= SUMMARY_KEYS and summary["kind"] == "randomisation"
    simulated = [r for r in records if r["status"] == "simulated"]
    failing = [r for r in simulated if not (r["holds"] and r["reached"])]
    assert failing, "the test scenario is designed so that some draws miss the target"
    assert len(failing) < len(simulated), "... and others reach it"
    assert code == 1 and summary["holds"] is False
    assert summary["failed_runs"] == len(failing)
    assert [f["run"] for f in summary["failures"]] == [r["run"] for r in failing]
    assert sorted(p.name for p in (out / "failures").iterdir()) == [
        f"run_{r['run']:06d}.yaml" for r in failing
    ]
    reached = sum(r["reached"] for r in simulated) / len(simulated)
    assert summary["guarantees"]["reach_and_stay"]["held_fraction"] == reached
    for name, record in summary["guarantees"].items():
        if name == "reach_and_stay":
            continue
        margins = [r["invariants"][name]["worst_margin"] for r in simulated]
        assert record["worst_margin"] == min(margins)
        held = np.mean([r["invariants"][name]["holds"] for r in simulated])
        assert record["held_fraction"] == pytest.approx(held)
    t_c = [r["t_tube_in_target"] for r in simulated if r["t_tube_in_target"] is not None]
    assert summary["t_tube_in_target"]["median"] == pytest.approx(np.median(t_c))
    assert summary["t_tube_in_target"]["max"] == max(t_c)
    assert (out / "randomisation.png").stat().st_size > 0
    # Reaching and stalling: every simulated record carries its stop reason and stalls.
    for record in simulated:
        assert record["stop_reason"] is None or isinstance(record["stop_reason"], str)
        assert isinstance(record["stalls"], list)
        stalled_to_end = bool(record["stalls"]) and record["stalls"][-1]["end_s"] is None
        named = (record["stop_reason"] or "").startswith("stall:")
        assert named == (stalled_to_end and not record["reached"])
    assert summary["reach_rate"] == reached
    reached_times = [r["t_tube_in_target"] for r in simulated if r["reached"]]
    assert summary["t_tube_in_target_percentiles"] == {
        key: pytest.approx(np.percentile(reached_times, q))
        for key, q in (("p50", 50), ("p90", 90), ("p99", 99))
    }
    stalled = [r for r in simulated if any(s["end_s"] is None for s in r["stalls"])]
    assert summary["stall_rate"] == len(stalled) / len(simulated)


@pytest.mark.slow
def test_a_failing_draw_replays_from_its_yaml_and_from_its_seed(randomised, tmp_path):
    _, out = randomised
    failing = next(r for r in _records(out) if r["status"] == "simulated" and not r["reached"])
    yaml_path = out / "failures" / f"run_{failing['run']:06d}.yaml"
    replays = {
        "yaml": ["run", str(yaml_path)],
        "seed": ["run", str(RANDOM), "--seed", str(failing["seed"])],
    }
    for label, args in replays.items():
        code = main([*args, "--out", str(tmp_path / label), "--no-figures"])
        assert code == 1, label
        metrics = json.loads((tmp_path / label / "metrics.json").read_text())
        assert metrics["scenario"] == "random_small"
        assert metrics["reached"] == failing["reached"]
        assert metrics["t_tube_in_target"] == failing["t_tube_in_target"]
        assert metrics["invariants"] == failing["invariants"], label


@pytest.mark.slow
def test_dask_scheduler_gives_the_same_runs_as_the_local_pool(randomised, tmp_path):
    _, local = randomised
    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        host="127.0.0.1",
        processes=True,
        dashboard_address=None,
    ) as cluster:
        out = tmp_path / "dask"
        code = main(_randomisation_args(out, "--scheduler", cluster.scheduler_address))
    assert code == 1
    assert _records(out) == _records(local)
    assert _without_wall_time(_summary(out)) == _without_wall_time(_summary(local))


@pytest.mark.slow
def test_killed_campaign_resumes_to_the_uninterrupted_summary(randomised, tmp_path):
    _, reference = randomised
    out = tmp_path / "resumed"
    process = subprocess.Popen(
        [_console_script(), *_randomisation_args(out, "--workers", "1")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    runs_file = out / "runs.jsonl"
    deadline = time.monotonic() + 300
    while not (runs_file.exists() and runs_file.read_text().count("\n") >= 1):
        assert process.poll() is None, "the campaign ended before it could be interrupted"
        assert time.monotonic() < deadline
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    done_before = len(read_records(runs_file))
    assert 1 <= done_before < RANDOM_RUNS

    assert main(_randomisation_args(out, "--workers", "2", "--resume")) == 1
    assert [r["run"] for r in _records(out)] == list(range(RANDOM_RUNS))
    assert _records(out) == _records(reference)
    assert _without_wall_time(_summary(out)) == _without_wall_time(_summary(reference))


@pytest.mark.slow
def test_a_count_range_field_is_randomised(tmp_path):
    """`count_range` draws the number of obstacles per run: a randomisation campaign takes
    it as a random field. 2 s is too short to reach the target (t_c ≈ 3.9 s)."""
    text = RANDOM.read_text().replace("count: 2", "count_range: [1, 3]")
    scenario = tmp_path / "count_range.yaml"
    scenario.write_text(text.replace("duration: 5.0", "duration: 2.0"))
    out = tmp_path / "out"
    args = ["campaign", str(scenario), "--kind", "randomisation", "--runs", "3"]
    code = main([*args, "--out", str(out), "--workers", "1", "--no-progress", "--no-figures"])
    assert code == 1
    summary = _summary(out)
    assert summary["kind"] == "randomisation" and summary["simulated_runs"] == 3
    assert summary["rejected_draws"] == 0 and summary["error_runs"] == 0
    assert summary["failed_runs"] == 3
    records = _records(out)
    assert [r["run"] for r in records] == [0, 1, 2]
    assert not any(r["reached"] for r in records)
    assert {r["obstacles"] for r in records} == {1, 2, 3}  # a count per draw, in [1, 3]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("field", "where"),
    [
        ("count: 1", "random_obstacles.count"),
        ("count_range: [1, 2]", "random_obstacles.count_range"),
    ],
)
def test_draws_that_break_the_assumptions_are_rejected_not_failed(field, where, tmp_path):
    """Obstacles drawn on top of the start can never meet the initial condition."""
    text = RANDOM.read_text()
    text = text.replace("region_min: [0.8, 0.8]", "region_min: [0.4, 0.4]")
    text = text.replace("region_max: [2.7, 2.7]", "region_max: [0.6, 0.6]")
    text = text.replace("count: 2", field)
    scenario = tmp_path / "crowded.yaml"
    scenario.write_text(text)
    out = tmp_path / "out"
    args = ["campaign", str(scenario), "--kind", "randomisation", "--runs", "2"]
    code = main([*args, "--out", str(out), "--workers", "1", "--no-progress", "--no-figures"])
    assert code == 1
    summary = _summary(out)
    assert summary["rejected_draws"] == 2 and summary["simulated_runs"] == 0
    assert summary["failed_runs"] == 0 and summary["error_runs"] == 0
    assert summary["holds"] is False
    records = _records(out)
    assert [r["status"] for r in records] == ["rejected", "rejected"]
    assert all(f"{where}: could not place" in r["reason"] for r in records)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["campaign", "nope.yaml", "--runs", "5"], "no such scenario file"),
        (["campaign", str(CASE1), "--runs", "0"], "--runs"),
        (["campaign", str(CASE1), "--runs", "5", "--ou-tau", "0"], "--ou-tau"),
        (["campaign", str(CASE1), "--runs", "5", "--workers", "0"], "--workers"),
        (
            ["campaign", str(CASE1), "--runs", "5", "--kind", "randomisation"],
            "scenario.random_obstacles",
        ),
    ],
)
def test_bad_input_exits_2_naming_the_field(args, message, tmp_path, capsys):
    assert main([*args, "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_randomisation_without_a_random_field_is_bad_input_even_if_run_0_is_rejected(
    tmp_path, capsys
):
    """A file with no random field whose fixed obstacle breaks the initial avoidance
    condition: before, run 0's rejected draw skipped the random-field check and every draw
    was rejected; the check now reads the parsed file, before anything is drawn."""
    blocked = tmp_path / "blocked.yaml"
    blocked.write_text(
        "start: [0.0, 0.0]\ninitial_set_radius: 0.5\ntarget: [4.0, 0.0]\n"
        "target_set_radius: 0.5\nduration: 2.0\n"
        "tube: {r_min: 0.1, r_max: 0.4, k1: 0.5, k2: 0.4, k3: 0.4, max_center_speed: 0.3}\n"
        "obstacles:\n"
        "  - motion: !ConstantVelocity {start: [0.05, 0.0], velocity: [0.0, 0.0]}\n"
        "    radius: 0.3\n    sigma: 0.1\n    epsilon: 0.9\n    p_d: 0.9999\n"
    )
    args = ["campaign", str(blocked), "--runs", "3", "--kind", "randomisation"]
    assert main([*args, "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "scenario.random_obstacles" in err and "needs a random_obstacles" in err
    assert not (tmp_path / "out" / "runs.jsonl").exists()


@pytest.mark.slow
def test_bad_scenario_field_exits_2_without_traceback(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(RANDOM.read_text().replace("r_min: 0.21", "r_min: 0.5"))
    completed = subprocess.run(
        [_console_script(), "campaign", str(bad), "--runs", "3", "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert completed.returncode == 2
    assert "scenario.tube.r_max" in completed.stderr
    assert "Traceback" not in completed.stderr + completed.stdout


def test_an_existing_campaign_needs_resume_and_the_same_spec(randomised, tmp_path, capsys):
    _, out = randomised
    copy_dir = tmp_path / "copy"
    copy_dir.mkdir()
    for name in ("campaign_spec.json", "runs.jsonl"):
        (copy_dir / name).write_bytes((out / name).read_bytes())
    assert main(_randomisation_args(copy_dir)) == 2
    assert "--resume" in capsys.readouterr().err
    other_seed = _randomisation_args(copy_dir, "--resume")
    other_seed[other_seed.index("--seed") + 1] = "1"
    assert main(other_seed) == 2
    assert "seed" in capsys.readouterr().err
    assert (copy_dir / "runs.jsonl").read_bytes() == (out / "runs.jsonl").read_bytes()


def test_records_of_an_older_version_without_stalls_are_kept_on_resume(randomised, tmp_path):
    """Run records without `stop_reason` and `stalls` (written before they existed) are
    valid: a resume keeps them (no malformed line, no run redone) and reads them as None
    and []. (Signed here: records of the versions before checksums are redone, see
    test_hostile_cli.)"""
    _, out = randomised
    old = tmp_path / "old"
    old.mkdir()
    (old / "campaign_spec.json").write_bytes((out / "campaign_spec.json").read_bytes())
    lines = []
    for record in _records(out):
        record.pop("stop_reason", None)
        record.pop("stalls", None)
        lines.append(record_line(record) + "\n")
    (old / "runs.jsonl").write_text("".join(lines))
    assert main(_randomisation_args(old, "--resume", "--no-figures")) == 1
    assert (old / "runs.jsonl").read_text() == "".join(lines)
    summary, reference = _summary(old), _summary(out)
    assert summary["malformed_lines"] == 0 and summary["stall_rate"] == 0.0
    ignored = {"wall_time_s", "stall_rate"}
    assert {k: v for k, v in summary.items() if k not in ignored} == {
        k: v for k, v in reference.items() if k not in ignored
    }


def test_a_torn_last_line_is_dropped_on_resume(tmp_path):
    runs = tmp_path / "runs.jsonl"
    runs.write_text('{"run": 0, "seed": 1}\n{"run": 1, "seed": 2}\n{"run": 2, "se')
    assert sorted(read_records(runs)) == [0, 1]
    assert runs.read_text() == '{"run": 0, "seed": 1}\n{"run": 1, "seed": 2}\n'


def test_extending_a_campaign_with_resume_equals_running_it_at_once(case1, tmp_path):
    """Resuming reuses the saved closed loop (no re-simulation) and only adds runs."""
    _, out = case1
    loop = ClosedLoop.load(out / CLOSED_LOOP_FILE)
    first = CampaignSpec(scenario=str(CASE1), runs=300, seed=4, motion="ou")
    options = {"workers": 1, "progress": False, "figures": False}
    run_campaign(first, tmp_path / "extended", closed_loop=loop, **options)
    longer = CampaignSpec(scenario=str(CASE1), runs=700, seed=4, motion="ou")
    extended = run_campaign(longer, tmp_path / "extended", resume=True, **options)
    at_once = run_campaign(longer, tmp_path / "at_once", closed_loop=loop, **options)
    assert extended.records == at_once.records
    assert _without_wall_time(extended.summary) == _without_wall_time(at_once.summary)
