"""Closed loops with full obstacle covariances (issue 13): diagrams/omni_anisotropic.yaml and
uav_anisotropic.yaml keep every guarantee, checked from the log independently of the
monitor (exact probabilities, and Monte Carlo at the worst samples), and the exact tube
passes where the isotropic inflation σ² = λ_max blocks the way."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from stt_drake.assembly import load_scenario
from stt_drake.core import anisotropic
from stt_drake.core.invariants import HOLDS_TOLERANCE
from stt_drake.run import simulate
from tests.conftest import DIAGRAMS

SCENARIOS = ["omni_anisotropic", "uav_anisotropic"]


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS)
def test_every_guarantee_holds_and_target_is_reached(run_scenario, name):
    result = run_scenario(name)
    metrics = result.metrics
    failed = {k: v for k, v in metrics["invariants"].items() if not v["holds"]}
    assert not failed, f"{name}: guarantees violated: {failed}"
    assert metrics["reached"] and metrics["stop_reason"] is None
    assert result.log.covariance is not None  # the run really used full covariances


def _margins(log, k: int) -> tuple[float, float, float]:
    """min_j (q_j − ε_j) at sample k for the centre (r_o + r_min), the tube ball (r_o + r)
    and the output (r_o), from the exact generalized chi-square probabilities."""
    belief = log.belief_at(k)
    c, r, y = log["center"][k], float(log["radius"][k]), log["output"][k]
    r_min = float(log["r_min"])
    worst = [np.inf, np.inf, np.inf]
    for j in range(belief.count):
        mean, covariance, r_o, eps = (
            belief.mean[j],
            belief.covariance[j],
            belief.radius[j],
            belief.epsilon[j],
        )
        worst[0] = min(
            worst[0], anisotropic.avoid_probability(c, mean, covariance, r_o + r_min) - eps
        )
        worst[1] = min(worst[1], anisotropic.avoid_probability(c, mean, covariance, r_o + r) - eps)
        worst[2] = min(worst[2], anisotropic.avoid_probability(y, mean, covariance, r_o) - eps)
    return tuple(worst)


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS)
def test_logged_run_meets_the_guarantees_by_recomputation(run_scenario, name):
    """Every logged sample: y in the tube, r > 0, and the three avoidance margins ≥ 0,
    recomputed from the logged belief (mean and Σ) with the exact probabilities; at the
    three samples with the smallest tube margin, Monte Carlo (4e5 draws of O_j ~ N(μ, Σ))
    agrees with the exact margin to 5 standard errors."""
    log = run_scenario(name).log
    tube_margins = []
    for k in range(len(log["t"])):
        c, r, y = log["center"][k], float(log["radius"][k]), log["output"][k]
        assert np.linalg.norm(y - c) < r and r > 0.0, f"y left the tube at t = {log['t'][k]}"
        margins = _margins(log, k)
        assert min(margins) > -HOLDS_TOLERANCE, f"t = {log['t'][k]}: margins {margins}"
        tube_margins.append(margins[1])
    rng = np.random.default_rng(13)
    draws = 400_000
    for k in np.argsort(tube_margins)[:3]:
        belief = log.belief_at(k)
        c, r = log["center"][k], float(log["radius"][k])
        for j in range(belief.count):
            factor = np.linalg.cholesky(belief.covariance[j])
            centres = belief.mean[j] + rng.standard_normal((draws, len(c))) @ factor.T
            frequency = np.mean(np.linalg.norm(centres - c, axis=1) >= belief.radius[j] + r)
            exact = anisotropic.avoid_probability(
                c, belief.mean[j], belief.covariance[j], belief.radius[j] + r
            )
            error = np.sqrt(max(exact * (1 - exact), 1e-12) / draws)
            assert abs(frequency - exact) <= 5 * error + 1e-6


def _inflated(name: str):
    """The scenario with every Σ_j replaced by the isotropic λ_max(Σ_j)·I (the safe stand-in
    a sigma-only tool would use)."""
    scenario = load_scenario(DIAGRAMS / f"{name}.yaml")
    belief = scenario.belief_at(0.0)
    obstacles = [
        replace(o, sigma=float(s), covariance=None, axes_sigma=None, rotation=None)
        for o, s in zip(scenario.obstacles, belief.sigma, strict=True)
    ]
    return replace(scenario, obstacles=obstacles)


@pytest.mark.slow
def test_the_exact_tube_passes_the_gap_the_inflated_one_cannot(run_scenario):
    """omni_anisotropic: the exact tube crosses the wall (x = 3 m) through the gap between
    the obstacles at y = 1.75 and 3.25 m; with Σ_j inflated to λ_max·I it never does (the
    gap's q_j < ε_j there) and does not cross the wall anywhere else either."""
    exact = run_scenario("omni_anisotropic").log
    inflated = simulate(_inflated("omni_anisotropic")).log
    assert inflated.covariance is None

    def crossings_in_gap(log) -> int:
        x, y = log["center"][:, 0], log["center"][:, 1]
        crossed = np.nonzero((x[:-1] < 3.0) & (x[1:] >= 3.0))[0]
        return int(np.sum(np.abs(y[crossed] - 2.5) < 0.75))

    assert crossings_in_gap(exact) == 1
    assert np.all(inflated["center"][:, 0] < 3.0)  # no crossing at all


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS)
def test_the_inflated_belief_does_not_reach_the_target(run_scenario, name):
    """Both scenarios: the exact tube reaches T; inflated to λ_max·I the way is shut and the
    (still safe) tube stalls in front of the obstacles until the end of the run, and the
    run names the stall."""
    assert run_scenario(name).metrics["reached"]
    inflated = simulate(_inflated(name)).metrics
    assert not inflated["reached"] and inflated["stop_reason"].startswith("stall:")
    assert inflated["stalls"][-1]["end_s"] is None
    assert all(v["holds"] for v in inflated["invariants"].values())


@pytest.mark.slow
def test_twenty_thousand_true_obstacle_runs_certify_every_obstacle(tmp_path):
    """Issue 13: true centres drawn from N(μ_j, Σ_j) (Cholesky of the logged Σ_j(t)),
    20 000 runs; every obstacle and both checks certified by the simultaneous 99 %
    Clopper-Pearson bound against 1 − ε_j."""
    import json

    from stt_drake.cli.main import main

    out = tmp_path / "campaign"
    code = main(
        [
            "campaign",
            str(DIAGRAMS / "omni_anisotropic.yaml"),
            "--runs",
            "20000",
            "--workers",
            "2",
            "--out",
            str(out),
            "--no-progress",
            "--no-figures",
        ]
    )
    assert code == 0
    summary = json.loads((out / "campaign.json").read_text())
    assert summary["runs"] == 20000 and summary["holds"] is True
    for obstacle in summary["obstacles"]:
        assert obstacle["verdict"] == "certified"
        assert obstacle["tube"]["verdict"] == "certified"
        assert obstacle["clopper_pearson_upper_99"] < obstacle["allowed_collision_probability"]
