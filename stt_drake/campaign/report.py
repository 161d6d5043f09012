"""What a campaign reports: the per-kind summaries with their simultaneous Clopper-Pearson
bounds, ``campaign.json``, the figure and the printed table.

Summaries are order-independent functions of the set of runs. The statistics are in
:mod:`stt_drake.core.statistics`. Randomisation and end-to-end summaries also hold the
crowd metrics against the true obstacles (:func:`stt_drake.campaign.crowd_metrics.crowd_summary`:
`collision_rate`, `min_distance_m` p5/p50, `comfort_violation_s` p50/p90, per-obstacle
frequencies against 1 − ε_j).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stt_drake.campaign.crowd_metrics import crowd_line, crowd_summary
from stt_drake.campaign.end_to_end import logged_times
from stt_drake.campaign.randomisation import draw_failed, failure_name, stalled_to_end
from stt_drake.campaign.sampling import CHECKS, ClosedLoop, output_collided
from stt_drake.campaign.spec import CampaignSpec
from stt_drake.core.consistency import CALIBRATION_LEVEL
from stt_drake.core.statistics import (
    VIOLATED,
    clopper_pearson,
    family_confidence,
    simultaneous_verdict,
)
from stt_drake.runlog import write_json

#: Confidence of every reported interval (jointly, over the whole family of tests).
CONFIDENCE = 0.99
SUMMARY_FILE = "campaign.json"

PROCEDURE = (
    "Simultaneous two-sided Clopper-Pearson intervals, Bonferroni over the whole family "
    "fixed before sampling: every (check in {output, tube}) x (obstacle) x (logged time). "
    "Each interval has level 1 - alpha/F (alpha = 0.01, F = family_size), so with "
    "probability >= 99 % all of them cover their collision probability at once. No "
    "pilot set, no data-driven choice of times: the worst time is reported, but it is "
    "tested at the simultaneous level, so taking the worst of many times causes no bias. "
    "certified: upper bound <= 1 - epsilon_j at every logged time; violated: lower bound "
    "> 1 - epsilon_j at some logged time; the claim covers the logged times only."
)


def collision_counts(records: Iterable[dict[str, Any]], count: int, steps: int) -> np.ndarray:
    """Per check, obstacle and time, how many runs collided: (len(CHECKS), m, T) ints."""
    edges = np.zeros((len(CHECKS), count, steps + 1), dtype=np.int64)
    for record in records:
        for c, check in enumerate(CHECKS):
            for j, ranges in enumerate(record[check]):
                for start, stop in ranges:
                    edges[c, j, start] += 1
                    edges[c, j, stop] -= 1
    return np.cumsum(edges, axis=2)[:, :, :steps]


def summarise_true_obstacles(loop: ClosedLoop, records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per obstacle and check: worst-time frequency, simultaneous CP bounds and verdict."""
    runs = len(records)
    steps = len(loop.t)
    counts = collision_counts(records, loop.count, steps)
    family = len(CHECKS) * loop.count * steps
    member = family_confidence(CONFIDENCE, family)
    model = loop.collision_probability()
    obstacles = []
    for j in range(loop.count):
        entry: dict[str, Any] = {"index": j}
        for c, check in enumerate(CHECKS):
            verdict, record = _verdict(
                counts[c, j], runs, loop.epsilon[j], loop.t, member, model[check][:, j]
            )
            record["model_collision_probability_at_t_worst"] = float(model[check][verdict.index, j])
            record["model_worst_collision_probability"] = float(np.max(model[check][:, j]))
            if check == "output":
                entry.update(record)
            else:
                entry["tube"] = record
        obstacles.append(entry)
    return {
        "holds": _holds(obstacles),
        "procedure": _procedure(family, member, steps),
        "runs_with_output_collision": sum(output_collided(r) for r in records),
        "runs_with_tube_collision": sum(any(r["tube"]) for r in records),
        "obstacles": obstacles,
    }


