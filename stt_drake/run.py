"""Simulate a scenario, check every guarantee, and write metrics, logs and figures."""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import Context, Diagram, EventStatus

from stt_drake.assembly.diagram import SttDiagram, build_diagram
from stt_drake.assembly.feasibility import scenario_warnings
from stt_drake.assembly.guide import stall_rule
from stt_drake.config import AssumptionError, Scenario
from stt_drake.config.assumptions import check_target_separation
from stt_drake.config.schema import default_simulator_config
from stt_drake.core import backend
from stt_drake.core.crowd_metrics import output_reach_time
from stt_drake.core.invariants import (
    HOLDS_TOLERANCE,
    InvariantTracker,
    RecoveryTracker,
    reach_story,
)
from stt_drake.core.progress import find_stalls
from stt_drake.metrics import RunMetrics
from stt_drake.runlog import RunLog, write_json
from stt_drake.story import (
    belief_discontinuities,
    separation_after_entry,
    stall_cause,
    target_separation_violations,
    track_consistency,
)
from stt_drake.systems.monitor import InvariantMonitor, StepRateWatchdog, step_rate_limit

#: Invariants whose margin is a length (the others are probabilities).
_METRE_MARGINS = ("output_in_tube", "radius_positive")
#: How many belief discontinuities, recovery episodes and stalls the summary lists.
_SUMMARY_LISTED = 3


@dataclass
class RunResult:
    """A finished run: the metrics (:class:`stt_drake.metrics.RunMetrics`, the
    `metrics.json` contract) and the run log (:class:`stt_drake.runlog.RunLog`, a mapping
    of the `log.npz` members)."""

    metrics: RunMetrics
    log: RunLog
    #: The plant's own summary lines (its `summary` hook, e.g. the arm's tasks and limits).
    plant_summary: list[str] = field(default_factory=list)

    @property
    def success(self) -> bool:
        """The run ended normally, every guarantee held, the target was reached (every task
        of a sequence) and no plant limit was exceeded (exit code 0)."""
        limits = self.metrics.plant.get("limits", {}).values()
        return bool(
            self.metrics.stop_reason is None
            and self.metrics.holds
            and self.metrics.reached
            and all(record["holds"] for record in limits)
        )


def obstacle_report(log: RunLog, scenario: Scenario) -> list[dict[str, Any]]:
    """Per obstacle: the closest approach of y to its mean, and its σ and ε."""
    sigmas = log.sigma
    distance = np.linalg.norm(log.output[:, None, :] - log.mean, axis=2)
    distance[~log.active] = np.inf  # a slot without a track has no mean
    report = []
    for j, obstacle in enumerate(scenario.obstacles):
        if not distance.size:  # nothing logged (a run that failed at its start)
            continue
        k = int(np.argmin(distance[:, j]))
        report.append(
            {
                "index": j,
                "min_distance_to_mean": float(distance[k, j]),
                "t_min_distance": float(log.t[k]),
                "sigma": float(sigmas[k, j]),
                "radius": obstacle.radius,
                "epsilon": obstacle.epsilon,
                "min_output_avoid_probability": float(np.min(log.output_avoid_probability[:, j])),
            }
        )
    return report


def worst_margin_so_far(tracker: InvariantTracker) -> str:
    """The lowest margin of any guarantee so far, as "name margin [m] at t = ... s"."""
    name, record = min(tracker.records.items(), key=lambda item: item[1].worst_margin)
    if not np.isfinite(record.worst_margin) and record.worst_margin > 0:
        return "none evaluated"
    unit = " m" if name in _METRE_MARGINS else ""
    return f"{name} {record.worst_margin:+.2e}{unit} at t = {record.t_worst:.2f} s"


#: The guarantees that are about the obstacles (vacuous in a scenario without any).
OBSTACLE_INVARIANTS = (
    "center_avoid_probability",
    "tube_avoid_probability",
    "output_avoid_probability",
)
#: What metrics.json says of them then (their margin is 1, above every real one, 1 − ε_j).
NO_OBSTACLE_NOTE = "no obstacle: vacuous, margin 1 by convention"


