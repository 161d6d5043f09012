"""The end-to-end campaign (issue 14): truth + sensor + tracker + tube + controller + plant
simulated per run, collisions counted against the TRUE obstacles, the belief's calibration
measured — and a deliberately overconfident tracker caught by it."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from stt_drake.campaign import CampaignError, CampaignSpec, read_records, run_campaign
from stt_drake.campaign.folder import record_line

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"

SCENARIO = """
name: short_tracked
start: [0.0, 0.0]
initial_set_radius: 0.3
target: [2.5, 0.0]
target_set_radius: 0.3
duration: 3.0
log_period: 0.05
tube: {{r_min: 0.21, r_max: 0.27, k1: 0.9, k2: 0.4, k3: 0.4, max_center_speed: 1.0}}
controller: {{kappa: [8.0]}}
perception:
  process_noise_density: 0.01
  sensor_period: 0.1
  noise_sigma: 0.05
  dropout_probability: 0.1
  initial_velocity_sigma: 0.3
  track_timeout: 0.5
{tracker}
obstacles:
  - motion: !ConstantVelocity {{start: [1.3, 0.9], velocity: [0.0, -0.2]}}
    radius: 0.15
    sigma: 0.05
    epsilon: 0.9
    p_d: 0.9999
"""
#: The tracker believes the sensor 10× better than it is (noise covariance understated ×10)
#: and the obstacle's motion 100× smoother.
OVERCONFIDENT = "  tracker_noise_sigma: 0.0158\n  tracker_process_density: 0.0001"


def campaign(tmp_path, name: str, tracker: str, runs: int, **options) -> dict:
    path = tmp_path / f"{name}.yaml"
    path.write_text(SCENARIO.format(tracker=tracker))
    spec = CampaignSpec(scenario=str(path), kind="end-to-end", runs=runs, seed=3)
    outcome = run_campaign(spec, tmp_path / name, workers=2, progress=False, **options)
    return outcome.summary


@pytest.mark.slow
def test_a_calibrated_tracker_is_calibrated_and_its_runs_hold(tmp_path):
    summary = campaign(tmp_path, "calibrated", "", 40)
    assert summary["kind"] == "end-to-end" and summary["simulated_runs"] == 40
    calibration = summary["calibration"]
    # 40 runs × ~55 tracked times, correlated within a run: a loose band around 0.95
    assert 0.88 < calibration["fraction_inside"] < 0.99
    # every guarantee held in most runs; the exceptions are the case below
    assert summary["guarantees_held_fraction"] is not None
    obstacle = summary["obstacles"][0]
    assert obstacle["verdict"] != "violated"
    assert set(obstacle) >= {
        "epsilon",
        "worst_collision_frequency",
        "clopper_pearson_lower_99",
        "clopper_pearson_upper_99",
        "verdict",
        "t_worst",
        "calibration_95",
        "tube",
    }
    written = json.loads((tmp_path / "calibrated" / "campaign.json").read_text())
    assert written["calibration"] == calibration
    assert (tmp_path / "calibrated" / "end_to_end.png").exists()


@pytest.mark.slow
def test_a_fast_approaching_level_set_is_recovered_from_and_reported(tmp_path):
    """Found by a calibrated campaign (run 33 of 400, campaign seed 4; 1 run in 440): the
    crossing obstacle's true centre wanders fast (q = 0.01 m²/s³) and blended corrections
    move its ε level set onto the tube faster than the tube can leave it (Theorem 3.2 (ii)
    needs it slower), so the centre margin goes negative: −0.064 at 1.77 s when found, with
    the tracker consuming every sample one period late (before issue 26); −0.028 at 1.65 s
    with samples consumed on time. The run must report it by name and recover (the episode
    ends) — not hide it, not stop."""
    from stt_drake.assembly import parse_scenario
    from stt_drake.run import simulate

    scenario = parse_scenario(SCENARIO.format(tracker=""), "short_tracked", seed=2455668279)
    metrics = simulate(scenario).metrics
    center = metrics["invariants"]["center_avoid_probability"]
    assert not center["holds"] and center["worst_margin"] < -1e-3
    assert metrics["stop_reason"] is None
    assert metrics["recovery"] and all(e["end_s"] is not None for e in metrics["recovery"])
    assert metrics["invariants"]["output_avoid_probability"]["holds"]


@pytest.mark.slow
def test_an_overconfident_tracker_is_caught(tmp_path):
    """≥ 300 runs with the tracker's noise covariance understated ×10: the campaign must
    come out violated or badly calibrated — proof that it can fail."""
    summary = campaign(tmp_path, "overconfident", OVERCONFIDENT, 300)
    calibration = summary["calibration"]
    violated = any(o["verdict"] == "violated" for o in summary["obstacles"])
    assert violated or calibration["clopper_pearson_upper_99"] < 0.9, calibration


@pytest.mark.slow
def test_a_resumed_campaign_keeps_its_runs(tmp_path):
    """... also runs without `stop_reason` and `stalls` (as an older version wrote them;
    signed here: records without a checksum are redone)."""
    first = campaign(tmp_path, "resumed", "", 6, figures=False)
    runs = tmp_path / "resumed" / "runs.jsonl"
    records = [json.loads(line) for line in runs.read_text().splitlines()]
    assert any(record["status"] == "simulated" for record in records)
    older = []
    for record in records:
        if record["status"] == "simulated":
            assert record["stop_reason"] is None or isinstance(record["stop_reason"], str)
            assert isinstance(record.pop("stalls"), list)
            record.pop("stop_reason")
        older.append(record_line(record))
    runs.write_text("".join(line + "\n" for line in older))
    lines = runs.read_text().splitlines()
    path = tmp_path / "resumed.yaml"
    spec = CampaignSpec(scenario=str(path), kind="end-to-end", runs=10, seed=3)
    outcome = run_campaign(spec, tmp_path / "resumed", workers=2, progress=False, resume=True)
    after = (tmp_path / "resumed" / "runs.jsonl").read_text().splitlines()
    assert after[: len(lines)] == lines and len(after) == 10
    assert outcome.summary["simulated_runs"] == 10
    assert first["calibration"]["tracked_times"] < outcome.summary["calibration"]["tracked_times"]


def test_end_to_end_needs_a_perception_section(tmp_path):
    path = tmp_path / "scripted.yaml"
    path.write_text(re.sub(r"perception:\n(  .*\n)*", "", SCENARIO.format(tracker="")))
    spec = CampaignSpec(scenario=str(path), kind="end-to-end", runs=2)
    with pytest.raises(CampaignError, match=r"scenario\.perception"):
        run_campaign(spec, tmp_path / "out", workers=1, progress=False)


@pytest.mark.slow
def test_dask_scheduler_gives_the_same_runs_as_the_local_pool(tmp_path):
    """The end-to-end kind on a real Dask scheduler (loopback, two worker processes): the
    same records and summary as the local pool, run for run."""
    from distributed import LocalCluster

    local = campaign(tmp_path, "local", "", 4, figures=False)
    path = tmp_path / "local.yaml"
    spec = CampaignSpec(scenario=str(path), kind="end-to-end", runs=4, seed=3)
    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        host="127.0.0.1",
        processes=True,
        dashboard_address=None,
    ) as cluster:
        outcome = run_campaign(
            spec,
            tmp_path / "dask",
            scheduler=cluster.scheduler_address,
            progress=False,
            figures=False,
        )
    records = read_records(tmp_path / "local" / "runs.jsonl").values()  # without checksums
    assert sorted(outcome.records, key=lambda r: r["run"]) == sorted(
        records, key=lambda r: r["run"]
    )
    for key in ("obstacles", "calibration", "guarantees_held_fraction"):
        assert outcome.summary[key] == local[key]


@pytest.mark.slow
def test_omni_tracked_run_that_broke_centre_avoidance_recovers():
    """Found by the 2 000-run end-to-end campaign of omni_tracked (run 980, campaign seed
    0; the only one of 2 000): with obstacle 0 (ε = 0.99) a blended correction moves its
    level set onto the tube faster than the tube leaves it; centre avoidance breaks by
    2e-3 at 1.82 s for 0.04 s, reported, recovered, and the robot still reaches."""
    from dataclasses import replace

    from stt_drake.assembly import load_scenario
    from stt_drake.run import simulate

    scenario = load_scenario(DIAGRAMS / "omni_tracked.yaml", seed=728248331)
    # That campaign ran before issue 26: the tracker then consumed every sample one sensor
    # period late whatever the latency (it read the sensor's state from before the update
    # of the same instant). Latency = one period now consumes sample k at (k + 1)·period,
    # as that run did, and reproduces it (worst margin equal to 1e-13). On time (the
    # file's latency 0) this run holds, by +3.9e-4 (measured), so the break is replayed
    # with the delay it was found with.
    perception = replace(scenario.perception, latency=scenario.perception.sensor_period)
    metrics = simulate(replace(scenario, perception=perception)).metrics
    center = metrics["invariants"]["center_avoid_probability"]
    assert not center["holds"] and -1e-2 < center["worst_margin"] < 0.0
    assert [e["obstacle"] for e in metrics["recovery"]] == [0]
    assert all(e["end_s"] is not None for e in metrics["recovery"])
    assert metrics["reached"] and metrics["invariants"]["output_avoid_probability"]["holds"]