def _verdict(
    counts: np.ndarray,
    runs: int,
    epsilon: float,
    times: np.ndarray,
    member: float,
    tie_break: np.ndarray | None = None,
) -> tuple[Any, dict[str, Any]]:
    """The simultaneous verdict on one obstacle and check, and its campaign.json record."""
    allowed = 1.0 - float(epsilon)
    verdict = simultaneous_verdict(counts, runs, allowed, member, tie_break)
    return verdict, {
        "epsilon": float(epsilon),
        "allowed_collision_probability": allowed,
        "worst_collision_frequency": verdict.frequency,
        "collisions_at_worst": int(counts[verdict.index]),
        "t_worst": float(times[verdict.index]),
        "clopper_pearson_upper_99": verdict.upper,
        "clopper_pearson_lower_99": verdict.lower,
        "verdict": verdict.verdict,
        "runs_to_certify": verdict.runs_to_certify,
    }


def _holds(obstacles: Sequence[dict[str, Any]]) -> bool:
    """No obstacle's output or tube verdict is `violated`."""
    return not any(o["verdict"] == VIOLATED or o["tube"]["verdict"] == VIOLATED for o in obstacles)


def _procedure(family: int, member: float, steps: int) -> dict[str, Any]:
    return {
        "name": "simultaneous-clopper-pearson-bonferroni",
        "confidence": CONFIDENCE,
        "family_size": family,
        "member_confidence": member,
        "logged_times": steps,
        "description": PROCEDURE,
    }


def summarise_end_to_end(
    records: Sequence[dict[str, Any]], epsilon: np.ndarray, times: np.ndarray
) -> dict[str, Any]:
    """Per obstacle: worst-time collision frequency with the TRUE obstacles, simultaneous CP
    bounds and verdict (as the true-obstacle kind), the belief's calibration (fraction of
    tracked logged times with the true centre in the belief's 95 % ellipsoid, with its 99 %
    CP interval), and how the runs went."""
    runs, steps, count = len(records), len(times), len(epsilon)
    counts = collision_counts(records, count, steps)
    family = len(CHECKS) * count * steps
    member = family_confidence(CONFIDENCE, family)
    simulated = [r for r in records if r["status"] == "simulated"]
    obstacles = []
    for j in range(count):
        entry: dict[str, Any] = {"index": j}
        for c, check in enumerate(CHECKS):
            record = _verdict(counts[c, j], runs, epsilon[j], times, member)[1]
            if check == "output":
                entry.update(record)
            else:
                entry["tube"] = record
        inside = sum(r["inside"][j] for r in simulated)
        tracked = sum(r["tracked"][j] for r in simulated)
        entry["calibration_95"] = inside / tracked if tracked else None
        obstacles.append(entry)
    inside = sum(sum(r["inside"]) for r in simulated)
    tracked = sum(sum(r["tracked"]) for r in simulated)
    lower, upper = clopper_pearson(inside, tracked, CONFIDENCE) if tracked else (None, None)
    return {
        "holds": _holds(obstacles) and len(simulated) == runs,  # no run raised
        "procedure": _procedure(family, member, steps),
        "simulated_runs": len(simulated),
        "error_runs": runs - len(simulated),
        "runs_with_output_collision": sum(any(r["output"]) for r in records),
        "runs_with_tube_collision": sum(any(r["tube"]) for r in records),
        "guarantees_held_fraction": _fraction(simulated, "holds"),
        "reached_fraction": _fraction(simulated, "reached"),
        "calibration": {
            "level": CALIBRATION_LEVEL,
            "fraction_inside": inside / tracked if tracked else None,
            "clopper_pearson_lower_99": None if lower is None else float(lower),
            "clopper_pearson_upper_99": None if upper is None else float(upper),
            "tracked_times": tracked,
            "note": "logged times are correlated within a run: the interval treats them as "
            "independent and is too narrow; read it as descriptive",
        },
        "obstacles": obstacles,
    }


def _fraction(records: Sequence[dict[str, Any]], key: str) -> float | None:
    return sum(r[key] for r in records) / len(records) if records else None


def _distribution(values: Sequence[float]) -> dict[str, float | None]:
    if not values:
        return dict.fromkeys(("min", "p05", "median", "p95", "max", "mean"))
    data = np.asarray(values, dtype=float)
    quantiles = np.quantile(data, [0.0, 0.05, 0.5, 0.95, 1.0])
    keys = ("min", "p05", "median", "p95", "max")
    return {
        **{k: float(v) for k, v in zip(keys, quantiles, strict=True)},
        "mean": float(data.mean()),
    }


