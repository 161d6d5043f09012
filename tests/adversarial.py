"""Shared checks of the adversarial scenario corpus (``tests/scenarios/*.yaml``).

Each corpus file states its required outcome in a comment line

    # expect: <outcome> [detail]

with <outcome> one of
- ``holds``: every guarantee holds (recomputed here from the log with scipy), the target
  is reached, the run ends normally;
- ``refused <text>``: validation refuses the file with a message containing <text>
  (e.g. ``scenario.tube.update_rate_hz``);
- ``recovers``: a belief discontinuity makes the tube recover; the violation is reported
  honestly (the tube's margin is negative in the log and metrics), every recovery episode
  ends, the run ends normally with a finite, bounded tube;
- ``warns <text>``: the run carries a pre-run warning containing <text> (e.g.
  ``Theorem 4.1``) and ends normally with a finite, bounded tube;
- ``stops <text>``: the run ends early with a ``stop_reason`` containing <text>;
- ``stalls <text>``: every guarantee holds and the run goes to its end, but the tube never
  settles in the target set (<text> names the cause, e.g. an equilibrium of the law): a
  known liveness limit, recorded so that a change in it shows. The run names it: its
  ``stop_reason`` starts with "stall:" and its last ``stalls`` entry lasts to the end.

Everything here is independent of the code under test: avoidance probabilities come from
``scipy.stats.ncx2`` on the raw logged centre, radius, output and belief.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import ncx2

from stt_drake.assembly import load_scenario, parse_scenario
from stt_drake.config import ScenarioError
from stt_drake.run import RunResult

SCENARIOS = Path(__file__).resolve().parent / "scenarios"

#: The margin a guarantee may sit below zero and still hold: the library's HOLDS_TOLERANCE
#: (1e-9), written out here rather than imported from the code under test. Margins are
#: probabilities (≤ 1) and lengths of a few metres; ncx2.sf and the logged doubles agree
#: to ~1e-12, far inside it.
TOLERANCE = 1e-9

#: Integrator steps per simulated second that a run which ends normally may take on
#: average: the issue asks for no more than 60 s of wall time per 60 s simulated; a step of
#: the omni base or the quadrotor costs at most ~1 ms here (the watchdog's measurements,
#: stt_drake.systems.monitor), so 500 steps per second keeps a corpus run at ≥ 2× real
#: time without timing a test. A run the watchdog stopped is bounded by the watchdog.
MAX_MEAN_STEPS_PER_SECOND = 500.0

_EXPECT = re.compile(r"^#\s*expect:\s*(holds|refused|recovers|warns|stops|stalls)\b\s*(.*)$")


@dataclass(frozen=True)
class Expectation:
    outcome: str  # holds | refused | recovers | warns | stops | stalls
    detail: str  # the text a refusal, warning or stop reason must contain ("" for holds)


def expectation(path: Path) -> Expectation:
    """The `# expect:` line of a corpus file (exactly one is required)."""
    found = [m for line in path.read_text().splitlines() if (m := _EXPECT.match(line.strip()))]
    if len(found) != 1:
        raise AssertionError(f"{path.name}: needs exactly one '# expect:' line, found {len(found)}")
    return Expectation(found[0].group(1), found[0].group(2).strip())


def corpus(prefix: str) -> list[Path]:
    """The corpus files whose names start with `prefix` (e.g. "omni_", "uav_")."""
    return sorted(SCENARIOS.glob(f"{prefix}*.yaml"))


def _q(point: np.ndarray, mean: np.ndarray, sigma: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """P(‖point − O_j‖ ≥ radius_j), O_j ~ N(mean_j, σ_j² I): the noncentral χ² tail."""
    n = mean.shape[-1]
    lam = np.sum((point - mean) ** 2, axis=-1) / sigma**2
    return ncx2.sf((radius / sigma) ** 2, n, lam)


def recomputed_margins(log: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every guarantee's margin at every logged sample, from the raw log.

    Returns (T,) arrays: `output_in_tube` r − ‖y − c‖ (m), `radius_positive` r (m) and,
    minimised over obstacles, `center_avoid_probability` q_j(c; r_o + r_min) − ε_j,
    `tube_avoid_probability` q_j(c; r_o + r) − ε_j, `output_avoid_probability`
    q_j(y; r_o) − ε_j. The belief record per obstacle is [μ (n), Σ (n², row-major), active]
    (every corpus belief is σ² I and active: checked); r_o and ε are the log's task numbers.
    """
    n = int(log["dimension"])
    samples = len(log["t"])
    belief = np.asarray(log["belief"], dtype=float).reshape(samples, -1, n + n * n + 1)
    mean, covariance = belief[..., :n], belief[..., n:-1].reshape(samples, -1, n, n)
    sigma = np.sqrt(covariance[..., 0, 0])
    np.testing.assert_array_equal(covariance, covariance[..., :1, :1] * np.eye(n))
    assert np.all(belief[..., -1] == 1.0)
    r_o, epsilon = np.asarray(log["obstacle_radius"]), np.asarray(log["epsilon"])
    center = np.asarray(log["center"], dtype=float)[:, None, :]
    output = np.asarray(log["output"], dtype=float)[:, None, :]
    radius = np.asarray(log["radius"], dtype=float)
    r_min = float(log["r_min"])
    return {
        "output_in_tube": radius - np.linalg.norm(output[:, 0] - center[:, 0], axis=1),
        "radius_positive": radius,
        "center_avoid_probability": (_q(center, mean, sigma, r_o + r_min) - epsilon).min(axis=1),
        "tube_avoid_probability": (_q(center, mean, sigma, r_o + radius[:, None]) - epsilon).min(
            axis=1
        ),
        "output_avoid_probability": (_q(output, mean, sigma, r_o) - epsilon).min(axis=1),
    }


