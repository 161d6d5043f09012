"""`stt-drake compare --draws K`: every controller on the same K randomised draws of a
scenario with a ``random_obstacles`` section — compared on *arriving*, not on one layout.

Draw i loads the scenario with the seed ``SeedSequence(seed, spawn_key=(i,))``
(:func:`stt_drake.campaign.run_seed`, as a randomisation campaign does), so every
controller meets the same obstacles; a draw that breaks the paper's assumptions is
rejected for all. Controllers: ``stt`` (the paper's reactive tube: the file's guide
section dropped), ``stt-guided`` (the tube under the guide: the file's section, or the
defaults of :class:`~stt_drake.config.GuideConfig` when it has none), ``cbf`` and ``apf``
(:mod:`stt_drake.compare`).

A draw's record (``draws.jsonl``, one line each): `controller`, `draw`, `seed`, `status`
(``simulated`` or ``rejected``) and, simulated: `reached` (the run ended normally and the
output reached the target set and stayed, :func:`stt_drake.compare.output_reach_time`),
`stalled` (not reached and a stall lasting to the end: the rule of
:mod:`stt_drake.core.progress` on the logged centre — the output for a baseline — and
attraction point), `unsafe` (at some logged time the belief's exact probability that the
output collides with obstacle j exceeds 1 − ε_j: the PrT-RAS task broken, Definition 2.3),
`t_reach_s`, `path_length_m`, `min_clearance_m` (min of ‖y − μ_j‖ − r_o_j), `step_us`.

A row of ``comparison.json`` (:data:`DRAW_ROW_KEYS`) per controller, over its simulated
draws: `success_rate` (reached), `stall_rate`, `timeout_rate` (neither reached nor
stalled: still moving at the end, or stopped), `unsafe_rate`, `t_reach_p50_s` /
`t_reach_p90_s` over the reached draws, `path_length_mean_m`, `min_clearance_m` (the
smallest over draws) and `step_us_median`.
"""

from __future__ import annotations

import multiprocessing
import statistics
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from stt_drake.compare import (
    CompareError,
    markdown_table,
    min_clearance,
    output_reach_time,
    simulate_baseline,
    simulate_stt,
)

#: The controllers a draws comparison knows, in table order.
DRAW_CONTROLLERS = ("stt", "stt-guided", "cbf", "apf")
#: The keys of every row of a draws comparison.json.
DRAW_ROW_KEYS = (
    "controller",
    "draws",
    "success_rate",
    "stall_rate",
    "timeout_rate",
    "unsafe_rate",
    "t_reach_p50_s",
    "t_reach_p90_s",
    "path_length_mean_m",
    "min_clearance_m",
    "step_us_median",
)
DRAWS_FILE = "draws.jsonl"


def draw_record(
    text: str, name: str, controller: str, draw: int, seed: int, solver: str = "osqp"
) -> dict[str, Any]:
    """Simulate `controller` on draw `draw` (scenario seed `seed`); the record of the
    module docstring."""
    from stt_drake.build import prepare_scenario
    from stt_drake.build.guide import stall_rule
    from stt_drake.campaign import ClosedLoop
    from stt_drake.config import AssumptionError, GuideConfig, parse_schema
    from stt_drake.core.progress import find_stalls

    record: dict[str, Any] = {"controller": controller, "draw": draw, "seed": seed}
    schema = parse_schema(text, name, guide=controller == "stt-guided")
    if controller == "stt-guided" and schema.guide is None:
        schema.guide = GuideConfig()
    try:
        scenario = prepare_scenario(schema, seed)
    except AssumptionError as error:
        return {**record, "status": "rejected", "reason": str(error)}
    if controller.startswith("stt"):
        run = simulate_stt(scenario)
    else:
        run = simulate_baseline(scenario, controller, solver)
    log = run.log
    t_reach = output_reach_time(log.t, log.output, log.target, log.target_set_radius)
    reached = run.finished and t_reach is not None
    stalls = find_stalls(
        log.t, log.center, log.attraction_point, stall_rule(scenario), log.target_set_radius
    )
    collision = ClosedLoop.from_log(log).collision_probability()["output"]
    unsafe = bool(np.any(collision > 1.0 - log.epsilon + 1e-9))
    steps = np.linalg.norm(np.diff(log.output, axis=0), axis=1)
    return {
        **record,
        "status": "simulated",
        "reached": reached,
        "stalled": not reached and bool(stalls) and stalls[-1]["end_s"] is None,
        "unsafe": unsafe,
        "t_reach_s": t_reach if reached else None,
        "path_length_m": float(steps.sum()),
        "min_clearance_m": min_clearance(log),
        "step_us": run.step_us,
    }


def _task(arguments: tuple[str, str, str, int, int, str]) -> dict[str, Any]:
    return draw_record(*arguments)