def no_obstacle_notes(invariants: dict[str, Any], obstacles: int) -> dict[str, Any]:
    """`invariants` (metrics.json's) with, in a scenario without obstacles, a `note`
    :data:`NO_OBSTACLE_NOTE` on each obstacle guarantee."""
    if obstacles == 0:
        for name in OBSTACLE_INVARIANTS:
            if name in invariants:
                invariants[name]["note"] = NO_OBSTACLE_NOTE
    return invariants


def failure_reason(error: Exception, t: float) -> str:
    """One sentence naming what failed inside the Simulator and when (t: the last
    completed step)."""
    text = str(error).strip().splitlines()
    detail = text[0] if text else ""
    if len(detail) > 200:
        detail = detail[:197] + "..."
    if "step smaller than minimum" in detail or "integrator" in detail.lower():
        what = "the integrator failed"
    else:
        what = f"the simulation raised {type(error).__name__}"
    return f"{what} at t = {t:.2f} s ({detail})" if detail else f"{what} at t = {t:.2f} s"


#: Relative slack on the max_step_size (see :func:`make_diagram_simulator`): far above
#: the rounding of event times (~1e-16 relative), far below anything the step's error
#: control or a user's step bound could notice.
MAX_STEP_SLACK = 1e-9


def make_simulator(
    built: SttDiagram,
    scenario: Scenario,
    tracker: InvariantTracker,
    strict: bool = False,
    watchdog: StepRateWatchdog | None = None,
    recoveries: RecoveryTracker | None = None,
    progress: Callable[[float, InvariantTracker], None] | None = None,
) -> Simulator:
    """The Simulator of a built scenario (:func:`make_diagram_simulator` with the
    scenario's SimulatorConfig), and the invariant monitor attached so every guarantee is
    checked at every step into `tracker`
    (:meth:`stt_drake.systems.monitor.InvariantMonitor.attach`: `strict` stops at the first
    violation, `watchdog` bounds the step rate, `recoveries` collects the recovery
    episodes, `progress` is told every step)."""
    simulator = scenario_simulator(built.diagram, scenario)
    built.monitor.attach(simulator, tracker, strict, watchdog, recoveries, progress)
    return simulator


def scenario_simulator(diagram: Diagram, scenario: Scenario) -> Simulator:
    """A Simulator of `diagram` with the scenario's SimulatorConfig and no monitor (the
    STT loop's is :func:`make_simulator`'s; a baseline's diagram has none)."""
    return make_diagram_simulator(diagram, config=scenario.simulator)


def make_diagram_simulator(
    diagram: Diagram,
    monitor: InvariantMonitor | None = None,
    tracker: InvariantTracker | None = None,
    *,
    config: SimulatorConfig | None = None,
    accuracy: float | None = None,
    max_step_size: float | None = None,
    strict: bool = False,
    also: Callable[[Context], EventStatus] | None = None,
) -> Simulator:
    """A Simulator of any Diagram (one's own, with :func:`stt_drake.AddStt` in it) set up
    as a scenario run's: `config`, by default a scenario's SimulatorConfig (runge_kutta3
    with error control, accuracy 1e-6, steps of at most 0.01 s), with `accuracy` and
    `max_step_size` (s) replacing its values when given.

    With `monitor` (an :class:`~stt_drake.systems.monitor.InvariantMonitor`, e.g.
    ``AddStt(...).monitor``) and `tracker`, every guarantee is checked at every integrator
    step into `tracker` (:meth:`~stt_drake.systems.monitor.InvariantMonitor.attach`;
    `strict` stops at the first violation; :func:`guarantees_report` prints them). `also`,
    a Simulator monitor of one's own, runs at every step too (with or without `monitor`;
    the most severe status wins, :func:`stt_drake.systems.monitor.combine_monitors`).

    Drake never takes a step longer than max_step_size, and a periodic event's time
    (offset + k·period) can lie one rounding beyond the integrator's t + max_step (a sum of
    steps): the event would then cost a ~1e-15 s step of its own (10 % of all steps of
    omni_cluttered_50). The step bound gets a relative slack of :data:`MAX_STEP_SLACK`.
    """
    if (monitor is None) != (tracker is None):
        raise ValueError("make_diagram_simulator: give `monitor` and `tracker` together")
    config = default_simulator_config() if config is None else copy.copy(config)
    if accuracy is not None:
        config.accuracy = accuracy
    if max_step_size is not None:
        config.max_step_size = max_step_size
    simulator = Simulator(diagram)
    ApplySimulatorConfig(config, simulator)
    simulator.get_mutable_integrator().set_maximum_step_size(
        config.max_step_size * (1.0 + MAX_STEP_SLACK)
    )
    if monitor is not None:
        monitor.attach(simulator, tracker, strict, also=also)
    elif also is not None:
        simulator.set_monitor(also)
    return simulator