def arena_excess(log: dict[str, np.ndarray]) -> float:
    """How far (m) the tube's centre ever got outside the arena, divided by the arena's
    size. The arena is the bounding box of the start, the target and every logged
    obstacle mean; its size is the box's diagonal. The issue's rule: ≤ 1."""
    n = int(log["dimension"])
    samples = len(log["t"])
    means = np.asarray(log["belief"], dtype=float).reshape(samples, -1, n + n * n + 1)[..., :n]
    points = np.vstack([means.reshape(-1, n), log["start"][None], np.atleast_2d(log["target"])])
    low, high = points.min(axis=0), points.max(axis=0)
    size = float(np.linalg.norm(high - low))
    center = np.asarray(log["center"], dtype=float)
    outside = np.maximum(low - center, 0.0) + np.maximum(center - high, 0.0)
    return float(np.linalg.norm(outside, axis=1).max()) / size


# --------------------------------------------------------------------------- the YAML alone


class _TaggedLoader(yaml.SafeLoader):
    """Reads Drake's ``!Tag {...}`` variants as plain mappings with their tag under "tag"."""


_TaggedLoader.add_multi_constructor(
    "!", lambda loader, tag, node: {"tag": tag, **loader.construct_mapping(node, deep=True)}
)


def scenario_data(path: Path) -> dict:
    """The file's YAML as plain data (no validation by the code under test)."""
    return yaml.load(path.read_text(), Loader=_TaggedLoader)


def update_rate(data: dict) -> float:
    """tube.update_rate_hz of a file's data (0: continuous time)."""
    return float(data.get("tube", {}).get("update_rate_hz", 0.0))


def _slope(times: list[float], values: np.ndarray) -> float:
    """Steepest ‖Δvalue‖/Δt over segments of positive length (a repeated time is a step)."""
    times = np.asarray(times, dtype=float)
    dt = np.diff(times)
    change = np.linalg.norm(np.diff(values, axis=0), axis=1)
    return float(np.max(change[dt > 0] / dt[dt > 0], initial=0.0))


def _motion(motion: dict) -> tuple[np.ndarray, float]:
    """Mean at t = 0 and speed bound sup ‖μ̇‖ (m/s) of one motion model."""
    if motion["tag"] == "ConstantVelocity":
        return np.asarray(motion["start"], float), float(np.linalg.norm(motion["velocity"]))
    if motion["tag"] == "Oscillation":
        phase = np.asarray(motion.get("phase") or 0.0, float)
        mean = np.asarray(motion["center"], float) + np.asarray(motion["amplitude"]) * np.sin(phase)
        speed = 2 * math.pi * motion.get("frequency_hz", 0.1) * np.linalg.norm(motion["amplitude"])
        return mean, float(speed)
    if motion["tag"] == "Waypoints":
        positions = np.asarray(motion["positions"], dtype=float)
        mean = np.array([np.interp(0.0, motion["times"], axis) for axis in positions.T])
        return mean, _slope(motion["times"], positions)
    raise AssertionError(f"unknown motion !{motion['tag']}")


