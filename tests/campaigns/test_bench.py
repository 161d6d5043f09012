"""Tests of `stt-drake bench` (stt_drake.bench): its workloads, its baseline and its
report. No timing assertions — only that every number is there, finite and consistent."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import ncx2

from stt_drake import bench
from stt_drake.cli.main import main
from stt_drake.core.probability import avoid_probability


@pytest.mark.parametrize("n", [2, 3])
def test_obstacle_fields_are_valid_tube_states(n):
    for worst in (False, True):
        law, center, belief = bench.obstacle_field(200, n, worst_case=worst)
        q = avoid_probability(center, belief.mean, belief.sigma, belief.radius + law.r_min)
        assert np.all(q > belief.epsilon)  # the centre is a valid tube state
        evaluation = law.evaluate(center, belief)
        exact = law.evaluate(center, belief, prune=False)
        if worst:  # every obstacle in its avoidance layer, none prunable
            assert np.all(q <= belief.p_d)
            np.testing.assert_array_equal(evaluation.quantile_distance, exact.quantile_distance)
        else:  # the typical field keeps the scenario's density: mostly far obstacles
            assert np.sum(evaluation.quantile_distance != exact.quantile_distance) > 150


@pytest.mark.parametrize("n", [2, 3])
def test_baseline_is_the_same_tube_law(n):
    # The scipy loop is an independent port of the law: it must agree with the kernel.
    law, center, belief = bench.obstacle_field(40, n, worst_case=True, seed=2)
    rate, radius, q, d_hat, theta = bench.baseline_tube_step(law, center, belief)
    evaluation = law.evaluate(center, belief)
    lam = np.sum((center - belief.mean) ** 2, axis=1) / belief.sigma**2
    np.testing.assert_allclose(
        q, ncx2.sf(((belief.radius + law.r_min) / belief.sigma) ** 2, n, lam), atol=1e-12
    )
    np.testing.assert_allclose(evaluation.avoid_probability, q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(evaluation.theta, theta, rtol=1e-9)
    np.testing.assert_allclose(evaluation.quantile_distance + belief.radius,
                               d_hat + belief.radius, rtol=1e-10)
    np.testing.assert_allclose(evaluation.center_rate, rate, rtol=1e-8)
    assert evaluation.radius == pytest.approx(radius, rel=1e-10)


def test_time_call_reports_median_and_spread():
    calls = []
    timing = bench.time_call(lambda: calls.append(1), repeats=3, min_time=1e-4)
    assert timing["repeats"] == 3 and timing["calls_per_repeat"] >= 1
    assert 0.0 < timing["min"] <= timing["median"] <= timing["max"]
    assert timing["iqr"] >= 0.0
    assert len(calls) >= 1 + 3 * timing["calls_per_repeat"]  # warm-up included


def test_missing_scenario_is_not_available():
    assert bench.bench_closed_loop("no_such_scenario", repeats=1) == {
        "available": False,
        "reason": "no_such_scenario.yaml not found",
    }


@pytest.mark.slow
def test_bench_json_report(tmp_path, capsys):
    code = main([
        "bench", "--json", "--repeats", "2", "--loop-repeats", "1", "--loop-duration", "1.0",
        "--counts", "10", "50", "--out", str(tmp_path), "--campaign-scale", "0.001",
    ])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    # one campaign of each kind on one worker; at scale 0.001: 2, 1 and 1 runs
    campaigns = result["details"]["campaigns"]
    assert {kind: row["runs"] for kind, row in campaigns.items()} == {
        "true-obstacles": 2, "randomisation": 1, "end-to-end": 1,
    }
    for kind, row in campaigns.items():
        assert row["wall_s"] > 0.0
        assert result["campaign_runs_per_core_second"][kind] == pytest.approx(
            row["runs"] / row["wall_s"]
        )
    for key in ("tube_step_us", "baseline_tube_step_us", "speedup_vs_baseline",
                "worst_case_tube_step_us", "controller_us", "realtime_factor", "targets"):
        assert key in result
    # full covariances (issue 13): one row per dimension, 50 obstacles, typical field
    anisotropic = result["tube_step_us"].pop("anisotropic")
    assert set(anisotropic) == {"2d", "3d"}
    assert all(set(row) == {"50"} and row["50"] > 0 for row in anisotropic.values())
    assert {"anisotropic_tube_step_50_2d_us", "anisotropic_tube_step_50_3d_us"} <= set(
        result["targets"]
    )
    # the Kalman tracker (issue 14): one row per dimension, 50 tracks
    tracker = result["tracker_update_us"]
    assert set(tracker) == {"2d", "3d"}
    assert all(set(row) == {"50"} and row["50"] > 0 for row in tracker.values())
    assert {"tracker_update_50_2d_us", "tracker_update_50_3d_us"} <= set(result["targets"])
    for row in result["details"]["tracker_update"].values():  # the default tracker's cost too
        assert row["monitored_update_us"]["median"] > 0.0
        assert row["monitored_step_us"]["median"] > 0.0
    # the guide (issue 24): one replan at 50 obstacles per dimension, and its closed loop
    plans = result["details"]["guide_plan"]
    for n in ("2d", "3d"):
        assert plans[n]["count"] == 50
        assert result["guide_plan_ms"][n] == {"50": plans[n]["median"]}
        assert 0.0 < plans[n]["median"] <= plans[n]["p99"]
        assert {f"guide_plan_ms_median_{n}", f"guide_plan_ms_p99_{n}"} <= set(result["targets"])
    guided = result["details"]["guided_loop"]
    assert result["guided_over_unguided"] == guided["ratio"] > 0.0
    assert set(guided["ratios"]) == {str(seed) for seed in range(8)}
    assert guided["worst_ratio"] == min(guided["ratios"].values()) <= guided["ratio"]
    for table in ("tube_step_us", "baseline_tube_step_us", "speedup_vs_baseline"):
        assert set(result[table]) == {"2d", "3d"}
        for dimension in ("2d", "3d"):
            assert set(result[table][dimension]) == {"10", "50"}
            assert all(np.isfinite(v) and v > 0 for v in result[table][dimension].values())
    for dimension in ("2d", "3d"):
        for count in ("10", "50"):
            ratio = (result["baseline_tube_step_us"][dimension][count]
                     / result["tube_step_us"][dimension][count])
            assert result["speedup_vs_baseline"][dimension][count] == pytest.approx(ratio)
    assert set(result["controller_us"]) == {"stage1", "stage2"}
    loops = result["details"]["closed_loop"]
    for name in bench.SCENARIOS:
        loop = loops[name]
        if loop["available"]:
            assert loop["holds"]
            assert loop["sim_time_s"] == pytest.approx(1.0)
            assert result["realtime_factor"][name] == loop["realtime_factor"] > 0.0
            assert loop["derivative_evaluations_per_s"] > 0.0
            # the loop's systems do work the floor's do not: more wall time per evaluation
            per_evaluation = 1e6 / loop["derivative_evaluations_per_s"]
            floor = result["details"]["drake_floor"]["us_per_derivative_evaluation"]
            assert result["over_drake_floor"][name] == pytest.approx(per_evaluation / floor)
            assert result["over_drake_floor"][name] > 1.0
        else:
            assert result["realtime_factor"][name] == "not available"
        fixed = loops[bench.fixed_rate_name(name)]  # the same loop with a 100 Hz tube
        if fixed["available"]:
            assert fixed["holds"]
            assert fixed["sim_time_s"] == pytest.approx(1.0)
            ratio = fixed["realtime_factor"] / loop["realtime_factor"]
            assert result["fixed_rate_over_continuous"][name] == pytest.approx(ratio)
    assert set(result["targets"]) >= {"tube_step_50_2d_us", "speedup_50_3d",
                                      "controller_stage1_us"}
    assert (tmp_path / "tube_step_scaling.png").stat().st_size > 1000


@pytest.mark.slow
def test_bench_table_and_bad_input(tmp_path, capsys):
    code = main(["bench", "--repeats", "1", "--loop-repeats", "1", "--loop-duration", "0.5",
                 "--counts", "10", "--out", str(tmp_path), "--no-campaigns"])
    assert code == 0
    out = capsys.readouterr().out
    assert "one tube step" in out and "controller evaluation" in out and "closed loop" in out
    assert "one campaign of each kind" not in out
    assert main(["bench", "--repeats", "0"]) == 2
    for scale in ("0", "-1", "nan"):
        assert main(["bench", "--campaign-scale", scale]) == 2
    assert "--campaign-scale must be a number > 0" in capsys.readouterr().err


def test_profile_lists_functions_by_own_time():
    profile = bench.profile_closed_loop("omni_cluttered_50", duration=0.3, top=10)
    assert profile["available"] and len(profile["top"]) == 10
    shares = [row["own_share"] for row in profile["top"]]
    assert shares == sorted(shares, reverse=True) and 0.0 < sum(shares) <= 1.0
    assert any("stt_drake" in row["function"] or ".py:" in row["function"]
               for row in profile["top"])
    assert not bench.profile_closed_loop("no_such_scenario")["available"]


def test_the_drake_floor_times_the_omni_loops_shape():
    """Five Python systems in a chain, the tube's and the plant's with continuous state,
    integrated at the fixed step: µs per derivative evaluation, spread ordered."""
    from stt_drake.bench.floor import DIMENSION, STEP, _floor_diagram, bench_drake_floor

    diagram = _floor_diagram()
    assert len(diagram.GetSystems()) == 5
    assert diagram.CreateDefaultContext().num_continuous_states() == DIMENSION + 3
    floor = bench_drake_floor(repeats=2, duration=50 * STEP)
    assert 0.0 < floor["min"] <= floor["us_per_derivative_evaluation"] <= floor["max"]
    assert floor["repeats"] == 2 and floor["systems"] == 5
