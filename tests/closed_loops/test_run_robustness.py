"""Every run ends cleanly and in bounded time: a failure inside the Simulator, a stalling
integrator or the step-rate watchdog stops it with metrics.json and log.npz written, a
one-sentence `stop_reason`, exit code 1 and no traceback."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from stt_drake import run as run_module
from stt_drake.assembly import load_scenario
from stt_drake.cli.main import main
from stt_drake.config import ScenarioError, validate
from stt_drake.run import simulate
from stt_drake.systems.controller import STTController
from stt_drake.systems.monitor import (
    DEFAULT_MAX_STEPS_PER_SECOND,
    WATCHDOG_WINDOW_STEPS,
    StepRateWatchdog,
    step_rate_limit,
)

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"
ENV = {**os.environ, "MPLBACKEND": "Agg", "DRAKE_ALLOW_NETWORK": "meshcat:package_map"}


def _case1(tmp_path: Path, duration: float, extra: str = "") -> Path:
    text = CASE1.read_text()
    assert "duration: 25.0" in text
    path = tmp_path / "scenario.yaml"
    path.write_text(text.replace("duration: 25.0", f"duration: {duration}") + extra)
    return path


def _outputs(out: Path) -> tuple[dict, dict[str, np.ndarray]]:
    metrics = json.loads((out / "metrics.json").read_text())
    with np.load(out / "log.npz") as log:
        return metrics, {name: log[name] for name in log.files}


# --------------------------------------------------------------------------- the watchdog


def test_watchdog_counts_windows_and_resets_them():
    # Times are exact binary fractions, so every window closes at exactly 10 steps.
    watchdog = StepRateWatchdog(limit=100.0, window_steps=10, window_seconds=10 / 64)
    assert watchdog.step(0.0) is None  # initialisation: opens the first window
    for k in range(1, 31):  # 10 steps per 10/64 s = 64 steps/s: three windows, none trips
        assert watchdog.step(k / 64) is None
    assert watchdog.max_rate == pytest.approx(64.0)
    t0 = watchdog.last_time
    # Then steps of 2⁻¹⁴ s: a burst may reach limit·window_seconds = 15.6 steps...
    for k in range(1, 16):
        assert watchdog.step(t0 + k / 2**14) is None
    message = watchdog.step(t0 + 16 / 2**14)  # ...the 16th trips it
    assert message is not None and message == watchdog.message
    assert message.startswith("step-rate watchdog: the integrator took 16 steps in")
    assert "> limit 100" in message and f"at t = {t0 + 16 / 2**14:.6g} s" in message


def test_watchdog_lets_a_short_burst_pass_and_judges_the_sustained_rate():
    """500 steps in 0.07 s (7e3 steps/s, as a fast crosser causes) and then 300 steps/s: the
    window spans 1 s with 800 steps, below a limit of 4000 per second."""
    watchdog = StepRateWatchdog(limit=4000.0)
    watchdog.step(0.0)
    for k in range(1, 501):
        assert watchdog.step(0.07 * k / 500) is None
    for k in range(1, 301):
        assert watchdog.step(0.07 + 0.93 * k / 300) is None
    assert watchdog.message is None
    assert watchdog.max_rate == pytest.approx(800.0)


def test_watchdog_trips_on_a_window_without_simulated_time():
    watchdog = StepRateWatchdog(limit=1e12, window_steps=5, window_seconds=0.0)
    watchdog.step(1.0)
    assert [watchdog.step(1.0) for _ in range(4)] == [None] * 4
    message = watchdog.step(1.0)
    assert message is not None and "5 steps in 0 s" in message and "inf steps/s" in message
    assert math.isinf(watchdog.max_rate)


def test_step_rate_limit_default_and_bad_values(tmp_path, capsys):
    assert step_rate_limit(0.0) == DEFAULT_MAX_STEPS_PER_SECOND
    assert step_rate_limit(50.0) == 50.0
    for bad in (-1.0, math.inf, math.nan):
        scenario = load_scenario(CASE1)
        scenario.max_steps_per_second = bad
        with pytest.raises(ScenarioError, match=r"scenario\.max_steps_per_second: must be finite"):
            validate(scenario)
    bad = _case1(tmp_path, 1.0, "max_steps_per_second: -5.0\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "out"), "--no-figures"]) == 2
    assert "scenario.max_steps_per_second" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_default_limit_is_far_above_a_normal_run_and_never_trips(run_scenario):
    """A whole scenario under the default limit: the watchdog judged its windows, the
    fastest was well below the limit, and the run ended normally."""
    metrics = run_scenario("omni_hardware_case1").metrics
    assert metrics["stop_reason"] is None
    step_rate = metrics["step_rate"]
    assert step_rate["limit_steps_per_s"] == DEFAULT_MAX_STEPS_PER_SECOND
    assert step_rate["window_steps"] == WATCHDOG_WINDOW_STEPS
    assert 50.0 < step_rate["max_window_steps_per_s"] < DEFAULT_MAX_STEPS_PER_SECOND / 5.0


@pytest.mark.slow
def test_scenario_step_limit_stops_the_run_through_the_cli(tmp_path, capsys):
    """A 10 ms max step takes ~100-200 steps per simulated second: a limit of 50 stops the
    run at the first judged window (500 steps, ~3 s), with every output written."""
    scenario = _case1(tmp_path, 8.0, "max_steps_per_second: 50.0\n")
    out = tmp_path / "out"
    code = main(["run", str(scenario), "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 1
    metrics, log = _outputs(out)
    reason = metrics["stop_reason"]
    assert reason.startswith("step-rate watchdog: the integrator took 500 steps in")
    assert "> limit 50)" in reason and "worst margin so far: " in reason
    assert metrics["strict_stop"] is None and metrics["reached"] is False
    assert 1.0 < metrics["sim_time_s"] < 8.0
    assert f"at t = {metrics['sim_time_s']:.6g} s" in reason
    assert metrics["steps"] == WATCHDOG_WINDOW_STEPS
    assert metrics["step_rate"]["limit_steps_per_s"] == 50.0
    assert metrics["step_rate"]["max_window_steps_per_s"] > 50.0
    # The log runs up to the stop, every signal with the same number of samples.
    assert metrics["sim_time_s"] - 0.02 <= log["t"][-1] <= metrics["sim_time_s"]
    assert len(log["output"]) == len(log["margins"]) == len(log["belief"]) == len(log["t"])
    for name in ("snapshots.png", "tube_3d.png", "margins.png"):
        assert (out / name).stat().st_size > 0, name
    assert "STOPPED EARLY: step-rate watchdog" in captured.out
    assert "result: FAILURE" in captured.out
    assert "Traceback" not in captured.out + captured.err


# --------------------------------------------------------------------------- failures


def _omni_fails_after(monkeypatch: pytest.MonkeyPatch, t_fail: float, how: str) -> None:
    """Make the velocity command the omni base receives misbehave for t > t_fail (the
    controller is the loop's Python system; the base is Drake primitives): `chatter` (a
    ±1e8 m/s bang-bang command switching every ~0.3 µs: error control shrinks the steps to
    ~1e-8 s; it calms down after CHATTER_EVALUATIONS evaluations, so that a broken watchdog
    fails the test instead of hanging it) or `nan` (the state goes NaN: the controller
    refuses it)."""
    control_of = STTController._calc_control
    chattered = [0]

    def misbehaving(self, context, output):
        control_of(self, context, output)
        t = context.get_time()
        if t > t_fail and how == "nan":
            output.SetFromVector([math.nan, 0.0])
        elif t > t_fail and chattered[0] < CHATTER_EVALUATIONS:
            chattered[0] += 1
            velocity = 1e8 * math.copysign(1.0, math.sin(1e7 * t))
            output.SetFromVector([velocity, 0.0])

    monkeypatch.setattr(STTController, "_calc_control", misbehaving)


#: How many derivative evaluations the chattering plant of the tests lasts (~20 s of wall
#: time here; the watchdog needs a few thousand).
CHATTER_EVALUATIONS = 100_000


@pytest.mark.slow
def test_a_stalling_integrator_is_stopped_by_the_default_watchdog(monkeypatch):
    """Without the watchdog this run takes steps of ~1e-8 s for as long as the plant
    chatters (forever for a plant that does not calm down); with it, the run ends within
    one window after the stall."""
    _omni_fails_after(monkeypatch, 1.0, "chatter")
    scenario = load_scenario(CASE1)
    scenario.duration = 3.0
    result = simulate(scenario)
    metrics = result.metrics
    reason = metrics["stop_reason"]
    # The stall starts at 1 s, inside the window that opened at 0: it trips once the count
    # exceeds limit·max(elapsed, 1 s) = 4000 steps.
    assert reason.startswith(
        f"step-rate watchdog: the integrator took {int(DEFAULT_MAX_STEPS_PER_SECOND) + 1} steps"
    )
    assert f"> limit {DEFAULT_MAX_STEPS_PER_SECOND:g})" in reason
    assert metrics["sim_time_s"] == pytest.approx(1.0, abs=1e-3)
    assert metrics["wall_time_s"] < 30.0
    assert result.log["t"][-1] == pytest.approx(1.0)
    assert not result.success


def test_an_integrator_failure_is_caught_and_named(monkeypatch):
    """Drake's own failure: with a minimum step size the chattering plant makes error
    control give up ("Error control wants to select step smaller than minimum allowed")."""
    _omni_fails_after(monkeypatch, 1.0, "chatter")
    apply_config = run_module.ApplySimulatorConfig

    def with_minimum_step(config, simulator):
        apply_config(config, simulator)
        integrator = simulator.get_mutable_integrator()
        integrator.set_requested_minimum_step_size(1e-6)
        integrator.set_throw_on_minimum_step_size_violation(True)

    monkeypatch.setattr(run_module, "ApplySimulatorConfig", with_minimum_step)
    scenario = load_scenario(CASE1)
    scenario.duration = 3.0
    result = simulate(scenario)
    reason = result.metrics["stop_reason"]
    assert reason.startswith("the integrator failed at t = 1.00 s (Error control wants to select")
    assert "; worst margin so far: " in reason
    assert result.metrics["sim_time_s"] == pytest.approx(1.0, abs=1e-3)
    assert result.log["t"][-1] == pytest.approx(1.0)
    assert result.metrics["reached"] is False and not result.success


@pytest.mark.slow
def test_exceptions_inside_advance_to_end_the_cli_run_cleanly(tmp_path):
    """Two real exceptions raised inside AdvanceTo, in a separate `stt-drake run` process:
    the controller's output raising ValueError at t > 1 s, and a NaN command that makes
    the state NaN, which the STT controller then refuses. Exit 1, outputs written up to the
    stop, no traceback."""
    scenario = _case1(tmp_path, 3.0)
    script = textwrap.dedent(
        """
        import math, sys
        from stt_drake.cli.main import main
        from stt_drake.systems.controller import STTController

        control_of = STTController._calc_control
        how = sys.argv[1]

        def failing(self, context, output):
            control_of(self, context, output)
            if context.get_time() > 1.0:
                if how == "raise":
                    raise ValueError("wheel encoder lost")
                output.SetFromVector([math.nan, 0.0])

        STTController._calc_control = failing
        sys.exit(main(["run", sys.argv[2], "--out", sys.argv[3], "--no-figures"]))
        """
    )
    for how, cause in (
        ("raise", "the simulation raised ValueError at t = 1.00 s (wheel encoder lost)"),
        ("nan", "the simulation raised ValueError at t = 1.00 s (controller input is not"),
    ):
        out = tmp_path / how
        completed = subprocess.run(
            [sys.executable, "-c", script, how, str(scenario), str(out)],
            capture_output=True,
            text=True,
            env=ENV,
            timeout=300,
            check=False,
        )
        assert completed.returncode == 1, completed.stdout + completed.stderr
        assert "Traceback" not in completed.stdout + completed.stderr
        assert "STOPPED EARLY: " + cause in completed.stdout
        metrics, log = _outputs(out)
        assert metrics["stop_reason"].startswith(cause)
        assert "worst margin so far: " in metrics["stop_reason"]
        assert metrics["sim_time_s"] == pytest.approx(1.0, abs=1e-3)
        assert log["t"][-1] == pytest.approx(1.0) and len(log["t"]) == 51
        assert np.all(np.isfinite(log["output"]))
        assert metrics["reached"] is False and metrics["invariants"]["output_in_tube"]["holds"]


@pytest.mark.parametrize("rate_hz", [0.0, 100.0])
def test_no_rounding_length_steps_at_periodic_events(tmp_path, rate_hz):
    """A log sample (k·0.02 s) or tube update (k·0.01 s) one rounding beyond t + max_step
    (a sum of 0.01 s steps) must not cost a ~1e-15 s integrator step of its own: without
    make_simulator's slack on max_step_size, 3-16 % of omni_cluttered_50's steps were."""
    from stt_drake.assembly.diagram import build_diagram
    from stt_drake.core.invariants import InvariantTracker
    from stt_drake.run import make_simulator

    scenario = load_scenario(_case1(tmp_path, 6.0, "log_period: 0.02\n"))
    scenario.tube.update_rate_hz = rate_hz
    assert scenario.simulator.max_step_size == 0.01
    built = build_diagram(scenario)
    simulator = make_simulator(built, scenario, InvariantTracker())
    times: list[float] = []
    check = simulator.get_monitor()

    def record(context):
        times.append(context.get_time())
        return check(context)

    simulator.set_monitor(record)
    simulator.Initialize()
    simulator.AdvanceTo(scenario.duration)
    steps = np.diff(times)
    assert len(steps) > 600  # 6 s at ≤ 0.01 s per step
    assert steps.min() > 1e-6, f"{np.sum(steps < 1e-9)} steps shorter than 1e-9 s"