def draw_row(controller: str, records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The row of one controller over its simulated draws (module docstring)."""
    simulated = [r for r in records if r["status"] == "simulated"]
    count = len(simulated)

    def rate(key: str) -> float | None:
        return sum(r[key] for r in simulated) / count if count else None

    times = [r["t_reach_s"] for r in simulated if r["reached"]]
    timeout = sum(not r["reached"] and not r["stalled"] for r in simulated)
    return {
        "controller": controller,
        "draws": count,
        "success_rate": rate("reached"),
        "stall_rate": rate("stalled"),
        "timeout_rate": timeout / count if count else None,
        "unsafe_rate": rate("unsafe"),
        "t_reach_p50_s": float(np.percentile(times, 50)) if times else None,
        "t_reach_p90_s": float(np.percentile(times, 90)) if times else None,
        "path_length_mean_m": statistics.fmean(r["path_length_m"] for r in simulated)
        if count
        else None,
        "min_clearance_m": min((r["min_clearance_m"] for r in simulated), default=None),
        "step_us_median": statistics.median(r["step_us"] for r in simulated) if count else None,
    }


def compare_draws(
    scenario_path: str | Path,
    controllers: Sequence[str],
    draws: int,
    out_dir: Path,
    seed: int = 0,
    workers: int | None = None,
    solver: str = "osqp",
) -> dict[str, Any]:
    """Run every controller on `draws` draws (module docstring) on `workers` local
    processes; write ``draws.jsonl``, ``comparison.json`` and ``comparison.md`` into
    `out_dir`; return the comparison.json document.

    Raises:
        CompareError: bad input (an option, the scenario without a random field), before
            any simulation.
    """
    from stt_drake.campaign import run_seed
    from stt_drake.campaign.backends import default_workers
    from stt_drake.config import ScenarioError, has_random_field, parse_schema, read_scenario_file
    from stt_drake.runlog import strict_json, unwritable_reason, write_json

    path = Path(scenario_path)
    unknown = [c for c in controllers if c not in DRAW_CONTROLLERS]
    if not controllers or unknown or len(set(controllers)) != len(controllers):
        raise CompareError(
            f"--controllers: each once, and each one of {', '.join(DRAW_CONTROLLERS)} (got "
            f"{', '.join(controllers) or 'none'})"
        )
    if draws < 1:
        raise CompareError(f"--draws: must be ≥ 1 (got {draws})")
    if workers is not None and workers < 1:
        raise CompareError(f"--workers: must be ≥ 1 (got {workers})")
    try:
        text = read_scenario_file(path)
        schema = parse_schema(text, path.stem)
    except ScenarioError as error:
        raise CompareError(f"SCENARIO: bad scenario {path}: {error}") from None
    if not has_random_field(schema.random_obstacles):
        raise CompareError(
            "--draws: the scenario needs a random_obstacles section (count > 0 or a "
            "count_range) to draw from"
        )
    reason = unwritable_reason(out_dir)
    if reason is not None:
        raise CompareError(f"--out: {out_dir} {reason}")
    out_dir.mkdir(parents=True, exist_ok=True)
    ordered = [c for c in DRAW_CONTROLLERS if c in controllers]
    tasks = [
        (text, schema.name, controller, i, run_seed(seed, i), solver)
        for i in range(draws)
        for controller in ordered
    ]
    context = multiprocessing.get_context("forkserver")
    with ProcessPoolExecutor(workers or default_workers(), mp_context=context) as pool:
        records = list(pool.map(_task, tasks))
    with (out_dir / DRAWS_FILE).open("w") as stream:
        for record in records:
            stream.write(strict_json(record) + "\n")
    rows = [draw_row(c, [r for r in records if r["controller"] == c]) for c in ordered]
    document = {
        "scenario": schema.name,
        "scenario_path": str(path),
        "mode": "draws",
        "draws": draws,
        "seed": seed,
        "rejected_draws": sum(r["status"] == "rejected" for r in records) // len(ordered),
        "controllers": ordered,
        "rows": rows,
    }
    write_json(out_dir / "comparison.json", document)
    (out_dir / "comparison.md").write_text(draws_table(rows) + "\n")
    return document


#: The draws table's columns: (header, row key).
_COLUMNS = (
    ("controller", "controller"),
    ("draws", "draws"),
    ("success", "success_rate"),
    ("stall", "stall_rate"),
    ("timeout", "timeout_rate"),
    ("unsafe", "unsafe_rate"),
    ("t_reach p50 (s)", "t_reach_p50_s"),
    ("t_reach p90 (s)", "t_reach_p90_s"),
    ("path (m, mean)", "path_length_mean_m"),
    ("min clearance (m)", "min_clearance_m"),
    ("step (µs)", "step_us_median"),
)


def draws_table(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as a markdown table (comparison.md, and what the command prints)."""
    return markdown_table(rows, _COLUMNS)