def load_kernels(scenario: Scenario, built: SttDiagram) -> float:
    """Compile, or load from numba's on-disk cache, every compiled kernel for the scenario's
    dimension before the run's clock starts (:func:`stt_drake.core.backend.warm_up`; `built`
    is not needed). Returns the seconds it took: 0.0 on the numpy path and once this process
    has loaded them."""
    return backend.warm_up(scenario.dimension)


def simulate(
    scenario: Scenario,
    strict: bool | None = None,
    meshcat: Meshcat | None = None,
    progress: Callable[[float, InvariantTracker], None] | None = None,
) -> RunResult:
    """Build, simulate for `scenario.duration` and check every guarantee.

    The guarantees are evaluated at every integrator step (Simulator monitor) and at every
    logged sample; `strict` (default: the scenario's) stops at the first violation. The
    run always ends with a result: an exception inside the Simulator, a strict stop or
    the step-rate watchdog (:class:`stt_drake.systems.monitor.StepRateWatchdog`) ends it
    early with everything logged up to then and `stop_reason` saying why. A run that
    ends normally, not reached, in a stall (:mod:`stt_drake.core.progress`) has a
    `stop_reason` naming the stall. A strict run of a scenario in which an obstacle covers
    the target for the whole run (Assumption 3, which a non-strict run records) stops
    before its first step with that reason; ``load_scenario(..., strict=True)`` refuses
    such a file at load instead. `progress` is called after every step with the time and
    the guarantees' tracker (``stt-drake run``'s progress lines).
    """
    strict = scenario.strict if strict is None else strict
    warnings = scenario_warnings(scenario)
    assumptions = target_separation_violations(scenario)
    built = build_diagram(scenario, meshcat)  # meshcat: also draw the run live there
    tracker = InvariantTracker()
    watchdog = StepRateWatchdog(step_rate_limit(scenario.max_steps_per_second))
    recoveries = RecoveryTracker()
    simulator = make_simulator(built, scenario, tracker, strict, watchdog, recoveries, progress)
    # Kernel compilation (or its on-disk cache's loading) is not simulation: it is done
    # and timed here, before the clock, and reported apart as compile_time_s.
    compile_time = load_kernels(scenario, built)
    stopped = failure = refused = None
    if strict:  # a strict run does not start with a broken Assumption 3 (see the docstring)
        try:
            check_target_separation(scenario, strict=True)
        except AssumptionError as error:
            refused = str(error)
    start = time.perf_counter()
    try:
        if refused is None:
            simulator.Initialize()
            simulator.AdvanceTo(scenario.duration)
    except Exception as error:  # every run ends with its metrics and log written
        # In strict mode the monitor fails the step of the first violation, so an error
        # with a violation on record is that stop.
        if strict and tracker.first_violation is not None:
            stopped = tracker.first_violation
        else:
            failure = error
    wall_time = time.perf_counter() - start
    context = simulator.get_context()
    # After an exception the context may hold a half-taken step: report the last good one.
    sim_time = context.get_time() if failure is None else (watchdog.last_time or 0.0)
    log = RunLog.from_loggers(
        built.loggers, context, scenario, built.extra_logs, built.log_constants
    )
    tracker.update_many(log.t, log.margins)
    stalls = find_stalls(
        log.t, log.center, log.attraction_point, stall_rule(scenario), scenario.target_set_radius
    )
    if refused is not None:
        cause = f"strict mode did not start the run: {refused}"
    elif stopped is not None:
        cause = f"strict mode stopped the run at the first violated guarantee: {stopped}"
    elif failure is not None:
        cause = failure_reason(failure, sim_time)
    else:
        cause = watchdog.message
    stop_reason = None
    if cause is not None:
        stop_reason = f"{cause}; worst margin so far: {worst_margin_so_far(tracker)}"
    # A task sequence is reached in its last task only (the sequencer logs the active target).
    reach = reach_story(
        log.t,
        log.center,
        log.radius,
        log.active_target,
        scenario.target_set_radius,
        final_target=log.target,
    )
    t_tube_in_target = reach.final_entry_s
    # Plant-specific metrics (none without a logged sample); a task sequence is reached
    # only when every task completed.
    plant_metrics = {}
    if built.plant_report is not None and log.samples > 0:
        plant_metrics = built.plant_report(log)
    segments = plant_metrics.get("segments", [])
    reached = (
        t_tube_in_target is not None
        and stop_reason is None
        and all(segment["completed"] for segment in segments)
    )
    if not reached and stop_reason is None and stalls and stalls[-1]["end_s"] is None:
        worst = worst_margin_so_far(tracker)
        stop_reason = f"{stall_cause(stalls[-1])}; worst margin so far: {worst}"
    metrics = RunMetrics(
        scenario=scenario.name,
        reached=reached,
        t_tube_in_target=t_tube_in_target,
        t_output_in_target=output_reach_time(
            log.t, log.output, log.target, scenario.target_set_radius
        ),
        holds=tracker.holds,
        sim_time_s=sim_time,
        wall_time_s=wall_time,
        compile_time_s=compile_time,
        realtime_factor=sim_time / wall_time if wall_time > 0 else None,
        steps=simulator.get_num_steps_taken(),
        holds_tolerance=HOLDS_TOLERANCE,
        stop_reason=stop_reason,
        strict_stop=stopped,
        first_violation=tracker.first_violation,
        invariants=no_obstacle_notes(tracker.as_dict(), len(scenario.obstacles)),
        reach=reach.as_dict(),
        warnings=warnings,
        assumptions=assumptions + separation_after_entry(log, t_tube_in_target),
        belief_discontinuities=belief_discontinuities(log),
        recovery=recoveries.episodes(),
        stalls=stalls,
        step_rate={
            "limit_steps_per_s": watchdog.limit,
            "window_steps": watchdog.window_steps,
            "max_window_steps_per_s": watchdog.max_rate,
        },
        obstacles=obstacle_report(log, scenario),
        tracks=track_consistency(
            log, 0.95 if scenario.perception is None else scenario.perception.nis_confidence
        ),
        plant=plant_metrics,
    )
    plant_summary = built.plant_summary(metrics) if built.plant_summary is not None else []
    return RunResult(metrics, log, plant_summary)


