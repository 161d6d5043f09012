"""Perception in the loop (issue 14): the scenario's `perception:` section, the tracker's
blended belief, and the tracked closed loop against the paper's guarantees."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from stt_drake.assembly import load_scenario, parse_scenario
from stt_drake.config import ScenarioError
from stt_drake.core.belief import GaussianBelief
from stt_drake.core.tracking import blend_beliefs
from stt_drake.run import simulate

DIAGRAMS = Path(__file__).resolve().parents[2] / "diagrams"


def belief(mean, covariance, active) -> GaussianBelief:
    return GaussianBelief(np.array(mean, float), np.array(covariance, float), np.array(active))


def test_blend_is_the_moment_matched_mixture_and_continuous():
    """w = 0 and 1 give the old and the new belief; in between the mean and covariance are
    those of the mixture (1 − w)N(old) + wN(new), checked against 4e5 samples of it; slots
    born or lost in between are the new belief's."""
    old = belief([[0.0, 0.0], [5.0, 5.0], [1.0, 1.0]], [np.eye(2) * 0.04] * 3, [1, 1, 0])
    new = belief(
        [[0.3, -0.1], [5.0, 5.2], [2.0, 2.0]],
        [[[0.01, 0.002], [0.002, 0.02]], np.eye(2) * 0.01, np.eye(2)],
        [1, 0, 1],
    )
    for w, expected in ((0.0, old), (1.0, new)):
        blended = blend_beliefs(old, new, w)
        np.testing.assert_allclose(blended.mean[0], expected.mean[0], atol=1e-15)
        np.testing.assert_allclose(blended.covariance[0], expected.covariance[0], atol=1e-15)
    blended = blend_beliefs(old, new, 0.3)
    rng = np.random.default_rng(3)
    count = 400_000
    pick = rng.uniform(size=count) < 0.3
    samples = np.where(
        pick[:, None],
        rng.multivariate_normal(new.mean[0], new.covariance[0], count),
        rng.multivariate_normal(old.mean[0], old.covariance[0], count),
    )
    # standard errors of a mean / covariance entry from 4e5 samples: ~3e-4 and ~1e-4
    np.testing.assert_allclose(blended.mean[0], samples.mean(axis=0), atol=2e-3)
    np.testing.assert_allclose(blended.covariance[0], np.cov(samples.T), atol=1e-3)
    # slot 1 lost, slot 2 born: the new belief's, not blended
    np.testing.assert_array_equal(blended.active, new.active)
    np.testing.assert_array_equal(blended.mean[2], new.mean[2])


@pytest.fixture(scope="module")
def tracked():
    scenario = load_scenario(DIAGRAMS / "omni_tracked.yaml")
    return scenario, simulate(replace(scenario, duration=12.0))


@pytest.mark.slow
def test_tracked_run_meets_every_guarantee_and_reaches(tracked):
    """omni_tracked, truth + sensor + tracker + tube + controller + plant: every guarantee
    with respect to the belief in force holds, the target is reached, the tracker's
    corrections are listed as belief discontinuities."""
    scenario, result = tracked
    metrics = result.metrics
    assert result.success, metrics["invariants"]
    assert metrics["reached"]
    kinds = {jump["kind"] for jump in metrics["belief_discontinuities"]}
    assert {"birth", "correction"} <= kinds
    births = [j for j in metrics["belief_discontinuities"] if j["kind"] == "birth"]
    assert sorted(j["obstacle"] for j in births) == list(range(len(scenario.obstacles)))


@pytest.mark.slow
def test_tracked_belief_follows_the_truth_within_its_covariance(tracked):
    """The logged belief against the logged true centres: the normalised squared error
    (O − μ)ᵀΣ⁻¹(O − μ) of the active slots averages near n = 2 (a calibrated tracker), and
    every slot is active after its first detection."""
    _, result = tracked
    log = result.log
    truth = log["true_obstacle_position"].reshape(len(log["t"]), -1, 2)
    active = log.active
    assert active[log.t > 0.5].all()
    error = truth - log.mean
    nees = np.einsum("tja,tjab,tjb->tj", error, np.linalg.inv(log.belief_covariance), error)
    # One run's logged times are strongly correlated (a track's error persists for many
    # samples), so its mean NEES spreads far more than 2/√samples: over seeds 0–5 of the
    # 25 s scene it ranged 1.56–2.06 (pooled 1.80), this 12 s run gives 1.92 (1.89 with the
    # one-period-late tracker before issue 26). NEES scales inversely with the covariance,
    # so the band fails this run's covariances scaled by 1/1.85 (overconfident) or by 1.95
    # (underconfident).
    assert 1.0 < float(np.mean(nees[active])) < 3.5


@pytest.mark.slow
def test_jumping_belief_without_blend_is_recovered_from_and_reported(tracked):
    """blend_time 0: the tracker's corrections jump the belief; a jump towards the tube
    drives q_j below ε_j, which the monitor reports (the guarantee is broken by the belief,
    not hidden) and the tube recovers from."""
    scenario, _ = tracked
    jumping = replace(
        scenario, duration=6.0, perception=replace(scenario.perception, blend_time=0.0)
    )
    metrics = simulate(jumping).metrics
    center = metrics["invariants"]["center_avoid_probability"]
    assert center["worst_margin"] < 0.0
    assert metrics["recovery"], "a violated centre margin must come with a recovery episode"
    assert all(episode["end_s"] is not None for episode in metrics["recovery"])


@pytest.mark.parametrize(
    "field, value, rule",
    [
        ("sensor_period", 0.0, "must be finite and > 0"),
        ("dropout_probability", 1.0, "must be in [0, 1)"),
        ("blend_time", 0.5, "blend_time: must be in [0, sensor_period"),
        ("track_timeout", 0.1, "track_timeout: must exceed"),  # = sensor_period + latency
        ("noise_covariance", [[0.01, 0.0], [0.0, -0.01]], "positive definite"),
    ],
)
def test_bad_perception_fields_are_named(field, value, rule):
    text = (DIAGRAMS / "omni_tracked.yaml").read_text()
    text = re.sub(rf"\n  {field}: [^\n]*", "", text)  # the file's own value, if any
    if field == "noise_covariance":  # one noise model: the file's noise_sigma goes
        text = re.sub(r"\n  noise_sigma: [^\n]*", "", text)
    text = text.replace("perception:\n", f"perception:\n  {field}: {value}\n", 1)
    with pytest.raises(ScenarioError, match=rf"scenario\.perception\.{field}") as error:
        parse_scenario(text, "bad")
    assert rule.split(": ")[-1] in str(error.value)


def test_perception_needs_the_continuous_tube():
    text = (DIAGRAMS / "omni_tracked.yaml").read_text().replace(
        "tube: {", "tube: {update_rate_hz: 50.0, ", 1
    )
    with pytest.raises(ScenarioError, match=r"update_rate_hz.*with perception"):
        parse_scenario(text, "bad")


@pytest.mark.slow
def test_tracked_uav_meets_every_guarantee_and_reaches():
    """uav_tracked: the UAV among four tracked obstacles in 3D (10 Hz detections within
    8 m, 10 % dropouts, the tube on the tracks' full covariances): every guarantee holds
    and the target is reached."""
    result = simulate(load_scenario(DIAGRAMS / "uav_tracked.yaml"))
    assert result.success, result.metrics["invariants"]
    assert result.metrics["reached"]
    assert result.log.full_covariance