def admissible_period(data: dict) -> float:
    """docs/guide/real_time.md, "The admissible period", from the file's numbers: the
    longest h with, for every obstacle j, 2·v̄_j·h ≤ r_o + r_min and 2·s̄_j·h ≤ σ_min,j/2,
    and the start certified for the first period: Q^h_j(s) > ε_j with Δ = v̄h,
    γ = σ/(σ − s̄h) − 1, R = r_o + r_min,
    a = ‖s − μ_j(0)‖, Q^h = P(‖Z'‖ ≥ (R + γ(a + Δ + R))/σ), Z' ~ N(max(a − Δ, 0)/σ·e, I)
    (scipy's noncentral χ², bisection where the start rule binds)."""
    assert not data.get("random_obstacles"), "refused files must list their obstacles"
    r_min = data["tube"]["r_min"]
    start = np.asarray(data["start"], dtype=float)
    longest = math.inf
    obstacles = []
    for obstacle in data["obstacles"]:
        mean, speed = _motion(obstacle["motion"])
        schedule = obstacle.get("sigma_schedule")
        if schedule:
            values = np.asarray(schedule["values"], dtype=float)
            sigma0 = float(np.interp(0.0, schedule["times"], values))
            sigma_rate = _slope(schedule["times"], values[:, None])
            sigma_min = float(values.min())
        else:
            sigma0 = sigma_min = float(obstacle.get("sigma", 0.1))
            sigma_rate = 0.0
        radius = obstacle.get("radius", 0.15) + r_min
        if speed > 0:
            longest = min(longest, radius / (2 * speed))
        if sigma_rate > 0:
            longest = min(longest, sigma_min / (4 * sigma_rate))
        obstacles.append((mean, speed, sigma0, sigma_rate, radius, obstacle.get("epsilon", 0.9)))

    def certified(h: float) -> bool:
        for mean, speed, sigma, sigma_rate, radius, epsilon in obstacles:
            low = sigma - sigma_rate * h
            if low <= 0:
                return False
            gamma, reach = sigma / low - 1.0, speed * h
            distance = float(np.linalg.norm(start - mean))
            threshold = (radius + gamma * (distance + reach + radius)) / sigma
            offset = max(distance - reach, 0.0) / sigma
            if not ncx2.sf(threshold**2, len(start), offset**2) > epsilon:
                return False
        return True

    high = longest if math.isfinite(longest) else 3600.0
    if certified(high):
        return longest
    low = 0.0
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if certified(middle) else (low, middle)
    return low


# --------------------------------------------------------------------------- the checks


def check_file(path: Path, run: Callable[[Path], RunResult]) -> None:
    """Check one corpus file against its `# expect:` line; `run` simulates a file."""
    expected = expectation(path)
    if expected.outcome == "refused":
        check_refused(path, expected.detail)
        return
    result = run(path)
    metrics = result.metrics
    check_every_run(path, result)
    if expected.outcome == "holds":
        check_safe(path, result)
        assert metrics["reached"], f"{path.name}: target not reached ({metrics['reach']})"
        # Every holding file says in its header why no warning applies.
        assert metrics["warnings"] == [], f"{path.name}: {metrics['warnings']}"
    elif expected.outcome == "recovers":
        check_recovers(path, result)
    elif expected.outcome == "warns":
        assert any(expected.detail in warning for warning in metrics["warnings"]), (
            f"{path.name}: no warning contains {expected.detail!r}: {metrics['warnings']}"
        )
        assert metrics["stop_reason"] is None, f"{path.name}: {metrics['stop_reason']}"
    elif expected.outcome == "stops":
        reason = metrics["stop_reason"]
        assert reason is not None and expected.detail in reason, f"{path.name}: {reason!r}"
        assert not metrics["reached"], f"{path.name}: a stopped run is never a success"
    elif expected.outcome == "stalls":  # safe but not live
        check_safe(path, result, stalled=True)
        assert metrics["reach"]["final_entry_s"] is None and not metrics["reached"], (
            f"{path.name}: reached the target after all ({metrics['reach']}): update the file"
        )
        assert metrics["stalls"] and metrics["stalls"][-1]["end_s"] is None, (
            f"{path.name}: no stall lasting to the end: {metrics['stalls']}"
        )
        duration = scenario_data(path)["duration"]
        assert metrics["sim_time_s"] == pytest.approx(duration), f"{path.name}: ended early"
    else:  # pragma: no cover (the expectation regex admits nothing else)
        raise AssertionError(f"{path.name}: unknown outcome {expected.outcome}")


