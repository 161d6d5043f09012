"""Simulate a scenario, check every guarantee, and write metrics, logs and figures."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator

from stt_drake.belief import record_size
from stt_drake.builders import SttDiagram, build_diagram
from stt_drake.invariants import HOLDS_TOLERANCE, InvariantTracker, tube_reach_time
from stt_drake.manipulator import summarize_arm
from stt_drake.scenario import Scenario, obstacle_rate_bounds


@dataclass
class RunResult:
    """A finished run: the metrics (the `metrics.json` contract) and the logs."""

    metrics: dict[str, Any]
    log: dict[str, np.ndarray]

    @property
    def success(self) -> bool:
        """Every guarantee held, the target was reached (every task of a sequence) and no
        plant limit was exceeded (exit code 0)."""
        limits = self.metrics.get("limits", {}).values()
        return bool(
            self.metrics["holds"]
            and self.metrics["reached"]
            and all(record["holds"] for record in limits)
        )


def collect_log(built: SttDiagram, scenario: Scenario, root_context: object) -> dict[str, Any]:
    """Read every logger into one dict of arrays (the `log.npz` layout, samples first)."""
    logs = {name: sink.FindLog(root_context) for name, sink in built.loggers.items()}
    mean_speed_bound, sigma_rate_bound = obstacle_rate_bounds(scenario.obstacles)
    n, m = scenario.dimension, len(scenario.obstacles)
    tube = logs["tube"].data().T
    diagnostics = logs["diagnostics"].data().T.reshape(-1, 3, m)
    log = {
        "name": np.array(scenario.name),
        "t": logs["tube"].sample_times().copy(),
        "output": logs["output"].data().T.copy(),
        "center": tube[:, :n].copy(),
        "radius": tube[:, n].copy(),
        "belief": logs["belief"].data().T.copy(),
        "avoid_probability": diagnostics[:, 0, :].copy(),
        "quantile_distance": diagnostics[:, 1, :].copy(),
        "theta": diagnostics[:, 2, :].copy(),
        "recovery": logs["recovery"].data().T.copy(),
        "control": logs["control"].data().T.copy(),
        "margins": logs["margins"].data().T.copy(),
        "output_avoid_probability": logs["output_avoid_probability"].data().T.copy(),
        "tube_avoid_probability": logs["tube_avoid_probability"].data().T.copy(),
        "dimension": np.array(n),
        "start": np.asarray(scenario.start, dtype=float),
        "initial_set_radius": np.array(scenario.initial_set_radius),
        "target": np.asarray(scenario.target, dtype=float),
        "target_set_radius": np.array(scenario.target_set_radius),
        "r_min": np.array(scenario.tube.r_min),
        "r_max": np.array(scenario.tube.r_max),
        "mean_speed_bound": mean_speed_bound,
        "sigma_rate_bound": sigma_rate_bound,
    }
    for name in built.extra_logs:  # plant-specific signals, samples first
        log[name] = logs[name].data().T.copy()
    log.update({name: np.asarray(value) for name, value in built.log_constants.items()})
    return log


def obstacle_report(log: dict[str, np.ndarray], scenario: Scenario) -> list[dict[str, Any]]:
    """Per obstacle: the closest approach of y to its mean, and its σ and ε."""
    n = scenario.dimension
    table = log["belief"].reshape(len(log["t"]), -1, record_size(n))
    means, sigmas = table[:, :, :n], table[:, :, n]
    distance = np.linalg.norm(log["output"][:, None, :] - means, axis=2)
    report = []
    for j, obstacle in enumerate(scenario.obstacles):
        k = int(np.argmin(distance[:, j]))
        report.append(
            {
                "index": j,
                "min_distance_to_mean": float(distance[k, j]),
                "t_min_distance": float(log["t"][k]),
                "sigma": float(sigmas[k, j]),
                "radius": obstacle.radius,
                "epsilon": obstacle.epsilon,
                "min_output_avoid_probability": float(
                    np.min(log["output_avoid_probability"][:, j])
                ),
            }
        )
    return report


def simulate(scenario: Scenario, strict: bool | None = None) -> RunResult:
    """Build, simulate for `scenario.duration` and check every guarantee.

    The guarantees are evaluated at every integrator step (Simulator monitor) and at every
    logged sample; `strict` (default: the scenario's) stops at the first violation.
    """
    strict = scenario.strict if strict is None else strict
    built = build_diagram(scenario)
    simulator = Simulator(built.diagram)
    ApplySimulatorConfig(scenario.simulator, simulator)
    tracker = InvariantTracker()
    built.monitor.attach(simulator, tracker, strict)
    stopped = None
    start = time.perf_counter()
    simulator.Initialize()
    try:
        simulator.AdvanceTo(scenario.duration)
    except RuntimeError as error:
        if tracker.first_violation is None or tracker.first_violation not in str(error):
            raise
        stopped = tracker.first_violation
    wall_time = time.perf_counter() - start
    context = simulator.get_context()
    sim_time = context.get_time()
    log = collect_log(built, scenario, context)
    tracker.update_many(log["t"], log["margins"])
    t_reach = tube_reach_time(
        log["t"], log["center"], log["radius"], log["target"], scenario.target_set_radius
    )
    # Plant-specific metrics; a task sequence is reached only when every task completed.
    plant_metrics = built.plant_report(log) if built.plant_report is not None else {}
    segments = plant_metrics.get("segments", [])
    metrics = {
        "scenario": scenario.name,
        "reached": t_reach is not None
        and stopped is None
        and all(segment["completed"] for segment in segments),
        "t_reach": t_reach,
        "holds": tracker.holds,
        "sim_time_s": sim_time,
        "wall_time_s": wall_time,
        "realtime_factor": sim_time / wall_time if wall_time > 0 else None,
        "steps": simulator.get_num_steps_taken(),
        "holds_tolerance": HOLDS_TOLERANCE,
        "strict_stop": stopped,
        "first_violation": tracker.first_violation,
        "invariants": tracker.as_dict(),
        "obstacles": obstacle_report(log, scenario),
        **plant_metrics,
    }
    return RunResult(metrics, log)


def write_outputs(result: RunResult, out_dir: Path, figures: bool = True) -> list[Path]:
    """Write metrics.json, log.npz and (optionally) the PNG figures into `out_dir`."""
    out_dir.mkdir(parents=True, exist_ok=True)
    metrics_path = out_dir / "metrics.json"
    metrics_path.write_text(json.dumps(result.metrics, indent=2) + "\n")
    log_path = out_dir / "log.npz"
    np.savez_compressed(log_path, **result.log)
    written = [metrics_path, log_path]
    if figures:
        from stt_drake.plotting import save_run_figures

        written += save_run_figures(result.log, out_dir)
    return written


def summary(result: RunResult) -> str:
    """A short human-readable summary of a run."""
    m = result.metrics
    lines = [f"scenario {m['scenario']}"]
    if m["reached"]:
        lines.append(f"  reached the target set: yes, t_c = {m['t_reach']:.2f} s")
    else:
        lines.append("  reached the target set: NO")
    lines.append(f"  guarantees (worst margin, at time; holds if ≥ −{m['holds_tolerance']:g}):")
    for name, record in m["invariants"].items():
        verdict = "holds" if record["holds"] else "VIOLATED"
        lines.append(
            f"    {name:<26} {verdict:<8} {record['worst_margin']:+.3e} at t = "
            f"{record['t_worst']:.2f} s"
        )
    if m["strict_stop"]:
        lines.append(f"  stopped (strict): {m['strict_stop']}")
    lines.append(
        f"  simulated {m['sim_time_s']:.1f} s in {m['wall_time_s']:.2f} s wall "
        f"(real-time factor {m['realtime_factor']:.1f}×, {m['steps']} steps)"
    )
    lines.append("  closest approach to each obstacle mean (distance, σ, ε):")
    for o in m["obstacles"]:
        lines.append(
            f"    #{o['index']:<3} {o['min_distance_to_mean']:.3f} m  σ = {o['sigma']:.3f} m  "
            f"ε = {o['epsilon']:.3f}"
        )
    arm = summarize_arm(m)
    if arm:
        lines.append("  tasks, joint limits and jerks:")
        lines += arm
    lines.append("  result: " + ("SUCCESS" if result.success else "FAILURE"))
    return "\n".join(lines)
