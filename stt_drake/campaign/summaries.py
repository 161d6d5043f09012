"""What a campaign's runs add up to: the per-kind summaries (the body of
``campaign.json``) with their simultaneous Clopper-Pearson bounds, and the per-kind lines
of the printed report. Which kind uses which is :mod:`stt_drake.campaign.kinds`.

Summaries are order-independent functions of the set of runs. The statistics are in
:mod:`stt_drake.core.statistics`. Randomisation and end-to-end summaries also hold the
crowd metrics against the true obstacles (:func:`stt_drake.campaign.crowd_metrics.crowd_summary`:
`collision_rate`, `min_distance_m` p5/p50, `comfort_violation_s` p50/p90, per-obstacle
frequencies against 1 − ε_j).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from stt_drake.campaign.randomisation import draw_failed, failure_name, stalled_to_end
from stt_drake.campaign.sampling import CHECKS, ClosedLoop, output_collided
from stt_drake.core.consistency import CALIBRATION_LEVEL
from stt_drake.core.statistics import (
    VIOLATED,
    clopper_pearson,
    family_confidence,
    simultaneous_verdict,
    verdict_words,
)

#: Confidence of every reported interval (jointly, over the whole family of tests).
CONFIDENCE = 0.99

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
    how many draws reached (`reach_rate`, `t_tube_in_target_percentiles` over them) and how many
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
        "t_tube_in_target": _distribution(
            [r["t_tube_in_target"] for r in simulated if r["t_tube_in_target"] is not None]
        ),
        "reach_rate": _fraction(simulated, "reached"),
        "t_tube_in_target_percentiles": _percentiles(
            [r["t_tube_in_target"] for r in simulated if r["reached"]]
        ),
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


def _reach_and_stall_line(summary: dict[str, Any]) -> str:
    """The randomisation summary's line on reaching and stalling."""

    def rate(value: float | None) -> str:
        return "n/a" if value is None else f"{value:.3f}"

    line = f"  reached in {rate(summary['reach_rate'])} of simulated draws"
    percentiles = summary["t_tube_in_target_percentiles"]
    if percentiles is not None:
        line += (
            f" (t_c p50 {percentiles['p50']:.2f} s, p90 {percentiles['p90']:.2f} s, "
            f"p99 {percentiles['p99']:.2f} s)"
        )
    return line + f"; stalled to the end in {rate(summary['stall_rate'])}"


def end_to_end_lines(summary: dict[str, Any]) -> list[str]:
    """The printed lines of an end-to-end summary: how the runs went, the belief's
    calibration, then the verdict table (:func:`verdict_table_lines`)."""
    calibration = summary["calibration"]
    fraction = calibration["fraction_inside"]
    return [
        f"  simulated {summary['simulated_runs']}, errors {summary['error_runs']}; every "
        f"guarantee held in {summary['guarantees_held_fraction']} of runs, target reached "
        f"in {summary['reached_fraction']}",
        "  calibration: true centre inside the belief's 95 % ellipsoid at "
        + ("n/a" if fraction is None else f"{fraction:.4f}")
        + f" of tracked logged times (expected {calibration['level']:g})",
        *verdict_table_lines(summary),
    ]


def true_obstacle_lines(summary: dict[str, Any]) -> list[str]:
    """The printed lines of a true-obstacle summary: the closed loop and the motion, then
    the verdict table (:func:`verdict_table_lines`)."""
    loop = summary["closed_loop"]
    return [
        f"  closed loop simulated {loop['simulations']} time(s); true obstacles: "
        f"{summary['true_obstacle_motion']}"
        + (f" (OU, τ = {summary['ou_tau_s']:g} s)" if summary["ou_tau_s"] else ""),
        *verdict_table_lines(summary),
    ]


def verdict_table_lines(summary: dict[str, Any]) -> list[str]:
    """The per-obstacle table of the output and tube verdicts (true-obstacle and
    end-to-end summaries)."""
    lines = [
        f"  simultaneous 99 % Clopper-Pearson over {summary['procedure']['family_size']} "
        "(check × obstacle × time) intervals",
        "  obst  check   ε      1−ε      worst freq  t_worst   CP99 lower  CP99 upper  verdict",
    ]
    for o in summary["obstacles"]:
        for check, record in (("output", o), ("tube", o["tube"])):
            lines.append(
                f"  #{o['index']:<3} {check:<7} {o['epsilon']:<6.3g} "
                f"{record['allowed_collision_probability']:<8.4g} "
                f"{record['worst_collision_frequency']:<11.5f} {record['t_worst']:<8.2f}  "
                f"{record['clopper_pearson_lower_99']:<11.5f} "
                f"{record['clopper_pearson_upper_99']:<11.5f} "
                f"{verdict_words(record['verdict'], record['runs_to_certify'])}"
            )
    return lines


def randomisation_lines(summary: dict[str, Any]) -> list[str]:
    """The printed lines of a randomisation summary: the draws, each guarantee, reaching
    and stalling, t_c and the failing draws."""
    lines = [
        f"  simulated {summary['simulated_runs']}, rejected draws {summary['rejected_draws']}, "
        f"errors {summary['error_runs']}, failed {summary['failed_runs']}"
    ]
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
    t_c = summary["t_tube_in_target"]
    if t_c["median"] is not None:
        lines.append(
            f"  tube inside the target set at t_c: median {t_c['median']:.2f} s, 5-95 % "
            f"[{t_c['p05']:.2f}, {t_c['p95']:.2f}] s, max {t_c['max']:.2f} s"
        )
    for failure in summary["failures"]:
        lines.append(
            f"  failing draw: run {failure['run']} seed {failure['seed']} → {failure['yaml']}"
        )
    return lines