def check_every_run(path: Path, result: RunResult) -> None:
    """What every simulated run must meet: a finite tube near the arena and a bounded
    number of integrator steps per simulated second (never wall time): the mean budget for
    a run that ended normally, the watchdog's own bound for one it stopped."""
    log, metrics = result.log, result.metrics
    assert len(log["t"]) >= 1, f"{path.name}: nothing logged"
    assert np.all(np.isfinite(log["center"])), f"{path.name}: non-finite tube centre"
    assert np.all(np.isfinite(log["radius"])), f"{path.name}: non-finite tube radius"
    excess = arena_excess(log)
    assert excess <= 1.0, f"{path.name}: the centre left the arena by {excess:.3g} arena sizes"
    assert metrics["sim_time_s"] > 0.0, f"{path.name}: no simulated time"
    stopped = metrics["stop_reason"] is not None and not metrics["stop_reason"].startswith(
        "stall:"  # a stall is named at the end of a run that went to its end
    )
    if stopped:
        step_rate = metrics["step_rate"]
        assert step_rate["max_window_steps_per_s"] > 0.0
        bound = step_rate["limit_steps_per_s"] * metrics["sim_time_s"] + step_rate["window_steps"]
        assert metrics["steps"] <= bound, f"{path.name}: {metrics['steps']} > {bound}"
        return
    rate = metrics["steps"] / metrics["sim_time_s"]
    assert rate <= MAX_MEAN_STEPS_PER_SECOND, (
        f"{path.name}: {metrics['steps']} steps in {metrics['sim_time_s']:.3g} s of "
        f"simulated time ({rate:.0f}/s > {MAX_MEAN_STEPS_PER_SECOND:.0f}/s)"
    )


def check_safe(path: Path, result: RunResult, stalled: bool = False) -> None:
    """The run ended normally (`stalled`: its only stop reason is a stall to the end) and
    every guarantee held, recomputed at every logged sample (≥ −TOLERANCE) and as the
    library reports it."""
    metrics, t = result.metrics, result.log["t"]
    reason = metrics["stop_reason"]
    if stalled:
        assert reason is not None and reason.startswith("stall:"), f"{path.name}: {reason}"
    else:
        assert reason is None, f"{path.name}: {reason}"
    for name, margin in recomputed_margins(result.log).items():
        k = int(np.argmin(margin))
        assert margin[k] >= -TOLERANCE, (
            f"{path.name}: {name} recomputed margin {margin[k]:.3e} at t = {t[k]:.3f} s"
        )
    failed = {k: v for k, v in metrics["invariants"].items() if not v["holds"]}
    assert metrics["holds"] and not failed, f"{path.name}: the library reports {failed}"


def check_recovers(path: Path, result: RunResult) -> None:
    """A belief jump the motion model cannot make, recovery episodes that all end, the
    violation visible in the recomputed centre margin and reported as not holding, and a
    normal end."""
    metrics = result.metrics
    assert metrics["stop_reason"] is None, f"{path.name}: {metrics['stop_reason']}"
    assert metrics["belief_discontinuities"], f"{path.name}: no belief discontinuity found"
    episodes = metrics["recovery"]
    assert episodes, f"{path.name}: the tube never recovered"
    unfinished = [e for e in episodes if e["end_s"] is None]
    assert not unfinished, f"{path.name}: still recovering at the end: {unfinished}"
    # Honest reporting: the violation is in the log and in the metrics.
    center = recomputed_margins(result.log)["center_avoid_probability"]
    assert center.min() < -TOLERANCE, (
        f"{path.name}: the jump never put the centre inside an ε level set "
        f"(worst recomputed margin {center.min():.3e})"
    )
    assert metrics["invariants"]["center_avoid_probability"]["holds"] is False, (
        f"{path.name}: the recomputed margin is {center.min():.3e}, but the library "
        "reports center_avoid_probability as holding"
    )


def check_refused(path: Path, detail: str) -> None:
    """The loader refuses the file naming `detail` and stating the largest admissible
    period computed here from the YAML alone (to its 4 printed digits); the file's own
    period is longer, and a period just inside the rule loads (the rate is the only
    thing wrong)."""
    data = scenario_data(path)
    period = admissible_period(data)
    rate = update_rate(data)
    assert rate > 0.0 and 1.0 / rate > period, (
        f"{path.name}: 1/{rate:g} Hz is admissible by the rule (≤ {period:.4g} s)"
    )
    with pytest.raises(ScenarioError) as refusal:
        load_scenario(path)
    message = str(refusal.value)
    assert detail in message, f"{path.name}: {message}"
    assert f"the largest admissible period is {period:.4g} s" in message, (
        f"{path.name}: expected the admissible period {period:.4g} s in: {message}"
    )
    inside, count = re.subn(
        r"update_rate_hz:\s*[0-9.eE+-]+", f"update_rate_hz: {1.01 / period!r}", path.read_text()
    )
    assert count == 1, f"{path.name}: expected exactly one update_rate_hz"
    parse_scenario(inside, default_name=path.stem)