def write_outputs(
    result: RunResult,
    out_dir: Path,
    figures: bool = True,
    snapshot_times: Sequence[float] | None = None,
) -> list[Path]:
    """Write metrics.json, log.npz and (optionally) the PNG figures into `out_dir` (no
    figures for a run that stopped before its second logged sample: no curve to draw).
    The snapshots are taken at `snapshot_times` (s), by default at the start, each
    guarantee's worst-margin time and the end
    (:func:`stt_drake.plotting.save_run_figures`).

    metrics.json is strict JSON (:func:`stt_drake.runlog.strict_json`): a non-finite
    value (an infinite margin, σ = ∞) is ``null``, named in its ``"non_finite"`` object."""
    out_dir.mkdir(parents=True, exist_ok=True)
    metrics_path = write_json(out_dir / "metrics.json", result.metrics.as_dict())
    log = RunLog.of(result.log)
    written = [metrics_path, log.save(out_dir / "log.npz")]
    if figures and log.samples >= 2:
        from stt_drake.plotting import save_run_figures

        invariants = result.metrics.invariants
        written += save_run_figures(
            log, out_dir, invariants=invariants, snapshot_times=snapshot_times
        )
    return written


def _times(values: list[float]) -> str:
    return ", ".join(f"{value:.2f}" for value in values) + " s"