def _percentiles(values: Sequence[float]) -> dict[str, float] | None:
    """{"p50", "p90", "p99"} of `values` (None when there are none)."""
    if not values:
        return None
    p50, p90, p99 = np.percentile(np.asarray(values, dtype=float), [50.0, 90.0, 99.0])
    return {"p50": float(p50), "p90": float(p90), "p99": float(p99)}


def summarise_randomisation(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Fraction of simulated draws where each guarantee held, t_c, worst margins, failures;
    how many draws reached (`reach_rate`, `t_reach_percentiles` over them) and how many
    ended in a stall (`stall_rate`: a stall lasting to the end)."""
    simulated = [r for r in records if r["status"] == "simulated"]
    failed = sorted((r for r in records if draw_failed(r)), key=lambda r: r["run"])
    guarantees: dict[str, Any] = {}
    names = list(simulated[0]["invariants"]) if simulated else []
    for name in names:
        worst = min(simulated, key=lambda r: (r["invariants"][name]["worst_margin"], r["run"]))
        held = sum(r["invariants"][name]["holds"] for r in simulated)
        guarantees[name] = {
            "held_runs": held,
            "held_fraction": held / len(simulated),
            "worst_margin": worst["invariants"][name]["worst_margin"],
            "t_worst": worst["invariants"][name]["t_worst"],
            "worst_run": worst["run"],
            "worst_seed": worst["seed"],
        }
    reached = sum(r["reached"] for r in simulated)
    guarantees["reach_and_stay"] = {
        "held_runs": reached,
        "held_fraction": reached / len(simulated) if simulated else None,
    }
    valid = len(simulated) + sum(r["status"] == "error" for r in records)  # not rejected
    upper = float(clopper_pearson(len(failed), valid, CONFIDENCE)[1]) if valid else None
    return {
        "holds": bool(simulated) and not failed,
        "simulated_runs": len(simulated),
        "rejected_draws": sum(r["status"] == "rejected" for r in records),
        "error_runs": sum(r["status"] == "error" for r in records),
        "failed_runs": len(failed),
        "failure_rate_clopper_pearson_upper_99": upper,
        "guarantees": guarantees,
        "t_reach": _distribution([r["t_reach"] for r in simulated if r["t_reach"] is not None]),
        "reach_rate": _fraction(simulated, "reached"),
        "t_reach_percentiles": _percentiles([r["t_reach"] for r in simulated if r["reached"]]),
        "stall_rate": (
            sum(stalled_to_end(r) for r in simulated) / len(simulated) if simulated else None
        ),
        "failures": [
            {"run": r["run"], "seed": r["seed"], "yaml": failure_name(r["run"])} for r in failed
        ],
        "obstacles": [],
    }


def error_summary(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """``error_runs`` (the runs whose record has status ``error``: the run raised) and
    ``first_error`` (the lowest such run's ``run``, ``seed`` and ``reason``, or None)."""
    errors = [r for r in records if r.get("status") == "error"]
    first = min(errors, key=lambda r: r["run"], default=None)
    return {
        "error_runs": len(errors),
        "first_error": None
        if first is None
        else {"run": first["run"], "seed": first["seed"], "reason": first["reason"]},
    }


def write_summary(
    spec: CampaignSpec,
    scenario_name: str,
    records: Sequence[dict[str, Any]],
    out_dir: Path,
    started: float,
    closed_loop: ClosedLoop | None = None,
    closed_loop_summary: dict[str, Any] | None = None,
    figures: bool = True,
    malformed_lines: int = 0,
    scenario: Any = None,
) -> dict[str, Any]:
    """Summarise the finished runs, write campaign.json (strict JSON) and the figure, and
    return the summary.

    `started` is the campaign's ``time.perf_counter()`` start; `closed_loop` and its
    summary belong to a true-obstacle campaign, `scenario` to an end-to-end one;
    `malformed_lines` counts the lines of ``runs.jsonl`` a resume skipped (their runs were
    redone).
    """
    randomising = spec.kind == "randomisation"
    if spec.kind == "end-to-end":
        epsilon = np.array([o.epsilon for o in scenario.obstacles], dtype=float)
        times = scenario.log_period * np.arange(logged_times(scenario))
        body = summarise_end_to_end(records, epsilon, times)
    elif randomising:
        body = summarise_randomisation(records)
    else:
        body = summarise_true_obstacles(closed_loop, records)
        body["true_obstacle_motion"] = spec.motion
        body["ou_tau_s"] = spec.tau if spec.motion == "ou" else None
        body["closed_loop"] = closed_loop_summary
    if spec.kind != "true-obstacles":
        body.update(crowd_summary(records, spec.comfort_distance))
    body.update(error_summary(records))
    if body["error_runs"]:
        body["holds"] = False  # a run that raised checked nothing: no verdict can hold
    summary = {
        "scenario": scenario_name,
        "scenario_path": str(Path(spec.scenario)),
        "kind": spec.kind,
        "runs": spec.runs,
        "seed": spec.seed,
        "guide": spec.guide,
        "run_seed": "SeedSequence(seed, spawn_key=(i,)).generate_state(1)[0]",
        "wall_time_s": time.perf_counter() - started,
        "malformed_lines": malformed_lines,
        **body,
    }
    write_json(out_dir / SUMMARY_FILE, summary)
    if figures:
        if spec.kind == "end-to-end":
            figure = plot_end_to_end(summary, records, epsilon, times)
            file = "end_to_end.png"
        elif randomising:
            figure, file = plot_randomisation(summary, records), "randomisation.png"
        else:
            figure, file = plot_collision_frequency(closed_loop, records), "collision_frequency.png"
        figure.savefig(out_dir / file, dpi=120)
    return summary


def plot_collision_frequency(loop: ClosedLoop, records: Sequence[dict[str, Any]]) -> Any:
    """Empirical collision frequency over time per obstacle (output and tube) with its
    simultaneous 99 % Clopper-Pearson band, against 1 − ε_j and the belief's prediction."""
    from matplotlib.figure import Figure

    from stt_drake.plotting import PALETTE

    runs, steps = len(records), len(loop.t)
    counts = collision_counts(records, loop.count, steps)
    member = family_confidence(CONFIDENCE, len(CHECKS) * loop.count * steps)
    model = loop.collision_probability()
    figure = Figure(figsize=(8.0, 1.9 * loop.count + 0.8), layout="constrained")
    axes = figure.subplots(loop.count, 1, sharex=True, squeeze=False)[:, 0]
    styles = {"output": (PALETTE["trajectory"], "output y"), "tube": (PALETTE["tube"], "tube Γ")}
    for j, ax in enumerate(axes):
        allowed = 1.0 - loop.epsilon[j]
        for c, check in enumerate(CHECKS):
            colour, label = styles[check]
            lower, upper = clopper_pearson(counts[c, j], runs, member)
            ax.fill_between(loop.t, lower, upper, color=colour, alpha=0.15, linewidth=0)
            ax.plot(loop.t, counts[c, j] / runs, color=colour, lw=1.2, label=f"{label}: frequency")
            ax.plot(
                loop.t, model[check][:, j], color=colour, lw=0.8, ls=":", label=f"{label}: belief"
            )
        ax.axhline(allowed, color=PALETTE["violation"], ls="--", lw=1.0, label="1 − ε_j")
        ax.set_ylim(0.0, max(1.6 * allowed, 1.1 * float(np.max(counts[:, j])) / runs))
        ax.set_ylabel(f"obstacle {j}\nP(collision)")
        ax.set_title(f"obstacle {j}: ε = {loop.epsilon[j]:.3g}", fontsize=9, loc="left")
    axes[0].legend(fontsize=7, ncols=3, loc="upper right")
    axes[-1].set_xlabel("t (s)")
    figure.suptitle(f"true-obstacle campaign, {runs} runs (bands: simultaneous 99 % CP)")
    return figure


def plot_end_to_end(
    summary: dict[str, Any],
    records: Sequence[dict[str, Any]],
    epsilon: np.ndarray,
    times: np.ndarray,
) -> Any:
    """Collision frequency with the TRUE obstacles over time per obstacle (output), with
    its simultaneous 99 % CP band, against 1 − ε_j; and the belief's calibration per
    obstacle against 0.95."""
    from matplotlib.figure import Figure

    from stt_drake.plotting import PALETTE

    runs, count = len(records), len(epsilon)
    counts = collision_counts(records, count, len(times))
    member = summary["procedure"]["member_confidence"]
    figure = Figure(figsize=(10.0, 3.6), layout="constrained")
    left, right = figure.subplots(1, 2, width_ratios=[2, 1])
    for j in range(count):
        colour = f"C{j % 10}"
        lower, upper = clopper_pearson(counts[0, j], runs, member)
        left.fill_between(times, lower, upper, color=colour, alpha=0.12, linewidth=0)
        left.plot(times, counts[0, j] / runs, color=colour, lw=1.2, label=f"obstacle {j}")
        left.axhline(1.0 - epsilon[j], color=colour, ls="--", lw=0.8)
    left.set(xlabel="t (s)", ylabel="P(‖y − O_true‖ < r_o)", title="collisions (dashed: 1 − ε_j)")
    left.legend(fontsize=7)
    calibration = [o["calibration_95"] or 0.0 for o in summary["obstacles"]]
    right.bar(range(count), calibration, color=PALETTE["tube"])
    right.axhline(CALIBRATION_LEVEL, color=PALETTE["reference"], ls="--", lw=1.0)
    right.set(xlabel="obstacle", ylabel="true centre in 95 % ellipsoid", ylim=(0.0, 1.0))
    right.set_xticks(range(count))
    figure.suptitle(f"end-to-end campaign, {runs} runs (bands: simultaneous 99 % CP)")
    return figure


def plot_randomisation(summary: dict[str, Any], records: Sequence[dict[str, Any]]) -> Any:
    """t_c histogram and every run's worst margin per guarantee (red: failed runs)."""
    from matplotlib.figure import Figure

    from stt_drake.plotting import PALETTE

    simulated = [r for r in records if r["status"] == "simulated"]
    figure = Figure(figsize=(10.0, 3.6), layout="constrained")
    left, right = figure.subplots(1, 2, width_ratios=[1, 2])
    reach = [r["t_reach"] for r in simulated if r["t_reach"] is not None]
    left.hist(reach, bins=max(5, int(np.sqrt(len(reach) or 1))), color=PALETTE["tube"])
    left.set_xlabel("t_c (s)")
    left.set_ylabel("runs")
    left.set_title(f"reached: {len(reach)} / {len(simulated)} simulated", fontsize=9)
    names = [n for n in summary["guarantees"] if n != "reach_and_stay"]
    for k, name in enumerate(names):
        margins = np.array([r["invariants"][name]["worst_margin"] for r in simulated])
        colours = [PALETTE["violation"] if draw_failed(r) else PALETTE["margin"] for r in simulated]
        jitter = np.linspace(-0.25, 0.25, len(margins)) if len(margins) > 1 else [0.0]
        right.scatter(k + np.asarray(jitter), margins, c=colours, s=8)
    right.axhline(0.0, color=PALETTE["reference"], lw=0.8)
    right.set_yscale("symlog", linthresh=1e-3)
    right.set_xticks(range(len(names)), [n.replace("_", "\n") for n in names], fontsize=7)
    right.set_ylabel("worst margin per run")
    figure.suptitle(
        f"randomisation campaign: {summary['runs']} runs, {summary['rejected_draws']} rejected, "
        f"{summary['failed_runs']} failed"
    )
    return figure


def _reach_and_stall_line(summary: dict[str, Any]) -> str:
    """The randomisation summary's line on reaching and stalling."""

    def rate(value: float | None) -> str:
        return "n/a" if value is None else f"{value:.3f}"

    line = f"  reached in {rate(summary['reach_rate'])} of simulated draws"
    percentiles = summary["t_reach_percentiles"]
    if percentiles is not None:
        line += (
            f" (t_c p50 {percentiles['p50']:.2f} s, p90 {percentiles['p90']:.2f} s, "
            f"p99 {percentiles['p99']:.2f} s)"
        )
    return line + f"; stalled to the end in {rate(summary['stall_rate'])}"


def report(summary: dict[str, Any]) -> str:
    """The printed campaign summary (per-obstacle table for true-obstacle campaigns)."""
    lines = [
        f"{summary['kind']} campaign on {summary['scenario']}: {summary['runs']} runs, "
        f"seed {summary['seed']}, {summary['wall_time_s']:.1f} s wall"
    ]
    if summary["kind"] == "end-to-end":
        calibration = summary["calibration"]
        fraction = calibration["fraction_inside"]
        lines.append(
            f"  simulated {summary['simulated_runs']}, errors {summary['error_runs']}; every "
            f"guarantee held in {summary['guarantees_held_fraction']} of runs, target reached "
            f"in {summary['reached_fraction']}"
        )
        lines.append(
            "  calibration: true centre inside the belief's 95 % ellipsoid at "
            + ("n/a" if fraction is None else f"{fraction:.4f}")
            + f" of tracked logged times (expected {calibration['level']:g})"
        )
    if summary["kind"] in ("true-obstacles", "end-to-end"):
        if summary["kind"] == "true-obstacles":
            loop = summary["closed_loop"]
            lines.append(
                f"  closed loop simulated {loop['simulations']} time(s); true obstacles: "
                f"{summary['true_obstacle_motion']}"
                + (f" (OU, τ = {summary['ou_tau_s']:g} s)" if summary["ou_tau_s"] else "")
            )
        lines.append(
            f"  simultaneous 99 % Clopper-Pearson over {summary['procedure']['family_size']} "
            "(check × obstacle × time) intervals"
        )
        lines.append(
            "  obst  check   ε      1−ε      worst freq  t_worst   CP99 lower  CP99 upper  verdict"
        )
        for o in summary["obstacles"]:
            for check, record in (("output", o), ("tube", o["tube"])):
                more = ""
                if record["runs_to_certify"] is not None:
                    more = f" (≈{record['runs_to_certify']} runs would certify)"
                lines.append(
                    f"  #{o['index']:<3} {check:<7} {o['epsilon']:<6.3g} "
                    f"{record['allowed_collision_probability']:<8.4g} "
                    f"{record['worst_collision_frequency']:<11.5f} {record['t_worst']:<8.2f}  "
                    f"{record['clopper_pearson_lower_99']:<11.5f} "
                    f"{record['clopper_pearson_upper_99']:<11.5f} {record['verdict']}{more}"
                )
    else:
        lines.append(
            f"  simulated {summary['simulated_runs']}, rejected draws {summary['rejected_draws']}, "
            f"errors {summary['error_runs']}, failed {summary['failed_runs']}"
        )
        for name, g in summary["guarantees"].items():
            fraction = g["held_fraction"]
            text = "n/a" if fraction is None else f"{fraction:.3f}"
            worst = (
                f", worst margin {g['worst_margin']:+.3e} (run {g['worst_run']})"
                if "worst_margin" in g
                else ""
            )
            lines.append(f"    {name:<26} held in {text} of runs{worst}")
        lines.append(_reach_and_stall_line(summary))
        t_reach = summary["t_reach"]
        if t_reach["median"] is not None:
            lines.append(
                f"  t_c: median {t_reach['median']:.2f} s, 5-95 % [{t_reach['p05']:.2f}, "
                f"{t_reach['p95']:.2f}] s, max {t_reach['max']:.2f} s"
            )
        for failure in summary["failures"]:
            lines.append(
                f"  failing draw: run {failure['run']} seed {failure['seed']} → {failure['yaml']}"
            )
    if "crowd_runs" in summary:
        lines.append(crowd_line(summary))
    if summary.get("error_runs"):
        first = summary["first_error"]
        reason = (first["reason"].strip().splitlines() or [""])[0]
        lines.append(
            f"  {summary['error_runs']} run(s) raised: first error (run {first['run']}, seed "
            f"{first['seed']}): {reason[:300]}"
        )
    if summary.get("malformed_lines"):
        lines.append(
            f"  runs.jsonl: {summary['malformed_lines']} malformed line(s) skipped; their runs "
            "were redone"
        )
    lines.append("  result: " + ("HOLDS" if summary["holds"] else "DOES NOT HOLD"))
    return "\n".join(lines)