def _reach_lines(m: dict[str, Any]) -> list[str]:
    reach = m["reach"]
    # A task sequence enters and leaves each task's own target set in turn.
    per_task = " (each task's target set)" if "segments" in m else ""
    if m["reached"]:
        line = (
            "  reached the target set: yes, tube inside the target set at t_c = "
            f"{m['t_tube_in_target']:.2f} s"
        )
        if m["t_output_in_target"] is not None:
            line += f" (the output from {m['t_output_in_target']:.2f} s)"
        lines = [line]
    else:
        lines = ["  reached the target set: NO"]
    if reach["first_entry_s"] is None:
        lines.append("    never entered the target set")
    elif reach["exits_s"]:
        lines.append(
            f"    first entry {reach['first_entry_s']:.2f} s; left at {_times(reach['exits_s'])}; "
            f"entered at {_times(reach['entries_s'])}{per_task}"
        )
    elif not m["reached"]:
        lines.append(f"    entered at {reach['first_entry_s']:.2f} s and stayed")
    return lines


def _story_lines(m: dict[str, Any]) -> list[str]:
    lines = []
    if m["warnings"]:
        lines.append("  warnings:")
        lines += [f"    {warning}" for warning in m["warnings"]]
    if m["assumptions"]:
        lines.append("  assumptions broken:")
        lines += [f"    {record['message']}" for record in m["assumptions"]]
    jumps = m["belief_discontinuities"]
    if jumps:
        lines.append(f"  belief discontinuities: {len(jumps)}")
        for jump in jumps[:_SUMMARY_LISTED]:
            lines.append(
                f"    obstacle {jump['obstacle']} at t = {jump['t']:.2f} s ({jump['kind']}): "
                "mean moved "
                f"{jump['mean_jump_m']:.3f} m, σ {jump['sigma_jump_m']:+.3f} m, q "
                f"{jump['q_before']:.4f} → {jump['q_after']:.4f}"
            )
        if len(jumps) > _SUMMARY_LISTED:
            lines.append(f"    ... and {len(jumps) - _SUMMARY_LISTED} more (metrics.json)")
    episodes = m["recovery"]
    if episodes:
        lines.append(f"  recovery episodes: {len(episodes)}")
        for episode in episodes[:_SUMMARY_LISTED]:
            end = episode["end_s"]
            end = "the end (still recovering)" if end is None else f"{end:.2f} s"
            lines.append(
                f"    obstacle {episode['obstacle']} from {episode['start_s']:.2f} s to {end}, "
                f"worst q − ε = {episode['worst_margin']:+.3e}"
            )
        if len(episodes) > _SUMMARY_LISTED:
            lines.append(f"    ... and {len(episodes) - _SUMMARY_LISTED} more (metrics.json)")
    return lines + _stall_lines(m["stalls"])


def _stall_lines(stalls: list[dict[str, Any]]) -> list[str]:
    if not stalls:
        return []
    lines = [f"  stalls: {len(stalls)}"]
    for stall in stalls[:_SUMMARY_LISTED]:
        end = "the end" if stall["end_s"] is None else f"{stall['end_s']:.2f} s ({stall['ended']})"
        lines.append(
            f"    from {stall['start_s']:.2f} s to {end}, detected at {stall['detected_s']:.2f} s "
            f"{stall['distance_m']:.2f} m from the attraction point"
        )
    if len(stalls) > _SUMMARY_LISTED:
        lines.append(f"    ... and {len(stalls) - _SUMMARY_LISTED} more (metrics.json)")
    return lines


def _track_lines(tracks: list[dict[str, Any]]) -> list[str]:
    """The tracker's consistency: one line for the calibration, a WARNING per track whose
    belief was overconfident or badly calibrated (the guarantees held w.r.t. that belief,
    not necessarily w.r.t. the true obstacles)."""
    if not tracks:
        return []
    calibrations = [t["calibration_95"] for t in tracks if t["calibration_95"] is not None]
    lines = []
    if calibrations:
        lines.append(
            f"  tracker: true centre in the belief's 95 % ellipsoid at "
            f"{min(calibrations):.3f}–{max(calibrations):.3f} of the tracked times per track"
        )
    for track in tracks:
        if track["warning"]:
            lines.append(
                f"  WARNING: belief inconsistent with the truth, {track['warning']}; the "
                "guarantees hold w.r.t. this belief only"
            )
    return lines


def guarantee_lines(invariants: dict[str, Any], tolerance: float) -> list[str]:
    """The guarantees' lines of a run's summary: per guarantee (metrics.json's
    `invariants`), holds or VIOLATED, its worst margin and when."""
    lines = [f"  guarantees (worst margin, at time; holds if ≥ −{tolerance:g}):"]
    for name, record in invariants.items():
        verdict = "holds" if record["holds"] else "VIOLATED"
        if "note" in record:
            lines.append(f"    {name:<26} {verdict:<8} — {record['note']}")
            continue
        lines.append(
            f"    {name:<26} {verdict:<8} {record['worst_margin']:+.3e} at t = "
            f"{record['t_worst']:.2f} s"
        )
    return lines


def guarantees_report(tracker: InvariantTracker) -> str:
    """What ``stt-drake run`` prints of the guarantees, for a run of one's own Diagram:
    one line per guarantee (:data:`stt_drake.core.invariants.INVARIANT_NAMES`) with holds
    or VIOLATED, its worst margin (m for the lengths, else a probability margin) and the
    time it occurred, e.g. ``output_avoid_probability   holds    +7.412e-02 at t = 1.72
    s``; a guarantee never evaluated reads ``+inf at t = 0.00 s``."""
    lines = guarantee_lines(tracker.as_dict(), HOLDS_TOLERANCE)
    return "\n".join(line.removeprefix("  ") for line in lines)  # the summary's indent


def summary(result: RunResult) -> str:
    """A short human-readable summary of a run."""
    m = result.metrics
    lines = [f"scenario {m['scenario']}"]
    if m["stop_reason"]:
        label = "STALLED" if m["stop_reason"].startswith("stall:") else "STOPPED EARLY"
        lines.append(f"  {label}: {m['stop_reason']}")
    lines += _reach_lines(m)
    lines += guarantee_lines(m["invariants"], m["holds_tolerance"])
    lines += _story_lines(m)
    factor = m["realtime_factor"]
    lines.append(
        f"  simulated {m['sim_time_s']:.1f} s in {m['wall_time_s']:.2f} s wall "
        f"(real-time factor {factor if factor is not None else math.nan:.1f}×, "
        f"{m['steps']} steps)"
    )
    if m["obstacles"]:
        lines.append("  closest approach to each obstacle mean (distance, σ, ε):")
    for o in m["obstacles"]:
        lines.append(
            f"    #{o['index']:<3} {o['min_distance_to_mean']:.3f} m  σ = {o['sigma']:.3f} m  "
            f"ε = {o['epsilon']:.3f}"
        )
    lines += result.plant_summary
    lines += _track_lines(m.get("tracks", []))
    lines.append("  result: " + ("SUCCESS" if result.success else "FAILURE"))
    return "\n".join(lines)
